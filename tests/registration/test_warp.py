"""Warping: accuracy against analytic images, the validity mask, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.errors import ParameterError
from hdrcore.registration import _kernels, rigid_matrix, spec, valid_mask, warp, warp_to_reference
from hdrcore.registration.transform import apply, homogeneous, invert, similarity_matrix

H, W = 96, 144


def _smooth(x, y):
    return np.sin(0.13 * x + 0.05 * y) + np.cos(0.07 * x - 0.11 * y) + 3.0


@pytest.mark.parametrize(
    "matrix, method",
    [
        (rigid_matrix(3.3, -2.7, 0.0, (H, W)), "shear"),
        (rigid_matrix(1.25, 4.5, 1.7, (H, W)), "shear"),
        (rigid_matrix(-10.2, 5.1, -2.0, (H, W)), "shear"),
        (np.array([[1.01, 0.02, 1.0], [0.0, 0.99, 2.0]]), "cubic"),
        (np.array([[1.005, -0.02, 1.5], [0.02, 1.005, -2.0], [2e-5, -3e-5, 1.0]]), "cubic"),
    ],
)
def test_warp_matches_analytic_image(matrix, method):
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    res = warp(_smooth(xx, yy), matrix)
    sx, sy = apply(matrix, xx, yy)
    inner = res.mask & (sx > 3) & (sx < W - 4) & (sy > 3) & (sy < H - 4)
    assert res.method == method
    assert np.abs(res.image - _smooth(sx, sy))[inner].max() < 1e-3


def test_integer_shift_is_exact_and_mask_marks_borders():
    img = np.random.default_rng(0).random((H, W)).astype(np.float32)
    res = warp(img, rigid_matrix(5.0, -3.0, 0.0, (H, W)))
    assert res.method == "integer"
    assert np.allclose(res.image[3:, : W - 5], img[: H - 3, 5:], atol=1e-6)
    assert res.mask[3:, : W - 5].all()
    assert not res.mask[:3].any() and not res.mask[:, W - 5 :].any()
    assert np.isnan(res.image[~res.mask]).all()


def test_mask_is_analytic_and_respects_margin():
    m = rigid_matrix(2.5, 1.5, 1.0, (H, W))
    mask = valid_mask(m, (H, W), (H, W), margin=2.0)
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    sx, sy = apply(m, xx, yy)
    expected = (sx >= 2) & (sx <= W - 3) & (sy >= 2) & (sy <= H - 3)
    assert np.array_equal(mask, expected)


def test_colour_frames_and_warp_to_reference():
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    img = np.stack([_smooth(xx, yy), 2 * _smooth(xx, yy), 0.5 * _smooth(xx, yy)], axis=-1)
    to_ref = rigid_matrix(2.0, -1.0, 0.5, (H, W))
    res = warp_to_reference(img, to_ref, fill=0.0)
    single = warp(img[..., 1], invert(to_ref), fill=0.0)
    assert res.image.shape == (H, W, 3)
    assert np.allclose(res.image[..., 1], single.image, atol=1e-5)
    assert (res.image[~res.mask] == 0).all()


def test_identity_warp_returns_the_image():
    img = np.random.default_rng(1).random((H, W)).astype(np.float32)
    res = warp(img, np.eye(2, 3))
    assert res.mask.all() and np.allclose(res.image, img)


def test_warp_rejects_bad_input():
    with pytest.raises(ParameterError, match="2x3"):
        warp(np.zeros((8, 8)), np.eye(4))
    with pytest.raises(ParameterError, match="3x3"):
        warp(np.zeros((8, 8)), np.full((3, 3), np.nan))
    with pytest.raises(ParameterError, match=r"\(H, W\)"):
        warp(np.zeros(8), np.eye(2, 3))


HOMOGRAPHY = np.array([[1.004, -0.015, 2.5], [0.012, 0.996, -1.5], [3e-5, -2e-5, 1.0]])


@pytest.mark.parametrize("margin", [0.0, 2.0])
def test_homography_mask_is_analytic(margin):
    mask = valid_mask(HOMOGRAPHY, (H, W), (H, W), margin=margin)
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    sx, sy = apply(HOMOGRAPHY, xx, yy)
    expected = (sx >= margin) & (sx <= W - 1 - margin) & (sy >= margin) & (sy <= H - 1 - margin)
    assert np.array_equal(mask, expected)


def test_affine_homography_takes_the_fast_paths():
    """A 3x3 matrix with last row (0, 0, 1) is warped exactly as its 2x3 form."""
    img = np.random.default_rng(2).random((H, W, 2)).astype(np.float32)
    for m in (
        rigid_matrix(3.0, -2.0, 0.0, (H, W)),
        rigid_matrix(1.5, 2.5, 1.2, (H, W)),
        similarity_matrix(1.5, 2.5, 1.2, 1.01, (H, W)),
    ):
        a, b = warp(img, m), warp(img, homogeneous(m))
        assert a.method == b.method
        np.testing.assert_array_equal(a.image, b.image)
        np.testing.assert_array_equal(a.mask, b.mask)


def test_homography_warp_round_trip_and_colour():
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    img = np.stack([_smooth(xx, yy), 2 * _smooth(xx, yy)], axis=-1)
    there = warp(img, HOMOGRAPHY, fill=0.0)
    back = warp(there.image, invert(HOMOGRAPHY))
    inner = back.mask & valid_mask(invert(HOMOGRAPHY), (H, W), (H, W), margin=4.0)
    assert inner.mean() > 0.7
    assert np.abs(back.image - img)[inner].max() < 2e-3
    assert np.allclose(there.image[..., 1], 2 * there.image[..., 0], atol=1e-5)


def test_direct_warp_kernel_matches_its_spec():
    """_kernels.warp_rows (compiled) against spec.warp_rows: 3 channels, a homography whose
    horizon crosses the output (NaN beyond), taps clamped at the edges."""
    rng = np.random.default_rng(3)
    src = rng.random((40, 50, 3)).astype(np.float32)
    m = np.array([[1.02, 0.05, -3.0], [-0.03, 0.97, 2.5], [0.004, -0.025, 1.0]])
    got = np.empty((45, 55, 3), np.float32)
    ref = np.empty_like(got)
    _kernels.warp_rows(src, m, 0, 45, got)
    spec.warp_rows(src, m, 0, 45, ref)
    assert np.isnan(ref).any() and np.isfinite(ref).mean() > 0.5
    np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
    np.testing.assert_allclose(got, ref, rtol=0, atol=2e-6, equal_nan=True)


@pytest.mark.parametrize(
    "matrix",
    [
        np.array([[1.0, 0.0, 4.0], [0.0, 1.0, -3.0]]),  # a shift: the shear passes
        rigid_matrix(2.5, -1.5, 2.0, (40, 60)),  # a rotation: the shear passes
        np.array([[1.02, 0.01, 3.0], [-0.01, 0.99, -2.0], [1e-5, 2e-5, 1.0]]),  # compiled cubic
    ],
)
def test_fill_none_extends_the_frame_edge_and_keeps_the_pixels_inside(matrix) -> None:
    # The exposure fusion's warp (hdrcore.merge.fusion): outside the frame's reach its edge
    # extended, continuous with the inside, never a constant; inside the same pixels and mask.
    yy, xx = np.mgrid[0:40, 0:60].astype(np.float32)
    img = np.stack([0.2 + 0.01 * xx, 0.3 + 0.01 * yy, 0.5 + 0.002 * (xx + yy)], axis=-1)
    filled = warp(img, matrix, fill=np.nan)
    extended = warp(img, matrix, fill=None)
    inside = filled.mask
    assert not inside.all() and inside.any()
    np.testing.assert_array_equal(extended.mask, inside)
    np.testing.assert_array_equal(extended.image[inside], filled.image[inside])
    assert np.isfinite(extended.image).all()
    # continuous across the edge of the frame's reach: neighbours differ by about one step of
    # the ramp (0.01 a pixel along x or y), as inside; a constant fill would jump
    for axis in (0, 1):
        step = np.abs(np.diff(extended.image, axis=axis)).max()
        assert step < 0.02


def test_fill_none_repeats_the_edge_pixels_under_a_whole_pixel_shift() -> None:
    img = np.random.default_rng(3).random((30, 50, 3)).astype(np.float32)
    res = warp(img, np.array([[1.0, 0.0, 4.0], [0.0, 1.0, -3.0]]), fill=None)  # src = out + (4, -3)
    ys = np.clip(np.arange(30) - 3, 0, 29)
    xs = np.clip(np.arange(50) + 4, 0, 49)
    np.testing.assert_array_equal(res.image, img[ys][:, xs])
    assert not res.mask[:3].any() and not res.mask[:, -4:].any() and res.mask[3:, :-4].all()
