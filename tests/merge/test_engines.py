"""The fused numba kernel against the numpy reference: same results on the test brackets.

The reference (``engine="numpy"``) is the specification; the fused kernel does the same float32
arithmetic in the same order, so every output must be identical (bit for bit, except ``exp`` of
the Gaussian weight on float frames, which may differ in the last place).
"""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.errors import ParameterError
from hdrcore.merge import MERGE_ENGINES, NoiseModel, default_engine, merge
from hdrcore.synthetic import simulate_bracket

from ._brackets import SHAPE, TIMES, bracket, inverse_gamma_lut

pytest.importorskip("numba")

FIELDS = (
    "radiance",
    "weight_sum",
    "shares",
    "clip_count",
    "clipped",
    "underexposed",
    "ghost_score",
    "ghost",
)


def both(frames, times, rtol: float = 0.0, ghost_atol: float = 0.0, **kw):
    ref = merge(frames, times, engine="numpy", **kw)
    fused = merge(frames, times, engine="numba", **kw)
    assert ref.engine == "numpy" and fused.engine == "numba"
    for name in FIELDS:
        a, b = getattr(ref, name), getattr(fused, name)
        assert a.dtype == b.dtype and a.shape == b.shape, name
        if name == "ghost_score" and ghost_atol:
            # sum(p E^2) - E^2 cancels: a last-place change of w moves a tiny score a lot in
            # relative terms, nothing next to the threshold (8)
            np.testing.assert_allclose(
                a.astype(np.float64), b.astype(np.float64), rtol=2e-3, atol=ghost_atol, err_msg=name
            )
        elif rtol == 0.0 or a.dtype == bool or a.dtype == np.uint8:
            np.testing.assert_array_equal(a, b, err_msg=name)
        else:  # float16 maps: one step of float16 (2**-10) after a last-place float32 change
            tol = max(rtol, 2.0**-10) if a.dtype == np.float16 else rtol
            np.testing.assert_allclose(
                a.astype(np.float64), b.astype(np.float64), rtol=tol, atol=1e-30, err_msg=name
            )
    assert ref.status == fused.status and ref.message == fused.message
    return ref, fused


def test_default_engine_is_the_fused_kernel():
    assert set(MERGE_ENGINES) == {"numba", "numpy"}
    assert default_engine() == "numba"
    sb = bracket(bits=12, response="linear", seed=1)
    res = merge(sb.frames, sb.exposure_times, max_level=sb.max_level)
    assert res.engine == "numba" and res.summary()["engine"] == "numba"


@pytest.mark.parametrize("workers", [1, 2])
def test_12bit_linear_noise_aware(workers):
    sb = bracket(bits=12, response="linear", noise_sigma=1.0, seed=1)
    both(sb.frames, sb.exposure_times, max_level=sb.max_level, workers=workers)


@pytest.mark.parametrize("bits", [8, 12])
def test_levels_with_a_lut_hat(bits):
    sb = bracket(bits=bits, response="gamma", noise_sigma=1.0, seed=2)
    both(sb.frames, sb.exposure_times, response=inverse_gamma_lut(sb.max_level))


@pytest.mark.parametrize("weighting", ["hat", "gaussian", "noise-aware", "uniform"])
def test_float_frames_every_weighting(weighting):
    sb = bracket(bits=12, response="linear", noise_sigma=1.0, seed=4)
    frames = [np.asarray(f, np.float32) / np.float32(4095) for f in sb.frames]
    if weighting == "gaussian":  # float32 exp: numba's libm vs numpy's SIMD, last place
        both(frames, sb.exposure_times, weighting=weighting, rtol=1e-6, ghost_atol=1e-2)
    else:
        both(frames, sb.exposure_times, weighting=weighting)


@pytest.mark.parametrize("weighting", ["hat", "gaussian", "uniform"])
def test_integer_levels_every_weighting_with_shot_noise(weighting):
    sb = bracket(bits=12, response="linear", seed=14, shot_noise_full_well=5000)
    noise = NoiseModel(read_noise=2e-4, full_well=5000)
    both(sb.frames, sb.exposure_times, max_level=4095, weighting=weighting, noise=noise)
    lut = np.tile(np.linspace(0.0, 1.0, 4096), (3, 1))
    both(sb.frames, sb.exposure_times, response=lut, weighting=weighting, noise=noise)


