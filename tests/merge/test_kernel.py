"""The merge's one compiled kernel against the whole-image specification
(:mod:`hdrcore.merge.spec`) on the test brackets, and what only it can show bit for bit: the
channel count, the workers, the frame count and the deprecated ``engine="numpy"`` alias change
nothing.

The kernel was checked bit for bit against the numpy engine until that engine was removed; each
of those comparisons is now one against the specification (the same decisions to the bit, the
values within float32 rounding: :func:`._spec_check.kernel_vs_spec`).
"""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.errors import ParameterError
from hdrcore.merge import MERGE_ENGINES, NoiseModel, default_engine, merge
from hdrcore.synthetic import simulate_bracket

from ._brackets import SHAPE, TIMES, bracket, inverse_gamma_lut
from ._spec_check import kernel_vs_spec, same_bits

pytest.importorskip("numba")


def test_the_kernel_is_the_one_engine():
    assert set(MERGE_ENGINES) == {"numba"}
    assert default_engine() == "numba"
    sb = bracket(bits=12, response="linear", seed=1)
    res = merge(sb.frames, sb.exposure_times, max_level=sb.max_level)
    assert res.engine == "numba" and res.summary()["engine"] == "numba"


def test_numpy_engine_is_a_deprecated_alias_of_the_kernel():
    sb = bracket(bits=12, response="linear", noise_sigma=1.0, seed=1)
    kw = dict(max_level=sb.max_level)
    res = merge(sb.frames, sb.exposure_times, **kw)
    with pytest.warns(DeprecationWarning, match="engine='numpy'.*deprecated"):
        old = merge(sb.frames, sb.exposure_times, engine="numpy", **kw)
    assert old.engine == "numba"
    same_bits(res, old)
    with pytest.warns(DeprecationWarning):  # deghost merges frames alone with the same name
        merge(sb.frames, sb.exposure_times, engine="NumPy", deghost=True, **kw)


@pytest.mark.parametrize("workers", [1, 2])
def test_12bit_linear_noise_aware(workers):
    sb = bracket(bits=12, response="linear", noise_sigma=1.0, seed=1)
    res, _ = kernel_vs_spec(sb.frames, sb.exposure_times, max_level=sb.max_level, workers=workers)
    # rows are independent: any split over threads gives the same bits
    other = merge(
        sb.frames,
        sb.exposure_times,
        max_level=sb.max_level,
        workers=3 - workers,
        chunk_pixels=7 * SHAPE[1],
        ghost_test="pixels",
    )
    same_bits(res, other)


@pytest.mark.parametrize("bits", [8, 12])
def test_levels_with_a_lut_hat(bits):
    sb = bracket(bits=bits, response="gamma", noise_sigma=1.0, seed=2)
    kernel_vs_spec(sb.frames, sb.exposure_times, response=inverse_gamma_lut(sb.max_level))


@pytest.mark.parametrize("weighting", ["hat", "gaussian", "noise-aware", "uniform"])
def test_float_frames_every_weighting(weighting):
    sb = bracket(bits=12, response="linear", noise_sigma=1.0, seed=4)
    frames = [np.asarray(f, np.float32) / np.float32(4095) for f in sb.frames]
    kernel_vs_spec(frames, sb.exposure_times, weighting=weighting)


