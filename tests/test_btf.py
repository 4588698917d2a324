"""Brightness transfer functions by cumulative histogram matching (Grossberg & Nayar 2002)."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.btf import brightness_transfer_function, quantile_levels
from hdrcore.errors import EstimationError, ParameterError
from hdrcore.histogram import histograms
from hdrcore.synthetic import simulate_bracket


def test_identity_for_identical_histograms() -> None:
    h = np.array([0, 5, 10, 0, 3, 2, 0, 0], np.int64)
    btf = brightness_transfer_function(h, h)
    occupied = h > 0
    np.testing.assert_allclose(btf.forward[occupied], np.arange(8)[occupied])
    np.testing.assert_allclose(btf.forward_at_edges()[[1, 4]], [1.5, 4.5])
    assert btf.forward_at_edges()[2] == pytest.approx(3.0)  # flat run 2.5..3.5: its middle
    assert btf.max_level_dark == 7


def test_linear_pair_recovers_ratio_at_bit_depths() -> None:
    for bits, tol in ((8, 0.01), (12, 0.002), (14, 0.002)):
        b = simulate_bracket(
            exposure_times=(1.0, 4.0), bits=bits, noise_sigma=1.0, shape=(128, 192), seed=3
        )
        m = b.max_level
        hd, hb = (histograms(f, m) for f in b.frames)
        btf = brightness_transfer_function(hd[1], hb[1])
        assert btf.forward.shape == (m + 1,)
        assert btf.inverse.shape == (m + 1,)
        x = np.arange(m + 1) + 0.5
        y = btf.forward_at_edges()
        sel = (x > 0.05 * m) & (y < 0.9 * m) & (btf.hist_dark > 0)
        ratio = np.median(y[sel] / x[sel])
        assert abs(ratio / 4.0 - 1) < tol
        # The inverse maps back.
        back = btf.transfer(btf.inverse_transfer(np.array([0.3 * m, 0.6 * m])))
        np.testing.assert_allclose(back, [0.3 * m, 0.6 * m], rtol=0.02)


def test_monotone() -> None:
    b = simulate_bracket(exposure_times=(1.0, 8.0), bits=8, shape=(64, 96), seed=1)
    hd, hb = (histograms(f, 255) for f in b.frames)
    btf = brightness_transfer_function(hd[0], hb[0])
    assert np.all(np.diff(btf.forward) >= 0)
    assert np.all(np.diff(btf.inverse) >= 0)


def test_quantile_levels_flat_run_takes_middle() -> None:
    cdf = np.array([0.5, 0.5, 0.5, 1.0])  # levels 1, 2 empty
    assert quantile_levels(cdf, np.array([0.5]))[0] == pytest.approx(1.5)


def test_bad_input() -> None:
    with pytest.raises(EstimationError, match="dark histogram is empty"):
        brightness_transfer_function(np.zeros(256, int), np.ones(256, int))
    with pytest.raises(ParameterError, match="one-dimensional"):
        brightness_transfer_function(np.ones((2, 256), int), np.ones(256, int))
    with pytest.raises(ParameterError, match="non-negative"):
        brightness_transfer_function(-np.ones(256, int), np.ones(256, int))
