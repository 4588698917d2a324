"""read_raw's levels: our demosaic holds its output at the frame's largest level itself.

The frame's largest level is the smallest of the channels' ``white - black`` (per-channel
blacks differ); the kernel clips before it rounds, so holding it at that integer level inside
the kernel gives the levels of the earlier rule: demosaic held at ``white - min(black)``,
rounded, then every channel held at the frame's largest level.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hdrcore.demosaic import DEMOSAIC_METHODS, demosaic
from hdrcore.io.raw import read_raw
from hdrcore.synthetic.dng import linear_to_raw, mosaic, write_dng
from hdrcore.synthetic.scenes import fractal_noise

BLACK = (250, 256, 261, 254)  # per 2x2 site, row-major (GRBG: G, R / B, G)
WHITE = 4095


@pytest.fixture(scope="module")
def clipped_dng(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray]:
    rng = np.random.default_rng(12)
    base = 0.55 + 0.6 * fractal_noise((80, 120), rng)
    lin = np.stack([np.clip(base * g, 0.0, 1.3) for g in (0.9, 1.0, 1.1)], axis=2)
    lin[30:50, 40:80] = 1.3  # a clipped block: the filters overshoot the white level around it
    raw = linear_to_raw(mosaic(lin, "GRBG"), black_level=BLACK, white_level=WHITE)
    path = tmp_path_factory.mktemp("clip") / "f.dng"
    write_dng(path, raw, exposure_time=0.01, pattern="GRBG", black_level=BLACK, white_level=WHITE)
    return path, raw


@pytest.mark.parametrize("method", sorted(DEMOSAIC_METHODS))
def test_levels_as_held_after_the_demosaic(
    clipped_dng: tuple[Path, np.ndarray], method: str
) -> None:
    path, raw = clipped_dng
    frame = read_raw(path, demosaic=method)
    assert frame.meta.max_level == WHITE - max(BLACK)  # (blue's black, 261)
    pattern = np.array([[1, 0], [2, 3]])  # LibRaw's colour indices for GRBG ("RGBG")
    black_per_index = (BLACK[1], BLACK[0], BLACK[2], BLACK[3])
    earlier = demosaic(
        raw,
        pattern,
        "RGBG",
        method=method,
        black_level=black_per_index,
        max_level=WHITE - min(BLACK),
        dtype=np.uint16,
    )
    np.minimum(earlier, np.uint16(frame.meta.max_level), out=earlier)
    np.testing.assert_array_equal(frame.levels, earlier)
    # the clipped block and the overshoot around it reach the level held, not beyond
    assert int(frame.levels.max()) == frame.meta.max_level
