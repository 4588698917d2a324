"""Atomic, non-destructive output: temporary file in the target directory, then ``os.replace``.

An output is never half-written (a crash leaves the old file or nothing), an existing file is kept
unless ``force`` is given, and a path that is one of the inputs is refused even with ``force``.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path

from ..errors import OutputError

__all__ = ["atomic_write", "check_output_path", "same_file"]


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether two names reach one file: equal once resolved (``./``, ``..``, symbolic links),
    or one existing file reached by both (hard links)."""
    pa, pb = Path(a), Path(b)
    try:
        if pa.resolve() == pb.resolve():
            return True
        return pa.exists() and pb.exists() and os.path.samefile(pa, pb)
    except OSError:
        return False


def check_output_path(
    path: str | os.PathLike, *, force: bool = False, inputs: Iterable[str | os.PathLike] = ()
) -> Path:
    """Validate an output path before any work is done; return it as a ``Path``.

    Raises :class:`OutputError` if it is an input file, an existing directory, exists without
    ``force``, or its directory does not exist.
    """
    out = Path(path)
    for inp in inputs:
        if same_file(out, inp):
            raise OutputError("refusing to overwrite an input file", path=out)
    if out.is_dir():
        raise OutputError("output path is a directory", path=out, expected="a file name")
    if out.exists() and not force:
        raise OutputError("output exists; use --force to replace it", path=out)
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise OutputError("output directory does not exist", path=parent)
    return out


def atomic_write(
    path: str | os.PathLike,
    writer: Callable[[Path], object],
    *,
    force: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
) -> Path:
    """Call ``writer(tmp_path)`` to write a temporary file, then move it onto ``path``.

    The temporary file sits in the same directory (so the rename is atomic) and keeps the
    target's suffix (so libraries that choose a format by extension behave). On any error the
    temporary file is removed and the target is untouched.
    """
    out = check_output_path(path, force=force, inputs=inputs)
    parent = out.parent if str(out.parent) else Path(".")
    try:
        fd, tmp_name = tempfile.mkstemp(
            prefix=f".{out.name}.", suffix=f".tmp{out.suffix}", dir=parent
        )
    except OSError as exc:  # a read-only folder or file system, no space, ...
        raise OutputError(
            f"cannot write in the output folder ({exc.strerror or exc})", path=out
        ) from exc
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        writer(tmp)
        # mkstemp creates 0600 files; give the output the permissions a plain open() would.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        if not force and out.exists():
            raise OutputError("output appeared while writing; use --force to replace it", path=out)
        os.replace(tmp, out)
    except OSError as exc:  # the disk filled up, the folder went read-only, ...
        tmp.unlink(missing_ok=True)
        raise OutputError(f"cannot write the output ({exc.strerror or exc})", path=out) from exc
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return out
