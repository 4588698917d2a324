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


def _quantiles_searched(cdf: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The binary-search form of quantile_levels (the order of ``q`` made irrelevant: it is
    answered shuffled and put back)."""
    perm = np.random.default_rng(0).permutation(q.size)
    out = np.empty(q.size)
    out[perm] = quantile_levels(cdf, q[perm])
    return out


@pytest.mark.parametrize("levels", [256, 4096, 65536])
def test_quantile_levels_rising_queries_match_binary_search_to_the_bit(levels: int) -> None:
    """Rising queries take one merged pass (btf._quantiles_rising): the same values as the
    binary searches, on histograms with empty runs, leading and trailing zeros, queries on the
    knots exactly, below the first and at the last."""
    rng = np.random.default_rng(levels)
    for trial in range(6):
        h = rng.poisson(rng.uniform(0.2, 30.0), levels).astype(np.int64)
        h[rng.random(levels) < 0.3] = 0  # empty runs
        h[: rng.integers(0, levels // 8)] = 0
        h[levels - rng.integers(1, levels // 8) :] = 0
        h[rng.integers(0, levels)] += 1
        cdf = np.cumsum(h) / h.sum()
        picked = cdf[rng.integers(0, levels, levels)]
        q = np.sort(np.concatenate([rng.random(3 * levels), picked, [0.0, 1.0, 1.5, -0.2]]))
        if trial % 2:
            q = cdf.copy()  # a BTF's own queries: every knot
        got = quantile_levels(cdf, q)
        want = _quantiles_searched(cdf, q)
        assert got.tobytes() == want.tobytes()
    # a query below 64 values, or falling, keeps the binary searches (same values either way)
    cdf = np.array([0.0, 0.25, 0.25, 0.75, 1.0])
    q = np.linspace(1.0, 0.0, 100)
    np.testing.assert_array_equal(quantile_levels(cdf, q), quantile_levels(cdf, q[::-1])[::-1])


def test_bad_input() -> None:
    with pytest.raises(EstimationError, match="dark histogram is empty"):
        brightness_transfer_function(np.zeros(256, int), np.ones(256, int))
    with pytest.raises(ParameterError, match="one-dimensional"):
        brightness_transfer_function(np.ones((2, 256), int), np.ones(256, int))
    with pytest.raises(ParameterError, match="non-negative"):
        brightness_transfer_function(-np.ones(256, int), np.ones(256, int))
