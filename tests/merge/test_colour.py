"""Camera RGB -> working space: neutrals stay neutral, identity without a camera matrix."""

from __future__ import annotations

import colour
import numpy as np
import pytest

from hdrcore.errors import ParameterError
from hdrcore.merge import camera_to_working, camera_to_working_matrix

# Adobe DNG ColorMatrix of a Canon EOS 5D Mark II (XYZ D65 -> camera), as dcraw's adobe_coeff
# lists it (/10000) and rawpy reports it in ``rgb_xyz_matrix``.
CAM_XYZ = (
    np.array([[4716, 603, -830], [-7798, 15474, 2480], [-1496, 1937, 6651], [0, 0, 0]], float)
    / 10000.0
)
WB = (2.1, 1.0, 1.5, 0.0)


def test_identity_without_camera_data():
    np.testing.assert_allclose(camera_to_working_matrix(), np.eye(3), atol=1e-12)


def test_camera_neutral_becomes_working_space_neutral():
    m = camera_to_working_matrix(CAM_XYZ, WB, "sRGB")
    grey_camera = np.array([1 / 2.1, 1.0, 1 / 1.5])  # a grey under the as-shot illuminant
    out = m @ grey_camera
    np.testing.assert_allclose(out, out[1], rtol=1e-9)


def test_other_working_spaces_keep_neutrals_and_match_colour_science():
    m_srgb = camera_to_working_matrix(CAM_XYZ, WB, "sRGB")
    m_aces = camera_to_working_matrix(CAM_XYZ, WB, "ACEScg")
    v = np.array([0.2, 0.5, 0.1])
    expected = colour.RGB_to_RGB(
        m_srgb @ v,
        colour.RGB_COLOURSPACES["sRGB"],
        colour.RGB_COLOURSPACES["ACEScg"],
        chromatic_adaptation_transform="Bradford",
    )
    np.testing.assert_allclose(m_aces @ v, expected, rtol=1e-6)
    grey = m_aces @ np.array([1 / 2.1, 1.0, 1 / 1.5])
    np.testing.assert_allclose(grey, grey[1], rtol=1e-3)


def test_image_conversion_and_clipped_pixels_become_neutral():
    rad = np.zeros((4, 5, 3), np.float32)
    rad[...] = (0.3, 0.6, 0.2)
    rad[0, 0] = (1.0, 0.4, 0.9)  # a clipped highlight: green clipped first -> would be magenta
    clipped = np.zeros((4, 5), bool)
    clipped[0, 0] = True
    out = camera_to_working(rad, CAM_XYZ, WB, clipped=clipped)
    m = camera_to_working_matrix(CAM_XYZ, WB)
    np.testing.assert_allclose(out[1, 1], m @ rad[1, 1], rtol=1e-5)
    np.testing.assert_allclose(out[0, 0], out[0, 0, 1], rtol=1e-5)
    assert out.dtype == np.float32


def test_bad_camera_data_is_refused():
    with pytest.raises(ParameterError, match="rgb_xyz_matrix"):
        camera_to_working_matrix(np.zeros((2, 3)) + 1)
    with pytest.raises(ParameterError, match="multipliers must be positive"):
        camera_to_working_matrix(CAM_XYZ, (1.0, -1.0, 1.0))
    with pytest.raises(ParameterError, match="unknown working space method 'XYZ'"):
        camera_to_working_matrix(working_space="XYZ")
    with pytest.raises(ParameterError, match=r"radiance must be \(H, W, 3\)"):
        camera_to_working(np.zeros((4, 4)))


