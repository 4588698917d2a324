"""The noise-matching blur of the refined estimator is cached (hdrcore.exposure.refined): a
re-fit with another saturation level or noise floor reuses the blurred histograms and their
transfer functions, and a cached fit equals a fresh one."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.exposure import refined
from hdrcore.exposure.refined import exposure_ratio_refined, quantised_sigma
from hdrcore.histogram import histogram
from hdrcore.synthetic import simulate_bracket


@pytest.fixture(scope="module")
def pair():
    sb = simulate_bracket(
        scene="window",
        shape=(240, 320),
        exposure_times=(1.0, 4.0),
        bits=12,
        response="linear",
        noise_sigma=2.0,
        seed=4,
    )
    hd = np.stack([histogram(sb.frames[0][..., c], sb.max_level) for c in range(3)])
    hb = np.stack([histogram(sb.frames[1][..., c], sb.max_level) for c in range(3)])
    return hd, hb, sb.max_level


def _fields(r):
    return (r.ratio, r.initial_ratio, tuple(r.iterates), r.status)


def test_sigma_grid_is_one_percent_steps():
    assert quantised_sigma(0.0) == 0.0
    for s in (0.37, 1.0, 3.3, 52.0):
        q = quantised_sigma(s)
        assert abs(q / s - 1) <= 0.005 + 1e-12
        assert quantised_sigma(q) == pytest.approx(q, rel=1e-12)


def test_cached_refit_equals_a_fresh_fit(pair):
    hd, hb, m = pair
    kw = dict(noise_floor=20.0, noise_sigma=2.0)
    refined._blur_cache.clear()
    first = exposure_ratio_refined(hd, hb, saturation=0.95 * m, **kw)
    assert len(refined._blur_cache) >= 1
    entries = len(refined._blur_cache)
    # another saturation level: the ratio moves a little, the blur's grid point does not
    cached = exposure_ratio_refined(hd, hb, saturation=0.94 * m, **kw)
    assert len(refined._blur_cache) == entries
    refined._blur_cache.clear()
    fresh = exposure_ratio_refined(hd, hb, saturation=0.94 * m, **kw)
    assert _fields(cached) == _fields(fresh)
    assert cached.ratio != first.ratio  # the re-fit did use the new saturation level
    for a, b in zip(cached.btfs, fresh.btfs, strict=True):
        np.testing.assert_array_equal(a.forward, b.forward)
        np.testing.assert_array_equal(a.hist_bright, b.hist_bright)


def test_cache_key_is_the_histograms_contents(pair):
    hd, hb, m = pair
    refined._blur_cache.clear()
    a = exposure_ratio_refined(hd, hb, saturation=0.95 * m, noise_sigma=2.0)
    other = hb.copy()
    other[:, 100:110] += 500  # another bright histogram: its own transfer functions
    b = exposure_ratio_refined(hd, other, saturation=0.95 * m, noise_sigma=2.0)
    refined._blur_cache.clear()
    c = exposure_ratio_refined(hd, other, saturation=0.95 * m, noise_sigma=2.0)
    assert _fields(b) == _fields(c) and b.ratio != a.ratio


@pytest.mark.parametrize("sigma", [0.7, 12.0, 16.5, 110.0, 590.0])
def test_blur_histogram_long_kernels_through_the_fft(sigma: float) -> None:
    """A 16-bit frame's noise blur (hundreds of levels: the real Pixel 7 bracket as 16-bit
    TIFFs) goes through the FFT: the direct Gaussian's values to 1e-12 of the largest bin, mass
    kept, no negative bin; short kernels keep the direct filter (the same values as before)."""
    from scipy.ndimage import gaussian_filter1d

    from hdrcore.exposure.refined import FFT_BLUR_RADIUS, blur_histogram

    rng = np.random.default_rng(int(sigma * 10))
    h = rng.poisson(40.0, (3, 65536)).astype(np.int64)
    h[:, :900] = 0
    h[:, -2500:] = 0
    h[:, 30000:30100] = 0
    got = blur_histogram(h, sigma)
    pad = int(np.ceil(4 * sigma)) + 1
    z = np.pad(h.astype(np.float64), [(0, 0), (pad, pad)])
    b = gaussian_filter1d(z, sigma, axis=-1, mode="constant", truncate=4.0)
    want = b[:, pad:-pad].copy()
    want[:, 0] += b[:, :pad].sum(axis=-1)
    want[:, -1] += b[:, -pad:].sum(axis=-1)
    assert got.shape == h.shape and got.min() >= 0.0
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * want.max())
    np.testing.assert_allclose(got.sum(axis=-1), h.sum(axis=-1), rtol=1e-12)
    if int(4 * sigma + 0.5) <= FFT_BLUR_RADIUS:
        assert got.tobytes() == want.tobytes()
