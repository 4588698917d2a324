"""The consistency-regions ghost test (hdrcore.merge.consistency): quiet on static non-linear
brackets, firing on moving objects; deghost leaves a static merge alone.

The synthetic brackets are the simulator's 8-bit frames, JPEG-encoded again (quality 85), made
with one response and merged through another (the sRGB curve linearised as a 2.2 gamma): the
per-pixel test sees the response's error everywhere, as it does on real JPEG brackets. Moving
objects are rendered through the frames' own response at 4x or 1/4 of the scene's radiance.
"""

from __future__ import annotations

import io

import numpy as np
import pytest
from scipy import ndimage

from hdrcore.errors import ParameterError
from hdrcore.merge import GhostTestParams, NoiseModel, merge
from hdrcore.synthetic import simulate_bracket
from hdrcore.synthetic.camera import apply_response

from ._brackets import inverse_gamma_lut
from ._ghost_spec_check import regions_vs_spec, sums_vs_spec

SHAPE = (192, 288)
TIMES = (1.0, 4.0, 16.0)
SIDE = 48
NONLINEAR = dict(response=inverse_gamma_lut(255), noise_floor=5.1, saturation_level=247.35)


def _jpeg(levels: np.ndarray, quality: int = 85) -> np.ndarray:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(levels.astype(np.uint8)).save(buf, "JPEG", quality=quality)
    return np.asarray(Image.open(io.BytesIO(buf.getvalue())))


def _bracket(response: str = "srgb", gain: float | None = None):
    """``(frames, times, footprint)``: the JPEG frames, and with ``gain`` a 48 x 48 object of
    ``gain`` times the scene's radiance at a new place in each frame (its footprint)."""
    sb = simulate_bracket(
        scene="window",
        shape=SHAPE,
        bits=8,
        response=response,
        exposure_times=TIMES,
        seed=3,
        noise_sigma=1.0,
        keep_linear=True,
    )
    frames, foot = [], np.zeros(SHAPE, bool)
    for k, (f, lin) in enumerate(zip(sb.frames, sb.linear_frames, strict=True)):
        f = f.copy()
        if gain is not None:
            box = (slice(70, 70 + SIDE), slice(40 + 70 * k, 40 + 70 * k + SIDE))
            f[box] = np.clip(np.rint(255 * apply_response(response, lin[box] * gain)), 0, 255)
            foot[box] = True
        frames.append(_jpeg(f))
    return frames, sb.exposure_times, foot


def test_static_nonlinear_bracket_flags_under_one_percent():
    frames, times, _ = _bracket()
    pixels = merge(frames, times, ghost_test="pixels", **NONLINEAR)
    regions = merge(frames, times, **NONLINEAR)
    assert pixels.ghost.mean() > 0.05  # the per-pixel test sees the response's error
    assert regions.ghost.mean() < 0.01
    assert regions.ghost_test == "regions" and regions.ghost_regions is not None
    s = regions.summary()
    assert s["ghost_test"] == "regions" and s["ghost_regions"]["pairs"]
    # the pair's transfer error (sRGB seen through a 2.2 gamma) was measured, not ignored
    assert max(float(np.abs(p.bias).max()) for p in regions.ghost_regions.pairs) > 0.05


@pytest.mark.parametrize("gain", [4.0, 0.25])
def test_a_moving_object_is_detected(gain):
    still, times, _ = _bracket("gamma")
    frames, _, foot = _bracket("gamma", gain)
    ref = merge(still, times, **NONLINEAR)
    moved = merge(frames, times, **NONLINEAR)
    # the ghost a viewer sees: the merge moved by more than 10 % where the object passed
    seen = (np.abs(moved.radiance - ref.radiance) / ref.radiance > 0.1).any(axis=-1)
    seen &= foot & ~moved.clipped
    assert seen.sum() > 2000
    assert moved.ghost[seen].mean() > (0.9 if gain > 1 else 0.8)
    away = ~ndimage.binary_dilation(foot, iterations=8)
    assert moved.ghost[away].mean() < 0.01
    assert moved.ghost_regions.regions >= 2


