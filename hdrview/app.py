"""The ``hdrview`` browser inspector: open a bracket, see every intermediate result, tune it live.

:class:`InspectorApp` is the server: the access guard (:mod:`hdrview.guard`), the one path
resolver (:mod:`hdrview.security`), the upload limits and temporary folder
(:mod:`hdrview.uploads`) and the decoded brackets shared by all pages
(:mod:`hdrview.cache`). Every page that connects gets its own :class:`~hdrview.view.ClientView`
(its own bracket, parameters, pipeline, uploads and notifications), built on its own GUI handles,
closed when it leaves. At start the bracket given on the command line (or the demo) is decoded
and run once in the background, so the first page shows its result at once and the terminal
says when the inspector is ready.
"""

from __future__ import annotations

import argparse
import logging
import os
import shutil
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import viser

from hdrcore.cli._common import parse_workers
from hdrcore.errors import HdrError

from . import security
from .cache import BracketCache
from .guard import ConnectionGuard, install_guard
from .session import Session, pipeline_available
from .uploads import UploadLimits, make_work_dir, remove_stale_work_dirs
from .view import PANEL_WIDTH, ClientView

if TYPE_CHECKING:  # imported on first use (slow: numba), not with the page
    from hdrcore.pipeline import PipelineParams

__all__ = ["InspectorApp", "main", "build_parser", "create_app", "DEMO_DIR", "PANEL_WIDTH"]

log = logging.getLogger(__name__)

DEMO_DIR = Path(__file__).resolve().parents[1] / "assets" / "demo"


#: Inspectors started in this process and not yet stopped (see :func:`main`).
_LIVE: set[InspectorApp] = set()


