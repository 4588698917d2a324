"""Real film bracket (Debevec & Malik 1997, memorial church): methods agree with each other.

The OpenCV comparison lives in ``bench/bench_response.py`` (tests never import cv2); here the
pixel and histogram methods must agree (shape RMS over levels 5..230 below 2 % for R and G; the
blue channel of these film scans is the least consistent between all methods, OpenCV's included,
so it gets 5 %).
"""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.io import load_bracket
from hdrcore.response import recover_response

pytestmark = pytest.mark.shared


def _load(memorial_dir):
    br = load_bracket(
        sorted(memorial_dir.glob("*.png")), exposure_times=memorial_dir / "exposure_times.txt"
    )
    frames = [f.levels for f in br.frames]
    blue = np.zeros(frames[0].shape[:2], bool)
    for f in frames:
        blue |= np.all(f == (0, 0, 255), axis=-1)
    return frames, [float(t) for t in br.exposure_times], ~blue


def _shape_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    sl = slice(5, 231)
    s = np.sum(a[:, sl] * b[:, sl], axis=1) / np.sum(a[:, sl] ** 2, axis=1)
    return np.sqrt(np.mean((a[:, sl] * s[:, None] - b[:, sl]) ** 2, axis=1)) / b[:, 230]


def test_histogram_methods_agree(memorial_dir) -> None:
    frames, times, mask = _load(memorial_dir)
    dmh = recover_response(frames, times, method="debevec-histogram", mask=mask, stride=2)
    gn = recover_response(frames, times, method="grossberg2003", mask=mask, stride=2)
    assert dmh.is_monotone and gn.is_monotone
    d = _shape_diff(dmh.g, gn.g)
    assert np.all(d[:2] < 0.02) and d[2] < 0.05, d


@pytest.mark.slow
def test_pixel_and_histogram_debevec_agree(memorial_dir) -> None:
    frames, times, mask = _load(memorial_dir)
    dm = recover_response(frames, times, method="debevec1997", mask=mask, n_samples=600)
    dmh = recover_response(frames, times, method="debevec-histogram", mask=mask, stride=2)
    d = _shape_diff(dm.g, dmh.g)
    assert np.all(d[:2] < 0.02) and d[2] < 0.05, d
