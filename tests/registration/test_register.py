"""Pair and bracket registration on simulated hand-held brackets with known motion."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.errors import ParameterError
from hdrcore.registration import (
    REGISTRATION_METHODS,
    corner_error,
    cross_correlation_shift,
    register_bracket,
    register_pair,
)
from hdrcore.synthetic import simulate_bracket

from ._pairs import green, simulated_pair

SHAPE = (128, 192)


def _register(dark, bright, ml, ratio=4.0, **kw):
    return register_pair(dark, bright, ratio, saturation=0.98, noise_floor=3 / ml, **kw)


@pytest.mark.parametrize(
    "bits, ratio, motion",
    [
        (12, 4.0, (3.4, -2.2, 0.0)),
        (12, 4.0, (-11.7, 6.3, 1.5)),
        (8, 4.0, (7.25, 9.5, -1.0)),
        (12, 8.0, (14.6, -13.1, 2.0)),
    ],
)
def test_fast_recovers_shift_and_rotation_across_exposure_gap(bits, ratio, motion):
    dark, bright, truth, ml = simulated_pair(bits=bits, motion=motion, ratio=ratio, shape=SHAPE)
    res = _register(dark, bright, ml, ratio)
    assert res.ok, res.message
    err = corner_error(res.matrix, truth, SHAPE)
    assert err.max() < (0.15 if bits == 8 else 0.08), err
    assert res.cost_after < res.cost_before
    assert res.iterations == len(res.cost_history) == len(res.level_history) > 0
    assert res.level_history[-1] == 0


def test_cerman2006_nelder_mead_recovers_motion():
    dark, bright, truth, ml = simulated_pair(motion=(-4.3, 2.6, 0.7), shape=SHAPE)
    res = _register(dark, bright, ml, method="Cerman 2006", max_samples=20_000)
    assert res.ok and res.method == "Cerman 2006"
    assert corner_error(res.matrix, truth, SHAPE).max() < 0.1


def test_shift_model_keeps_zero_rotation():
    dark, bright, truth, ml = simulated_pair(motion=(5.5, -3.25, 0.0), shape=SHAPE)
    res = _register(dark, bright, ml, model="shift")
    assert res.ok and res.angle_deg == 0.0
    assert corner_error(res.matrix, truth, SHAPE).max() < 0.08


def test_identical_frames_give_identity():
    dark, _, _, ml = simulated_pair(shape=SHAPE)
    res = _register(dark, dark.copy(), ml, ratio=1.0)
    assert res.ok
    assert np.allclose(res.matrix, np.eye(2, 3), atol=1e-6)
    assert res.cost_after == pytest.approx(0.0, abs=1e-12)


def test_flat_pair_fails_with_a_message_and_identity():
    rng = np.random.default_rng(0)
    dark = np.clip(0.1 + rng.normal(0, 1 / 4095, SHAPE), 0, 1).astype(np.float32)
    bright = np.clip(0.4 + rng.normal(0, 1 / 4095, SHAPE), 0, 1).astype(np.float32)
    res = register_pair(dark, bright, 4.0, saturation=0.98, noise_floor=0.001)
    assert not res.ok
    assert res.status == "flat"
    assert "texture" in res.message
    assert np.allclose(res.matrix, np.eye(2, 3))


def test_saturated_pair_fails_with_a_message():
    dark, bright, _, ml = simulated_pair(shape=SHAPE)
    res = register_pair(np.ones(SHAPE), np.ones(SHAPE), 4.0, saturation=0.98, noise_floor=0.01)
    assert res.status == "saturated" and "well-exposed" in res.message
    assert np.allclose(res.matrix, np.eye(2, 3))
    # bright frame blown out entirely
    res = register_pair(dark, np.ones(SHAPE), 4.0, saturation=0.98, noise_floor=3 / ml)
    assert res.status == "saturated"


def test_unrelated_frames_give_weak_peak():
    _, bright, _, ml = simulated_pair(shape=SHAPE, seed=1)
    rng = np.random.default_rng(5)
    noise = (0.05 + 0.04 * rng.random(SHAPE)).astype(np.float32)
    res = register_pair(noise, bright, 4.0, saturation=0.98, noise_floor=3 / ml)
    assert res.status in ("weak-peak", "diverged")
    assert res.message


def test_fourier_shift_sign_convention():
    rng = np.random.default_rng(3)
    base = rng.random((64, 96))
    dark = np.roll(base, (5, -7), axis=(0, 1))  # dark[y + 5, x - 7] = bright[y, x]
    shift = cross_correlation_shift(base, dark)  # eq. 5: dark(x + dx, y + dy) = bright(x, y)
    assert (shift.dx, shift.dy) == (-7, 5)
    assert shift.ncc > 0.9 and shift.psr > 10


@pytest.fixture(scope="module")
def three_frames():
    """A simulated 12-bit hand-held bracket of three frames and their green channels."""
    sb = simulate_bracket(
        shape=SHAPE,
        exposure_times=(1.0, 4.0, 16.0),
        bits=12,
        noise_sigma=1.0,
        max_shift=6.0,
        max_rotation_deg=1.0,
        seed=4,
    )
    return sb, [green(f, sb.max_level) for f in sb.frames]


def test_bracket_chain_matches_truth_and_reference(three_frames):
    sb, frames = three_frames
    res = register_bracket(frames, sb.ratios, saturation=0.98, noise_floor=3 / sb.max_level)
    assert res.ok and res.reference == 1
    for k in range(3):
        assert corner_error(res.to_reference[k], sb.to_reference[k], SHAPE).max() < 0.1
    js = res.to_json()
    assert js["reference"] == 1 and len(js["pairs"]) == 2 and len(js["to_reference"]) == 3
    res0 = register_bracket(
        frames,
        sb.ratios,
        reference=0,
        saturation=0.98,
        noise_floor=3 / sb.max_level,
        previews=False,
    )
    assert np.allclose(res0.to_reference[0], np.eye(2, 3))


def test_previews_for_the_inspector():
    dark, bright, _, ml = simulated_pair(motion=(6.0, -4.0, 1.0), shape=SHAPE)
    res = _register(dark, bright, ml)
    p = res.preview
    assert p is not None
    assert p.overlay_before.shape == p.overlay_after.shape == SHAPE + (3,)
    assert p.overlay_after.dtype == np.uint8
    assert np.nanmean(p.difference_after**2) < np.nanmean(p.difference_before**2)
    assert np.nanmax(np.abs(p.difference_after)) <= 1.0


def test_bad_input_is_rejected():
    img = np.ones(SHAPE, np.float32)
    with pytest.raises(ParameterError, match="unknown registration method"):
        register_pair(img, img, 2.0, method="sift")
    with pytest.raises(ParameterError, match="unknown motion model"):
        register_pair(img, img, 2.0, model="projective")
    with pytest.raises(ParameterError, match="differ in size"):
        register_pair(img, img[:-1], 2.0)
    with pytest.raises(ParameterError, match="single-channel"):
        register_pair(np.ones(SHAPE + (3,)), np.ones(SHAPE + (3,)), 2.0)
    with pytest.raises(ParameterError, match="exposure ratio"):
        register_pair(img, img, -1.0)
    with pytest.raises(ParameterError, match="noise floor"):
        register_pair(img, img, 2.0, saturation=1.0, noise_floor=2.0)
    with pytest.raises(ParameterError, match="one exposure ratio per consecutive pair"):
        register_bracket([img, img, img], [2.0])
    assert set(REGISTRATION_METHODS) == {"fast", "Cerman 2006"}


def test_unknown_option_is_rejected_with_the_accepted_names():
    img = np.ones(SHAPE, np.float32)
    with pytest.raises(ParameterError, match="unknown option.*max_samples"):
        register_pair(img, img, 2.0, max_smaples=10)


def test_warping_with_the_result_aligns_the_frames():
    from hdrcore.registration import warp_to_reference

    dark, bright, _, ml = simulated_pair(motion=(6.5, -3.5, 1.2), shape=SHAPE)
    res = _register(dark, bright, ml)
    warped = warp_to_reference(bright, res.matrix, margin=2.0)  # bright -> dark frame
    k = 4.0
    ok = warped.mask & (dark > 20 / ml) & (warped.image < 0.9) & (dark * k < 0.9)
    rel = np.abs(warped.image[ok] - k * dark[ok]) / (warped.image[ok] + k * dark[ok])
    assert ok.mean() > 0.3
    assert np.median(rel) < 0.02


def test_initial_matrix_without_overlap_fails_as_no_overlap():
    dark, bright, _, ml = simulated_pair(shape=SHAPE)
    far = np.array([[1.0, 0.0, 180.0], [0.0, 1.0, 120.0]])
    res = _register(dark, bright, ml, initial=far)
    assert res.status == "no-overlap" and res.overlap < 0.2
    assert np.allclose(res.matrix, np.eye(2, 3))


def test_bracket_then_runs_on_each_pair_before_the_chain(three_frames):
    """``then`` is applied to every registered pair (on its worker) and its pairs are chained;
    a pair it gives without a 2x3 matrix makes the chain 3x3 matrices."""
    from dataclasses import replace

    sb, frames = three_frames
    kw = dict(saturation=0.98, noise_floor=3 / sb.max_level, previews=False)
    seen: list[int] = []

    def note(q):
        seen.append(q.dark)
        return replace(q, message=q.message + " (seen)")

    kept = register_bracket(frames, sb.ratios, then=note, **kw)
    assert sorted(seen) == [0, 1]
    assert all(q.message.endswith("(seen)") for q in kept.pairs)
    assert kept.to_reference is not None  # every pair still affine: 2x3 chain

    def as_homography(q):
        return replace(q, matrix=None, model="homography") if q.dark == 0 else q

    mixed = register_bracket(frames, sb.ratios, then=as_homography, **kw)
    assert mixed.to_reference is None and len(mixed.to_reference_homography) == 3
    for k in range(3):
        np.testing.assert_allclose(
            mixed.to_reference_homography[k][:2], kept.to_reference[k], atol=1e-9
        )
