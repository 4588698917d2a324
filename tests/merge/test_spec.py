"""The kernel against the plain whole-image specification (:mod:`hdrcore.merge.spec`): the same
decisions (clipped, below the floor, which frame a fallback takes) everywhere, the same values
within float32 rounding, on tripod and resampled brackets (through displacement fields too), 1,
3 and 4 channels, every weighting, masks, floors, LUTs and black frames."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.registration.field import DisplacementField
from hdrcore.synthetic import simulate_bracket

from ._brackets import SHAPE, TIMES, bracket, inverse_gamma_lut
from ._spec_check import kernel_vs_spec

pytest.importorskip("numba")


def check(frames, times, **kw) -> dict:
    return kernel_vs_spec(frames, times, **kw)[1]


def _channels(frames, c):
    """1 channel: red alone; 4: the RGB frames and blue again."""
    if c == 1:
        return [np.ascontiguousarray(f[..., :1]) for f in frames]
    if c == 4:
        return [np.ascontiguousarray(np.concatenate([f, f[..., 2:]], axis=2)) for f in frames]
    return frames


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


@pytest.mark.parametrize("c", [1, 3, 4])
@pytest.mark.parametrize("weighting", ["hat", "gaussian", "noise-aware", "uniform"])
def test_float_frames_every_weighting(weighting, c) -> None:
    sb = bracket(bits=12, response="linear", noise_sigma=1.0, seed=4)
    frames = [np.asarray(f, np.float32) / np.float32(4095) for f in _channels(sb.frames, c)]
    check(frames, sb.exposure_times, weighting=weighting, noise_floor=0.002)


@pytest.mark.parametrize("c", [1, 3, 4])
@pytest.mark.parametrize("resample", ["cubic", "bilinear"])
def test_resampled_frames_linear_and_through_a_lut(resample, c) -> None:
    sb = bracket(bits=8, response="gamma", noise_sigma=1.0, seed=5, scene="window")
    frames = _channels(sb.frames, c)
    t = np.array([[np.cos(0.01), -np.sin(0.01), 1.3], [np.sin(0.01), np.cos(0.01), -0.6]])
    tf = [t, None, np.array([[1.0, 0.0, -2.25], [0.0, 1.0, 0.5]])]
    check(
        frames,
        sb.exposure_times,
        response=inverse_gamma_lut(sb.max_level, c),
        transforms=tf,
        resample=resample,
    )
    check(frames, sb.exposure_times, max_level=255, transforms=tf, resample=resample, noise_floor=6)


@pytest.mark.parametrize("c", [1, 3, 4])
@pytest.mark.parametrize("weighting", ["hat", "gaussian", "noise-aware", "uniform"])
def test_displacement_fields_masks_and_every_weighting(weighting, c) -> None:
    """Frames read through a homography plus a displacement field (local refinement), one
    through a field on the identity, masks in output coordinates."""
    sb = bracket(bits=12, response="linear", noise_sigma=1.0, seed=9, scene="window")
    frames = _channels(sb.frames, c)
    h, w = SHAPE
    gh, gw = DisplacementField.grid((h, w), 16)
    yy, xx = np.mgrid[0:gh, 0:gw].astype(np.float64) * 16
    bump = 2.5 * np.exp(-(((xx - w / 2) / 30) ** 2 + ((yy - h / 2) / 20) ** 2))
    fields = [
        DisplacementField(16, np.stack([bump, -0.5 * bump], axis=-1)),
        None,
        DisplacementField(16, np.stack([-0.7 * bump + 0.3, 0.4 * bump], axis=-1)),
    ]
    persp = np.array([[1.0, 0.002, 1.1], [-0.001, 1.0, -0.4], [1e-5, -2e-5, 1.0]])
    mask = np.ones(SHAPE, bool)
    mask[30:60, 50:120] = False
    check(
        frames,
        sb.exposure_times,
        max_level=4095,
        weighting=weighting,
        transforms=[persp, None, None],
        fields=fields,
        masks=[None, mask, mask],
        noise_floor=8,
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
    for c in (1, 4):  # the CFA sites' layouts
        fc = _channels([black, *frames], c)
        spec = check(fc, (0.25, *times), max_level=4095, noise_floor=30)
        assert spec["clipped"].any() and spec["underexposed"].any()
