"""The engines against the plain whole-image specification (:mod:`hdrcore.merge.spec`): the same
decisions (clipped, below the floor, which frame a fallback takes) everywhere, the same values
within float32 rounding, on tripod and resampled brackets, every weighting, masks, floors, LUTs
and black frames."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hdrcore.merge import DEFAULT_GHOST_THRESHOLD, DEFAULT_MODEL_ERROR, merge
from hdrcore.merge.plan import make_plan
from hdrcore.merge.spec import merge_spec
from hdrcore.synthetic import simulate_bracket

from ._brackets import SHAPE, TIMES, bracket, inverse_gamma_lut

pytest.importorskip("numba")


def check(frames, times, engines=("numba", "numpy"), **kw) -> dict:
    plan = make_plan(
        frames,
        times,
        kw.get("response"),
        kw.get("max_level"),
        kw.get("masks"),
        kw.get("saturation_level"),
        kw.get("noise_floor"),
        kw.get("weighting"),
        kw.get("noise"),
        kw.get("transforms"),
        None,
    )
    plan = replace(plan, resample=kw.get("resample", "cubic"))
    spec = merge_spec(
        plan, ghost_threshold=DEFAULT_GHOST_THRESHOLD, model_error=DEFAULT_MODEL_ERROR
    )
    for engine in engines:
        res = merge(frames, times, engine=engine, ghost_test="pixels", **kw)
        for name in ("clip_count", "clipped", "underexposed"):
            np.testing.assert_array_equal(getattr(res, name), spec[name], err_msg=name)
        np.testing.assert_allclose(res.radiance, spec["radiance"], rtol=1e-4, atol=1e-12)
        np.testing.assert_allclose(res.weight_sum, spec["weight_sum"], rtol=1e-4, atol=1e-12)
        np.testing.assert_allclose(res.shares.astype(np.float64), spec["shares"], atol=1e-3)
        score = res.ghost_score.astype(np.float64)
        small = spec["ghost_score"] < 6e4  # float16's range
        # sum(w E^2) / sum(w) - E^2 cancels in float32: a fraction of a unit of the score
        np.testing.assert_allclose(score[small], spec["ghost_score"][small], rtol=5e-3, atol=0.5)
        clear = np.abs(spec["ghost_score"] - DEFAULT_GHOST_THRESHOLD) > 0.6
        np.testing.assert_array_equal(res.ghost[clear], spec["ghost"][clear])
    return spec


def test_12bit_with_a_clipped_patch_and_a_moving_object() -> None:
    rng = np.random.default_rng(0)
    rad = np.exp(rng.normal(-1.0, 0.8, SHAPE + (3,))).astype(np.float32)
    rad[40:80, 60:120] = 1e4
    sb = simulate_bracket(rad, exposure_times=TIMES, bits=12, key=0.1, seed=7)
    frames = [f.copy() for f in sb.frames]
    frames[1][60:90, 20:60] = 1500
    spec = check(frames, sb.exposure_times, max_level=sb.max_level)
    assert spec["clipped"].any() and spec["ghost"].any()


@pytest.mark.parametrize("bits", [8, 12])
def test_levels_through_a_lut_with_masks_and_a_noise_floor(bits) -> None:
    sb = bracket(bits=bits, response="gamma", noise_sigma=1.0, seed=2, scene="window")
    mask = np.ones(SHAPE, bool)
    mask[:, :20] = False
    spec = check(
        sb.frames,
        sb.exposure_times,
        response=inverse_gamma_lut(sb.max_level),
        masks=[None, mask, None],
        noise_floor=0.15 * sb.max_level,
    )
    assert spec["underexposed"].any()


@pytest.mark.parametrize("weighting", ["hat", "gaussian", "noise-aware", "uniform"])
def test_float_frames_every_weighting(weighting) -> None:
    sb = bracket(bits=12, response="linear", noise_sigma=1.0, seed=4)
    frames = [np.asarray(f, np.float32) / np.float32(4095) for f in sb.frames]
    check(frames, sb.exposure_times, weighting=weighting, noise_floor=0.002)


@pytest.mark.parametrize("resample", ["cubic", "bilinear"])
def test_resampled_frames_linear_and_through_a_lut(resample) -> None:
    sb = bracket(bits=8, response="gamma", noise_sigma=1.0, seed=5, scene="window")
    t = np.array([[np.cos(0.01), -np.sin(0.01), 1.3], [np.sin(0.01), np.cos(0.01), -0.6]])
    tf = [t, None, np.array([[1.0, 0.0, -2.25], [0.0, 1.0, 0.5]])]
    check(
        sb.frames,
        sb.exposure_times,
        response=inverse_gamma_lut(sb.max_level),
        transforms=tf,
        resample=resample,
    )
    check(
        sb.frames, sb.exposure_times, max_level=255, transforms=tf, resample=resample, noise_floor=6
    )


def test_black_frames_and_every_fallback() -> None:
    times = (1.0, 4.0, 16.0)
    rng = np.random.default_rng(1)
    rad = np.exp(rng.uniform(np.log(1e-3), np.log(400.0), (24, 32, 3)))
    frames = [
        np.clip(np.rint(rad * 100 * t + rng.normal(0, 1, rad.shape)), 0, 4095).astype(np.uint16)
        for t in times
    ]
    black = np.zeros_like(frames[0])
    for floor in (0, 30):
        spec = check([black, *frames], (0.25, *times), max_level=4095, noise_floor=floor)
        assert spec["clipped"].any() and spec["underexposed"].any()
        check([*frames, black], (*times, 64.0), max_level=4095, noise_floor=floor)