class InspectorApp:
    """The server-wide state; one :class:`ClientView` per connected page in ``views``."""

    def __init__(
        self,
        server: viser.ViserServer,
        *,
        root: str | Path = ".",
        demo_dir: str | Path | None = DEMO_DIR,
        files: Sequence[str | Path] = (),
        limits: UploadLimits | None = None,
        batch: Sequence[Any] = (),
        workers: int | None = None,
    ) -> None:
        """``files``: paths the operator named on the command line (readable even outside
        ``root``; every page opens them first, else the demo); ``limits``: the upload limits;
        ``workers``: ``PipelineParams.workers`` of every page's runs."""
        self.server = server
        self.workers = workers
        self.guard: ConnectionGuard | None = None  # set by create_app
        self.url = f"http://127.0.0.1:{server.get_port()}/"
        self.demo_dir = None if demo_dir is None else Path(demo_dir)
        self.limits = limits or UploadLimits()
        # One private temporary folder: upload sets and export files; removed by stop().
        self.work_dir = make_work_dir()
        _LIVE.add(self)  # stopped by main() even when a signal comes before it holds the app
        # Every path the inspector reads is checked by this one resolver.
        # ``batch``: an hdrcore batch's brackets, worst first (hdrview.batch); their frames may
        # be opened like the files named on the command line, the worst first.
        self.batch = list(batch)
        batch_files = [f for r in self.batch for f in r.files]
        self.resolver = security.RootResolver(root, files=[*files, *batch_files])
        if self.demo_dir is not None and self.demo_dir.is_dir():
            self.resolver.allow_folder(self.demo_dir)
        self.root = self.resolver.root
        # Relative to the folder the inspector was started in (not to --root).
        self.files = [Path(f).absolute() for f in files]
        self.brackets = BracketCache()
        self._defaults: Any = None  # the pipeline's parameters, imported on first use
        self._defaults_lock = threading.Lock()
        self.first_run = True  # no pipeline has run in this process yet (kernels compile)
        self.views: dict[int, ClientView] = {}
        self._lock = threading.Lock()
        self._pages = 0
        self._warm: tuple[tuple, threading.Thread, list] | None = None
        # Pages whose controls are being built: the start-up run waits for them (see warm_up).
        self._building = 0
        self._built = threading.Condition()
        self._stopped = False
        self.ready_seconds: float | None = None
        server.on_client_connect(self._on_connect)
        server.on_client_disconnect(self._on_disconnect)

    @property
    def defaults(self) -> PipelineParams:
        """The pipeline's default parameters (``hdrcore.pipeline`` is imported on first use:
        at start the start-up run's thread imports it while the browser loads the page)."""
        if self._defaults is None:
            with self._defaults_lock:
                if self._defaults is None:
                    self._defaults = _default_params()
        return self._defaults

    def next_page_number(self) -> int:
        with self._lock:
            self._pages += 1
            return self._pages

    # -- pages -----------------------------------------------------------------------------

    def default_paths(self) -> tuple[list[Path], str] | None:
        if self.batch and not self.files:
            return [Path(f) for f in self.batch[0].files], self.batch[0].name
        if self.files:
            label = self.files[0].name if len(self.files) == 1 else f"{len(self.files)} files"
            return list(self.files), label
        if self.demo_dir is not None and self.demo_dir.is_dir():
            return [self.demo_dir], "demo"
        return None

    def _on_connect(self, client: viser.ClientHandle) -> None:
        with self._built:
            self._building += 1
        try:
            view = ClientView(self, client.gui, client)
        finally:
            with self._built:
                self._building -= 1
                self._built.notify_all()
        with self._lock:
            self.views[client.client_id] = view
        if self.batch:
            from .batch import add_batch_panel

            add_batch_panel(view, self.batch)
        self._open_default(view)

    def _on_disconnect(self, client: viser.ClientHandle) -> None:
        with self._lock:
            view = self.views.pop(client.client_id, None)
        if view is not None:
            view.close()

    def _open_default(self, view: ClientView) -> None:
        default = self.default_paths()
        if default is None:
            view.notify(
                "No demo bracket",
                f"the demo bracket is not installed at {self.demo_dir}",
                level="warning",
            )
            return
        paths, label = default
        view.request_paths(paths, label)

    def headless_view(self) -> ClientView:
        """A view without a page, on the server's shared GUI (tests and the bench)."""
        view = ClientView(self, self.server.gui, None)
        with self._lock:
            self.views[-1 - len(self.views)] = view
        return view

    def page_views(self) -> list[ClientView]:
        with self._lock:
            return [v for v in self.views.values() if v.client is not None]

    # -- the warm start ---------------------------------------------------------------------

    def _after_pages_built(self, *_: object, limit: float = 2.0) -> None:
        """Wait (``limit`` seconds at most) while a page's controls are being built. The
        start-up run calls it before it starts and between its stages (as its progress
        callback): building a page is 0.05 s of Python alone but took 0.4-0.9 s beside the
        run's stages (the GIL), and the page shows nothing until it is done."""
        deadline = time.perf_counter() + limit
        with self._built:
            while self._building and not self._stopped:
                left = deadline - time.perf_counter()
                if left <= 0:
                    break
                self._built.wait(left)

    def warm_up(self, *, announce: bool = False) -> None:
        """Decode the default bracket and run the pipeline once in the background; the first
        page that opens it takes this session over (its result is then drawn at once).

        First of all, on the same thread, what the first page's build waits for
        (:func:`hdrview.view.prepare_page_controls`: the library's registries, 0.6-1.3 s of
        imports), while the browser evaluates the page's script; then the frames; then what the
        page shows after them (:func:`hdrview.view.prepare_page_extras`: plotly's figure
        classes and viser's icons, 0.25 s, which the page's build no longer waits for); then
        the pipeline's run. Made beside the decode, both ended later (the GIL) and the page was
        built behind them. Measured (``bench_hdrview.py``'s first page, 6 alternating starts
        each, 2026-12-07): page ready median 3.17 -> 2.83 s, result drawn 4.13 -> 3.97 s; the
        extras after the frames: see the README."""
        default = self.default_paths()
        inputs = None
        if default is not None:
            try:
                inputs = self.resolver.bracket_inputs(default[0])
            except HdrError:
                pass  # the page will say why when it opens them
        if default is None or inputs is None:
            threading.Thread(
                target=_prepare_first_page, name="hdrview-imports", daemon=True
            ).start()
            return
        label = default[1]
        key = (
            tuple(str(p) for p in inputs.files),
            None if inputs.times is None else str(inputs.times),
        )
        box: list = []
        t0 = time.perf_counter()

        def run() -> None:
            _prepare_first_page("controls")
            session = Session(workers=self.workers)
            try:
                # Then the frames (the page draws them from the shared cache as soon as they
                # are decoded), what the page shows after them (plotly, the buttons' icons),
                # then the pipeline's run.
                session.load(
                    list(inputs.files), source=label, times=inputs.times, loader=self.brackets.get
                )
                _prepare_first_page("extras")
                if not pipeline_available():  # imports it, off the thread that serves pages
                    return
                _ = self.defaults
                from .session import Controls

                self._after_pages_built()
                session.run(Controls(), progress=self._after_pages_built)
                self.first_run = False
                box.append(session)
            except Exception:  # noqa: BLE001 -- the page reports it when it loads
                log.debug("warm-up failed", exc_info=True)
            self.ready_seconds = time.perf_counter() - t0
            if announce and not self._stopped:
                print(
                    f"hdrview: ready ({label} processed in {self.ready_seconds:.1f} s)",
                    file=sys.stderr,
                    flush=True,
                )

        thread = threading.Thread(target=run, name="hdrview-warm-up", daemon=True)
        self._warm = (key, thread, box)
        thread.start()

    def warm_pending(self, files: Sequence[str], times: str | None) -> bool:
        """Whether the start-up run of these inputs is still going."""
        with self._lock:
            warm = self._warm
        return warm is not None and warm[0] == (tuple(files), times) and warm[1].is_alive()

    def take_warm(self, files: Sequence[str], times: str | None) -> Session | None:
        """The warmed-up session for these inputs (waiting for it to finish), once."""
        with self._lock:
            warm = self._warm
            if warm is None or warm[0] != (tuple(files), times):
                return None
            self._warm = None
        warm[1].join()
        return warm[2][0] if warm[2] else None

    def stop(self) -> None:
        """Close every page and remove the temporary folder (uploads, exports)."""
        self._stopped = True
        with self._lock:
            views = list(self.views.values())
            self.views.clear()
        for v in views:
            v.close()
        for _ in range(5):  # a page's thread may still be finishing a write in it
            shutil.rmtree(self.work_dir, ignore_errors=True)
            if not self.work_dir.exists():
                break
            time.sleep(0.1)
        _LIVE.discard(self)