def test_masks_per_channel_white_levels_and_noise_floor():
    sb = bracket(bits=12, response="linear", noise_sigma=1.0, seed=13, scene="window")
    frames = [f.copy() for f in sb.frames]
    for f in frames:
        f[..., 0] = np.minimum(f[..., 0], 3000)
    mask = np.ones(SHAPE, bool)
    mask[:, :20] = False
    mask2 = np.ones(SHAPE, bool)
    mask2[:10] = False
    kw = dict(max_level=4095, saturation_level=(3000, 4095, 4095), noise_floor=12)
    both(frames, sb.exposure_times, masks=[None, mask2, mask], **kw)
    floats = [f.astype(np.float32) / np.float32(4095) for f in frames]
    both(
        floats,
        sb.exposure_times,
        masks=[mask2, None, mask],
        saturation_level=(3000 / 4095, 1.0, 1.0),
        noise_floor=12 / 4095,
    )


def test_clipped_everywhere_patch_and_moving_object():
    rng = np.random.default_rng(0)
    rad = np.exp(rng.normal(-1.0, 0.3, SHAPE + (3,))).astype(np.float32)
    rad[40:80, 60:120] = 1e4
    sb = simulate_bracket(rad, exposure_times=TIMES, bits=12, key=0.1, seed=7)
    frames = [f.copy() for f in sb.frames]
    frames[1][60:90, 20:60] = 1500
    ref, _ = both(frames, sb.exposure_times, max_level=sb.max_level)
    assert ref.clipped.any() and ref.ghost.any()
    ref, _ = both(frames[::-1], sb.exposure_times[::-1], max_level=sb.max_level)
    assert ref.clipped.any()


def test_fallbacks_when_the_darkest_frame_is_invalid_or_no_frame_is_valid():
    frames = [np.full((8, 8, 3), v, np.uint16) for v in (100, 4095, 4095)]
    frames[0][:, 4:] = 4095  # clipped everywhere on the right
    m0 = np.ones((8, 8), bool)
    m0[:4] = False  # darkest frame invalid at the top: the next valid frame's value
    m1 = np.ones((8, 8), bool)
    m1[:2] = False
    m2 = m1.copy()  # top two rows: no valid frame at all
    for f in frames:
        f[6:, :2, 2] = 5  # blue below the noise floor everywhere: underexposed
    kw = dict(max_level=4095, noise_floor=10, masks=[m0, m1, m2])
    ref, _ = both(frames, (1.0, 4.0, 16.0), **kw)
    assert ref.clipped[4:, 4:].all() and not ref.clipped[:2].any()
    assert ref.underexposed[6:, :2].all()
    floats = [f.astype(np.float32) / np.float32(4095) for f in frames]
    both(floats, (1.0, 4.0, 16.0), masks=[m0, m1, m2], noise_floor=10 / 4095)


def test_fallbacks_of_frames_below_the_floor_against_a_clipped_one():
    """No frame gives the pixel weight (issue 17's black frame): a clipped frame's lower bound
    wins over shorter exposures below the floor (they could not see it), while a longer
    exposure below the floor where a shorter one clipped contradicts it (a marker, a moving
    object) and keeps its reading, as before the fix."""
    ml, floor = 4095, 40
    times = (1.0, 4.0, 16.0)
    frames = [np.full((2, 4, 3), 1000, np.uint16) for _ in times]
    frames[0][0, 0] = (5, 0, 30)  # shortest: below the floor
    frames[1][0, 0] = (4095, 20, 10)  # clipped in red: radiance at least ~4013 / 4
    frames[2][0, 0] = (4095, 4095, 4095)
    frames[0][1, 0] = (4095, 4095, 10)  # shortest clipped ...
    frames[1][1, 0] = (30, 0, 2)  # ... the longer ones below the floor: contradiction
    frames[2][1, 0] = (12, 3, 0)
    ref, _ = both(frames, times, max_level=ml, noise_floor=floor)
    np.testing.assert_allclose(ref.radiance[0, 0], frames[1][0, 0] / ml / 4.0, rtol=1e-6)
    assert ref.clipped[0, 0] and not ref.underexposed[0, 0]
    assert ref.shares[1, 0, 0] == 1.0
    np.testing.assert_allclose(ref.radiance[1, 0], frames[2][1, 0] / ml / 16.0, rtol=1e-6)
    assert ref.underexposed[1, 0] and not ref.clipped[1, 0]
    # the black frame: shorter than every other, it changes nothing
    black = np.zeros_like(frames[0])
    ref2, _ = both([black, *frames], (0.25, *times), max_level=ml, noise_floor=floor)
    np.testing.assert_array_equal(ref2.radiance, ref.radiance)
    np.testing.assert_array_equal(ref2.clipped, ref.clipped)


