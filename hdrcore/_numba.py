"""The project's numba decorators, in one place.

``njit``: compiled, GIL released (``nogil``, so kernels run on Python threads side by side),
cached on disk (only the first call on a machine compiles), no fast-math (results match the
numpy specifications the tests hold the kernels to), numpy's error model (division by zero
gives inf/nan, as numpy does). ``inline``: the same, inlined into its callers (a call passing
arrays would touch their reference counts per pixel). numba is a dependency: at run time only
the compiled kernels run. ``AVAILABLE`` is False only where numba cannot be imported; the
decorators then return the plain Python functions (slow, for debugging a kernel in Python).

The compiled code of hdrcore's kernels is cached in the user's cache folder,
:func:`cache_dir` (``$XDG_CACHE_HOME/hdrcore/numba``, else ``~/.cache/hdrcore/numba``), not in
``__pycache__`` beside the modules (site-packages: shared, often read-only). numba's own
``NUMBA_CACHE_DIR`` still wins when set. The choice applies to functions defined in hdrcore's
files only (one more locator in numba's list that declines every other file): numba's caching
of other libraries is unchanged. If the folder cannot be written, numba's usual places are used.
"""

from __future__ import annotations

import functools
import hashlib
import os
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent


def cache_dir() -> Path:
    """The folder hdrcore's compiled kernels are cached in (see the module's docstring)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "hdrcore" / "numba"


try:
    import numba
    from numba.core import caching as _caching

    njit = numba.njit(nogil=True, cache=True, fastmath=False, error_model="numpy")
    inline = numba.njit(
        nogil=True, cache=True, fastmath=False, error_model="numpy", inline="always"
    )
    AVAILABLE = True
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None  # type: ignore[assignment]  # no numba at run time: the names stay, set to None
    _caching = None  # type: ignore[assignment]  # (mypy checks against the installed numba)
    AVAILABLE = False

    def njit(fn):
        return fn

    inline = njit


@functools.cache
def package_digest() -> str:
    """A digest of every ``.py`` file of the package (paths and contents), made once per
    process (9 ms on this machine): part of each compiled kernel's cache stamp, so a change to any
    module (an inlined helper of another file) compiles the kernels again."""
    h = hashlib.blake2b(digest_size=16)
    for path in sorted(PACKAGE.rglob("*.py")):
        h.update(str(path.relative_to(PACKAGE)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def _in_package(py_file: str) -> bool:
    try:
        Path(py_file).resolve().relative_to(PACKAGE)
    except (ValueError, OSError):
        return False
    return True


if _caching is not None and all(
    hasattr(_caching, name)
    for name in ("_CacheLocator", "_SourceFileBackedLocatorMixin", "CacheImpl")
):

    class UserCacheLocator(_caching._SourceFileBackedLocatorMixin, _caching._CacheLocator):
        """numba cache locator: hdrcore's functions in :func:`cache_dir` (one sub-folder per
        source folder, numba's own naming, so two installs never share files)."""

        def __init__(self, py_func, py_file):
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            self._cache_path = os.path.join(
                str(cache_dir()), self.get_suitable_cache_subpath(py_file)
            )

        def get_cache_path(self):
            return self._cache_path

        def get_source_stamp(self):
            # numba checks only the function's own file; a kernel inlines helpers from other
            # modules (the merge kernel its weightings, hdrcore.merge.weights), whose change
            # left a stale kernel in the cache: every source of the package is in the stamp.
            return (super().get_source_stamp(), package_digest())

        @classmethod
        def from_function(cls, py_func, py_file):
            if os.environ.get("NUMBA_CACHE_DIR") or not _in_package(py_file):
                return None  # numba's own choice (NUMBA_CACHE_DIR), or not one of ours
            return super().from_function(py_func, py_file)

    _locators = _caching.CacheImpl._locator_classes
    if not any(getattr(c, "__name__", "") == "UserCacheLocator" for c in _locators):
        # after numba's NUMBA_CACHE_DIR locator, before its __pycache__ one
        _locators.insert(
            1
            if _locators and _locators[0] is getattr(_caching, "UserProvidedCacheLocator", None)
            else 0,
            UserCacheLocator,
        )

__all__ = ["AVAILABLE", "cache_dir", "inline", "njit", "numba"]
