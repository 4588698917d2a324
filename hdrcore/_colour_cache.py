"""colour-science's tables, kept in the user's cache folder between processes.

Importing colour-science takes 0.8-0.9 s on a 2-core machine (its package imports its plotting
and matplotlib), and a command or an inspector start that needs one table from it would pay that
on every run: a JPEG bracket's response recovery (the sRGB decoding is one of its candidates)
and every preview (the sRGB encoding and the luminance weights). The values do not change within
one colour-science version, so each table is computed by colour-science once and kept in the
user's cache folder (``$XDG_CACHE_HOME/hdrcore`` or ``~/.cache/hdrcore``), one file per table
and colour-science version. A missing, stale or unreadable file is computed again; a folder
that cannot be written is not an error (the table is then computed in every process).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from functools import lru_cache

import numpy as np

__all__ = ["cache_file", "cached_arrays", "clear_memory", "srgb_eotf"]

_LOCK = threading.Lock()
_MEMORY: dict[tuple[str, str | None], dict[str, np.ndarray]] = {}


@lru_cache(maxsize=1)
def _version() -> str | None:
    """colour-science's version (looked up once a process: a metadata search takes ~1 ms, and
    the preview asks for its tables on every call)."""
    try:
        from importlib.metadata import version

        return version("colour-science")
    except Exception:
        return None


def cache_file(stem: str) -> str | None:
    """The cache file of the table ``stem`` for the installed colour-science (``None`` when
    its version is unknown: nothing is kept then)."""
    ver = _version()
    if ver is None:
        return None
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "hdrcore", f"{stem}-colour-science-{ver}.npz")


def cached_arrays(
    stem: str,
    compute: Callable[[], dict[str, np.ndarray]],
    valid: Callable[[dict[str, np.ndarray]], bool],
) -> dict[str, np.ndarray]:
    """The arrays ``compute()`` makes (it imports colour-science), read from the table's cache
    file when that holds arrays ``valid`` accepts, else computed and written there (atomically;
    a failed write is ignored). Kept in memory per process and cache file: shared, not to be
    written to (left writeable: a read-only array is another type to numba's kernels, one more
    compilation)."""
    path = cache_file(stem)
    key = (stem, path)
    with _LOCK:
        hit = _MEMORY.get(key)
    if hit is not None:
        return hit
    arrays: dict[str, np.ndarray] | None = None
    if path is not None:
        try:
            with np.load(path) as z:
                arrays = {k: z[k] for k in z.files}
            if not valid(arrays):
                arrays = None
        except (OSError, KeyError, ValueError, EOFError):
            arrays = None
    if arrays is None:
        arrays = compute()
        if path is not None:
            from .errors import HdrError
            from .io.atomic import atomic_write

            data = dict(arrays)
            try:
                os.makedirs(os.path.dirname(path), exist_ok=True)
                atomic_write(path, lambda tmp: np.savez(tmp, **data), force=True)  # type: ignore[arg-type]
            except (OSError, HdrError):
                pass
    with _LOCK:
        _MEMORY[key] = arrays
    return arrays


def clear_memory() -> None:
    """Forget the tables read in this process (tests: a new cache folder, a changed file)."""
    with _LOCK:
        _MEMORY.clear()


def srgb_eotf(max_level: int) -> np.ndarray:
    """colour-science's sRGB decoding (IEC 61966-2-1 EOTF, ``colour.models.eotf_sRGB``, the
    same values as ``colour.cctf_decoding(..., function="sRGB")``) at the levels ``0 ..
    max_level`` divided by ``max_level``: float64 ``(max_level + 1,)``, shared (not to be
    written to)."""
    m = int(max_level)

    def compute() -> dict[str, np.ndarray]:
        import colour

        v = np.arange(m + 1, dtype=np.float64) / m
        return {"eotf": np.asarray(colour.models.eotf_sRGB(v), dtype=np.float64)}

    def valid(a: dict[str, np.ndarray]) -> bool:
        g = a.get("eotf")
        return (
            g is not None
            and g.shape == (m + 1,)
            and g.dtype == np.float64
            and bool(np.all(np.isfinite(g)))
        )

    return cached_arrays(f"srgb-eotf-{m}", compute, valid)["eotf"]
