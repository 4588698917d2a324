"""What the libraries print while the program runs, said once in the program's words.

Pillow, colour-science and NumPy speak through Python warnings, tifffile and ExifRead through
logging; both reach the terminal only through :func:`library_chatter`, which the program
installs around a subcommand (never at import: a library caller keeps its own settings). Each
becomes one line, ``hdrcore: warning: <file>: <what it means>``, naming the file being read when
it was said (:func:`hdrcore.io._capture.file_being_read`), once; or nothing, where it says
nothing a user can act on (floating-point chatter, deprecations, Pillow's decompression-bomb
warning: our own pixel limit, read from the header first, is the one that counts). What is said
about the files while a bracket loads is held back (:func:`holding_file_warnings`): when the
load fails, the error is the one line printed. LibRaw's C-level output is caught in
:mod:`hdrcore.io.raw` itself.
"""

from __future__ import annotations

import contextlib
import logging
import re
import sys
import threading
import warnings
from collections.abc import Iterator

from ..io._capture import file_being_read

__all__ = ["library_chatter", "holding_file_warnings", "warning_words", "log_words"]

_EXIF_WORDS = re.compile(r"exif|truncated file read|makernote", re.IGNORECASE)


def _first_line(text: object) -> str:
    lines = str(text).strip().splitlines()
    return " ".join(lines[0].split()) if lines else ""


def warning_words(message: object, category: type[Warning], filename: str) -> str | None:
    """A Python warning in the program's words, or ``None`` to say nothing."""
    name = category.__name__
    module = category.__module__ or ""
    source = str(filename).replace("\\", "/")
    text = _first_line(message) or name
    if name == "DecompressionBombWarning":
        return None
    if issubclass(category, (DeprecationWarning, PendingDeprecationWarning, FutureWarning)):
        return None  # for the developers, not the user
    if module.startswith("PIL") or "/PIL/" in source:
        if _EXIF_WORDS.search(text):
            return (
                f"its EXIF metadata is damaged (Pillow: {text}); its exposure time, ISO or "
                "orientation may be missing"
            )
        return f"Pillow: {text}"
    if module.startswith("colour"):
        if name == "ColourUsageWarning":
            return None  # about how hdrcore calls colour-science, not about the input
        return f"colour-science: {text}"
    if issubclass(category, RuntimeWarning) and (
        "/numpy/" in source or "/hdrcore/" in source or "/scipy/" in source
    ):
        return None  # invalid values, division by zero: handled by the code that raised them
    return f"{text} ({name})"


def log_words(record: logging.LogRecord) -> str | None:
    """A library's log record in the program's words, or ``None`` to say nothing."""
    if record.levelno < logging.WARNING:
        return None
    text = _first_line(record.getMessage())
    library = record.name.split(".", 1)[0]
    if library == "tifffile":
        return f"its TIFF structure is damaged (tifffile: {text})"
    if library == "exifread":
        return f"its EXIF metadata is damaged (ExifRead: {text})"
    return f"{library}: {text}"


class _Sayer:
    """Prints each warning line once; holds back the lines about files while asked to."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._seen: set[str] = set()
        self._held: list[str] | None = None

    def say(self, text: str, file: str | None) -> None:
        line = f"hdrcore: warning: {file}: {text}" if file else f"hdrcore: warning: {text}"
        with self._lock:
            if line in self._seen:
                return
            self._seen.add(line)
            if file is not None and self._held is not None:
                self._held.append(line)
                return
        print(line, file=sys.stderr, flush=True)

    @contextlib.contextmanager
    def holding(self) -> Iterator[None]:
        with self._lock:
            self._held = []
        try:
            yield
        except BaseException:
            with self._lock:
                self._held = None  # the error that ends the program says what matters
            raise
        with self._lock:
            held, self._held = self._held or [], None
        for line in held:
            print(line, file=sys.stderr, flush=True)


class _Handler(logging.Handler):
    """hdrcore's own records as ``hdrcore: <level>: <message>``; libraries' through the sayer."""

    def __init__(self, sayer: _Sayer, debug: bool) -> None:
        super().__init__(logging.DEBUG if debug else logging.WARNING)
        self.sayer = sayer
        self.debug = debug

    def emit(self, record: logging.LogRecord) -> None:
        try:
            own = record.name == "hdrcore" or record.name.startswith("hdrcore.")
            if own or self.debug:
                where = "" if own else f"{record.name}: "
                print(
                    f"hdrcore: {record.levelname.lower()}: {where}{record.getMessage()}",
                    file=sys.stderr,
                    flush=True,
                )
                return
            words = log_words(record)
            if words is not None:
                self.sayer.say(words, file_being_read())
        except Exception:  # a handler never raises
            self.handleError(record)


_active: _Sayer | None = None


@contextlib.contextmanager
def library_chatter(debug: bool = False) -> Iterator[None]:
    """Inside the block, library warnings and log records reach stderr in the program's words
    (``debug``: log records at every level, Python warnings as Python shows them)."""
    global _active
    sayer = _Sayer()
    root = logging.getLogger()
    handler = _Handler(sayer, debug)
    old_level = root.level
    root.addHandler(handler)
    root.setLevel(logging.DEBUG if debug else logging.WARNING)
    previous, _active = _active, sayer
    try:
        with warnings.catch_warnings():
            if not debug:
                warnings.simplefilter("always")  # each is said once, by the sayer

                def show(message, category, filename, lineno, file=None, line=None) -> None:
                    words = warning_words(message, category, filename)
                    if words is None:
                        logging.getLogger(__name__).debug(
                            "silenced %s: %s (%s:%s)", category.__name__, message, filename, lineno
                        )
                        return
                    sayer.say(words, file_being_read())

                warnings.showwarning = show
            yield
    finally:
        _active = previous
        root.removeHandler(handler)
        root.setLevel(old_level)


@contextlib.contextmanager
def holding_file_warnings() -> Iterator[None]:
    """Hold back what is said about files inside the block until it ends without an error;
    with an error, drop it (the error is the line that counts)."""
    sayer = _active
    if sayer is None:
        yield
        return
    with sayer.holding():
        yield
