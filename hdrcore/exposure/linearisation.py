"""Linearisation tables for non-linear frames (JPEG/PNG) before the ratio fit.

A table ``g`` maps integer levels ``0 .. max_level`` to linear exposure with ``g(max_level) = 1``.
Prefer the camera's recovered response (``ResponseCurve.to_lut(max_level)``); until one is known
the documented fallback is the sRGB decoding function (IEC 61966-2-1), via colour-science.
"""

from __future__ import annotations

import numpy as np

__all__ = ["linear_lut", "srgb_lut"]


def linear_lut(max_level: int) -> np.ndarray:
    """``g(m) = m / max_level`` (linear frames: RAW, linear TIFF)."""
    return np.arange(max_level + 1, dtype=np.float64) / max_level


def srgb_lut(max_level: int) -> np.ndarray:
    """The sRGB inverse transfer function sampled at every level, ``(max_level + 1,)`` float64
    (colour-science's, kept in the user's cache folder: :func:`hdrcore._colour_cache.srgb_eotf`;
    ``cctf_decoding(..., function="sRGB")`` gives the same values)."""
    from .._colour_cache import srgb_eotf

    g = srgb_eotf(max_level)
    return g / g[-1]
