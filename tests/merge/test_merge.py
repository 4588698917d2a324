"""The merge against simulated brackets with known radiance (hdrcore.synthetic.simulate_bracket).

Truth: a frame of exposure ``t`` records ``radiance * t * key`` (linear, before the response), so
with the true exposure times the merge must return ``radiance * key``.
"""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.errors import ParameterError
from hdrcore.merge import NoiseModel, merge
from hdrcore.synthetic import simulate_bracket

from ._brackets import SHAPE, TIMES, bracket, inverse_gamma_lut, relative_error, well_exposed


@pytest.mark.parametrize("workers", [1, 2])
def test_tripod_12bit_linear_median_error_below_one_percent(workers):
    sb = bracket(bits=12, response="linear", noise_sigma=1.0, seed=1)
    res = merge(sb.frames, sb.exposure_times, max_level=sb.max_level, workers=workers)
    assert res.weighting == "noise-aware"
    assert res.radiance.dtype == np.float32 and res.radiance.shape == sb.radiance.shape
    err = relative_error(res.radiance, sb)
    assert float(np.median(err[well_exposed(sb)])) <= 0.01


def test_tripod_12bit_gamma_with_lut_median_error_below_one_percent():
    sb = bracket(bits=12, response="gamma", noise_sigma=1.0, seed=2)
    res = merge(sb.frames, sb.exposure_times, response=inverse_gamma_lut(sb.max_level))
    assert res.weighting == "hat-noise-aware"
    err = relative_error(res.radiance, sb)
    assert float(np.median(err[well_exposed(sb)])) <= 0.01


def test_tripod_8bit_gamma_median_error_within_quantisation():
    sb = bracket(bits=8, response="gamma", noise_sigma=1.0, seed=3)
    res = merge(sb.frames, sb.exposure_times, response=inverse_gamma_lut(255))
    err = relative_error(res.radiance, sb)
    # 8 bits: one level is ~1 % of mid-grey after the gamma; the merge averages three frames.
    assert float(np.median(err[well_exposed(sb)])) <= 0.02


def test_float_linear_frames_are_merged_exactly_without_noise():
    sb = bracket(bits=12, response="linear", seed=4)
    frames = [np.asarray(f, np.float32) for f in sb.linear_frames]
    res = merge(frames, sb.exposure_times)
    assert res.units == "linear"
    err = relative_error(res.radiance, sb)
    assert float(np.max(err[well_exposed(sb)])) < 1e-4


def test_workers_give_identical_results():
    sb = bracket(bits=12, response="linear", seed=5)
    a = merge(sb.frames, sb.exposure_times, max_level=sb.max_level, workers=1, chunk_pixels=5000)
    b = merge(sb.frames, sb.exposure_times, max_level=sb.max_level, workers=3, chunk_pixels=5000)
    np.testing.assert_array_equal(a.radiance, b.radiance)
    np.testing.assert_array_equal(a.shares, b.shares)
    np.testing.assert_array_equal(a.ghost_score, b.ghost_score)


def test_frame_order_does_not_matter():
    sb = bracket(bits=12, response="linear", seed=6)
    a = merge(sb.frames, sb.exposure_times, max_level=sb.max_level)
    b = merge(sb.frames[::-1], sb.exposure_times[::-1], max_level=sb.max_level)
    np.testing.assert_allclose(a.radiance, b.radiance, rtol=1e-6)
    np.testing.assert_array_equal(a.shares, b.shares[::-1])


def _bright_patch_radiance() -> np.ndarray:
    rng = np.random.default_rng(0)
    rad = np.exp(rng.normal(-1.0, 0.3, SHAPE + (3,))).astype(np.float32)
    rad[40:80, 60:120] = 1e4  # far above saturation even in the darkest frame
    return rad


def test_pixels_clipped_in_every_frame_take_the_darkest_frame_and_are_flagged():
    rad = _bright_patch_radiance()
    sb = simulate_bracket(rad, exposure_times=TIMES, bits=12, key=0.1, seed=7)
    res = merge(sb.frames, sb.exposure_times, max_level=sb.max_level)
    patch = np.zeros(SHAPE, bool)
    patch[40:80, 60:120] = True
    assert res.clipped[patch].all()
    assert not res.clipped[~patch].any()
    assert (res.clip_count[patch] == 3).all()
    darkest = sb.frames[0][patch].astype(np.float64) / sb.max_level / TIMES[0]
    np.testing.assert_allclose(res.radiance[patch], darkest, rtol=1e-6)
    assert (res.shares[0][patch] == 1).all() and (res.shares[1:, patch] == 0).all()
    assert res.status == "warning" and "clipped in every frame" in res.message