def _prepare_first_page(part: str = "all") -> None:
    """:func:`hdrview.view.prepare_first_page` (``"all"``), or its ``"controls"`` or
    ``"extras"`` part."""
    from . import view

    make = {
        "all": view.prepare_first_page,
        "controls": view.prepare_page_controls,
        "extras": view.prepare_page_extras,
    }[part]
    try:
        make()
    except Exception:  # noqa: BLE001 -- the page reports a broken install when it opens
        log.debug("preparing the first page failed", exc_info=True)


def _default_params() -> PipelineParams:
    from hdrcore.pipeline import PipelineParams

    return PipelineParams()


LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1", "[::1]")


class StartError(Exception):
    """The inspector cannot start as asked (one line for the user, exit 2)."""


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="hdrview",
        description="Browser inspector for exposure brackets: ratios from histograms, masks, "
        "registration and the merged result, with live parameters.",
    )
    p.add_argument(
        "files",
        nargs="*",
        metavar="FILE|DIR",
        help="frames of one bracket or a folder (default: the demo bracket)",
    )
    p.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to listen on (default 127.0.0.1: this machine only; any other "
        "address needs --allow-remote)",
    )
    p.add_argument(
        "--allow-remote",
        action="store_true",
        help="allow --host to be an address other machines can reach (prefer SSH "
        "port forwarding, see the README)",
    )
    p.add_argument(
        "--port",
        type=int,
        default=8080,
        help="port (default 8080; a busy port is an error; 0 picks a free one)",
    )
    p.add_argument(
        "--root",
        default=".",
        help="the page may only open paths under this folder (default: current folder)",
    )
    p.add_argument(
        "--allow-origin",
        action="append",
        default=[],
        metavar="URL",
        help="also accept pages from this origin (e.g. https://proxy.example:443); "
        "by default only the inspector's own address may use it",
    )
    p.add_argument(
        "--no-token",
        action="store_true",
        help="do not require the access token printed at start (any local program "
        "and any page of an allowed origin can then use the inspector)",
    )
    d = UploadLimits()
    p.add_argument(
        "--max-upload-mb",
        type=float,
        default=d.file_bytes / 1e6,
        metavar="MB",
        help=f"largest uploaded file (default {d.file_bytes / 1e6:g}; 0: no limit)",
    )
    p.add_argument(
        "--max-upload-total-mb",
        type=float,
        default=d.total_bytes / 1e6,
        metavar="MB",
        help=f"largest upload set, a zip once extracted (default "
        f"{d.total_bytes / 1e6:g}; 0: no limit)",
    )
    p.add_argument(
        "--max-upload-pixels",
        type=float,
        default=float(d.frame_pixels),
        metavar="N",
        help=f"largest uploaded frame in pixels, read from its header "
        f"before decoding (default {d.frame_pixels:.0e}; 0: none)",
    )
    p.add_argument(
        "--batch",
        metavar="OUTDIR",
        help="the output folder of 'hdrcore batch': list its brackets worst first "
        "and open them (the worst first)",
    )
    # PipelineParams.workers, as on every hdrcore command (tests/cli/test_params_flags.py)
    p.add_argument(
        "--workers",
        type=parse_workers,
        default=None,
        metavar="N",
        help="threads for the compiled kernels of each run, scipy's convention: -1 "
        "every core, -2 all but one (default: up to 2)",
    )
    p.add_argument("--debug", action="store_true", help="debug logging")
    return p


