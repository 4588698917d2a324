"""Helpers: simulated hand-held pairs with known motion (the seed's camera model)."""

from __future__ import annotations

import numpy as np

from hdrcore.synthetic import simulate_bracket


def green(frame: np.ndarray, max_level: int) -> np.ndarray:
    """The green channel of an integer frame as linear values in [0, 1] (linear response)."""
    return frame[..., 1].astype(np.float32) / max_level


def simulated_pair(*, bits=12, seed=0, motion=(0.0, 0.0, 0.0), shape=(128, 192), ratio=4.0,
                   noise_sigma=1.0, scene="window"):
    """(dark, bright, true pair matrix, max_level) for a pair with the bright frame moved."""
    sb = simulate_bracket(
        scene=scene, shape=shape, exposure_times=(1.0, ratio), bits=bits,
        noise_sigma=noise_sigma, motion=[(0.0, 0.0, 0.0), motion], reference=0, seed=seed,
    )
    ml = sb.max_level
    return green(sb.frames[0], ml), green(sb.frames[1], ml), sb.pair_matrix(0, 1), ml
