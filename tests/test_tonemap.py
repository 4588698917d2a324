"""Tonemapped previews: 8-bit output, monotone operators, colour-science's sRGB encoding."""

from __future__ import annotations

import colour
import numpy as np
import pytest

from hdrcore import tonemap_spec as spec
from hdrcore.errors import ParameterError
from hdrcore.tonemap import TONEMAP_OPERATORS, srgb_encode_8bit, tonemap


def _ramp() -> np.ndarray:
    v = np.logspace(-4, 4, 400, dtype=np.float32)
    return np.stack([v, v * 0.8, v * 0.5], axis=-1)[None]  # (1, 400, 3), increasing


@pytest.mark.parametrize("method", list(TONEMAP_OPERATORS))
def test_output_is_uint8_in_range_and_monotone(method):
    res = tonemap(_ramp(), method)
    assert res.image.dtype == np.uint8 and res.image.shape == (1, 400, 3)
    for c in range(3):
        assert np.all(np.diff(res.image[0, :, c].astype(int)) >= 0)
    assert res.image.min() == 0 or method != "linear"
    assert res.image.max() > 200


def test_reinhard_keeps_hue_and_maps_white_point():
    res = tonemap(np.full((2, 2, 3), 4.0, np.float32), "reinhard", auto_exposure=False, white=4.0)
    assert (res.image == 255).all()
    img = tonemap(_ramp(), "reinhard").image[0].astype(int)
    mid = img[200]
    assert mid[0] >= mid[1] >= mid[2]


def test_exposure_brightens_and_log_average_goes_to_key():
    rad = np.full((4, 4, 3), 3.0, np.float32)
    a = tonemap(rad, "linear")
    b = tonemap(rad, "linear", exposure=1.0)
    assert a.log_average == pytest.approx(3.0, rel=1e-4)
    assert a.scale == pytest.approx(0.18 / 3.0, rel=1e-4)
    assert int(b.image[0, 0, 0]) > int(a.image[0, 0, 0])
    expected = np.rint(255 * colour.cctf_encoding(0.18, function="sRGB"))
    assert abs(int(a.image[0, 0, 0]) - expected) <= 1


def test_srgb_encoding_matches_colour_science():
    x = np.linspace(0, 1, 1001, dtype=np.float32)
    ref = np.rint(255 * colour.cctf_encoding(x.astype(np.float64), function="sRGB"))
    assert np.max(np.abs(srgb_encode_8bit(x).astype(int) - ref)) <= 1


def test_non_finite_values_are_black_and_grey_images_accepted():
    rad = np.ones((3, 3), np.float32)
    rad[0, 0] = np.nan
    res = tonemap(rad, "reinhard-rgb", auto_exposure=False)
    assert res.image.shape == (3, 3, 3)
    assert (res.image[0, 0] == 0).all()


def test_bad_input_is_refused():
    with pytest.raises(ParameterError, match="unknown tonemap method 'drago'"):
        tonemap(np.ones((2, 2, 3)), "drago")
    with pytest.raises(ParameterError, match=r"radiance must be \(H, W, 3\)"):
        tonemap(np.ones((2, 2, 4)))
    with pytest.raises(ParameterError, match="key must be positive"):
        tonemap(np.ones((2, 2, 3)), key=0)


@pytest.mark.parametrize("method", ["linear", "reinhard", "reinhard-rgb"])
@pytest.mark.parametrize("white", [None, 4.0])
def test_fused_tonemap_matches_the_spec_to_the_bit(method, white):
    """The compiled pass against the operator functions on chunks (``tonemap_spec``)."""
    rng = np.random.default_rng(0)
    rad = np.exp(rng.normal(0.0, 2.0, (64, 96, 3))).astype(np.float32)
    rad[0, 0] = (np.nan, np.inf, -1.0)
    fused = tonemap(rad, method, white=white, exposure=0.5, workers=2)
    np.testing.assert_array_equal(fused.image, spec.global_8bit(rad, method, fused.scale, white))
    grey = tonemap(rad[..., 1], method, white=white)
    np.testing.assert_array_equal(
        grey.image, spec.global_8bit(rad[..., 1], method, grey.scale, white)
    )
    with pytest.warns(DeprecationWarning, match="engine='numpy'"):
        alias = tonemap(rad, method, white=white, exposure=0.5, engine="numpy")
    np.testing.assert_array_equal(alias.image, fused.image)
    with pytest.raises(ParameterError, match="tonemap engine"):
        tonemap(rad, method, engine="gpu")


def test_an_added_operator_runs_on_chunks(monkeypatch):
    """Operators added to TONEMAP_OPERATORS (no compiled form) run on chunks of pixels."""
    calls = []

    def half(x, *, white=None):
        calls.append(x.shape)
        x *= np.float32(0.5)
        np.clip(x, 0.0, 1.0, out=x)
        return x

    monkeypatch.setitem(TONEMAP_OPERATORS, "half", half)
    rad = np.full((4, 5, 3), 1.0, np.float32)
    res = tonemap(rad, "half", auto_exposure=False, chunk_pixels=8)
    assert res.method == "half" and [c[0] for c in calls] == [8, 8, 4]
    assert (res.image == srgb_encode_8bit(np.full(1, 0.5, np.float32))[0]).all()