def test_deghost_leaves_a_static_merge_unchanged():
    frames, times, _ = _bracket()
    plain = merge(frames, times, **NONLINEAR)
    filled = merge(frames, times, deghost=True, **NONLINEAR)
    assert not filled.deghosted.any()
    np.testing.assert_array_equal(filled.radiance, plain.radiance)


def test_a_wrong_exposure_time_is_a_transfer_error_not_a_ghost():
    """One frame's time 30 % off: every block of its pairs disagrees by the same ratio, which
    the pair's transfer error takes."""
    frames, times, _ = _bracket("gamma")
    wrong = (times[0], times[1] * 1.3, times[2])
    res = merge(frames, wrong, **NONLINEAR)
    assert merge(frames, wrong, ghost_test="pixels", **NONLINEAR).ghost.mean() > 0.05
    assert res.ghost.mean() < 0.01
    first = res.ghost_regions.pairs[0]
    assert first.frames == (0, 1) and np.median(first.bias[1]) == pytest.approx(
        -np.log(1.3), abs=0.05
    )


def _kernel_inputs(seed: int = 0):
    rng = np.random.default_rng(seed)
    frames = [rng.integers(0, 256, (60, 70, 3)).astype(np.uint16) for _ in range(4)]
    t = np.array([[np.cos(0.02), -np.sin(0.02), 1.7], [np.sin(0.02), np.cos(0.02), -2.3]])
    masks = [None, rng.random((60, 70)) > 0.05, None, None]
    return frames, [None, t, None, t * 0.999], masks


@pytest.mark.parametrize("case", ["lut", "linear", "warped", "float", "step"])
def test_compiled_chains_match_the_spec(case):
    frames, tfs, masks = _kernel_inputs()
    params = GhostTestParams(
        sample_pixels=500, min_bin_samples=3, pixel_step=2 if case == "step" else 1
    )
    kw = dict(saturation=[250] * 3, floor=5, noise=NoiseModel(level_noise=2.0), params=params)
    times = [1.0, 4.0, 2.0, 8.0]
    if case == "lut":
        kw["lut"] = inverse_gamma_lut(255)
    elif case == "linear":
        kw["max_level"] = 255
    elif case in ("warped", "step"):
        kw.update(lut=inverse_gamma_lut(255), transforms=tfs, masks=masks)
    else:
        frames = [f.astype(np.float32) / 255 for f in frames[:3]]
        times = times[:3]
        kw.update(saturation=[0.98] * 3, floor=0.02, transforms=tfs[:3])
    a, _ = sums_vs_spec(frames, times, **kw)
    assert a.count.sum() > 1000


def test_bad_parameters_are_refused():
    with pytest.raises(ParameterError, match="block must be >= 1"):
        GhostTestParams(block=0)
    with pytest.raises(ParameterError, match="pixel_step"):
        GhostTestParams(pixel_step=3)
    with pytest.raises(ParameterError, match="edge_margin"):
        GhostTestParams(edge_margin=0.6)
    frames, times, _ = _bracket()
    with pytest.raises(ParameterError, match="regions"):
        merge(frames, times, ghost_test="everywhere", **NONLINEAR)