def _port_free(host: str, port: int) -> bool:
    import socket

    family = socket.AF_INET6 if ":" in host.strip("[]") else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host.strip("[]"), port))
        except OSError:
            return False
    return True


def create_app(
    files: Sequence[str] = (),
    *,
    host: str = "127.0.0.1",
    port: int = 8080,
    root: str = ".",
    verbose: bool = True,
    demo_dir: Path | None = DEMO_DIR,
    token: bool = True,
    allow_origins: Sequence[str] = (),
    limits: UploadLimits | None = None,
    announce: bool = False,
    batch: Sequence[Any] = (),
    workers: int | None = None,
) -> InspectorApp:
    """Start the server and the app; load ``files`` or the demo bracket.

    Only the inspector's own address (and ``allow_origins``) may use it, and with ``token`` only
    a client that brings the access token (:mod:`hdrview.guard`); ``app.url`` is the address to
    open. A busy ``port`` raises :class:`StartError` (viser itself would move to the next
    port without a word); ``port=0`` takes a free one. Each page that connects opens ``files``
    (or the demo bracket), which are decoded and processed once at start (``announce``: say
    "ready" on stderr when done).
    """
    if port and not _port_free(host, port):
        raise StartError(
            f"port {port} on {host} is in use (another hdrview?): choose another "
            f"with --port N, or --port 0 for any free port"
        )
    holder: list[viser.ViserServer] = []
    guard = ConnectionGuard(
        lambda: holder[0].get_port() if holder else port,
        bind_host=host,
        allow_origins=allow_origins,
        token="" if token else None,
    )
    with install_guard(guard):
        server = viser.ViserServer(host=host, port=port, label="hdrview", verbose=verbose)
    holder.append(server)
    if port and server.get_port() != port:  # taken between the check and the start
        server.stop()
        raise StartError(
            f"port {port} on {host} is in use: choose another with --port N, "
            f"or --port 0 for any free port"
        )
    app = InspectorApp(
        server,
        root=root,
        demo_dir=demo_dir,
        files=files,
        limits=limits,
        batch=batch,
        workers=workers,
    )
    app.guard = guard
    app.url = guard.url("127.0.0.1" if host in ("0.0.0.0", "::", "") else host)
    app.warm_up(announce=announce)
    return app