def test_fused_conversion_matches_numpy_and_works_in_place():
    rng = np.random.default_rng(0)
    rad = rng.random((16, 24, 3)).astype(np.float32) * 4
    clipped = rng.random((16, 24)) < 0.1
    m = camera_to_working_matrix(CAM_XYZ, WB)
    expected = np.einsum("ij,hwj->hwi", m, rad.astype(np.float64))
    out = camera_to_working(rad, CAM_XYZ, WB, clipped=clipped)
    np.testing.assert_allclose(out[~clipped], expected[~clipped], rtol=1e-5, atol=1e-6)
    assert np.allclose(out[clipped], out[clipped][:, 1:2], rtol=1e-5)  # neutral
    inplace = rad.copy()
    res = camera_to_working(inplace, CAM_XYZ, WB, clipped=clipped, out=inplace, workers=2)
    assert res is inplace
    np.testing.assert_allclose(inplace, out, rtol=1e-6)
    with pytest.raises(ParameterError, match="out must be a C-contiguous float32"):
        camera_to_working(rad, CAM_XYZ, WB, out=np.empty((2, 2, 3), np.float32))


def test_numpy_fallback_in_place(monkeypatch):
    import hdrcore.merge.colour as colour_module

    rng = np.random.default_rng(1)
    rad = rng.random((8, 12, 3)).astype(np.float32)
    clipped = rng.random((8, 12)) < 0.2
    fused = camera_to_working(rad, CAM_XYZ, WB, clipped=clipped)
    monkeypatch.setattr(colour_module, "AVAILABLE", False)
    inplace = rad.copy()
    camera_to_working(inplace, CAM_XYZ, WB, clipped=clipped, out=inplace)
    np.testing.assert_allclose(inplace, fused, rtol=1e-5, atol=1e-7)


def test_srgb_matrix_copy_matches_colour_science():
    import hdrcore.merge.colour as colour_module

    np.testing.assert_array_equal(
        colour_module._SRGB_TO_XYZ,
        np.asarray(colour.RGB_COLOURSPACES["sRGB"].matrix_RGB_to_XYZ, dtype=np.float64),
    )


@pytest.mark.parametrize("case", ["raw", "raw-warped", "lut", "float"])
def test_merge_applies_colour_as_camera_to_working(case):
    """merge(..., colour=) gives bit for bit what camera_to_working gives on its result, the
    pixels clipped in every frame made neutral, on every path of the kernel (it converts each
    block inside its finishing pass)."""
    from hdrcore.merge import apply_colour, colour_conversion, merge

    rng = np.random.default_rng(5)
    base = rng.random((24, 40, 3)) * np.array([1.0, 0.6, 0.8])
    base[:4, :6] = 40.0  # clipped in every frame
    times = (1.0, 4.0, 16.0)
    kw: dict = {}
    if case == "lut":
        frames = [
            np.clip(np.rint(255 * np.clip(base * t / 16, 0, 1) ** (1 / 2.2)), 0, 255).astype(
                np.uint8
            )
            for t in times
        ]
        kw["response"] = np.tile(np.linspace(0, 1, 256) ** 2.2, (3, 1))
    elif case == "float":
        frames = [np.clip(base * t / 16, 0, 1).astype(np.float32) for t in times]
    else:
        frames = [np.clip(np.rint(4095 * base * t / 16), 0, 4095).astype(np.uint16) for t in times]
        kw["max_level"] = 4095
    if case == "raw-warped":
        kw["transforms"] = [np.array([[1.0, 0.01, 0.4], [-0.01, 1.0, -0.3]]), None, None]
    conv = colour_conversion(CAM_XYZ, WB, "sRGB")
    plain = merge(frames, times, **kw)
    assert plain.clipped.any()
    fused = merge(frames, times, colour=conv, **kw)
    expected = apply_colour(plain.radiance, conv, clipped=plain.clipped)
    np.testing.assert_array_equal(fused.radiance, expected)
    np.testing.assert_array_equal(fused.clipped, plain.clipped)
    # a clipped pixel is neutral: equal white-balanced camera values
    y, x = np.argwhere(plain.clipped)[0]
    v = (plain.radiance[y, x] * conv.white_balance).max()
    np.testing.assert_allclose(fused.radiance[y, x], v * conv.neutral, rtol=1e-6)