def test_no_colour_cast_where_one_channel_clips_first():
    """A saturated orange: red clips in the middle frame while green and blue do not."""
    rad = np.empty(SHAPE + (3,), np.float32)
    rad[...] = (1.0, 0.3, 0.1)
    rad[:, SHAPE[1] // 2 :] = (0.05, 0.04, 0.03)  # a dim part so the bracket has range
    sb = simulate_bracket(rad, exposure_times=(1.0, 2.0, 4.0), bits=12, key=0.7, seed=8)
    # frame 1: red at 1.4 (clipped), green at 0.42 (fine) -> must not be used for any channel.
    res = merge(sb.frames, sb.exposure_times, max_level=sb.max_level)
    left = res.radiance[:, : SHAPE[1] // 2] / sb.key
    ratio_rg = left[..., 0] / left[..., 1]
    ratio_gb = left[..., 1] / left[..., 2]
    assert abs(float(np.median(ratio_rg)) - 1.0 / 0.3) / (1.0 / 0.3) < 0.01
    assert abs(float(np.median(ratio_gb)) - 3.0) / 3.0 < 0.01
    # every pixel of the orange comes from the darkest frame only
    assert (res.shares[0][:, : SHAPE[1] // 2] == 1).all()


def test_per_channel_white_levels():
    """RAW-like: the red channel saturates at a lower level (3000) than green and blue (4095)."""
    rad = np.empty(SHAPE + (3,), np.float32)
    rad[...] = (0.8, 0.5, 0.3)
    sb = simulate_bracket(rad, exposure_times=(1.0, 2.0), bits=12, key=0.5, seed=9)
    frames = [f.copy() for f in sb.frames]
    for f in frames:
        f[..., 0] = np.minimum(f[..., 0], 3000)  # frame 1 red: 0.8 * 4095 -> clipped at 3000
    res = merge(frames, sb.exposure_times, max_level=4095, saturation_level=(3000, 4095, 4095))
    e = res.radiance / sb.key
    np.testing.assert_allclose(np.median(e.reshape(-1, 3), axis=0), (0.8, 0.5, 0.3), rtol=0.01)
    assert (res.shares[1] == 0).all()


def test_ghost_map_lights_up_on_a_moving_object():
    sb = bracket(bits=12, response="linear", noise_sigma=1.0, seed=10, scene="window")
    frames = [f.copy() for f in sb.frames]
    # an object in the middle frame only: a grey square where the other frames see the scene
    frames[1][60:90, 20:60] = 1500
    res = merge(frames, sb.exposure_times, max_level=sb.max_level)
    obj = np.zeros(SHAPE, bool)
    obj[60:90, 20:60] = True
    multi = (res.shares.astype(np.float32) > 0.02).sum(axis=0) >= 2
    inside = obj & multi
    assert inside.sum() > 100
    assert res.ghost[inside].mean() > 0.8
    assert res.ghost[~obj].mean() < 0.01
    assert res.summary()["ghost_fraction"] > 0


def test_static_bracket_has_almost_no_ghosts():
    sb = bracket(bits=8, response="gamma", noise_sigma=1.0, seed=11)
    res = merge(sb.frames, sb.exposure_times, response=inverse_gamma_lut(255))
    assert res.ghost.mean() < 0.005


def test_provenance_shares_sum_to_one_and_favour_long_exposures_in_shadows():
    sb = bracket(bits=12, response="linear", noise_sigma=1.0, seed=12)
    res = merge(sb.frames, sb.exposure_times, max_level=sb.max_level)
    shares = res.shares.astype(np.float32)
    assert res.shares.dtype == np.float16 and res.shares.shape == (3,) + SHAPE
    assert shares.min() >= 0 and shares.max() <= 1
    np.testing.assert_allclose(shares.sum(axis=0), 1.0, atol=2e-3)
    dark = (sb.linear_frames[2] < 0.5).all(axis=2)  # unclipped in the longest exposure
    assert (res.dominant_frame[dark] == 2).mean() > 0.99
    summary = res.summary()
    assert abs(sum(summary["provenance"]["mean_share"]) - 1) < 1e-6


def test_validity_masks_drop_warped_borders():
    sb = bracket(bits=12, response="linear", seed=13)
    mask = np.ones(SHAPE, bool)
    mask[:, :20] = False
    res = merge(sb.frames, sb.exposure_times, max_level=sb.max_level, masks=[None, None, mask])
    assert (res.shares[2][:, :20] == 0).all()
    assert (res.clip_count[:, :20] <= 2).all()
    err = relative_error(res.radiance, sb)
    assert float(np.median(err[well_exposed(sb)])) <= 0.01


def test_below_noise_floor_everywhere_is_flagged_and_takes_the_brightest_frame():
    frames = [np.full((8, 8, 3), v, np.uint16) for v in (100, 400, 1600)]
    for f in frames:
        f[:2, :2, 2] = 5  # blue at level 5 in every frame: below a floor of 10
    res = merge(frames, (1.0, 4.0, 16.0), max_level=4095, noise_floor=10)
    assert res.underexposed[:2, :2].all() and not res.underexposed[2:].any()
    np.testing.assert_allclose(res.radiance[:2, :2, 2], 5 / 4095 / 16.0, rtol=1e-6)
    np.testing.assert_allclose(res.radiance[:2, :2, 0], 100 / 4095, rtol=1e-3)
    np.testing.assert_allclose(res.shares.astype(np.float32).sum(axis=0), 1.0, atol=2e-3)


def test_noise_aware_weights_win_under_shot_noise():
    """With shot noise (full well 5000 e-) the inverse-variance weight is the most accurate."""
    sb = bracket(bits=12, response="linear", seed=14, shot_noise_full_well=5000)
    noise = NoiseModel(read_noise=2e-4, full_well=5000)
    errors = {}
    for name in ("hat", "gaussian", "uniform", "noise-aware"):
        res = merge(sb.frames, sb.exposure_times, max_level=4095, weighting=name, noise=noise)
        assert res.weighting == name
        errors[name] = float(np.median(relative_error(res.radiance, sb)[well_exposed(sb)]))
    assert errors["noise-aware"] == min(errors.values())
    assert errors["noise-aware"] < 0.02 < errors["uniform"]
    assert res.summary()["noise"]["full_well"] == 5000


# ---- bad input -------------------------------------------------------------------------------


def _frames(n=3, shape=(4, 5, 3), dtype=np.uint16):
    return [np.full(shape, 100 * (k + 1), dtype) for k in range(n)]


def test_empty_list_is_refused():
    with pytest.raises(ParameterError, match="no frames to merge"):
        merge([], [])


def test_mismatched_shapes_are_refused():
    frames = _frames()
    frames[2] = np.zeros((4, 6, 3), np.uint16)
    with pytest.raises(ParameterError, match=r"frame 2 has a different shape.*\(4, 5, 3\)"):
        merge(frames, (1, 2, 4), max_level=4095)


@pytest.mark.parametrize("times", [(1, 0, 4), (1, -2, 4), (1, np.nan, 4)])
def test_non_positive_times_are_refused(times):
    with pytest.raises(ParameterError, match="exposure times must be finite and positive"):
        merge(_frames(), times, max_level=4095)


def test_wrong_number_of_times_is_refused():
    with pytest.raises(ParameterError, match="one exposure time per frame"):
        merge(_frames(), (1, 2), max_level=4095)


def test_mixed_dtypes_are_refused():
    frames = _frames()
    frames[1] = frames[1].astype(np.float32)
    with pytest.raises(ParameterError, match="mix integer levels and float"):
        merge(frames, (1, 2, 4), max_level=4095)


def test_uint16_without_max_level_or_lut_is_refused():
    with pytest.raises(ParameterError, match="max_level is needed"):
        merge(_frames(), (1, 2, 4))


def test_lut_of_the_wrong_length_is_refused():
    with pytest.raises(ParameterError, match="LUT length must be max_level"):
        merge(_frames(), (1, 2, 4), response=np.zeros((3, 256)), max_level=4095)
    with pytest.raises(ParameterError, match=r"\(C, L\)"):
        merge(_frames(), (1, 2, 4), response=np.zeros((2, 4096)))


def test_lut_with_float_frames_is_refused():
    frames = [f.astype(np.float32) / 4095 for f in _frames()]
    with pytest.raises(ParameterError, match="integer levels only"):
        merge(frames, (1, 2, 4), response=np.zeros((3, 4096)))


def test_out_of_range_levels_are_refused():
    with pytest.raises(ParameterError, match="saturation level out of range"):
        merge(_frames(), (1, 2, 4), max_level=4095, saturation_level=5000)
    with pytest.raises(ParameterError, match="noise floor out of range"):
        merge(_frames(), (1, 2, 4), max_level=4095, noise_floor=4000, saturation_level=3000)
    with pytest.raises(ParameterError, match="one per channel"):
        merge(_frames(), (1, 2, 4), max_level=4095, saturation_level=(4000, 4000))


def test_unknown_weighting_lists_the_valid_names():
    with pytest.raises(ParameterError, match="unknown weighting method 'tent'.*'hat'"):
        merge(_frames(), (1, 2, 4), max_level=4095, weighting="tent")


def test_mask_of_the_wrong_shape_is_refused():
    with pytest.raises(ParameterError, match="validity mask 1 does not match"):
        merge(_frames(), (1, 2, 4), max_level=4095, masks=[None, np.ones((3, 3), bool), None])


def test_unsupported_dtype_is_refused():
    frames = [f.astype(np.int16) for f in _frames()]
    with pytest.raises(ParameterError, match="unsupported dtype"):
        merge(frames, (1, 2, 4), max_level=4095)


_MAPS_FIELDS = ("radiance", "clipped", "underexposed", "ghost_score", "ghost")


def _summary(res) -> dict:
    s = res.summary()
    s.pop("timings")
    if s["ghost_regions"] is not None:
        s["ghost_regions"].pop("timings")
    return s


@pytest.mark.parametrize("warped", [False, True])
@pytest.mark.parametrize("channels", [3, 4])
def test_without_weight_maps_the_same_merge_and_provenance(warped, channels):
    """``weight_maps=False`` keeps no shares nor weight sum; every other output and the
    summary (its provenance counted in the kernel) are those of a merge that keeps them, to
    the last bit. Frame 2 repeats frame 1 (same time): their shares tie everywhere, and the
    tie goes to the first, as :func:`provenance_summary` has it."""
    from hdrcore.merge import provenance_summary
    from hdrcore.registration import invert

    sb = bracket(bits=12, response="linear", seed=4, max_shift=3.0, max_rotation_deg=0.5)
    frames = list(sb.frames)
    if channels == 4:
        frames = [np.ascontiguousarray(np.concatenate([f, f[..., 1:2]], axis=2)) for f in frames]
    frames = [frames[0], frames[1], frames[1].copy(), *frames[2:]]
    times = [sb.exposure_times[0], sb.exposure_times[1], sb.exposure_times[1]]
    times += list(sb.exposure_times[2:])
    tf = None
    if warped:
        inv = [invert(t) for t in sb.to_reference]
        tf = [inv[0], inv[1], inv[1], *inv[2:]]
    kw = {"max_level": 4095, "transforms": tf, "workers": 2, "chunk_pixels": 512}
    kept = merge(frames, times, **kw)
    lean = merge(frames, times, weight_maps=False, **kw)
    assert lean.share_maps is None and lean.weight_sum_map is None
    assert lean.clip_count_map is None
    with pytest.raises(ValueError, match="weight_maps"):
        _ = lean.clip_count
    with pytest.raises(ValueError, match="weight_maps"):
        _ = lean.shares
    with pytest.raises(ValueError, match="weight_maps"):
        _ = lean.weight_sum
    for name in _MAPS_FIELDS:
        np.testing.assert_array_equal(getattr(lean, name), getattr(kept, name), err_msg=name)
    assert lean.provenance == provenance_summary(kept.shares)
    assert lean.provenance["dominant_fraction"][2] == 0.0  # the tie went to frame 1
    assert lean.provenance["dominant_fraction"][1] > 0.0
    assert _summary(lean) == _summary(kept)
    assert lean.n_frames == kept.n_frames == len(frames)


def test_weight_maps_kept_for_deghosting_and_made_for_a_reuse_without_them():
    sb = bracket(bits=12, response="linear", seed=5)
    kw = {"max_level": 4095}
    kept = merge(sb.frames, sb.exposure_times, deghost=True, **kw)
    lean = merge(sb.frames, sb.exposure_times, deghost=True, weight_maps=False, **kw)
    np.testing.assert_array_equal(lean.shares, kept.shares)  # deghosting reads them
    np.testing.assert_array_equal(lean.weight_sum, kept.weight_sum)
    np.testing.assert_array_equal(lean.clip_count, kept.clip_count)
    np.testing.assert_array_equal(lean.radiance, kept.radiance)
    fresh = merge(sb.frames, sb.exposure_times, **kw)
    old = merge(sb.frames, sb.exposure_times, weight_maps=False, saturation_level=3000, **kw)
    radiance = old.radiance
    again = merge(sb.frames, sb.exposure_times, reuse=old, **kw)  # maps made anew
    assert again.radiance is radiance
    np.testing.assert_array_equal(again.shares, fresh.shares)
    np.testing.assert_array_equal(again.weight_sum, fresh.weight_sum)
    np.testing.assert_array_equal(again.clip_count, fresh.clip_count)
    lean_again = merge(sb.frames, sb.exposure_times, reuse=again, weight_maps=False, **kw)
    assert lean_again.share_maps is None and lean_again.radiance is radiance
    assert lean_again.provenance == provenance_summary_of(fresh)


def provenance_summary_of(res) -> dict:
    from hdrcore.merge import provenance_summary

    return provenance_summary(res.shares)


def test_progress_is_told_when_the_region_ghost_test_starts():
    sb = bracket(bits=12, response="linear", seed=6)
    calls: list[tuple[float, str]] = []
    merge(sb.frames, sb.exposure_times, max_level=4095, progress=lambda f, m: calls.append((f, m)))
    assert calls == [(0.5, "ghost test")]
    calls.clear()
    merge(
        sb.frames,
        sb.exposure_times,
        max_level=4095,
        ghost_test="pixels",
        progress=lambda f, m: calls.append((f, m)),
    )
    assert calls == []  # no region test, nothing to tell
