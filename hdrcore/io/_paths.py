"""Why a path given as input cannot be used, in plain words (a loop of symbolic links, a broken
link, no permission), instead of an ``OSError`` or the ``RuntimeError`` ``Path.resolve`` raises."""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

from ..errors import InputError

__all__ = ["input_file", "path_problem", "resolved"]


def path_problem(path: Path, exc: OSError | RuntimeError | None = None) -> str:
    """What is wrong with ``path`` (which cannot be opened or stat-ed), as a short phrase."""
    code = getattr(exc, "errno", None)
    if code == errno.ELOOP or isinstance(exc, RuntimeError):
        return "symbolic link loop (the link leads back to itself, never to a file)"
    if code in (errno.ENOENT, None) and path.is_symlink():
        try:
            target = os.readlink(path)
        except OSError:
            target = "?"
        return f"broken symbolic link (it points to {target}, which does not exist)"
    if code == errno.ENOENT:
        return "file not found"
    if code == errno.ENOTDIR:
        return "file not found (a part of the path is not a folder)"
    if code in (errno.EACCES, errno.EPERM):
        return "permission denied"
    if code == errno.ENAMETOOLONG:
        return "file name too long"
    if isinstance(exc, OSError) and exc.strerror:
        return f"cannot read it ({exc.strerror})"
    return "cannot read it"


def input_file(path: str | os.PathLike, what: str = "file") -> Path:
    """``path`` as a :class:`Path` when it is a regular file, else :class:`InputError` saying
    why not (``what`` names it in the message: ``"exposure-times file"``)."""
    p = Path(path)
    try:
        st = p.stat()
    except OSError as exc:
        problem = path_problem(p, exc)
        if problem.startswith("file not found"):
            problem = what + problem[len("file") :]
        elif what != "file":
            problem = f"{what}: {problem}"
        raise InputError(problem, path=p) from None
    if stat.S_ISDIR(st.st_mode):
        raise InputError(f"{what} is a folder, not a regular file", path=p)
    if not stat.S_ISREG(st.st_mode):
        raise InputError(
            f"{what} is not a regular file",
            path=p,
            expected="a file (not a device, pipe or socket)",
        )
    return p


def resolved(path: Path) -> Path:
    """``path.resolve()``, with a loop of symbolic links an :class:`InputError`."""
    try:
        return path.resolve()
    except (OSError, RuntimeError) as exc:  # RuntimeError: Python < 3.13 on a symlink loop
        raise InputError(path_problem(path, exc), path=path) from None
