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
    """The sRGB inverse transfer function sampled at every level, ``(max_level + 1,)`` float64."""
    import colour  # imported lazily: colour-science is slow to import

    v = np.arange(max_level + 1, dtype=np.float64) / max_level
    g = np.asarray(colour.cctf_decoding(v, function="sRGB"), np.float64)
    return g / g[-1]