def test_real_tripod_brackets_flag_almost_nothing(frobisher_dir, memorial_dir):
    """Nothing moves in the tripod brackets of ../shared/data: neither flags anything. The
    memorial scans once flagged 1.9 %, the bottom band where scan 0073 (1/128 s) has its film
    base fogged 5-10 levels above the others': with Debevec's triangle weight those levels
    counted as much as a long frame's and, times 128, made an orange band 2-10x too bright.
    The default weight for non-linear frames (``hat-noise-aware``, the triangle times the
    inverse variance of ``x / dt``) gives a 1/128 s frame near the film base next to nothing:
    the band is gone without deghosting, and so are the bright specks the short frames' film
    grain made in the dark ceiling."""
    from hdrcore.io import load_bracket
    from hdrcore.pipeline import Pipeline, PipelineParams

    b = load_bracket([frobisher_dir])
    r = Pipeline(b).run(until="merge")
    assert r.merge.ghost.mean() < 0.01
    filled = Pipeline(b).run(PipelineParams(deghost=True), until="merge")
    np.testing.assert_array_equal(
        filled.radiance[~filled.merge.deghosted], r.radiance[~filled.merge.deghosted]
    )
    b = load_bracket([memorial_dir], exposure_times=memorial_dir / "exposure_times.txt")
    r = Pipeline(b, PipelineParams(exclude_colour=(0, 0, 255), align="none")).run(until="merge")
    assert r.merge.weighting == "hat-noise-aware"
    assert r.merge.ghost.mean() < 0.002
    levels = [f.levels for f in b.frames]
    masks = [~np.all(lv == (0, 0, 255), axis=-1) for lv in levels]
    keep = [k for k, f in enumerate(b.frames) if f.name != "memorial0073.png"]
    assert len(keep) == len(b) - 1

    def specks(rad: np.ndarray) -> int:  # pixels 3x their 5x5 median and 2x every neighbour
        lum = rad.mean(axis=-1).astype(np.float64)
        ring = np.ones((3, 3), bool)
        ring[1, 1] = False
        med = ndimage.median_filter(lum, size=5)
        return int(
            ((lum > 3 * med) & (lum > 2 * ndimage.maximum_filter(lum, footprint=ring))).sum()
        )

    band = {}
    speck = {}
    for weighting in ("hat", "hat-noise-aware"):
        kw = dict(
            response=r.lut,
            saturation_level=r.saturation,
            noise_floor=r.noise_floor,
            weighting=weighting,
        )
        full = merge(levels, r.exposure_times, masks=masks, **kw)
        without = merge(
            [levels[k] for k in keep],
            [r.exposure_times[k] for k in keep],
            masks=[masks[k] for k in keep],
            **kw,
        )
        ratio = (full.radiance / without.radiance).max(axis=-1)
        band[weighting] = np.median(ratio[720:750])
        assert abs(np.median(ratio[:700]) - 1.0) < 0.01  # the same elsewhere
        speck[weighting] = specks(full.radiance)
    assert band["hat"] > 1.5  # scan 0073's band, 2x too bright with the triangle alone
    assert abs(band["hat-noise-aware"] - 1.0) < 0.02  # gone
    assert speck["hat-noise-aware"] < 0.25 * speck["hat"]


@pytest.mark.parametrize("case", ["lut", "warped", "step"])
def test_compiled_block_test_matches_the_spec(case):
    """The whole test (sums, transfer error, block z, regions) through the kernels and through
    the specification: the same blocks, z and regions."""
    frames, times, _ = _bracket("gamma", 4.0)
    kw = dict(
        saturation=[247.35] * 3,
        floor=5.1,
        lut=inverse_gamma_lut(255),
        noise=NoiseModel(level_noise=2.0),
    )
    if case == "step":
        kw["params"] = GhostTestParams(pixel_step=2)
    if case == "warped":
        t = np.array([[1.0, 0.002, 0.6], [-0.002, 1.0, -0.4]])
        kw.update(
            transforms=[None, t, None],
            masks=[None, None, np.random.default_rng(1).random(SHAPE) > 0.02],
        )
    a = regions_vs_spec(frames, times, **kw)
    assert a.regions >= 2 and a.blocks.any()


def test_read_only_frames_and_long_brackets_run():
    """The kernel takes read-only frames (a bracket's arrays); a bracket longer than its tuple
    slots goes through in groups of frames, with the specification's sums."""
    from hdrcore.merge.consistency import MAX_KERNEL_FRAMES

    rng = np.random.default_rng(5)
    n = MAX_KERNEL_FRAMES + 2
    frames = [rng.integers(0, 256, (24, 32, 3)).astype(np.uint16) for _ in range(n)]
    for f in frames[::2]:
        f.flags.writeable = False
    times = [1.1**k for k in range(n)]
    kw = dict(
        saturation=[250] * 3,
        floor=5,
        lut=inverse_gamma_lut(255),
        params=GhostTestParams(sample_pixels=500, min_bin_samples=3),
    )
    for m in (3, MAX_KERNEL_FRAMES, n):
        a, _ = sums_vs_spec(frames[:m], times[:m], **kw)
        assert a.count.sum() > 0 and a.count.shape[0] == m - 1
        # every consecutive pair, the last across the group boundary too, was compared
        assert (a.count.sum(axis=(1, 2, 3)) > 0).all()
