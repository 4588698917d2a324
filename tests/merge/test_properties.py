"""Property tests of the merge (issue 17): what must hold for any bracket, not one example.

Frames are rendered from a random radiance map through a linear 12-bit camera (clipped, with
a little noise), so every property is checked on data the merge really sees."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrcore.merge import merge

ML = 4095


def _bracket(seed: int, n: int, base: float, step: float, channels: int = 3):
    rng = np.random.default_rng(seed)
    radiance = np.exp(rng.uniform(np.log(0.02), np.log(50.0), (12, 16, channels)))
    times = [base * step**k for k in range(n)]
    frames = []
    for t in times:
        y = radiance * t * ML / 8.0 + rng.normal(0.0, 1.0, radiance.shape)
        frames.append(np.clip(np.rint(y), 0, ML).astype(np.uint16))
    return frames, times


def _radiance(frames, times):
    res = merge(frames, times, max_level=ML)
    return np.asarray(res.radiance, np.float64)


brackets = st.tuples(
    st.integers(0, 10_000), st.integers(2, 5), st.floats(0.01, 0.5), st.sampled_from([2.0, 4.0])
)


@settings(max_examples=15, deadline=None)
@given(brackets, st.floats(0.1, 10.0))
def test_scaling_every_time_scales_the_radiance_inversely(b, c) -> None:
    frames, times = _bracket(*b)
    e1 = _radiance(frames, times)
    e2 = _radiance(frames, [t * c for t in times])
    ok = np.isfinite(e1) & (e1 > 0)
    assert ok.mean() > 0.5
    np.testing.assert_allclose(e2[ok] * c, e1[ok], rtol=1e-5)


@settings(max_examples=15, deadline=None)
@given(brackets, st.randoms(use_true_random=False))
def test_the_order_of_the_frames_changes_nothing(b, rnd) -> None:
    frames, times = _bracket(*b)
    order = list(range(len(frames)))
    rnd.shuffle(order)
    e1 = _radiance(frames, times)
    e2 = _radiance([frames[k] for k in order], [times[k] for k in order])
    np.testing.assert_allclose(e2, e1, rtol=1e-6, atol=0)


@pytest.mark.parametrize("channels", [3, 4, 1])
def test_a_black_frame_adds_nothing(channels) -> None:
    # the example that found the bug (issue 17): 42 % of the pixels are clipped in both frames
    # (or dark in one channel of a pixel clipped in another); a black frame set them to 0
    frames, times = _bracket(0, 2, 0.5, 2.0, channels)
    r1 = merge(frames, times, max_level=ML)
    black = np.zeros_like(frames[0])
    r2 = merge([black, *frames], [times[0] / 4.0, *times], max_level=ML)
    assert r1.clipped.mean() > (0.15 if channels == 1 else 0.3)
    np.testing.assert_allclose(r2.radiance, r1.radiance, rtol=1e-6, atol=0)
    np.testing.assert_array_equal(r2.clipped, r1.clipped)
    np.testing.assert_array_equal(r2.underexposed, r1.underexposed)
    np.testing.assert_array_equal(r2.shares[0], 0.0)  # the black frame's share
    np.testing.assert_array_equal(r2.shares[1:], r1.shares)


@settings(max_examples=20, deadline=None)
@given(brackets, st.floats(1 / 64, 64.0), st.integers(0, 40), st.sampled_from([1, 3, 4]))
def test_a_black_frame_of_any_time_adds_nothing_with_a_noise_floor(b, c, floor, channels) -> None:
    # the black frame darker, between or brighter than the others; a noise floor (the
    # pipeline's) leaves channels of no weight that take a frame's value below the floor.
    # Shorter than every frame: nothing changes anywhere. Otherwise nothing changes where some
    # frame gave the pixel weight; where none did, a black frame longer than a frame clipped
    # there contradicts it (as a marker or a moving object would) and the longest reading
    # stays, and a pixel below the floor in every frame takes the longest frame's value.
    frames, times = _bracket(*b, channels)
    kw = dict(max_level=ML, noise_floor=floor)
    r1 = merge(frames, times, **kw)
    r2 = merge([*frames, np.zeros_like(frames[0])], [*times, times[0] * c], **kw)
    if c < 1.0:
        np.testing.assert_allclose(r2.radiance, r1.radiance, rtol=1e-6, atol=0)
        np.testing.assert_array_equal(r2.clipped, r1.clipped)
        np.testing.assert_array_equal(r2.underexposed, r1.underexposed)
        np.testing.assert_array_equal(r2.shares[-1], 0.0)
        np.testing.assert_array_equal(r2.shares[:-1], r1.shares)
    else:
        seen = r1.weight_sum > 0
        assert seen.mean() > 0.3
        np.testing.assert_allclose(r2.radiance[seen], r1.radiance[seen], rtol=1e-6, atol=0)
        np.testing.assert_array_equal(r2.underexposed[seen], r1.underexposed[seen])


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 10_000), st.integers(2, 5), st.floats(0.01, 0.05))
def test_a_black_frame_adds_nothing_where_nothing_is_clipped(seed, n, base) -> None:
    # the part of the property that holds today: no pixel clipped in every frame, and the
    # black frame's zeros outweighed where the others see light
    frames, times = _bracket(seed, n, base, 2.0)
    e1 = _radiance(frames, times)
    e2 = _radiance([np.zeros_like(frames[0]), *frames], [times[0] / 4.0, *times])
    bright = np.min([f for f in frames], axis=0) >= 50  # well above the read noise everywhere
    np.testing.assert_allclose(e2[bright], e1[bright], rtol=1e-2)