def test_read_only_and_writable_frames_mixed():
    """A decoded bracket's levels are read-only, a frame the caller made is not: numba types
    them differently, and the kernel's frame tuple must still be one type (it was a
    TypingError traceback)."""
    frames = [np.full((6, 8, 3), 100 * (k + 1), np.uint16) for k in range(3)]
    frames[0].setflags(write=False)
    masks = [np.ones((6, 8), bool), None, np.ones((6, 8), bool)]
    masks[0].setflags(write=False)
    both(frames, (1.0, 2.0, 4.0), max_level=4095, masks=masks)
    both(
        frames,
        (1.0, 2.0, 4.0),
        max_level=4095,
        transforms=[None, np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.25]]), None],
    )


def test_levels_above_max_level_with_a_lut_are_refused():
    frames = [np.full((4, 5, 3), 100 * (k + 1), np.uint16) for k in range(3)]
    frames[1][0, 0, 0] = 300
    for engine in MERGE_ENGINES:
        with pytest.raises(ParameterError, match="levels above max_level"):
            merge(frames, (1, 2, 4), response=np.linspace(0, 1, 256), engine=engine)


def test_levels_above_max_level_without_a_lut_are_clipped_in_both_engines():
    frames = [np.full((4, 5, 3), 100 * (k + 1), np.uint16) for k in range(3)]
    for f in frames:
        f[0, 0] = 5000
    ref, _ = both(frames, (1, 2, 4), max_level=4095)
    assert ref.clipped[0, 0] and ref.radiance[0, 0, 0] > 1.0


def test_engine_names():
    frames = [np.full((4, 5), 100 * (k + 1), np.uint16) for k in range(3)]
    with pytest.raises(ParameterError, match="unknown merge engine method 'cuda'.*'numba'"):
        merge(frames, (1, 2, 4), max_level=4095, engine="cuda")
    assert merge(frames, (1, 2, 4), max_level=4095).engine == "numba"  # grey: the kernel too


def _channels(frames, c):
    """1 channel: green alone; 4: the RGB frames and green again (a CFA cell's layout)."""
    if c == 1:
        return [np.ascontiguousarray(f[..., 1:2]) for f in frames]
    return [np.ascontiguousarray(np.concatenate([f, f[..., 1:2]], axis=2)) for f in frames]


@pytest.mark.parametrize("c", [1, 4])
def test_one_and_four_channels(c):
    """The kernel takes any channel count (the RAW mosaic merge: 4 CFA sites, or 1 per site
    plane): the same results as the reference, bit for bit, on every path."""
    sb = bracket(bits=12, response="linear", noise_sigma=1.0, seed=13, scene="window")
    frames = _channels(sb.frames, c)
    for f in frames:
        f[100:110, 30:60] = 5  # below the noise floor in every frame: underexposed
    times = sb.exposure_times
    rot = np.array([[np.cos(0.01), -np.sin(0.01), 1.3], [np.sin(0.01), np.cos(0.01), -0.6]])
    tf = [rot, None, np.array([[1.0, 0.0, -2.25], [0.0, 1.0, 0.5]])]
    lut = np.linspace(0.0, 1.0, 4096) ** 1.5
    mask = np.ones(SHAPE, bool)
    mask[:, :20] = False
    ref, _ = both(frames, times, max_level=4095, noise_floor=12, masks=[None, mask, None])
    assert ref.clipped.any() and ref.underexposed.any()
    for weighting in ("hat", "gaussian", "uniform"):
        both(frames, times, response=lut, weighting=weighting)
    both(frames, times, max_level=4095, transforms=tf)
    both(frames, times, response=lut, transforms=tf)
    both(frames, times, max_level=4095, transforms=tf, resample="bilinear")
    floats = [f.astype(np.float32) / np.float32(4095) for f in frames]
    both(floats, times, weighting="hat", saturation_level=[0.9] + [0.98] * (c - 1))


def test_one_compiled_kernel_serves_every_frame_count():
    """The frame tuples are padded (TUPLE_SLOTS): a bracket of 5 or 9 frames runs the kernel
    compiled for 3 instead of compiling its own (seconds on first use)."""
    from hdrcore.merge import _fused

    def frames(n):
        return [np.full((6, 8, 3), 100 * (k + 1), np.uint16) for k in range(n)]

    merge(frames(3), (1.0, 2.0, 4.0), max_level=4095, engine="numba")
    before = len(_fused.merge_rows.signatures)
    for n in (2, 5, 9, 16):
        times = tuple(float(2**k) for k in range(n))
        ref, fused = both(frames(n), times, max_level=4095)
        assert fused.shares.shape == (n, 6, 8)
    assert len(_fused.merge_rows.signatures) == before
