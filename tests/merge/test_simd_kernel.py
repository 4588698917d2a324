"""The SIMD layout of :func:`hdrcore.merge._fused.merge_rows` against the specification.

The kernel cuts each row into blocks of ``_fused._WBLOCK`` pixels and each block into runs of
pixels whose supports share their source rows and column offset; the suite's usual frames are
narrower than one block. These frames are wider than two blocks, with motions that break runs
at many places (rotation: the source row steps; shear and scale: the column offset steps; a
large shift: supports leave the frame at both ends), and must give the specification's result
(:mod:`hdrcore.merge.spec`: the same decisions to the bit, values within float32 rounding),
with 3 channels and with the RAW mosaic's 4 and 1.
"""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.merge import _fused, merge

from ._brackets import inverse_gamma_lut
from ._spec_check import kernel_vs_spec

pytest.importorskip("numba")

WIDE = (24, 2 * _fused._WBLOCK + 77)  # two full blocks and a partial one per row


def _frames(
    dtype=np.uint16, max_level: int = 4095, seed: int = 0, channels: int = 3
) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    h, w = WIDE
    yy, xx = np.mgrid[0:h, 0:w]
    # smooth scene with fine detail, a few clipped spots in the brighter frames
    base = 0.35 + 0.25 * np.sin(xx / 7.0)[..., None] * np.cos(yy / 5.0)[..., None]
    base = base * np.array([1.0, 0.8, 0.6, 0.9][:channels])
    frames = []
    for k, gain in enumerate((0.5, 1.0, 2.0)):
        v = base * gain * max_level + rng.normal(0, 2.0, base.shape)
        f = np.clip(np.rint(v), 0, max_level).astype(dtype)
        frames.append(f)
        assert k < 2 or (f >= 0.98 * max_level).any()
    return frames


MOTIONS = {
    "rotation": np.array([[np.cos(0.02), -np.sin(0.02), 1.3], [np.sin(0.02), np.cos(0.02), -0.4]]),
    "shear-scale": np.array([[1.003, 0.01, -2.2], [0.0, 0.998, 0.7]]),
    "large-shift": np.array([[1.0, 0.0, 35.25], [0.0, 1.0, 3.5]]),
}


@pytest.mark.parametrize("channels", [3, 4, 1])
@pytest.mark.parametrize("resample", ["cubic", "bilinear"])
@pytest.mark.parametrize("motion", sorted(MOTIONS))
def test_wide_rows_agree(motion, resample, channels):
    frames = _frames(channels=channels)
    tf = [MOTIONS[motion], None, np.linalg.inv(np.vstack([MOTIONS[motion], [0, 0, 1]]))[:2]]
    kernel_vs_spec(frames, (1.0, 2.0, 4.0), max_level=4095, transforms=tf, resample=resample)


@pytest.mark.parametrize("channels", [3, 4])
def test_wide_rows_with_masks_and_a_lut_agree(channels):
    frames = _frames(np.uint8, 255, seed=1, channels=channels)
    mask = np.ones(WIDE, bool)
    mask[5:15, 600:900] = False
    tf = [MOTIONS["rotation"], MOTIONS["shear-scale"], None]
    kernel_vs_spec(
        frames,
        (1.0, 2.0, 4.0),
        response=inverse_gamma_lut(255, channels),
        transforms=tf,
        masks=[None, mask, mask],
    )


@pytest.mark.parametrize("channels", [3, 4])
@pytest.mark.parametrize("weighting", ["hat", "noise-aware", "uniform"])
def test_wide_linear_frames_read_in_place_agree(weighting, channels):
    # no transform at all: the tripod path of linear levels takes the same kernel
    frames = _frames(seed=2, channels=channels)
    mask = np.ones(WIDE, bool)
    mask[:, 1000:1100] = False
    res, _ = kernel_vs_spec(
        frames,
        (1.0, 2.0, 4.0),
        max_level=4095,
        weighting=weighting,
        masks=[mask, None, None],
        noise_floor=20,
    )
    assert res.clipped.any() or res.clip_count.any()


def test_frames_smaller_than_the_support_are_no_data():
    # every 4x4 support leaves a 3 x 3 frame: the resampled frame reads no taps and has no data
    frames = [np.full((3, 3, 3), 100 * (k + 1), np.uint16) for k in range(3)]
    tf = [np.array([[1.0, 0.0, 0.25], [0.0, 1.0, 0.5]]), None, None]
    res, _ = kernel_vs_spec(frames, (1.0, 2.0, 4.0), max_level=4095, transforms=tf)
    assert (res.shares[0] == 0).all()
    # the others alone: the same values to the bit
    alone = merge(frames[1:], (2.0, 4.0), max_level=4095)
    np.testing.assert_array_equal(res.radiance, alone.radiance)


@pytest.mark.parametrize("resample", ["cubic", "bilinear"])
@pytest.mark.parametrize("times", [(1.0, 2.0, 4.0), (4.0, 1.0, 2.0)])
def test_every_fallback_agrees(resample, times):
    # the kernel decides the fallbacks of a block in straight passes: each kind must occur
    # here and give the specification's value, shares and flags
    h, w = WIDE
    frames = _frames(seed=4)
    dark = int(np.argmin(times))  # the darkest frame
    for f in frames:
        f[:, 100:300] = 3  # below the noise floor in every frame: brightest frame's value
        f[:, 300:420, 1] = 3  # one channel only
        f[:, 500:700] = 4095  # clipped in every frame
    masks = [np.ones(WIDE, bool) for _ in range(3)]
    masks[dark][:, 600:700] = False  # ... the darkest one invalid: the next valid one's value
    for m in masks:
        m[:, 800:900] = False  # no valid frame at all: the darkest frame, not flagged clipped
    c, s = np.cos(0.002), np.sin(0.002)
    small = np.array([[c, -s, 1.3], [s, c, -0.4]])
    tf = [small, None, MOTIONS["shear-scale"]]  # supports inside the frame over rows 5..18
    ref, _ = kernel_vs_spec(
        frames, times, max_level=4095, transforms=tf, resample=resample, masks=masks, noise_floor=40
    )
    mid = slice(5, h - 5)
    assert ref.underexposed[mid, 120:280].all() and (ref.weight_sum[mid, 120:280] == 0).all()
    assert ref.underexposed[mid, 320:400].all() and (ref.weight_sum[mid, 320:400] > 0).all()
    assert ref.clipped[mid, 520:680].all()
    assert not ref.clipped[mid, 820:880].any() and not ref.underexposed[mid, 820:880].any()
    shares = ref.shares.astype(np.float32)
    assert (shares[dark, mid, 520:580] == 1).all() and (shares[dark, mid, 620:680] == 0).all()
    assert (shares[dark, mid, 820:880] == 1).all()
