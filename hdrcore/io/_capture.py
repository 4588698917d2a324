"""What the decoders say while they read a file, kept off the terminal and tied to that file.

* :func:`reading` marks the file this thread is reading, so whoever shows a Python warning or a
  library's log record (the command line does) can say which file it is about
  (:func:`file_being_read`).
* :func:`c_stderr` captures what C code writes to file descriptor 2 (LibRaw's ``fprintf(stderr,
  "%s: Unexpected end of file\\n", name)``, which no Python setting reaches). Frames are decoded
  two at a time in threads, and a descriptor belongs to the whole process, so there is one
  redirection, reference-counted under a lock: the first reader points descriptor 2 at a
  temporary file, the last one points it back. Each line that starts with a file's name goes to
  the reader of that file; any other line (someone else's output during the window) is passed
  on to the real stderr unchanged.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

__all__ = ["reading", "file_being_read", "c_stderr"]

_local = threading.local()


@contextlib.contextmanager
def reading(path: str | os.PathLike) -> Iterator[None]:
    """This thread reads ``path`` inside the block (nested blocks: the innermost counts)."""
    stack = getattr(_local, "stack", None)
    if stack is None:
        stack = _local.stack = []
    stack.append(str(path))
    try:
        yield
    finally:
        stack.pop()


def file_being_read() -> str | None:
    """The file this thread is reading (as given to :func:`reading`), or ``None``."""
    stack = getattr(_local, "stack", None)
    return stack[-1] if stack else None


class _Fd2Capture:
    """One process-wide redirection of descriptor 2, shared by every reader that needs it."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._users: dict[str, int] = {}
        self._lines: dict[str, list[str]] = {}
        self._saved: int | None = None
        self._tmp: int | None = None
        self._read = 0

    def enter(self, name: str) -> bool:
        with self._lock:
            if self._saved is None:
                try:
                    sys.stderr.flush()
                except (AttributeError, OSError, ValueError):
                    pass
                try:
                    fd, tmp = tempfile.mkstemp(prefix="hdrcore-stderr-")
                except OSError:
                    return False
                os.unlink(tmp)
                try:
                    saved = os.dup(2)
                    os.dup2(fd, 2)
                except OSError:  # no descriptor 2 (a daemon): nothing to capture
                    os.close(fd)
                    return False
                self._saved, self._tmp, self._read = saved, fd, 0
            self._users[name] = self._users.get(name, 0) + 1
            self._lines.setdefault(name, [])
            return True

    def leave(self, name: str) -> list[str]:
        with self._lock:
            self._collect(final=False)
            lines = self._lines.pop(name, [])
            self._users[name] -= 1
            if self._users[name]:
                self._lines[name] = []
            else:
                del self._users[name]
            if not self._users and self._saved is not None and self._tmp is not None:
                try:
                    sys.stderr.flush()
                except (AttributeError, OSError, ValueError):
                    pass
                os.dup2(self._saved, 2)
                self._collect(final=True)
                os.close(self._saved)
                os.close(self._tmp)
                self._saved = self._tmp = None
            return lines

    def _collect(self, final: bool) -> None:
        """Hand out the complete lines written since the last call (``final``: all of it)."""
        assert self._tmp is not None and self._saved is not None
        size = os.fstat(self._tmp).st_size
        # pread: the descriptor shares its offset with descriptor 2, which must stay at the end.
        data = os.pread(self._tmp, size - self._read, self._read) if size > self._read else b""
        end = len(data) if final else data.rfind(b"\n") + 1
        self._read += end
        names = sorted(self._users, key=len, reverse=True)
        passed = []
        for raw in data[:end].splitlines(keepends=True):
            line = raw.decode("utf-8", "replace").rstrip("\r\n")
            owner = next((n for n in names if line.startswith(n + ":")), None)
            if owner is not None:
                text = line[len(owner) + 1 :].strip()
                if text and text not in self._lines[owner]:
                    self._lines[owner].append(text)
            elif line.strip():
                passed.append(raw if raw.endswith(b"\n") else raw + b"\n")
        if passed:
            with contextlib.suppress(OSError):
                os.write(self._saved, b"".join(passed))


_FD2 = _Fd2Capture()


@contextlib.contextmanager
def c_stderr(path: str | Path) -> Iterator[list[str]]:
    """Capture C-level output about ``path`` (lines ``"<path>: <text>"``) inside the block.

    Yields a list that holds, once the block ends, the texts of those lines (name removed,
    repeated lines once); it stays empty when descriptor 2 cannot be redirected.
    """
    name = str(path)
    lines: list[str] = []
    captured = _FD2.enter(name)
    try:
        yield lines
    finally:
        if captured:
            lines.extend(_FD2.leave(name))
