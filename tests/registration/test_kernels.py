"""The compiled registration kernels agree with their numpy specifications (eqs. 6-7, pyramids;
hdrcore.registration.spec and _sampling.reduce2)."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.registration import _kernels
from hdrcore.registration._problem import (
    motion_update,
    normal_equations,
    prepare,
    sample_residuals,
    select_samples,
)
from hdrcore.registration._sampling import reduce2
from hdrcore.registration.transform import homogeneous, rigid_matrix, similarity_matrix

from ._pairs import run, simulated_pair


@pytest.fixture(scope="module")
def pair():
    dark, bright, truth, ml = simulated_pair(bits=12, motion=(6.3, -4.1, 1.2), shape=(160, 224))
    return dark, bright, ml


def test_bin_clip_matches_clip_then_reduce2(pair):
    dark, bright, ml = pair
    lo, hi, k = 3 / ml * 4.0, 0.98, 4.0
    ref_b = reduce2(np.clip(np.multiply(dark, np.float32(k), dtype=np.float32), lo, hi))
    ref_a = reduce2(np.clip(bright, lo, hi).astype(np.float32))
    out = np.empty_like(ref_a)
    _kernels.bin_clip(dark, None, k, lo, hi, out)
    np.testing.assert_array_equal(out, ref_b)
    _kernels.bin_clip(bright, None, 1.0, lo, hi, out)
    np.testing.assert_array_equal(out, ref_a)
    # integer levels through a table (a strided channel view of an RGB frame)
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 4096, (40, 62, 3)).astype(np.uint16)
    lut = (np.arange(4096) / 4095.0).astype(np.float32) ** 2
    lin = lut[rgb[..., 1]]
    out = np.empty((20, 31), np.float32)
    _kernels.bin_clip(rgb[..., 1], lut, 2.0, 0.01, 0.9, out)
    ref = reduce2(np.clip(lin * np.float32(2.0), np.float32(0.01), np.float32(0.9)))
    np.testing.assert_array_equal(out, ref)


def test_reduce2_matches_the_spec(pair):
    img = pair[0][:101, :77]
    out = np.empty((50, 38), np.float32)
    _kernels.reduce2(np.ascontiguousarray(img), out)
    np.testing.assert_array_equal(out, reduce2(img))


@pytest.mark.parametrize("level", [0, 1, 2])
@pytest.mark.parametrize("n_par", [2, 3, 4, 8])
def test_normal_equations_match_the_spec(pair, level, n_par):
    dark, bright, ml = pair
    data = prepare(dark, bright, 4.0, saturation=0.98, noise_floor=3 / ml, threshold=0.1)
    s = select_samples(data, level, 5000)
    shape_l = data.level_shape(level)
    persp = homogeneous(similarity_matrix(-6.3 / 2**level, 4.1 / 2**level, -1.1, 1.01, shape_l))
    persp[2, :2] = (2e-5 * 2**level, -1e-5 * 2**level)
    # near the truth and far from it (many samples outside), affine and perspective
    for m in (
        rigid_matrix(-6.3 / 2**level, 4.1 / 2**level, -1.1, shape_l),
        rigid_matrix(20.0, -9.0, 3.0, shape_l),
        persp,
    ):
        c_ref = run(False, normal_equations, data, level, m, s, n_par=n_par)
        c_jit = run(True, normal_equations, data, level, m, s, n_par=n_par)
        assert c_ref[1] > 0
        np.testing.assert_allclose(c_jit[1], c_ref[1], rtol=1e-12)
        np.testing.assert_allclose(c_jit[0], c_ref[0], rtol=1e-10)
        np.testing.assert_allclose(c_jit[2], c_ref[2], rtol=1e-9, atol=1e-12 * abs(c_ref[2]).max())
        np.testing.assert_allclose(c_jit[3], c_ref[3], rtol=1e-9, atol=1e-12 * abs(c_ref[3]).max())
        assert c_jit[2].shape == (n_par, n_par) and c_jit[3].shape == (n_par,)


def test_jacobian_columns_are_derivatives_of_the_residuals(pair):
    """J'n from the normal equations equals half the numerical gradient of the eq. 6 sum along
    each generator of motion_update (so the Gauss-Newton step and the update agree)."""
    dark, bright, ml = pair
    data = prepare(dark, bright, 4.0, saturation=0.98, noise_floor=3 / ml, threshold=0.1)
    s = select_samples(data, 1, 3000)
    shape_l = data.level_shape(1)
    m = homogeneous(similarity_matrix(-3.0, 2.0, -1.0, 1.004, shape_l))
    ssum, wsum, hess, grad = normal_equations(data, 1, m, s, n_par=8, ramp=1e-9)
    for i in range(8):
        eps = 1e-4 if i < 2 else 1e-6
        d = np.zeros(8)
        d[i] = eps
        up = normal_equations(
            data, 1, motion_update(d, shape_l) @ m, s, n_par=8, gradient=False, ramp=1e-9
        )[0]
        down = normal_equations(
            data, 1, motion_update(-d, shape_l) @ m, s, n_par=8, gradient=False, ramp=1e-9
        )[0]
        numeric = (up - down) / (2 * eps) / 2
        assert numeric == pytest.approx(grad[i], rel=2e-3, abs=1e-6 * abs(grad).max()), i


@pytest.mark.parametrize("level", [0, 1])
@pytest.mark.parametrize(("n_par", "n_gain"), [(2, 1), (4, 3), (8, 3)])
def test_normal_equations_with_gain_match_the_spec(pair, level, n_par, n_gain):
    dark, bright, ml = pair
    data = prepare(dark, bright, 4.0, saturation=0.98, noise_floor=3 / ml, threshold=0.1)
    s = select_samples(data, level, 5000)
    shape_l = data.level_shape(level)
    m = rigid_matrix(-6.3 / 2**level, 4.1 / 2**level, -1.1, shape_l)
    gain = np.array([0.12, -0.05, 0.08])
    c_ref = run(False, normal_equations, data, level, m, s, n_par=n_par, gain=gain, n_gain=n_gain)
    c_jit = run(True, normal_equations, data, level, m, s, n_par=n_par, gain=gain, n_gain=n_gain)
    n = n_par + n_gain
    assert c_jit[2].shape == (n, n) and c_jit[3].shape == (n,)
    np.testing.assert_allclose(c_jit[0], c_ref[0], rtol=1e-10)
    np.testing.assert_allclose(c_jit[2], c_ref[2], rtol=1e-9, atol=1e-12 * abs(c_ref[2]).max())
    np.testing.assert_allclose(c_jit[3], c_ref[3], rtol=1e-9, atol=1e-12 * abs(c_ref[3]).max())
    # the gain changes the cost (it is applied, not only differentiated)
    assert normal_equations(data, level, m, s, n_par=n_par)[0] != pytest.approx(c_jit[0])


@pytest.mark.parametrize("level", [0, 1])
def test_robust_normal_equations_match_the_spec(pair, level):
    dark, bright, ml = pair
    data = prepare(dark, bright, 4.0, saturation=0.98, noise_floor=3 / ml, threshold=0.1)
    s = select_samples(data, level, 5000)
    m = homogeneous(rigid_matrix(-6.0 / 2**level, 4.0 / 2**level, -1.0, data.level_shape(level)))
    kw = dict(n_par=8, gain=np.array([0.05, 0.0, 0.02]), n_gain=3, robust=0.02, ramp=1e-9)
    c_ref = run(False, normal_equations, data, level, m, s, **kw)
    c_jit = run(True, normal_equations, data, level, m, s, **kw)
    np.testing.assert_allclose(c_jit[0], c_ref[0], rtol=1e-10)
    np.testing.assert_allclose(c_jit[2], c_ref[2], rtol=1e-9, atol=1e-12 * abs(c_ref[2]).max())
    np.testing.assert_allclose(c_jit[3], c_ref[3], rtol=1e-9, atol=1e-12 * abs(c_ref[3]).max())
    # Cauchy's loss is below the sum of squares, and the step's gradient is its derivative
    plain = run(True, normal_equations, data, level, m, s, n_par=8)
    assert c_jit[0] < plain[0]
    d = np.zeros(11)
    d[0] = 1e-4
    up = normal_equations(
        data, level, motion_update(d[:8], data.level_shape(level)) @ m, s, gradient=False, **kw
    )[0]
    down = normal_equations(
        data, level, motion_update(-d[:8], data.level_shape(level)) @ m, s, gradient=False, **kw
    )[0]
    numeric = (up - down) / 2e-4 / 2
    assert numeric == pytest.approx(c_jit[3][0], rel=5e-3, abs=1e-6 * abs(c_jit[3]).max())


def test_gain_columns_are_derivatives_of_the_residuals(pair):
    dark, bright, ml = pair
    data = prepare(dark, bright, 4.0, saturation=0.98, noise_floor=3 / ml, threshold=0.1)
    s = select_samples(data, 1, 3000)
    m = homogeneous(similarity_matrix(-3.0, 2.0, -1.0, 1.004, data.level_shape(1)))
    gain = np.array([0.05, 0.02, -0.03])
    _, _, _, grad = normal_equations(data, 1, m, s, n_par=4, ramp=1e-9, gain=gain, n_gain=3)
    for i in range(3):
        d = np.zeros(3)
        d[i] = 1e-6
        up = normal_equations(data, 1, m, s, n_par=4, gradient=False, ramp=1e-9, gain=gain + d)[0]
        down = normal_equations(data, 1, m, s, n_par=4, gradient=False, ramp=1e-9, gain=gain - d)[0]
        numeric = (up - down) / 2e-6 / 2
        assert numeric == pytest.approx(grad[4 + i], rel=2e-3, abs=1e-6 * abs(grad).max()), i


@pytest.mark.parametrize("level", [0, 1])
@pytest.mark.parametrize("by_gradient, n", [(True, 4000), (False, 6000), (True, 10**6)])
@pytest.mark.parametrize("motion, reach", [("identity", 0), ("truth", 0), ("homography", 1)])
def test_select_samples_compiled_matches_the_spec(pair, level, by_gradient, n, motion, reach):
    dark, bright, ml = pair
    data = prepare(dark, bright, 4.0, saturation=0.98, noise_floor=3 / ml, threshold=0.1)
    shape_l = data.level_shape(level)
    m = {
        "identity": None,
        "truth": rigid_matrix(-6.3 / 2**level, 4.1 / 2**level, -1.2, shape_l),
        "homography": homogeneous(
            similarity_matrix(-6.0 / 2**level, 4.0 / 2**level, -1.0, 1.01, shape_l)
        )
        + np.array([[0, 0, 0], [0, 0, 0], [3e-5 * 2**level, -2e-5 * 2**level, 0]]),
    }[motion]
    kw = dict(motion=m, by_gradient=by_gradient, seed=3, reach=reach)
    a = run(False, select_samples, data, level, n, **kw)
    b = run(True, select_samples, data, level, n, **kw)
    assert 0 < a.b.size <= n
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.y, b.y)
    np.testing.assert_array_equal(a.b, b.b)
    assert a.well_exposed == b.well_exposed
    order = a.y * dark.shape[1] + a.x
    assert np.all(np.diff(order) >= 0)  # raster order


def test_candidates_spread_over_the_frame(pair):
    dark, bright, ml = pair
    data = prepare(dark, bright, 4.0, saturation=2.0, noise_floor=0.0, threshold=0.1)
    s = select_samples(data, 0, 500, by_gradient=False)
    h, w = dark.shape
    # one candidate per run of the raster: every band of rows gets its share
    counts = np.histogram(s.y, bins=8, range=(0, h))[0]
    assert counts.min() >= 0.6 * counts.mean()
    assert s.x.min() < 0.2 * w and s.x.max() > 0.8 * w


@pytest.mark.parametrize("compiled", [False, True])
def test_random_subset_holds_max_samples_well_exposed_pixels(compiled):
    # a mostly dark frame: a band of 30 rows of 300 above the noise floor; the samples'
    # 5x5 neighbourhoods must lie inside it, i.e. rows 2..27 of the 296 candidate rows
    dark = np.full((300, 400), 0.001, np.float32)
    dark[:30] = 0.3
    data = prepare(dark, dark, 1.0, saturation=0.98, noise_floor=0.01, threshold=0.1)
    s = run(compiled, select_samples, data, 0, 5000, by_gradient=False)
    assert s.b.size == 5000
    assert np.all(s.b == np.float32(0.3))
    assert s.y.min() >= 2 and s.y.max() <= 27
    assert s.well_exposed == pytest.approx(26 / 296, abs=0.01)


@pytest.mark.parametrize("level", [0, 1])
def test_per_sample_residuals_match_the_spec_and_the_sums(pair, level):
    """sample_residuals (the kernel's per_sample output; the refit's off blocks) against the
    spec's, samples outside the bright frame included (n = w = 0), and sum w n^2 is the sum."""
    dark, bright, ml = pair
    data = prepare(dark, bright, 4.0, saturation=0.98, noise_floor=3 / ml, threshold=0.1)
    s = select_samples(data, level, 5000)
    m = homogeneous(rigid_matrix(15.0 / 2**level, -9.0 / 2**level, 2.0, data.level_shape(level)))
    gain = np.array([0.05, -0.02, 0.03])
    n, w = sample_residuals(data, level, m, s, gain=gain)
    n_ref, w_ref = run(False, sample_residuals, data, level, m, s, gain=gain)
    assert (w == 0).any() and (w > 0).sum() > 1000
    np.testing.assert_array_equal(w == 0, w_ref == 0)
    np.testing.assert_allclose(n, n_ref, rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(w, w_ref, rtol=1e-12)
    ssum, wsum, _, _ = normal_equations(data, level, m, s, gradient=False, gain=gain)
    assert np.sum(w * n * n) == pytest.approx(ssum, rel=1e-12)
    assert w.sum() == pytest.approx(wsum, rel=1e-12)
