"""The ``hdrcore`` command: thin subcommands that print JSON built from the result objects.

Each subcommand lives in its own module ``hdrcore/cli/<name>.py`` with ``add_parser(subparsers)``
and ``run(args) -> int``. Errors of the project's own types and usage errors print one line and
exit with 2; no traceback unless ``--debug``. What the libraries say on the way (Python warnings,
log records) is said once in the program's words, or not at all (:mod:`hdrcore.cli._chatter`).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import signal
import sys
from collections.abc import Sequence
from typing import NoReturn

from .. import __version__
from ..errors import HdrError
from ._chatter import library_chatter

__all__ = ["main", "build_parser"]

SUBCOMMANDS = ("info", "simulate", "ratios", "response", "align", "merge", "batch")


def _modules(names: Sequence[str] = SUBCOMMANDS) -> list:
    mods = []
    for name in names:
        full = f"{__name__}.{name}"
        if importlib.util.find_spec(full) is not None:
            mods.append(importlib.import_module(full))
    return mods


class _Parser(argparse.ArgumentParser):
    """Usage errors on one line, like every other error: ``hdrcore merge: error: ... (see
    'hdrcore merge --help')``, exit 2 (argparse prints the whole usage first)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def _named_command(argv: Sequence[str]) -> str | None:
    """The subcommand ``argv`` names before any other word (options first allowed), or None."""
    for word in argv:
        if word == "--":
            return None
        if not word.startswith("-"):
            return word if word in SUBCOMMANDS else None
    return None


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The whole parser; given ``argv`` that names a subcommand, only that subcommand's module
    is imported (``hdrcore merge`` does not load the simulator's or the batch runner's
    modules: 0.5 s of a 24 MP merge's start)."""
    parser = _Parser(
        prog="hdrcore",
        description="Exposure brackets to HDR (Cerman & Hlavac 2006): ratios from histograms, "
        "response recovery, hand-held registration, merge.",
    )
    parser.add_argument("--version", action="version", version=f"hdrcore {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks and debug logs")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    named = None if argv is None else _named_command(argv)
    for mod in _modules(SUBCOMMANDS if named is None else (named,)):
        mod.add_parser(sub)
    return parser


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP reached the program: unwound like Ctrl-C, so every temporary output
    file is removed (:func:`hdrcore.io.atomic.atomic_write` cleans up on any exception)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def _on_signal(signum: int, _frame: object) -> None:
    raise Terminated(signum)


def catch_termination() -> None:
    """Turn SIGTERM and SIGHUP into :class:`Terminated` in the main thread (the program only:
    a library caller keeps its own handlers)."""
    for name in ("SIGTERM", "SIGHUP"):
        sig = getattr(signal, name, None)
        if sig is not None:
            signal.signal(sig, _on_signal)


def main(argv: Sequence[str] | None = None) -> int:
    if argv is None:  # run as the program (not called from Python): see hdrcore._memory
        from .._memory import retain_freed_memory

        retain_freed_memory()
        catch_termination()
    parser = build_parser(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    try:
        with library_chatter(debug=args.debug):
            return int(args.run(args) or 0)
    except HdrError as exc:
        if args.debug:
            raise
        print(f"hdrcore: error: {exc}", file=sys.stderr)
        return 2
    except Terminated as exc:
        print(
            f"hdrcore: terminated (signal {exc.signum}); no partial output was left",
            file=sys.stderr,
        )
        return 128 + exc.signum
    except KeyboardInterrupt:
        print("hdrcore: interrupted", file=sys.stderr)
        return 130
    except MemoryError:
        print("hdrcore: error: out of memory (try smaller frames)", file=sys.stderr)
        return 3
    except Exception as exc:  # last resort: one line, never a bare traceback
        if args.debug:
            raise
        print(
            f"hdrcore: internal error: {type(exc).__name__}: {exc} (run with --debug for details)",
            file=sys.stderr,
        )
        return 3


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
