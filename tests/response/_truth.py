"""Ground truth for response tests: the simulator's response ``f`` inverted numerically."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from hdrcore.synthetic import apply_response, simulate_bracket

SEED_TIMES = (1.0, 4.0, 16.0, 64.0, 256.0, 1024.0)  # the seed's protocol, section 4.2


def truth_g(response: str, max_level: int = 255) -> np.ndarray:
    """``g = f^-1`` at every level ``0 .. max_level`` (normalised, as the curves are)."""
    x = np.linspace(0.0, 1.0, 400_001)
    return np.interp(np.arange(max_level + 1) / max_level, apply_response(response, x), x)


def rms(g: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """RMS of ``g - truth`` over all levels, per channel (fraction of the range)."""
    return np.sqrt(np.mean((np.atleast_2d(g) - truth[None]) ** 2, axis=1))


def shape_rms(g: np.ndarray, truth: np.ndarray, top: float = 0.95) -> np.ndarray:
    """RMS over the levels below ``top * max`` after the best common scale (shape only)."""
    g = np.atleast_2d(g)
    n = int(top * (truth.size - 1))
    s = np.sum(g[:, :n] * truth[None, :n], axis=1) / np.sum(g[:, :n] ** 2, axis=1)
    return np.sqrt(np.mean((g[:, :n] * s[:, None] - truth[None, :n]) ** 2, axis=1))


@lru_cache(maxsize=16)
def seed_bracket(response: str, noise_sigma: float, shape=(128, 192), seed: int = 1):
    return simulate_bracket(
        scene="window",
        shape=shape,
        exposure_times=SEED_TIMES,
        bits=8,
        response=response,
        noise_sigma=noise_sigma,
        seed=seed,
    )
