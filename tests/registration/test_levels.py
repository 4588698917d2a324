"""Registration of integer levels through a linearisation table (``lut``): same estimate as the
linear frames, no linear copy, any strides (a channel view of the raw RGB frames)."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.errors import ParameterError
from hdrcore.registration import _problem, register_bracket, register_pair
from hdrcore.registration._problem import normal_equations, prepare, select_samples
from hdrcore.registration.transform import rigid_matrix
from hdrcore.synthetic import simulate_bracket

from ._pairs import run

SHAPE = (144, 208)


@pytest.fixture(scope="module")
def bracket():
    sb = simulate_bracket(
        scene="window",
        shape=SHAPE,
        exposure_times=(1.0, 4.0, 16.0),
        bits=12,
        noise_sigma=1.0,
        max_shift=8,
        max_rotation_deg=1.0,
        seed=5,
    )
    ml = sb.max_level
    lut = (np.arange(ml + 1) / ml).astype(np.float32) ** 1.1  # a non-trivial table
    linear = [lut[f[..., 1]] for f in sb.frames]
    return sb, lut, linear


@pytest.mark.parametrize("large_path", [False, True])
def test_levels_with_lut_match_linear_frames(bracket, monkeypatch, large_path):
    sb, lut, linear = bracket
    if large_path:  # frames above the size limit keep no full-resolution clipped copy
        monkeypatch.setattr(_problem, "_SMALL", 1000)
    kw = dict(saturation=float(lut[-1]) * 0.97, noise_floor=float(lut[40]), previews=False)
    ref = register_pair(linear[0], linear[1], 4.0, **kw)
    views = [f[..., 1] for f in sb.frames]  # strided uint16 views
    assert not views[0].flags.c_contiguous
    res = register_pair(views[0], views[1], 4.0, lut=lut, **kw)
    assert ref.ok and res.ok
    np.testing.assert_allclose(res.matrix, ref.matrix, rtol=0, atol=1e-9)
    assert res.cost_after == pytest.approx(ref.cost_after, rel=1e-9)
    assert res.iterations == ref.iterations


def test_bracket_of_levels_matches_linear_bracket(bracket):
    sb, lut, linear = bracket
    kw = dict(saturation=float(lut[-1]) * 0.97, noise_floor=float(lut[40]), previews=True)
    ref = register_bracket(linear, sb.ratios, **kw)
    res = register_bracket([f[..., 1] for f in sb.frames], sb.ratios, lut=lut, **kw)
    for a, b in zip(ref.to_reference, res.to_reference, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-9)
    for p, q in zip(ref.pairs, res.pairs, strict=True):  # previews from the levels too
        np.testing.assert_allclose(
            q.preview.difference_after, p.preview.difference_after, atol=1e-6, equal_nan=True
        )


def test_the_spec_reads_levels_through_the_table(bracket, monkeypatch):
    sb, lut, linear = bracket
    monkeypatch.setattr(_problem, "_SMALL", 1000)
    args = dict(saturation=float(lut[-1]) * 0.97, noise_floor=float(lut[40]), threshold=0.1)
    d_lin = prepare(linear[0], linear[1], 4.0, **args)
    d_lev = prepare(sb.frames[0][..., 1], sb.frames[1][..., 1], 4.0, lut=lut, **args)
    s_lin = select_samples(d_lin, 0, 3000)
    s_lev = select_samples(d_lev, 0, 3000)
    np.testing.assert_array_equal(s_lin.x, s_lev.x)
    np.testing.assert_array_equal(s_lin.b, s_lev.b)
    m = rigid_matrix(1.5, -2.0, 0.4, SHAPE)
    for compiled in (False, True):
        a = run(compiled, normal_equations, d_lin, 0, m, s_lin)
        b = run(compiled, normal_equations, d_lev, 0, m, s_lev)
        assert a[1] == b[1] > 0
        np.testing.assert_allclose(b[0], a[0], rtol=1e-12)
        np.testing.assert_allclose(b[2], a[2], rtol=1e-12)
    for lvl in range(1, len(d_lin.levels)):
        np.testing.assert_array_equal(d_lev.levels[lvl][0], d_lin.levels[lvl][0])
        np.testing.assert_array_equal(d_lev.levels[lvl][1], d_lin.levels[lvl][1])


def test_levels_above_the_table_read_its_last_entry():
    lut = np.linspace(0.0, 1.0, 256, dtype=np.float32)
    dark = np.full((32, 32), 300, np.uint16)
    data = prepare(dark, dark, 1.0, saturation=2.0, noise_floor=0.0, threshold=0.1, lut=lut)
    assert data.lut.size == 65536
    assert np.all(data.linear(dark) == 1.0)


def test_lut_needs_integer_frames():
    img = np.random.default_rng(0).random((32, 32)).astype(np.float32)
    with pytest.raises(ParameterError, match="integer levels"):
        register_pair(img, img, 2.0, lut=np.linspace(0, 1, 256))
    lev = (img * 255).astype(np.uint8)
    with pytest.raises(ParameterError, match="differ in type"):
        register_pair(lev, lev.astype(np.uint16), 2.0, lut=np.linspace(0, 1, 256))
    with pytest.raises(ParameterError, match="1-D array"):
        register_pair(lev, lev, 2.0, lut=np.ones((2, 256)))
