"""The colour of a non-linear merge checked against its frames, anchored to them, and exposure
fusion for brackets no response can linearise (issue 15)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hdrcore.errors import ParameterError
from hdrcore.merge import merge
from hdrcore.merge.colour_check import (
    MAX_MERGE_ERROR,
    anchor_colour,
    check_colour,
    chromaticity,
    colour_check,
    srgb_decode_lut,
)
from hdrcore.merge.fusion import exposure_fusion
from hdrcore.synthetic import simulate_bracket

TIMES = (1.0, 4.0, 16.0)
LUT = np.tile(srgb_decode_lut(255), (3, 1))
LUMA = np.array([0.2126, 0.7152, 0.0722])


@pytest.fixture(scope="module")
def srgb_bracket():
    sim = simulate_bracket(
        scene="patches",
        shape=(120, 180),
        exposure_times=TIMES,
        bits=8,
        response="srgb",
        noise_sigma=0.5,
        seed=4,
    )
    frames = [f.astype(np.uint8) for f in sim.frames]
    res = merge(frames, TIMES, response=LUT, max_level=255)
    return sim, frames, res


def test_a_right_merge_passes(srgb_bracket) -> None:
    sim, frames, res = srgb_bracket
    cc = colour_check(frames, res.radiance, LUT, max_level=255, reference=1)
    assert cc.status == "ok" and cc.merge_error < 0.005
    assert cc.merge_error == pytest.approx(cc.merge_error_srgb)  # the LUT is sRGB here
    assert cc.frame_consistency < 0.01 and len(cc.frame_pairs) == 2
    assert cc.white_balance_differs == ()
    d = json.loads(json.dumps(cc.to_json()))
    assert d["status"] == "ok" and len(d["best_frame_errors"]) == 3


def test_a_tinted_merge_is_flagged(srgb_bracket) -> None:
    _, frames, res = srgb_bracket
    tinted = res.radiance * np.array([1.0, 1.0, 0.7], np.float32)
    cc = colour_check(frames, tinted, LUT, max_level=255, reference=1)
    assert cc.status == "drift" and cc.merge_error > MAX_MERGE_ERROR
    assert "drift" in cc.message


def test_per_frame_white_balance_is_measured() -> None:
    sim = simulate_bracket(
        scene="patches",
        shape=(120, 180),
        exposure_times=TIMES,
        bits=8,
        response="linear",
        noise_sigma=0.0,
        seed=4,
    )
    x = [f.astype(np.float64) / 255 for f in sim.frames]
    x[2] = x[2] * np.array([1.0, 1.0, 0.9])  # the third shot balanced bluer... less blue
    frames = [
        np.clip(
            np.rint(
                255
                * np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.maximum(v, 0) ** (1 / 2.4) - 0.055)
            ),
            0,
            255,
        ).astype(np.uint8)
        for v in x
    ]
    res = merge(frames, TIMES, response=LUT, max_level=255)
    cc = colour_check(frames, res.radiance, LUT, max_level=255, reference=1)
    assert cc.white_balance_differs == (2,)
    assert cc.white_balance[2][2] == pytest.approx(0.9, abs=0.02)
    assert "white balance differs" in cc.message
    # the re-balanced shot's pair agrees once each frame's balance is divided out, and the
    # report carries both per pair
    raw, out = cc.frame_pairs[1].median_difference, cc.frame_pairs_wb[1].median_difference
    assert raw > 0.01 and out < 0.5 * raw
    d = json.loads(json.dumps(cc.to_json()))
    assert [p["median_difference"] for p in d["frame_pairs_wb"]] == pytest.approx(
        [p.median_difference for p in cc.frame_pairs_wb]
    )


def test_anchoring_gives_the_frames_colour_and_keeps_luminance(srgb_bracket) -> None:
    _, frames, res = srgb_bracket
    tinted = (res.radiance * np.array([1.1, 1.0, 0.75], np.float32)).astype(np.float32)
    y_before = tinted @ LUMA.astype(np.float32)
    done = anchor_colour(
        tinted,
        frames,
        srgb_decode_lut(255),
        max_level=255,
        saturation=250,
        noise_floor=2,
        reference=1,
        lut=LUT,
        exposure_times=TIMES,
        shares=res.shares,
    )
    assert done.max_shift > 0.02 and abs(sum(done.frame_shares) - 1) < 1e-9
    np.testing.assert_allclose(tinted @ LUMA.astype(np.float32), y_before, rtol=1e-4, atol=1e-7)
    cc = colour_check(frames, tinted, LUT, max_level=255, reference=1)
    assert cc.merge_error < 0.005
    # where the reference is clipped the darker frame's colour is followed
    assert cc.best_frame_errors[0][0] < 0.01


def test_check_colour_reports_before_and_after(srgb_bracket) -> None:
    _, frames, res = srgb_bracket
    rad = (res.radiance * np.array([1.0, 1.0, 0.8], np.float32)).astype(np.float32)
    out = check_colour(
        frames,
        rad,
        LUT,
        max_level=255,
        reference=1,
        saturation=250,
        noise_floor=2,
        exposure_times=TIMES,
        shares=res.shares,
    )
    assert out.before.merge_error > MAX_MERGE_ERROR > out.after.merge_error
    assert out.anchor is not None and not out.local_tone_mapping.detected
    assert "anchored" in out.message
    json.dumps(out.to_json())
    kept = check_colour(
        frames,
        rad.copy(),
        LUT,
        max_level=255,
        reference=1,
        saturation=250,
        noise_floor=2,
        anchor=False,
    )
    assert kept.anchor is None and kept.after is kept.before


def test_bad_input(srgb_bracket) -> None:
    _, frames, res = srgb_bracket
    with pytest.raises(ParameterError, match="reference"):
        colour_check(frames, res.radiance, LUT, max_level=255, reference=5)
    with pytest.raises(ParameterError, match="radiance"):
        colour_check(frames, res.radiance[:10], LUT, max_level=255, reference=1)
    with pytest.raises(ParameterError, match="lut"):
        colour_check(frames, res.radiance, LUT[:, :100], max_level=255, reference=1)


def test_exposure_fusion() -> None:
    f = (np.arange(64 * 96 * 3) % 251).reshape(64, 96, 3).astype(np.uint8)
    same = exposure_fusion([f, f], max_level=255)
    assert same.shape == f.shape and same.dtype == np.uint8
    assert np.max(np.abs(same.astype(int) - f.astype(int))) <= 1  # one frame: itself
    sim = simulate_bracket(
        scene="window",
        shape=(96, 144),
        exposure_times=TIMES,
        bits=8,
        response="srgb",
        noise_sigma=0.5,
        seed=1,
    )
    fused = exposure_fusion([x.astype(np.uint8) for x in sim.frames], max_level=255, factor=2)
    assert fused.shape == (48, 72, 3)
    # fewer clipped and black pixels than any single frame
    bad = [np.mean((x >= 250) | (x <= 5)) for x in sim.frames]
    assert np.mean((fused >= 250) | (fused <= 5)) < min(bad)
    assert chromaticity(np.ones((2, 3)))[0] == pytest.approx([1 / 3, 1 / 3])


def _rebalanced(frame: np.ndarray, gains: tuple[float, float, float]) -> np.ndarray:
    """``frame`` (8-bit sRGB) rendered again with another white balance."""
    lin = srgb_decode_lut(255)[frame] * np.asarray(gains)
    v = np.clip(lin, 0.0, 1.0)
    enc = np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)
    return np.round(enc * 255).astype(np.uint8)


@pytest.mark.parametrize("numba", [True, False])
def test_anchoring_gives_every_frame_its_own_colour_where_it_is_best_exposed(
    srgb_bracket, numba, monkeypatch
) -> None:
    """Frames that disagree in colour (a phone re-balancing each shot): each pixel takes the
    colour of the frames well exposed there, the one nearest mid-grey first, so every frame's
    best-exposed regions have that frame's colour (the issue's target measured on every frame,
    not only the reference). The old rule (the reference's colour wherever it is well exposed)
    meets the reference and misses the others."""
    import hdrcore.merge.colour_check as module
    from hdrcore.merge.colour_check import REFERENCE_BAND, frame_colours

    if not numba:
        monkeypatch.setattr(module, "AVAILABLE", False)
    _, frames, _ = srgb_bracket
    frames = [
        _rebalanced(frames[0], (1.06, 1.0, 0.94)),
        frames[1],
        _rebalanced(frames[2], (0.94, 1.0, 1.06)),
    ]
    res = merge(frames, TIMES, response=LUT, max_level=255)
    kw = dict(max_level=255, reference=1)
    anchor_kw = dict(
        max_level=255,
        saturation=250,
        noise_floor=2,
        reference=1,
        lut=LUT,
        exposure_times=TIMES,
        shares=res.shares,
    )
    plain = frame_colours(frames, res.radiance, **kw)
    rad = res.radiance.copy()
    y_before = rad @ LUMA.astype(np.float32)
    done = anchor_colour(rad, frames, srgb_decode_lut(255), **anchor_kw)
    own = frame_colours(frames, rad, **kw)
    old = res.radiance.copy()
    anchor_colour(
        old,
        frames,
        srgb_decode_lut(255),
        **anchor_kw,
        frame_band=None,
        reference_band=REFERENCE_BAND,
    )
    ref_only = frame_colours(frames, old, **kw)
    np.testing.assert_allclose(rad @ LUMA.astype(np.float32), y_before, rtol=1e-4, atol=1e-7)
    assert done.own_colour_fraction > 0.5
    # the merge alone misses a frame's colour where it is the best exposed (0.007 with the
    # default weighting, the triangle times dt^2 / var; 0.011 with the triangle alone, which
    # mixed more of the other frames in), the anchored map meets every frame
    assert max(f.best_error for f in plain) > 0.005
    assert max(f.best_error for f in own) < 0.002
    assert ref_only[1].well_error < 1e-4  # the reference met exactly ...
    assert max(f.best_error for f in ref_only) > 0.005  # ... the frames around it missed


def test_block_consistency_averages_the_noise_and_keeps_a_wrong_curve() -> None:
    """Consecutive frames of a noisy sRGB bracket: per pixel the noise shows as a colour
    difference; on 4x4 means it is averaged down with the right curve, while a curve whose
    channels disagree keeps its difference."""
    from hdrcore.merge.colour_check import block_consistency

    sim = simulate_bracket(
        scene="patches",
        shape=(160, 240),
        exposure_times=TIMES,
        bits=8,
        response="srgb",
        noise_sigma=2.0,
        seed=5,
    )
    frames = [f.astype(np.uint8) for f in sim.frames]
    res = merge(frames, TIMES, response=LUT, max_level=255)
    right = colour_check(frames, res.radiance, LUT, max_level=255, reference=1)
    assert right.frame_consistency_blocks < 0.5 * right.frame_consistency
    assert len(right.frame_pairs_blocks) == 2
    assert all(p.n_pixels >= 50 for p in right.frame_pairs_blocks)
    wrong = LUT ** np.array([[1.15], [1.0], [0.85]])
    pairs = block_consistency(frames, wrong, max_level=255, reference=1)
    worse = float(np.median([p.median_difference for p in pairs]))
    assert worse > 3 * right.frame_consistency_blocks


def test_per_pixel_agreement_of_a_right_curve_is_the_noise() -> None:
    """The issue's per-pixel target (0.01) is what noise of one level alone leaves with the
    true curve: the difference halves with every doubling of the block side (pure noise;
    bench_response.py section 2b shows the same halving on the real Canon bracket, 0.0126 ->
    0.0063 -> 0.0031, and nearly on the memorial scans), so only block means measure a curve."""
    from hdrcore.merge.colour_check import block_consistency

    sim = simulate_bracket(
        scene="patches",
        shape=(192, 288),
        exposure_times=(1.0, 2.0, 4.0),
        bits=8,
        response="srgb",
        noise_sigma=1.0,
        seed=6,
    )
    frames = [f.astype(np.uint8) for f in sim.frames]

    def median(block: int) -> float:
        pairs = block_consistency(frames, LUT, max_level=255, reference=1, block=block)
        return float(np.median([p.median_difference for p in pairs]))

    pixel, two, four = median(1), median(2), median(4)
    assert 0.007 < pixel < 0.014
    assert 0.4 < two / pixel < 0.6 and 0.4 < four / two < 0.6


def test_frame_colours_follow_the_registration_and_engines_agree(srgb_bracket, monkeypatch) -> None:
    """Frames displaced by a known shift and given with their ``to_reference`` matrices are
    read at the right pixels (the same colours as the aligned frames away from the border),
    and the compiled pass equals the numpy one."""
    import hdrcore.merge.colour_check as module

    _, frames, res = srgb_bracket
    frames = [
        _rebalanced(frames[0], (1.06, 1.0, 0.94)),
        frames[1],
        _rebalanced(frames[2], (0.94, 1.0, 1.06)),
    ]
    moved = [
        np.roll(frames[0], (2, 3), axis=(0, 1)),
        frames[1],
        np.roll(frames[2], (-1, 4), axis=(0, 1)),
    ]
    to_ref = [
        np.array([[1.0, 0, -3], [0, 1, -2]]),
        np.eye(3)[:2],
        np.array([[1.0, 0, -4], [0, 1, 1]]),
    ]
    kw = dict(
        max_level=255,
        saturation=250,
        noise_floor=2,
        reference=1,
        lut=LUT,
        exposure_times=TIMES,
        shares=res.shares,
    )
    aligned = res.radiance.copy()
    anchor_colour(aligned, frames, srgb_decode_lut(255), **kw)
    runs = {}
    for numba in (True, False):
        monkeypatch.setattr(module, "AVAILABLE", numba and module.AVAILABLE)
        rad = res.radiance.copy()
        anchor_colour(rad, moved, srgb_decode_lut(255), **kw, to_reference=to_ref)
        runs[numba] = rad
    np.testing.assert_allclose(runs[True], runs[False], rtol=2e-5, atol=1e-7)
    inner = (slice(12, -12), slice(12, -12))
    np.testing.assert_allclose(
        chromaticity(runs[True][inner]), chromaticity(aligned[inner]), atol=2e-3
    )
