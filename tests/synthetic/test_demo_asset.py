"""The committed demo bracket (assets/demo) agrees with its truth.json.

Checks what a later stage relies on: the files load as a linear RAW bracket with exact EXIF times,
and the truth's pair matrices and ratios describe the pixel data (warping the darker frame by the
pair matrix and scaling by the ratio reproduces the brighter frame; without the matrix it does not).
"""

from __future__ import annotations

import json
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from hdrcore.io import load_bracket, read_exposure_times

DEMO = Path(__file__).resolve().parents[2] / "assets" / "demo"


@pytest.fixture(scope="module")
def demo():
    if not DEMO.is_dir():
        pytest.skip("assets/demo not present")
    truth = json.loads((DEMO / "truth.json").read_text())
    bracket = load_bracket([str(DEMO / f["file"]) for f in truth["frames"]])
    return truth, bracket


def test_demo_loads_as_a_linear_raw_bracket_with_exact_times(demo) -> None:
    truth, b = demo
    assert len(b) == 5 and b.is_linear and b.warnings == ()
    assert b.max_level == truth["file_max_level"] == 3839
    assert b.shape == tuple(truth["shape"])
    times = [Fraction(f["exposure_time_exact"]) for f in truth["frames"]]
    assert [f.meta.exposure_time for f in b.frames] == times
    assert times == [Fraction(1, 256) * 4**k for k in range(5)]
    assert read_exposure_times(DEMO / "exposure_times.txt") == {
        f["file"]: Fraction(f["exposure_time_exact"]) for f in truth["frames"]
    }
    total = sum(p.stat().st_size for p in DEMO.iterdir())
    assert total < 4_000_000


def _log_ratio(dark: np.ndarray, bright: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """log(bright / dark sampled at matrix @ p) over well-exposed pixels away from clipping."""
    h, w = bright.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    xs = matrix[0, 0] * xx + matrix[0, 1] * yy + matrix[0, 2]
    ys = matrix[1, 0] * xx + matrix[1, 1] * yy + matrix[1, 2]
    # Smoothing mixes clipped neighbours into a pixel: stay 6 px away from anything near clipping.
    near_clip = ndimage.binary_dilation(bright > 3000, iterations=6)
    dark_clip = ndimage.binary_dilation(dark > 3000, iterations=6).astype(float)
    near_clip |= ndimage.map_coordinates(dark_clip, [ys, xs], order=0, cval=1.0) > 0
    dark_at = ndimage.map_coordinates(
        ndimage.gaussian_filter(dark, 1.0), [ys, xs], order=1, cval=np.nan
    )
    bright = ndimage.gaussian_filter(bright, 1.0)
    ok = (dark_at > 150) & (bright > 150) & ~near_clip
    ok[:16], ok[-16:], ok[:, :16], ok[:, -16:] = False, False, False, False
    return np.log(bright[ok] / dark_at[ok])


def test_pair_matrices_and_ratios_describe_the_pixels(demo) -> None:
    truth, b = demo
    for pair in truth["pairs"]:
        dark = b.frames[pair["dark"]].levels[..., 1].astype(float)
        bright = b.frames[pair["bright"]].levels[..., 1].astype(float)
        aligned = _log_ratio(dark, bright, np.array(pair["matrix"]))
        assert np.exp(np.median(aligned)) == pytest.approx(pair["ratio"], rel=0.005)
        unaligned = _log_ratio(dark, bright, np.eye(2, 3))
        spread = np.median(np.abs(aligned - np.median(aligned)))
        assert spread < 0.25 * np.median(np.abs(unaligned - np.median(unaligned)))