def main(argv: Sequence[str] | None = None) -> int:
    if argv is None:  # run as the program: large buffers reuse freed memory (hdrcore._memory)
        from hdrcore._memory import retain_freed_memory
        from hdrcore.cli import catch_termination

        retain_freed_memory()
        catch_termination()  # SIGTERM/SIGHUP unwind like Ctrl-C: the temporary folder goes
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.debug else logging.INFO,
        format="hdrview: %(levelname)s: %(message)s",
    )
    root = Path(args.root)
    if not root.is_dir():
        print(f"hdrview: --root {root} is not a folder", file=sys.stderr)
        return 2
    for f in args.files:
        if not Path(f).exists():
            print(f"hdrview: {f}: file or folder not found", file=sys.stderr)
            return 2
    batch: list = []
    if args.batch:
        from .batch import batch_listing, load_batch

        try:
            batch = load_batch(args.batch)
        except HdrError as exc:
            print(f"hdrview: {exc}", file=sys.stderr)
            return 2
        if not batch:
            print(f"hdrview: {args.batch}: the batch has no brackets", file=sys.stderr)
            return 2
        print(batch_listing(batch), file=sys.stderr)
    remote = args.host not in LOOPBACK_HOSTS
    if remote and not args.allow_remote:
        print(
            f"hdrview: --host {args.host} lets other machines reach the inspector and read "
            f"files under {root.resolve()}: add --allow-remote if you mean it (safer: SSH "
            f"port forwarding, see the README)",
            file=sys.stderr,
        )
        return 2
    for opt in ("max_upload_mb", "max_upload_total_mb", "max_upload_pixels"):
        if not getattr(args, opt) >= 0:
            print(f"hdrview: --{opt.replace('_', '-')} must be 0 or more", file=sys.stderr)
            return 2
    limits = UploadLimits(
        file_bytes=int(args.max_upload_mb * 1e6),
        total_bytes=int(args.max_upload_total_mb * 1e6),
        frame_pixels=int(args.max_upload_pixels),
    )
    for stale in remove_stale_work_dirs():
        log.info("removed %s, left by an inspector that was killed", stale)
    app = None
    try:
        try:
            app = create_app(
                args.files,
                host=args.host,
                port=args.port,
                root=str(root),
                token=not args.no_token,
                allow_origins=args.allow_origin,
                limits=limits,
                announce=True,
                batch=batch,
                workers=args.workers,
            )
        except (StartError, ValueError, HdrError) as exc:
            print(f"hdrview: {exc}", file=sys.stderr)
            return 2
        if remote:
            log.warning(
                "listening on %s: anyone who can reach this address and has the token "
                "can read files under %s",
                args.host,
                root.resolve(),
            )
        print(f"hdrview: open {app.url}", file=sys.stderr, flush=True)
        # Short sleeps, not viser's sleep_forever (time.sleep(3600)): a SIGTERM that the kernel
        # delivers to another thread does not interrupt the main thread's sleep, and Python
        # runs the handler only when that sleep ends (CI once waited 30 s for it).
        while True:
            time.sleep(0.2)
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM/SIGHUP (hdrcore.cli.Terminated)
        signum = getattr(exc, "signum", None)
        status = 0 if signum is None else 128 + int(signum)
    else:
        status = 0
    finally:
        # Also an app whose creation a signal interrupted before main() held it (SIGTERM right
        # after start): its temporary folder goes too.
        for live in [*([app] if app is not None else []), *(a for a in _LIVE if a is not app)]:
            live.stop()
            live.server.stop()
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError, TypeError):
                pass
    if argv is None:
        # The program ends here, its temporary folder removed: background threads (a start-up
        # run still compiling kernels) are not waited for, and the interpreter's own shutdown,
        # which they could disturb (once: exit status 120 instead of 143), is skipped.
        os._exit(status)
    return status


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
