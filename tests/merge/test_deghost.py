"""merge(..., deghost=True): each region where the frames disagree is filled from one frame."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.merge import merge
from hdrcore.registration import invert

from ._brackets import bracket, relative_error

SQUARE = (slice(50, 74), slice(80, 104))


def _with_object(sb, k: int, square=SQUARE) -> list[np.ndarray]:
    """The bracket's frames with a 24 x 24 object 3x brighter than the scene in frame ``k``
    only (something that moved through the scene while that frame was exposed)."""
    frames = [f.copy() for f in sb.frames]
    obj = frames[k][square].astype(np.int64) * 3
    frames[k][square] = np.minimum(obj, sb.max_level).astype(frames[k].dtype)
    return frames


def test_an_object_in_one_frame_is_removed_and_the_rest_unchanged():
    sb = bracket(bits=12, response="linear", noise_sigma=1.0, seed=2)
    frames = _with_object(sb, 1)
    kw = dict(max_level=sb.max_level)
    mixed = merge(frames, sb.exposure_times, **kw)
    clean = merge(frames, sb.exposure_times, deghost=True, **kw)
    # the weighted mix shows the object faintly (a ghost); one frame per region does not
    assert np.median(relative_error(mixed.radiance, sb)[SQUARE]) > 0.05
    assert np.median(relative_error(clean.radiance, sb)[SQUARE]) < 0.002
    assert clean.deghosted[SQUARE].mean() > 0.9 and mixed.deghosted is None
    # the replaced pixels hold one frame's value and all of its share ...
    k = int(np.argmax(clean.shares[:, 60, 90]))
    assert k != 1 and clean.shares[k, 60, 90] == 1.0
    alone = merge(
        [frames[k]],
        [sb.exposure_times[k]],
        max_level=sb.max_level,
        saturation_level=clean.saturation_level,
        noise_floor=clean.noise_floor,
        weighting=clean.weighting,
    )
    d = clean.deghosted
    np.testing.assert_array_equal(clean.radiance[d], alone.radiance[d])
    # ... the ghost map still says where the frames disagreed, and nothing else changed
    np.testing.assert_array_equal(clean.ghost, mixed.ghost)
    np.testing.assert_array_equal(clean.radiance[~d], mixed.radiance[~d])
    assert "filled from one frame" in clean.message
    assert clean.summary()["deghosted_fraction"] == pytest.approx(d.mean())


def test_hand_held_frames_are_cut_to_bands_with_their_transform_shifted():
    """A moved frame merged alone over a band of rows gives what it gives over the whole
    frame (the band holds the source rows, the transform is shifted to it)."""
    sb = bracket(
        bits=12, response="linear", noise_sigma=1.0, seed=3, max_shift=6.0, max_rotation_deg=1.5
    )
    tf = [invert(t) for t in sb.to_reference]
    moved = [k for k, t in enumerate(tf) if not np.allclose(t, np.eye(2, 3))]
    frames = _with_object(sb, moved[0])
    kw = dict(max_level=sb.max_level, transforms=tf)
    a = merge(frames, sb.exposure_times, deghost=True, **kw)
    b = merge(frames, sb.exposure_times, **kw)
    assert a.deghosted.any()
    # outside the filled regions the weighted average stays, to the bit
    np.testing.assert_array_equal(a.radiance[~a.deghosted], b.radiance[~a.deghosted])
    for k in range(len(frames)):
        take = a.deghosted & (a.shares[k] == 1.0)
        if not take.any():
            continue
        alone = merge(
            [frames[k]],
            [sb.exposure_times[k]],
            max_level=sb.max_level,
            transforms=[tf[k]],
            saturation_level=a.saturation_level,
            noise_floor=a.noise_floor,
            weighting=a.weighting,
        )
        np.testing.assert_array_equal(a.radiance[take], alone.radiance[take])


def test_only_ghost_regions_change():
    """Pixels outside the grown ghost regions keep the weighted average; without ghosts nothing
    changes."""
    from scipy import ndimage

    sb = bracket(bits=12, response="linear", noise_sigma=1.0, seed=4, scene="window")
    plain = merge(sb.frames, sb.exposure_times, max_level=sb.max_level)
    res = merge(sb.frames, sb.exposure_times, max_level=sb.max_level, deghost=True)
    np.testing.assert_array_equal(res.radiance[~res.deghosted], plain.radiance[~res.deghosted])
    assert not (res.deghosted & ~ndimage.binary_dilation(plain.ghost, iterations=2)).any()
    still = [np.full((16, 24, 3), 400 * (k + 1), np.uint16) for k in range(3)]
    flat = merge(still, (1.0, 2.0, 3.0), max_level=4095, deghost=True)
    assert not flat.ghost.any() and not flat.deghosted.any()
    np.testing.assert_array_equal(
        flat.radiance, merge(still, (1.0, 2.0, 3.0), max_level=4095).radiance
    )


@pytest.mark.parametrize(
    "other, prefer, expected",
    [
        (0.6, None, 0),
        (0.6, [False, True], 1),
        (0.4, [False, True], 0),
        (0.6, [True, True], 0),
    ],
)
def test_frame_choice_prefers_frames_not_resampled(other, prefer, expected):
    """The frame with the largest share of a region fills it, unless a preferred frame (not
    resampled) has at least half of that share; regions under min_area keep the average."""
    import types

    from hdrcore.merge.deghost import fill_ghost_regions

    h, w = 20, 30
    ghost = np.zeros((h, w), bool)
    ghost[5:15, 5:15] = True
    ghost[1, 25] = True  # an isolated pixel: too small to fill
    shares = np.zeros((2, h, w), np.float16)
    shares[0], shares[1] = 1.0 / (1.0 + other), other / (1.0 + other)
    radiance = np.full((h, w, 3), -1.0, np.float32)
    weight_sum = np.ones((h, w), np.float32)

    def single(k, y0, y1):
        n = y1 - y0
        return types.SimpleNamespace(
            radiance=np.full((n, w, 3), float(k), np.float32),
            weight_sum=np.full((n, w), 2.0, np.float32),
            clipped=np.zeros((n, w), bool),
            underexposed=np.zeros((n, w), bool),
        )

    done = fill_ghost_regions(
        radiance,
        weight_sum,
        shares,
        ghost,
        single,
        prefer=None if prefer is None else np.array(prefer),
    )
    assert done[10, 10] and not done[1, 25] and not done[0, 0]
    assert (radiance[done] == expected).all() and (radiance[~done] == -1.0).all()
    assert (shares[expected][done] == 1.0).all() and (shares[1 - expected][done] == 0.0).all()
    assert (weight_sum[done] == 2.0).all()