@pytest.mark.parametrize("weighting", ["hat", "gaussian", "uniform"])
def test_integer_levels_every_weighting_with_shot_noise(weighting):
    sb = bracket(bits=12, response="linear", seed=14, shot_noise_full_well=5000)
    noise = NoiseModel(read_noise=2e-4, full_well=5000)
    kernel_vs_spec(sb.frames, sb.exposure_times, max_level=4095, weighting=weighting, noise=noise)
    lut = np.tile(np.linspace(0.0, 1.0, 4096), (3, 1))
    kernel_vs_spec(sb.frames, sb.exposure_times, response=lut, weighting=weighting, noise=noise)


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
    kernel_vs_spec(frames, sb.exposure_times, masks=[None, mask2, mask], **kw)
    floats = [f.astype(np.float32) / np.float32(4095) for f in frames]
    kernel_vs_spec(
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
    res, _ = kernel_vs_spec(frames, sb.exposure_times, max_level=sb.max_level)
    assert res.clipped.any() and res.ghost.any()
    back, _ = kernel_vs_spec(frames[::-1], sb.exposure_times[::-1], max_level=sb.max_level)
    assert back.clipped.any()
    # the frames' order changes nothing but the order of the shares
    same_bits(res, back, ("radiance", "weight_sum", "clip_count", "clipped", "underexposed"))
    np.testing.assert_array_equal(res.shares, back.shares[::-1])


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
    res, _ = kernel_vs_spec(frames, (1.0, 4.0, 16.0), **kw)
    assert res.clipped[4:, 4:].all() and not res.clipped[:2].any()
    assert res.underexposed[6:, :2].all()
    floats = [f.astype(np.float32) / np.float32(4095) for f in frames]
    kernel_vs_spec(floats, (1.0, 4.0, 16.0), masks=[m0, m1, m2], noise_floor=10 / 4095)


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
    res, _ = kernel_vs_spec(frames, times, max_level=ml, noise_floor=floor)
    np.testing.assert_allclose(res.radiance[0, 0], frames[1][0, 0] / ml / 4.0, rtol=1e-6)
    assert res.clipped[0, 0] and not res.underexposed[0, 0]
    assert res.shares[1, 0, 0] == 1.0
    np.testing.assert_allclose(res.radiance[1, 0], frames[2][1, 0] / ml / 16.0, rtol=1e-6)
    assert res.underexposed[1, 0] and not res.clipped[1, 0]
    # the black frame: shorter than every other, it changes nothing
    black = np.zeros_like(frames[0])
    res2, _ = kernel_vs_spec([black, *frames], (0.25, *times), max_level=ml, noise_floor=floor)
    np.testing.assert_array_equal(res2.radiance, res.radiance)
    np.testing.assert_array_equal(res2.clipped, res.clipped)


def test_read_only_and_writable_frames_mixed():
    """A decoded bracket's levels are read-only, a frame the caller made is not: numba types
    them differently, and the kernel's frame tuple must still be one type (it was a
    TypingError traceback)."""
    frames = [np.full((6, 8, 3), 100 * (k + 1), np.uint16) for k in range(3)]
    frames[1][2:4, 3:6] = 4095
    writable = [f.copy() for f in frames]
    frames[0].setflags(write=False)
    masks = [np.ones((6, 8), bool), None, np.ones((6, 8), bool)]
    masks[0].setflags(write=False)
    res, _ = kernel_vs_spec(frames, (1.0, 2.0, 4.0), max_level=4095, masks=masks)
    same_bits(res, merge(writable, (1.0, 2.0, 4.0), max_level=4095, ghost_test="pixels"))
    kernel_vs_spec(
        frames,
        (1.0, 2.0, 4.0),
        max_level=4095,
        transforms=[None, np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.25]]), None],
    )


def test_levels_above_max_level_with_a_lut_are_refused():
    frames = [np.full((4, 5, 3), 100 * (k + 1), np.uint16) for k in range(3)]
    frames[1][0, 0, 0] = 300
    with pytest.raises(ParameterError, match="levels above max_level"):
        merge(frames, (1, 2, 4), response=np.linspace(0, 1, 256))


def test_levels_above_max_level_without_a_lut_are_clipped():
    frames = [np.full((4, 5, 3), 100 * (k + 1), np.uint16) for k in range(3)]
    for f in frames:
        f[0, 0] = 5000
    res, _ = kernel_vs_spec(frames, (1, 2, 4), max_level=4095)
    assert res.clipped[0, 0] and res.radiance[0, 0, 0] > 1.0


def test_other_unsigned_dtypes_are_read_as_16_bit_levels():
    """uint32 levels (within 16 bits) merge as the same uint16 levels; a max_level past 16
    bits is refused (float frames then)."""
    frames = [np.full((4, 5, 3), 100 * (k + 1), np.uint16) for k in range(3)]
    frames[2][1, 1] = 4095
    wide = [f.astype(np.uint32) for f in frames]
    same_bits(merge(frames, (1, 2, 4), max_level=4095), merge(wide, (1, 2, 4), max_level=4095))
    same_bits(
        merge([frames[0], frames[1].astype(np.uint8), frames[2]], (1, 2, 4), max_level=255),
        merge(
            [f.astype(np.uint16) for f in (frames[0], frames[1].astype(np.uint8), frames[2])],
            (1, 2, 4),
            max_level=255,
        ),
    )
    with pytest.raises(ParameterError, match="max_level out of range"):
        merge(wide, (1, 2, 4), max_level=100000)


def test_engine_names():
    frames = [np.full((4, 5), 100 * (k + 1), np.uint16) for k in range(3)]
    with pytest.raises(ParameterError, match="unknown merge engine method 'cuda'.*'numba'"):
        merge(frames, (1, 2, 4), max_level=4095, engine="cuda")
    assert merge(frames, (1, 2, 4), max_level=4095, engine="numba").engine == "numba"


def test_a_colour_conversion_needs_rgb():
    from hdrcore.merge import colour_conversion

    frames = [np.full((4, 5, 4), 100 * (k + 1), np.uint16) for k in range(3)]
    with pytest.raises(ParameterError, match="colour conversion needs RGB"):
        merge(frames, (1, 2, 4), max_level=4095, colour=colour_conversion(None, None))


def _channels(frames, c):
    """1 channel: green alone; 4: the RGB frames and green again (a CFA cell's layout)."""
    if c == 1:
        return [np.ascontiguousarray(f[..., 1:2]) for f in frames]
    return [np.ascontiguousarray(np.concatenate([f, f[..., 1:2]], axis=2)) for f in frames]


