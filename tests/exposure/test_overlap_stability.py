"""Beyond the paper: grouped 3V, cached re-fits, overlap-restricted histograms of registered pairs
and the region jack-knife that flags pairs disturbed by hand-held motion (simulated truth)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hdrcore.errors import ParameterError
from hdrcore.exposure import (
    bracket_exposures,
    bracket_exposures_from_histograms,
    bracket_exposures_registered,
    bracket_histograms,
    chain_pair_matrix,
    common_field_masks,
    pair_histograms_in_overlap,
    region_histograms,
)
from hdrcore.exposure._core import solve_3v
from hdrcore.histogram import histograms
from hdrcore.registration import valid_mask
from hdrcore.synthetic import invert, rigid_matrix, simulate_bracket

TIMES = (1.0, 4.0, 16.0, 64.0)


@pytest.fixture(scope="module")
def integer_hand_held():
    # Whole-pixel shifts: the simulator samples the scene without interpolation, so the common
    # field of view of two frames holds exactly the same radiance samples.
    motion = [(9.0, -7.0, 0.0), (-6.0, 8.0, 0.0), (0.0, 0.0, 0.0), (11.0, 5.0, 0.0)]
    return simulate_bracket(
        scene="night",
        shape=(160, 240),
        exposure_times=TIMES,
        bits=12,
        noise_sigma=1.0,
        motion=motion,
        seed=11,
    )


def test_grouped_solver_is_exact_least_squares() -> None:
    rng = np.random.default_rng(0)
    x = rng.uniform(0.1, 1.0, 400)
    y = 3.0 * x + rng.normal(0, 0.01, 400)
    w = rng.uniform(0.5, 2.0, 400)
    exact = float(np.sum(w**2 * x * y) / np.sum(w**2 * x**2))
    for groups in (None, np.arange(400) // 8):
        k, iterates, mask, residuals, _, se = solve_3v(x, y, w, groups=groups)
        assert iterates[0] == pytest.approx(exact, rel=1e-12)  # k0: closed form over all rows
        assert abs(k / 3 - 1) < 1e-3 and se > 0
        np.testing.assert_allclose(residuals, w * y - k * w * x)
        if groups is not None:  # whole groups are in or out together
            assert all(len(set(mask[groups == g])) == 1 for g in range(50))


def test_refit_is_identical_to_a_fresh_fit_and_reuses_transfer_functions() -> None:
    b = simulate_bracket(shape=(96, 144), exposure_times=TIMES, bits=14, seed=7)
    hists = bracket_histograms(b.frames, b.max_level)
    first = bracket_exposures_from_histograms(hists)
    btf = hists.pair(0, 1).btfs()
    assert hists.pair(0, 1).btfs() is btf  # cached per pair
    assert btf[0].forward_at_edges() is btf[0].forward_at_edges()
    for z, floor in ((15000, 300), (16000, 500)):
        refit = bracket_exposures_from_histograms(hists, saturation=z, noise_floor=floor)
        fresh = bracket_exposures_from_histograms(
            bracket_histograms(b.frames, b.max_level), saturation=z, noise_floor=floor
        )
        assert refit.ratios == fresh.ratios
        for p, q in zip(
            refit.pairs + refit.extra_pairs, fresh.pairs + fresh.extra_pairs, strict=True
        ):
            assert (p.ratio, p.status, p.message, p.iterates) == (
                q.ratio,
                q.status,
                q.message,
                q.iterates,
            )
            assert p.region_ratios == q.region_ratios
            np.testing.assert_array_equal(p.inlier_mask, q.inlier_mask)
        assert hists.pair(0, 1).btfs() is btf
    np.testing.assert_allclose(first.ratios, [4, 4, 4], rtol=1e-3)


def test_common_field_masks_follow_the_registration_convention() -> None:
    shape = (40, 60)
    m = rigid_matrix(3.5, -2.0, 0.7, shape)
    d0, b0 = common_field_masks(m, shape, margin=0)
    np.testing.assert_array_equal(b0, valid_mask(m, shape, shape))
    # The dark set follows the bright set through the matrix: the registration's test of the
    # inverse up to border pixels.
    diff = d0 != valid_mask(invert(m), shape, shape)
    assert diff.sum() <= 2 * sum(shape)  # at most about one ring of border pixels
    d2, b2 = common_field_masks(m, shape, margin=2)
    own = np.zeros(shape, bool)
    own[2:-2, 2:-2] = True
    np.testing.assert_array_equal(b2, valid_mask(m, shape, shape, 2) & own)


@pytest.mark.parametrize("dx,dy", [(5.0, -3.0), (5.0014, -2.9993), (4.4996, 3.5004)])
def test_sub_pixel_shift_counts_the_same_pixels(dx: float, dy: float) -> None:
    # A registration is never exactly integer: the masks must still be images of each other.
    shape = (30, 50)
    m = np.array([[1.0, 0.0, dx], [0.0, 1.0, dy]])
    d, b = common_field_masks(m, shape, margin=2)
    assert d.sum() == b.sum()
    ys, xs = np.nonzero(b)
    np.testing.assert_array_equal(
        d[np.rint(ys + dy).astype(int), np.rint(xs + dx).astype(int)], True
    )


def test_pair_histograms_in_overlap_counts_the_same_content(integer_hand_held) -> None:
    b = integer_hand_held
    m = b.pair_matrix(0, 1)
    ph = pair_histograms_in_overlap(
        b.frames[0], b.frames[1], b.max_level, m, margin=1, dark=0, bright=1
    )
    assert ph.overlap_restricted and 0.8 < ph.common_fraction < 1.0
    assert ph.counts_dark.sum() == ph.counts_bright.sum()  # a shift maps pixels one to one
    np.testing.assert_array_equal(ph.regions_dark.sum(axis=0), ph.counts_dark)
    mask_d, mask_b = common_field_masks(m, b.frames[0].shape[:2], margin=1)
    np.testing.assert_array_equal(ph.counts_bright, histograms(b.frames[1], b.max_level, mask_b))
    np.testing.assert_array_equal(ph.counts_dark, histograms(b.frames[0], b.max_level, mask_d))
    # The identity with no margin counts whole frames; regions sum to the frame histogram.
    same = pair_histograms_in_overlap(b.frames[0], b.frames[1], b.max_level, np.eye(2, 3), margin=0)
    np.testing.assert_array_equal(same.counts_dark, histograms(b.frames[0], b.max_level))
    np.testing.assert_array_equal(
        region_histograms(b.frames[0], b.max_level).sum(axis=0),
        histograms(b.frames[0], b.max_level),
    )


def test_overlap_restriction_recovers_tripod_accuracy(integer_hand_held) -> None:
    b = integer_hand_held
    mats = [b.pair_matrix(k, k + 1) for k in range(len(TIMES) - 1)]
    plain = bracket_exposures(b.frames, b.max_level)
    reg = bracket_exposures_registered(b.frames, b.max_level, mats)
    err_plain = max(abs(p.ratio / 4 - 1) for p in plain.pairs)
    err_reg = max(abs(p.ratio / 4 - 1) for p in reg.pairs)
    assert err_plain > 0.005  # the borders disturb the whole-frame histograms
    assert err_reg < 5e-4  # tripod accuracy at 12 bits (test_exposure: 5e-4)
    assert reg.ok, reg.message
    for p in reg.pairs:
        assert p.overlap_restricted and p.common_fraction < 1
        assert "common field of view" in p.message
        assert p.to_json()["overlap_restricted"] is True
    assert all(e.overlap_restricted for e in reg.extra_pairs)


def test_pairs_disturbed_by_motion_are_flagged_unstable() -> None:
    b = simulate_bracket(
        scene="night",
        shape=(160, 240),
        exposure_times=TIMES,
        bits=12,
        noise_sigma=1.0,
        max_shift=10,
        max_rotation_deg=0.5,
        seed=3,
    )
    res = bracket_exposures(b.frames, b.max_level)
    errors = [abs(p.ratio / 4 - 1) for p in res.pairs]
    assert max(errors) > 0.01
    for p, e in zip(res.pairs, errors, strict=True):
        if e > 0.01:
            assert not p.ok
        assert np.isfinite(p.region_std_error) and len(p.region_ratios) == 9
    unstable = [p for p in res.pairs if p.status == "unstable"]
    assert unstable
    assert "register the frames first" in unstable[0].message
    assert unstable[0].honest_std_error >= unstable[0].std_error


def test_tripod_pairs_stay_ok_with_an_honest_error() -> None:
    b = simulate_bracket(
        scene="landscape", shape=(128, 192), exposure_times=TIMES, bits=12, noise_sigma=1.0, seed=5
    )
    res = bracket_exposures(b.frames, b.max_level)
    assert res.ok, res.message
    for p in res.pairs:
        assert p.region_std_error < 0.001 * p.ratio
        assert p.region_std_error > p.std_error  # the fit's error ignores correlated rows
    off = bracket_exposures(b.frames, b.max_level, regions=None)
    assert all(not p.region_ratios and np.isnan(p.region_std_error) for p in off.pairs)
    assert off.ratios == pytest.approx(res.ratios, rel=1e-6)  # chain weights differ


def test_chain_pair_matrix_composes_consecutive_pairs(integer_hand_held) -> None:
    b = integer_hand_held
    mats = [b.pair_matrix(k, k + 1) for k in range(3)]
    np.testing.assert_allclose(chain_pair_matrix(mats, 0, 3), b.pair_matrix(0, 3), atol=1e-9)
    np.testing.assert_allclose(chain_pair_matrix(mats, 1, 2), mats[1])


def test_bad_overlap_input() -> None:
    f = np.zeros((20, 30, 3), np.uint16)
    with pytest.raises(ParameterError, match="finite 2x3 affine"):
        pair_histograms_in_overlap(f, f, 255, np.eye(3))
    with pytest.raises(ParameterError, match="singular"):
        pair_histograms_in_overlap(f, f, 255, np.zeros((2, 3)))
    with pytest.raises(ParameterError, match="same"):
        pair_histograms_in_overlap(f, f[:10], 255, np.eye(2, 3))
    with pytest.raises(ParameterError, match="one pair matrix per consecutive pair"):
        bracket_histograms([f, f, f], 255, pair_matrices=[np.eye(2, 3)])
    with pytest.raises(ParameterError, match="grid"):
        bracket_histograms([f, f], 255, regions=(0, 3))


def test_starting_ratios_replace_wild_estimates() -> None:
    b = simulate_bracket(scene="window", shape=(96, 144), exposure_times=TIMES, bits=12, seed=2)
    res = bracket_exposures(b.frames, b.max_level)
    np.testing.assert_allclose(res.starting_ratios(), [p.ratio for p in res.pairs])
    wild = replace(res, pairs=(replace(res.pairs[0], ratio=0.6),) + res.pairs[1:])
    assert wild.starting_ratios()[0] == pytest.approx(
        np.median([0.6] + [p.ratio for p in res.pairs[1:]])
    )
    with_exif = replace(wild, exif_ratios=(4.0, 4.0, 4.0))
    assert with_exif.starting_ratios()[0] == 4.0
