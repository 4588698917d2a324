"""The seed's camera model (Cerman & Hlavac 2006, sections 4.2 and 5.3): M = q(f(s(E dt)) + n).

Ground truth here is analytic: with no noise and a linear response, frame levels are the clipped,
rounded product radiance * t * key * max_level; motion follows the project's 2x3 convention.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrcore.errors import ParameterError
from hdrcore.synthetic import (
    RESPONSES,
    apply_response,
    compose,
    invert,
    pair_matrix,
    rigid_matrix,
    simulate_bracket,
)

SHAPE = (64, 96)


def test_linear_noiseless_frames_are_clipped_scaled_radiance() -> None:
    sim = simulate_bracket(shape=SHAPE, exposure_times=(1, 4, 16), bits=12, noise_sigma=0)
    for t, frame in zip(sim.exposure_times, sim.frames, strict=True):
        expect = np.clip(np.rint(np.clip(sim.radiance * t * sim.key, 0, 1) * 4095), 0, 4095)
        # float32 radiance vs float64 here: a rounding tie may land one level apart.
        np.testing.assert_allclose(frame, expect, atol=1)
        assert np.mean(frame == expect) > 0.999
    assert sim.max_level == 4095
    assert sim.ratios == (4.0, 4.0)


def test_key_puts_the_median_at_018_for_the_geometric_mean_time() -> None:
    sim = simulate_bracket(shape=SHAPE, exposure_times=(1, 4, 16), noise_sigma=0)
    assert np.median(sim.radiance) * 4.0 * sim.key == pytest.approx(0.18, rel=1e-5)


def test_frames_are_uint16_at_native_bit_depth() -> None:
    for bits in (8, 10, 12, 14, 16):
        sim = simulate_bracket(shape=SHAPE, exposure_times=(1, 8), bits=bits, noise_sigma=2)
        for f in sim.frames:
            assert f.dtype == np.uint16 and f.shape == (*SHAPE, 3)
            assert int(f.max()) <= (1 << bits) - 1
        # The bright frame reaches saturation in the window scene.
        assert int(sim.frames[1].max()) == (1 << bits) - 1


def test_unsaturated_level_ratio_equals_exposure_ratio() -> None:
    sim = simulate_bracket(shape=SHAPE, exposure_times=(1, 4), bits=14, noise_sigma=0)
    a, b = (f.astype(float) for f in sim.frames)
    ok = (a > 200) & (b < 16000)
    assert np.median(b[ok] / a[ok]) == pytest.approx(4.0, rel=2e-3)


def test_gaussian_noise_has_the_requested_sigma() -> None:
    clean = simulate_bracket(shape=SHAPE, exposure_times=(1,), bits=12, noise_sigma=0)
    noisy = simulate_bracket(shape=SHAPE, exposure_times=(1,), bits=12, noise_sigma=5)
    d = noisy.frames[0].astype(float) - clean.frames[0].astype(float)
    mid = (clean.frames[0] > 100) & (clean.frames[0] < 3900)
    assert d[mid].std() == pytest.approx(5.0, rel=0.05)
    assert abs(d[mid].mean()) < 0.2


def test_shot_noise_grows_with_signal() -> None:
    kw = dict(shape=(96, 144), exposure_times=(1,), bits=14, noise_sigma=0, scene="patches")
    clean = simulate_bracket(**kw).frames[0].astype(float)
    noisy = simulate_bracket(shot_noise_full_well=1000.0, **kw).frames[0].astype(float)
    d = noisy - clean
    x = clean / 16383
    lo, hi = (x > 0.02) & (x < 0.05), (x > 0.4) & (x < 0.9)
    # Electrons e = x * full_well; sigma in levels = sqrt(x / full_well) * max_level.
    for sel in (lo, hi):
        predicted = np.sqrt(np.mean(x[sel]) / 1000.0) * 16383
        assert d[sel].std() == pytest.approx(predicted, rel=0.15)
    assert d[hi].std() > 2 * d[lo].std()


@pytest.mark.parametrize("name", sorted(RESPONSES))
def test_responses_are_monotone_and_fix_the_ends(name: str) -> None:
    x = np.linspace(0, 1, 1001)
    y = apply_response(name, x)
    assert y[0] == pytest.approx(0.0, abs=1e-12) and y[-1] == pytest.approx(1.0, abs=1e-12)
    assert np.all(np.diff(y) > 0)


def test_nonlinear_response_is_applied_to_levels() -> None:
    sim = simulate_bracket(
        shape=SHAPE, exposure_times=(1,), bits=8, noise_sigma=0, response="gamma"
    )
    lin = np.clip(sim.radiance * sim.key, 0, 1)
    expect = np.rint(np.power(lin, 1 / 2.2) * 255)
    np.testing.assert_array_equal(sim.frames[0], expect.astype(np.uint16))


def test_integer_shift_moves_content_by_the_matrix() -> None:
    # Frame 1 moved by (dx, dy) = (3, -2): to_reference maps its pixel (x, y) to (x + 3, y - 2)
    # of the reference frame, so frame1[y, x] == frame0[y - 2, x + 3] (same exposure, no noise).
    sim = simulate_bracket(
        shape=SHAPE,
        exposure_times=(1, 1),
        bits=16,
        noise_sigma=0,
        reference=0,
        motion=[(0.0, 0.0, 0.0), (3.0, -2.0, 0.0)],
    )
    f0, f1 = (f.astype(int) for f in sim.frames)
    np.testing.assert_allclose(f1[4:-4, 4:-4], f0[2:-6, 7:-1], atol=1)
    m = sim.pair_matrix(0, 1)
    np.testing.assert_allclose(m, [[1, 0, 3], [0, 1, -2]], atol=1e-12)


def test_rotation_matrix_turns_about_the_centre() -> None:
    h, w = SHAPE
    m = rigid_matrix(0, 0, 90, (h, w))
    centre = np.array([(w - 1) / 2, (h - 1) / 2, 1.0])
    np.testing.assert_allclose(m @ centre, centre[:2], atol=1e-12)
    # +90 degrees turns the x axis towards y (clockwise on screen, y down).
    step = m @ (centre + [1, 0, 0]) - centre[:2]
    np.testing.assert_allclose(step, [0, 1], atol=1e-12)


def test_random_hand_held_motion_stays_within_bounds_and_keeps_the_reference() -> None:
    sim = simulate_bracket(
        shape=SHAPE, exposure_times=(1, 4, 16), max_shift=5, max_rotation_deg=1, seed=4
    )
    assert sim.reference == 1
    np.testing.assert_allclose(sim.to_reference[1], rigid_matrix(0, 0, 0, SHAPE), atol=1e-12)
    for m in sim.to_reference:
        angle = np.degrees(np.arctan2(m[1, 0], m[0, 0]))
        assert abs(angle) <= 1.0 + 1e-9
    # The pair matrix composes the per-frame transforms: p_dark = P @ p_bright.
    p = sim.pair_matrix(0, 1)
    np.testing.assert_allclose(compose(sim.to_reference[0], p), sim.to_reference[1], atol=1e-12)


matrices = st.tuples(st.floats(-20, 20), st.floats(-20, 20), st.floats(-10, 10)).map(
    lambda m: rigid_matrix(m[0], m[1], m[2], (48, 64))
)


@settings(max_examples=40, deadline=None)
@given(matrices, matrices, matrices)
def test_transform_axioms(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> None:
    ident = rigid_matrix(0, 0, 0, (48, 64))
    np.testing.assert_allclose(compose(a, invert(a)), ident, atol=1e-9)
    np.testing.assert_allclose(compose(compose(a, b), c), compose(a, compose(b, c)), atol=1e-9)
    # Chaining consecutive pair matrices gives the pair matrix of the outer frames.
    to_ref = (a, b, c)
    np.testing.assert_allclose(
        compose(pair_matrix(to_ref, 0, 1), pair_matrix(to_ref, 1, 2)),
        pair_matrix(to_ref, 0, 2),
        atol=1e-9,
    )


def test_truth_is_json_ready_and_consistent() -> None:
    sim = simulate_bracket(shape=SHAPE, exposure_times=(1, 4, 16), max_shift=3, seed=1)
    truth = json.loads(json.dumps(sim.truth()))
    assert truth["exposure_times"] == [1.0, 4.0, 16.0]
    assert truth["ratios"] == [4.0, 4.0]
    assert truth["shape"] == list(SHAPE)
    assert len(truth["pairs"]) == 2
    np.testing.assert_allclose(truth["pairs"][0]["matrix"], sim.pair_matrix(0, 1))


def test_same_seed_same_bracket() -> None:
    kw = dict(shape=SHAPE, exposure_times=(1, 4), max_shift=4, noise_sigma=1, seed=9)
    a, b = simulate_bracket(**kw), simulate_bracket(**kw)
    for fa, fb in zip(a.frames, b.frames, strict=True):
        np.testing.assert_array_equal(fa, fb)


def test_keep_linear_gives_noiseless_clipped_values() -> None:
    sim = simulate_bracket(shape=SHAPE, exposure_times=(1, 16), keep_linear=True)
    assert len(sim.linear_frames) == 2
    np.testing.assert_allclose(
        sim.linear_frames[0], np.clip(sim.radiance * sim.key, 0, 1), rtol=1e-6
    )
    assert float(sim.linear_frames[1].max()) == 1.0


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (dict(exposure_times=(1, -2)), r"exposure times must be positive"),
        (dict(exposure_times=()), r"exposure times must be positive"),
        (dict(bits=9), r"unsupported bit depth.*expected 8, 10, 12, 14 or 16.*found 9"),
        (dict(noise_sigma=-1), r"noise sigma must be >= 0"),
        (dict(response="cubic"), r"unknown response method 'cubic'"),
        (dict(reference=5), r"reference frame out of range.*0\.\.2"),
        (dict(motion=[(0, 0, 0)]), r"one motion per frame.*expected 3.*found 1"),
        (dict(radiance=np.ones((8, 8))), r"radiance must be \(H, W, 3\)"),
        (dict(radiance=np.zeros((8, 8, 3))), r"radiance must be finite and positive"),
    ],
)
def test_bad_parameters(kwargs: dict, message: str) -> None:
    kw = dict(shape=SHAPE, exposure_times=(1, 4, 16))
    kw.update(kwargs)
    with pytest.raises(ParameterError, match=message):
        simulate_bracket(**kw)
