"""The project's numba decorators, in one place.

``njit``: compiled, GIL released (``nogil``, so kernels run on Python threads side by side),
cached on disk next to the calling module (``__pycache__``: only the first call on a machine
compiles), no fast-math (results match the numpy references), numpy's error model (division
by zero gives inf/nan, as numpy does). ``inline``: the same, inlined into its callers (a call
passing arrays would touch their reference counts per pixel). ``AVAILABLE`` is False without
numba: the decorators then return the plain Python functions and the callers use their numpy
references.
"""

from __future__ import annotations

try:
    import numba

    njit = numba.njit(nogil=True, cache=True, fastmath=False, error_model="numpy")
    inline = numba.njit(nogil=True, cache=True, fastmath=False, error_model="numpy",
                        inline="always")
    AVAILABLE = True
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None
    AVAILABLE = False

    def njit(fn):
        return fn

    inline = njit

__all__ = ["AVAILABLE", "inline", "njit", "numba"]
