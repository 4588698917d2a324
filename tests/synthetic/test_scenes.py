"""Procedural scenes: deterministic, positive, textured, several decades of dynamic range."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.errors import ParameterError
from hdrcore.synthetic import SCENES, fractal_noise, make_scene

SHAPE = (96, 144)


@pytest.mark.parametrize("name", sorted(SCENES))
def test_scene_is_positive_float_rgb_with_median_one(name: str) -> None:
    e = make_scene(name, SHAPE, seed=3)
    assert e.shape == (*SHAPE, 3)
    assert e.dtype == np.float32
    assert np.all(np.isfinite(e)) and np.all(e > 0)
    assert np.median(e) == pytest.approx(1.0, rel=1e-5)


@pytest.mark.parametrize("name", sorted(SCENES))
def test_scene_spans_at_least_four_decades(name: str) -> None:
    # The module promises "a dynamic range of at least four decades" (robust percentiles).
    # Robust: between the 0.1 and 99.9 percentiles, not just two extreme pixels.
    lum = make_scene(name, (128, 192), seed=0).mean(axis=2)
    lo, hi = np.percentile(lum, [0.1, 99.9])
    assert np.log10(hi / lo) >= 4.0


@pytest.mark.parametrize("name", sorted(SCENES))
def test_scene_is_textured_in_the_dark(name: str) -> None:
    # Registration and histogram methods need structure in the dark range too.
    lum = np.log(make_scene(name, SHAPE, seed=1).mean(axis=2))
    dark = lum < np.percentile(lum, 25)
    grad = np.abs(np.diff(lum, axis=1))[dark[:, 1:]]
    assert np.mean(grad > 1e-3) > 0.5


def test_same_seed_same_scene_other_seed_other_scene() -> None:
    a = make_scene("window", SHAPE, seed=5)
    b = make_scene("window", SHAPE, seed=5)
    c = make_scene("window", SHAPE, seed=6)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_scene_name_is_case_insensitive() -> None:
    np.testing.assert_array_equal(make_scene("Window", SHAPE), make_scene("window", SHAPE))


def test_unknown_scene_lists_valid_names() -> None:
    with pytest.raises(ParameterError, match=r"unknown scene method 'moon'.*'window'"):
        make_scene("moon", SHAPE)


def test_scene_too_small() -> None:
    with pytest.raises(ParameterError, match=r"scene too small.*at least 16x16.*8x64"):
        make_scene("window", (8, 64))


def test_fractal_noise_is_standardised() -> None:
    n = fractal_noise((64, 80), np.random.default_rng(0))
    assert n.shape == (64, 80) and n.dtype == np.float32
    assert abs(float(n.mean())) < 1e-5
    assert float(n.std()) == pytest.approx(1.0, rel=1e-4)
