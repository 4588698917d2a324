"""The merge resamples a frame through a homography plus a displacement field (local refinement,
issue 14): a frame whose content moves by a smooth non-rigid field merges back onto the reference
only with the field, the kernel's result is the specification's (:mod:`hdrcore.merge.spec`), and
a deghosted merge with fields runs (the band of rows shifted with its field)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from hdrcore.errors import ParameterError
from hdrcore.merge import merge
from hdrcore.registration.field import DisplacementField, map_points

from ._spec_check import kernel_vs_spec


def _scene(h: int, w: int) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    base = 0.4 + 0.2 * np.sin(xx / 7.0) * np.cos(yy / 9.0) + 0.1 * np.sin((xx + yy) / 13.0)
    return np.stack([base, base * 0.9, base * 0.8], axis=-1)


@pytest.fixture(scope="module")
def frames():
    h, w = 96, 160
    ref = _scene(h + 40, w + 40)[20:-20, 20:-20]
    big = _scene(h + 40, w + 40)
    # the frame shows the scene at H(x) + d(x) for reference pixel x: a shift and a bump of
    # up to 3 px in the middle (a near object's parallax), smooth on a 16 px node grid
    hmat = np.array([[1.0, 0.0, 1.3], [0.0, 1.0, -0.6], [0.0, 0.0, 1.0]])
    gh, gw = DisplacementField.grid((h, w), 16)
    yy, xx = np.mgrid[0:gh, 0:gw].astype(np.float64) * 16
    bump = 3.0 * np.exp(-(((xx - w / 2) / 30) ** 2 + ((yy - h / 2) / 20) ** 2))
    fld = DisplacementField(16, np.stack([bump, -0.5 * bump], axis=-1))
    # render the frame: frame pixel q shows what reference pixel x shows where q = H x + d(x);
    # invert by fixed-point iteration on a dense grid
    qy, qx = np.mgrid[0:h, 0:w].astype(np.float64)
    x, y = qx - 1.3, qy + 0.6
    for _ in range(30):
        sx, sy = map_points(hmat, fld, x, y)
        x, y = x + (qx - sx), y + (qy - sy)
    moved = np.stack(
        [
            ndimage.map_coordinates(big[..., c], [y + 20, x + 20], order=3, mode="nearest")
            for c in range(3)
        ],
        axis=-1,
    )

    def to16(a: np.ndarray) -> np.ndarray:
        return np.clip(np.rint(a * 60000), 0, 65535).astype(np.uint16)

    return to16(ref), to16(moved), hmat, fld


def _error(out: np.ndarray, ref: np.ndarray) -> np.ndarray:
    truth = ref.astype(np.float64) / 65535.0
    inner = (slice(10, -10), slice(10, -10))
    return np.abs(out[inner] - truth[inner]) / truth[inner]


def test_the_field_brings_a_non_rigid_motion_back(frames) -> None:
    ref, moved, hmat, fld = frames
    with_field = merge([moved], [1.0], max_level=65535, transforms=[hmat], fields=[fld]).radiance
    without = merge([moved], [1.0], max_level=65535, transforms=[hmat]).radiance
    e1, e0 = _error(with_field, ref), _error(without, ref)
    assert np.nanmedian(e1) < 3e-3 and np.nanpercentile(e1, 99) < 2e-2
    # the bump alone (3 px at its centre) is what the homography cannot hold
    assert np.nanpercentile(e0, 99) > 5 * np.nanpercentile(e1, 99)


@pytest.mark.parametrize("c", [1, 3, 4])
def test_kernel_agrees_with_fields(frames, c) -> None:
    ref, moved, hmat, fld = frames
    pick = [0, 1, 2, 1][:c] if c > 1 else [1]
    kernel_vs_spec(
        [ref[..., pick], moved[..., pick]],
        [1.0, 1.0],
        max_level=65535,
        transforms=[None, hmat],
        fields=[None, fld],
    )


def test_a_field_on_an_identity_transform_is_still_applied(frames) -> None:
    ref, moved, hmat, fld = frames
    shifted = DisplacementField(fld.step, fld.offsets + np.array([1.3, -0.6], np.float32))
    out = merge([moved], [1.0], max_level=65535, transforms=[None], fields=[shifted]).radiance
    assert np.nanmedian(_error(out, ref)) < 3e-3


def test_deghost_with_fields_fills_regions_from_one_frame(frames) -> None:
    """A region where the frames disagree (an object in the moved frame only) is filled from
    one frame: the pixels taken from the moved frame are that frame merged alone through its
    transform and field (the band of rows cut for it shifted with its field), to the bit, and
    the rest is the weighted average."""
    ref, moved, hmat, fld = frames
    moved = moved.copy()
    moved[40:60, 60:90] = np.minimum(moved[40:60, 60:90].astype(np.int64) * 3, 65535)
    kw = dict(max_level=65535, transforms=[None, hmat], fields=[None, fld])
    plain = merge([ref, moved], [1.0, 1.0], **kw)
    a = merge([ref, moved], [1.0, 1.0], deghost=True, **kw)
    d = a.deghosted
    assert d.any()
    np.testing.assert_array_equal(a.radiance[~d], plain.radiance[~d])
    alone = [
        merge([ref], [1.0], max_level=65535, saturation_level=a.saturation_level),
        merge(
            [moved],
            [1.0],
            max_level=65535,
            transforms=[hmat],
            fields=[fld],
            saturation_level=a.saturation_level,
        ),
    ]
    taken = 0
    for k in range(2):
        take = d & (a.shares[k] == 1.0)
        taken += int(take.sum())
        np.testing.assert_array_equal(a.radiance[take], alone[k].radiance[take])
    assert taken == d.sum()


def test_fields_are_checked(frames) -> None:
    ref, moved, hmat, fld = frames
    with pytest.raises(ParameterError, match="one displacement field"):
        merge([moved], [1.0], max_level=65535, fields=[fld, fld])
    with pytest.raises(ParameterError, match="not a displacement field"):
        merge([moved], [1.0], max_level=65535, fields=[np.zeros((4, 4, 2))])
    other = DisplacementField(8, np.zeros((13, 21, 2)))
    with pytest.raises(ParameterError, match="share their grid"):
        merge([moved, moved], [1.0, 1.0], max_level=65535, fields=[fld, other])


def test_field_lookup_on_a_grid_equals_pointwise() -> None:
    rng = np.random.default_rng(3)
    fld = DisplacementField(32, rng.normal(size=(5, 7, 2)), origin=(-3.0, 5.0))
    xs = np.linspace(-20, 230, 37)
    ys = np.linspace(-10, 150, 23)
    gx, gy = fld.on_grid(xs, ys)
    xx, yy = np.meshgrid(xs, ys)
    px, py = fld.at(xx, yy)
    assert np.allclose(gx, px) and np.allclose(gy, py)
    # at a node the field is the node's value; a band's shifted field reads the same place
    assert np.allclose(fld.at(np.array([-3.0 + 64]), np.array([5.0 + 32]))[0], fld.offsets[1, 2, 0])
    band = fld.shifted(0.0, 40.0)
    assert np.allclose(band.at(xx, yy - 40.0)[0], px)
