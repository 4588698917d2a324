"""Small simulated brackets with truth for the merge tests (sizes keep the suite fast)."""

from __future__ import annotations

import numpy as np

from hdrcore.synthetic import simulate_bracket

SHAPE = (128, 192)
TIMES = (1.0, 4.0, 16.0)


def well_exposed(sb, low: float = 0.05, high: float = 0.9) -> np.ndarray:
    """Pixels that at least one frame recorded with every channel well inside its range."""
    mask = np.zeros(sb.radiance.shape[:2], bool)
    for lf in sb.linear_frames:
        mask |= ((lf > low) & (lf < high)).all(axis=2)
    return mask


def relative_error(merged: np.ndarray, sb) -> np.ndarray:
    """|E / key - truth| / truth (the merge returns ``radiance * key`` for the true times)."""
    return np.abs(merged / sb.key - sb.radiance) / sb.radiance


def bracket(**kw):
    kw.setdefault("shape", SHAPE)
    kw.setdefault("exposure_times", TIMES)
    kw.setdefault("keep_linear", True)
    return simulate_bracket(**kw)


def inverse_gamma_lut(max_level: int, channels: int = 3) -> np.ndarray:
    """``g`` of the simulator's "gamma" response (``f(x) = x**(1/2.2)``) as a (C, L) LUT."""
    return np.tile(np.linspace(0.0, 1.0, max_level + 1) ** 2.2, (channels, 1))
