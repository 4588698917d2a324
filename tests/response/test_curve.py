"""The response object: normalisation, evaluate/invert, LUT, apply, JSON, plot, special curves."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from PIL import Image

from hdrcore.errors import InputError, OutputError, ParameterError
from hdrcore.response import (
    ResponseCurve,
    linear_response,
    normalise_curve,
    plot_curves,
    resolve_response,
    srgb_response,
)


def _gamma_curve(max_level: int = 255, channels: int = 3) -> ResponseCurve:
    g = np.tile((np.arange(max_level + 1) / max_level) ** 2.2, (channels, 1))
    return ResponseCurve(g=g, method="test", exposure_ratios=(4.0, 4.0))


@settings(max_examples=60, deadline=None)
@given(
    arrays(
        np.float64, st.tuples(st.integers(1, 3), st.integers(2, 300)), elements=st.floats(-1e3, 1e3)
    )
)
def test_normalise_gives_monotone_unit_curves(raw: np.ndarray) -> None:
    # a channel that never rises above its first value cannot be normalised: refused
    flat = np.max(raw, axis=1) <= raw[:, 0]
    if np.any(flat):
        with pytest.raises(ParameterError, match="increase"):
            normalise_curve(raw)
        return
    g = normalise_curve(raw)
    assert g.shape == raw.shape
    assert np.all(np.diff(g, axis=1) >= 0)
    assert np.allclose(g[:, 0], 0) and np.allclose(g[:, -1], 1)
    ResponseCurve(g=g, method="x")  # accepted by the object


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.floats(0.3, 4.0), st.lists(st.floats(0, 255), min_size=1, max_size=20))
def test_invert_is_inverse_of_evaluate(gamma: float, levels: list[float]) -> None:
    g = (np.arange(256) / 255.0) ** gamma
    curve = ResponseCurve(g=np.tile(g, (3, 1)), method="x")
    z = np.array(levels)
    for c in range(3):
        back = curve.invert(curve.evaluate(z, channel=c), channel=c)
        np.testing.assert_allclose(back, z, atol=1e-6)


def test_object_rejects_bad_tables() -> None:
    with pytest.raises(ParameterError, match="non-decreasing"):
        ResponseCurve(g=np.array([[0.0, 0.6, 0.5, 1.0]]), method="x")
    with pytest.raises(ParameterError, match="normalised"):
        ResponseCurve(g=np.array([[0.0, 0.5, 0.9]]), method="x")
    with pytest.raises(ParameterError, match="finite"):
        ResponseCurve(g=np.array([[0.0, np.nan, 1.0]]), method="x")


def test_lut_and_apply() -> None:
    curve = _gamma_curve()
    lut = curve.to_lut()
    assert lut.shape == (3, 256) and lut.dtype == np.float64
    lut12 = curve.to_lut(4095)
    assert lut12.shape == (3, 4096)
    np.testing.assert_allclose(lut12[:, ::4095], [[0, 1]] * 3)
    frame = np.array([[[0, 128, 255]]], np.uint16)
    out = curve.apply(frame)
    assert out.dtype == np.float32 and out.shape == (1, 1, 3)
    np.testing.assert_allclose(out[0, 0], [0, (128 / 255) ** 2.2, 1], rtol=1e-6)
    with pytest.raises(ParameterError, match="integer"):
        curve.apply(frame.astype(np.float32))
    with pytest.raises(ParameterError, match="channel"):
        curve.apply(np.zeros((2, 2, 4), np.uint8))


def test_json_round_trip_and_atomic_save(tmp_path) -> None:
    curve = _gamma_curve()
    p = curve.save(tmp_path / "c.json")
    back = ResponseCurve.load(p)
    np.testing.assert_array_equal(back.g, curve.g)
    assert back.exposure_ratios == curve.exposure_ratios and back.method == "test"
    d = json.loads(p.read_text())
    assert set(d) >= {"method", "channels", "exposure_ratios"}
    assert len(d["channels"][0]["levels"]) == len(d["channels"][0]["g"]) == 256
    with pytest.raises(OutputError, match="exists"):
        curve.save(p)
    curve.save(p, force=True)
    bad = tmp_path / "bad.json"
    bad.write_text('{"channels": 3}')
    with pytest.raises(InputError, match="not a response curve"):
        ResponseCurve.load(bad)
    with pytest.raises(InputError, match="not found"):
        ResponseCurve.load(tmp_path / "missing.json")


def test_plot_png(tmp_path) -> None:
    curve = _gamma_curve()
    p = curve.plot(tmp_path / "one.png")
    assert Image.open(p).size[0] > 100
    p2 = plot_curves([(curve, "a"), (srgb_response(), "srgb")], tmp_path / "two.png")
    assert Image.open(p2).mode == "RGB"
    with pytest.raises(OutputError, match="exists"):
        curve.plot(p)


def test_special_responses_and_resolve(tmp_path) -> None:
    lin = linear_response(255)
    np.testing.assert_allclose(lin.g[0], np.arange(256) / 255)
    s = srgb_response(255)
    assert s.is_monotone and s.g[0, 128] == pytest.approx(0.2158605, abs=1e-6)
    assert resolve_response("sRGB", max_level=255).method == "srgb"
    assert resolve_response("linear", max_level=4095, n_channels=1).g.shape == (1, 4096)
    p = _gamma_curve().save(tmp_path / "saved.json")
    assert resolve_response(str(p)).method == "test"
    with pytest.raises(ParameterError, match="'linear', 'srgb', 'debevec1997'"):
        resolve_response("cubic")
    with pytest.raises(ParameterError, match="max_level"):
        resolve_response("srgb")
    with pytest.raises(ParameterError, match="needs the frames"):
        resolve_response("debevec1997")