@pytest.mark.parametrize("c", [1, 4])
def test_one_and_four_channels(c):
    """The kernel takes any channel count (the RAW mosaic merge: 4 CFA sites, or 1 per site
    plane): the specification's results on every path (masks, floors, LUTs, every weighting,
    resampled cubic and bilinear, float frames), and exactly the 3-channel kernel's radiance
    and decisions where the channels say the same."""
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
    res, _ = kernel_vs_spec(frames, times, max_level=4095, noise_floor=12, masks=[None, mask, None])
    assert res.clipped.any() and res.underexposed.any()
    for weighting in ("hat", "gaussian", "uniform", "noise-aware"):
        kernel_vs_spec(frames, times, response=lut, weighting=weighting)
    kernel_vs_spec(frames, times, max_level=4095, transforms=tf, masks=[mask, None, None])
    kernel_vs_spec(frames, times, response=lut, transforms=tf)
    kernel_vs_spec(frames, times, max_level=4095, transforms=tf, resample="bilinear")
    floats = [f.astype(np.float32) / np.float32(4095) for f in frames]
    kernel_vs_spec(floats, times, weighting="hat", saturation_level=[0.9] + [0.98] * (c - 1))


@pytest.mark.parametrize("resampled", [False, True])
def test_channel_counts_agree_bit_for_bit(resampled):
    """Each channel's radiance depends on the others only through the "any channel clipped"
    test: an RGB bracket plus green again (4 channels) gives the RGB merge's radiance in its
    first three channels, a grey bracket the same radiance as 1, 3 or 4 channels, with the
    same clip counts and flags, to the bit."""
    sb = bracket(bits=12, response="linear", noise_sigma=1.0, seed=6, scene="window")
    frames = [f.copy() for f in sb.frames]
    for f in frames:
        f[20:30, 40:90] = 3  # below the floor in every frame
    tf = None
    if resampled:
        rot = np.array([[np.cos(0.01), -np.sin(0.01), 1.3], [np.sin(0.01), np.cos(0.01), -0.6]])
        tf = [rot, None, np.array([[1.0, 0.0, -2.25], [0.0, 1.0, 0.5]])]
    kw = dict(max_level=4095, noise_floor=10, transforms=tf, ghost_test="pixels")
    flags = ("clip_count", "clipped", "underexposed")
    rgb = merge(frames, sb.exposure_times, **kw)
    four = merge(_channels(frames, 4), sb.exposure_times, **kw)
    np.testing.assert_array_equal(four.radiance[..., :3], rgb.radiance)
    np.testing.assert_array_equal(four.radiance[..., 3], rgb.radiance[..., 1])
    same_bits(rgb, four, flags)
    assert rgb.clipped.any() and rgb.underexposed.any()
    grey = [np.ascontiguousarray(np.repeat(f[..., 1:2], 3, axis=2)) for f in frames]
    g3 = merge(grey, sb.exposure_times, **kw)
    for c in (1, 4):
        gc = merge(_channels(grey, c), sb.exposure_times, **kw)
        same_bits(g3, gc, flags)
        for ch in range(c):
            np.testing.assert_array_equal(gc.radiance[..., ch], g3.radiance[..., 1])


def test_one_compiled_kernel_serves_every_frame_count():
    """The frame tuples are padded (TUPLE_SLOTS): a bracket of 5 or 9 frames runs the kernel
    compiled for 3 instead of compiling its own (seconds on first use)."""
    from hdrcore.merge import _fused

    def frames(n):
        return [np.full((6, 8, 3), 100 * (k + 1), np.uint16) for k in range(n)]

    merge(frames(3), (1.0, 2.0, 4.0), max_level=4095)
    before = len(_fused.merge_rows.signatures)
    for n in (2, 5, 9, 16):
        times = tuple(float(2**k) for k in range(n))
        res, _ = kernel_vs_spec(frames(n), times, max_level=4095)
        assert res.shares.shape == (n, 6, 8)
    assert len(_fused.merge_rows.signatures) == before


@pytest.mark.parametrize("c", [1, 3])
def test_gaussian_weight_of_a_resampled_frame_reads_it_resampled(c):
    """The Gaussian weight sends integer frames read in place through per-level tables; a
    resampled frame of the same merge must still be read at its mapped position (it was read
    in place: 78 % of the pixels of this bracket wrong)."""
    sb = bracket(bits=12, response="linear", noise_sigma=1.0, seed=1, scene="window")
    frames = sb.frames if c == 3 else _channels(sb.frames, 1)
    tf = [np.array([[1.0, 0.0, 2.5], [0.0, 1.0, -1.25]]), None, None]
    kernel_vs_spec(frames, sb.exposure_times, max_level=4095, weighting="gaussian", transforms=tf)
