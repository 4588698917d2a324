"""The region ghost test's compiled kernels for any number of frames: a 40-frame bracket (more
than the kernel's tuple slots) held to the specification, the thread count and the chains'
row groups changing no bit, and ``engine="numpy"`` a deprecated alias of the kernels."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.errors import ParameterError
from hdrcore.merge import NoiseModel
from hdrcore.merge import consistency as cons
from hdrcore.merge.consistency import MAX_KERNEL_FRAMES, consistency_regions, pair_residuals
from hdrcore.registration import invert
from hdrcore.synthetic import simulate_bracket

from ._brackets import inverse_gamma_lut
from ._ghost_spec_check import regions_vs_spec, sums_vs_spec

SHAPE = (96, 136)
N = 40


def _long_bracket(hand_held: bool):
    """40 frames 1/6 stop apart (8-bit gamma), a bright square one step further in each frame;
    hand-held: each frame's own small motion, read through its transform."""
    times = tuple(2 ** (k / 6) for k in range(N))
    sb = simulate_bracket(
        scene="window",
        shape=SHAPE,
        bits=8,
        response="gamma",
        exposure_times=times,
        seed=11,
        noise_sigma=1.0,
        max_shift=2.0 if hand_held else 0.0,
        max_rotation_deg=0.3 if hand_held else 0.0,
    )
    frames = [f.astype(np.uint8) for f in sb.frames]
    for k, f in enumerate(frames):
        x0 = 8 + 2 * k
        f[30:54, x0 : x0 + 24] = np.minimum(255, f[30:54, x0 : x0 + 24].astype(int) * 2 + 40)
    rng = np.random.default_rng(3)
    masks = [rng.random(SHAPE) > 0.03 if k % 7 == 3 else None for k in range(N)]
    kw = dict(
        saturation=[247.0] * 3,
        floor=5.0,
        lut=inverse_gamma_lut(255),
        noise=NoiseModel(level_noise=2.0),
        masks=masks,
    )
    if hand_held:
        kw["transforms"] = [invert(t) for t in sb.to_reference]
    return frames, list(sb.exposure_times), kw


@pytest.mark.parametrize("hand_held", [False, True])
def test_forty_frames_through_the_kernel_match_the_spec(hand_held):
    assert N > MAX_KERNEL_FRAMES
    frames, times, kw = _long_bracket(hand_held)
    res = regions_vs_spec(frames, times, **kw)
    assert len(res.pairs) == N - 1 and res.regions >= 1 and res.blocks.any()
    # the square moved 2 px a frame: every consecutive pair was compared, the pairs across
    # the kernel's group boundary (frames 31, 32) too
    assert all(p.blocks > 0 for p in res.pairs)
    assert res.pairs[MAX_KERNEL_FRAMES - 1].frames == (MAX_KERNEL_FRAMES - 1, MAX_KERNEL_FRAMES)


def test_row_groups_and_threads_change_no_bit(monkeypatch):
    """A long bracket goes through the frame groups a few rows at a time (the chains' state
    kept per row between groups): one row at a time, or one thread, gives the same bits."""
    frames, times, kw = _long_bracket(True)
    ref = pair_residuals(frames, times, workers=2, **kw)
    monkeypatch.setattr(cons, "_STATE_BYTES", 1)
    for workers in (1, 2):
        got = pair_residuals(frames, times, workers=workers, **kw)
        for name in ("weighted", "weights", "additive", "first", "second", "count", "bias"):
            np.testing.assert_array_equal(getattr(got, name), getattr(ref, name), err_msg=name)
    # the same holds for the spec comparison with the smallest groups
    cut = {k: (v[:34] if k in ("masks", "transforms") else v) for k, v in kw.items()}
    sums_vs_spec(frames[:34], times[:34], workers=1, **cut)


def test_numpy_engine_is_a_deprecated_alias():
    frames, times, kw = _long_bracket(False)
    frames, times = frames[:5], times[:5]
    kw["masks"] = kw["masks"][:5]
    a = consistency_regions(frames, times, **kw)
    with pytest.warns(DeprecationWarning, match="engine='numpy'"):
        b = consistency_regions(frames, times, engine="numpy", **kw)
    for name in ("blocks", "z", "tested", "ghost"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    with pytest.warns(DeprecationWarning, match="pair_residuals"):
        c = pair_residuals(frames, times, engine="numpy", **kw)
    d = pair_residuals(frames, times, engine="numba", **kw)
    np.testing.assert_array_equal(c.weighted, d.weighted)
    with pytest.raises(ParameterError, match="ghost test engine"):
        pair_residuals(frames, times, engine="cuda", **kw)
