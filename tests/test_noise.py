"""The noise floor measured from the noise (hdrcore.noise): robust sigma, the dark-region
estimate on synthetic planes and simulated DNG brackets, the optical black of real Canon CRWs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hdrcore.io import load_bracket
from hdrcore.noise import (
    K_SIGMA,
    NONLINEAR_MIN_FLOOR_FRACTION,
    RAW_MIN_FLOOR,
    FrameNoise,
    bracket_noise,
    frame_noise,
    robust_sigma,
)
from hdrcore.pipeline import Pipeline
from hdrcore.synthetic import faults


def test_robust_sigma_of_integer_gaussian_noise_with_outliers():
    rng = np.random.default_rng(1)
    for sigma in (0.7, 1.0, 2.5, 10.0):
        v = np.round(rng.normal(0, sigma, 200_000))
        v[:2000] = 500.0  # edges and texture
        est = robust_sigma(v)
        # Rounding adds 1/12 level^2 (quantisation is noise too).
        assert est == pytest.approx(math.sqrt(sigma**2 + 1 / 12), rel=0.03)


@pytest.mark.parametrize("sigma", [0.8, 2.0, 6.0])
def test_dark_region_estimate_ignores_gradients_and_bright_texture(sigma):
    rng = np.random.default_rng(2)
    h, w = 600, 800
    y, x = np.mgrid[0:h, 0:w]
    scene = 256 + 0.05 * x + 0.02 * y  # a dark ramp above black 256 ...
    scene[:, 600:] += 2000 * (1 + np.sin(x[:, 600:] / 3.0))  # ... and bright texture
    plane = np.round(scene + rng.normal(0, sigma, scene.shape))
    fn = frame_noise(plane, black=256.0, white=4095.0)
    assert fn.source == "dark-regions"
    assert fn.sigma == pytest.approx(math.sqrt(sigma**2 + 1 / 12), rel=0.06)
    assert fn.level < 100  # measured in the dark part


def test_clipped_samples_are_left_out():
    """A non-linear frame clips at 0: samples touching 0 would shrink the estimate."""
    rng = np.random.default_rng(3)
    plane = np.clip(np.round(rng.normal(1.0, 1.5, (400, 600))), 0, 255)
    plane[:, 300:] = np.clip(np.round(40 + rng.normal(0, 1.5, (400, 300))), 0, 255)
    fn = frame_noise(plane, black=0.0, white=255.0, clipped_low=0.0)
    assert fn.sigma > 1.2  # not the ~0.7 of the clipped half


def test_bracket_floor_rules():
    frames = (
        FrameNoise(1.0, "dark-regions", 5000, 3.0),
        FrameNoise(4.0, "dark-regions", 5000, 300.0),
    )
    raw = bracket_noise(frames, max_level=4095, linear=True)
    assert raw.sigma == 1.0  # the estimate made nearest black
    assert raw.floor == pytest.approx(max(K_SIGMA * 1.0, RAW_MIN_FLOOR))
    ob = bracket_noise(frames + (FrameNoise(0.5, "optical-black"),), max_level=4095, linear=True)
    assert ob.source == "optical-black" and ob.sigma == 0.5 and ob.floor == RAW_MIN_FLOOR
    jpeg = bracket_noise((FrameNoise(0.2, "dark-regions", 5000, 2.0),), max_level=255, linear=False)
    assert jpeg.floor == pytest.approx(NONLINEAR_MIN_FLOOR_FRACTION * 255)
    none = bracket_noise((FrameNoise(float("nan"), "none"),), max_level=4095, linear=True)
    assert none.floor == RAW_MIN_FLOOR and none.source == "none"


@pytest.mark.parametrize("margins", [None, 16], ids=["dark-regions", "optical-black"])
def test_pipeline_measures_the_simulated_read_noise(tmp_path, margins):
    spec = faults.DARK_RAW_12BIT.replace(shape=(128, 192), noise_sigma=3.0, margins=margins)
    fb = faults.write_dark_raw_bracket(tmp_path / "raw", spec=spec)
    pipe = Pipeline(load_bracket([fb.directory]))
    noise = pipe.noise()
    assert noise.source == ("optical-black" if margins else "dark-regions")
    assert noise.sigma == pytest.approx(3.0, rel=0.12)
    assert pipe.auto_noise_floor() == pytest.approx(K_SIGMA * noise.sigma, rel=1e-6)
    assert pipe.auto_noise_floor() < 0.01 * 4095  # the old default was 2 % (82 levels)


@pytest.mark.shared
def test_real_canon_crw_optical_black(crw_dir):
    """Two real Canon CRW files (10 bits, black 32, ISO 50): the masked margins give the read
    noise, about 0.65-0.8 levels (measured: S40 0.646, G2 0.731 without quantisation)."""
    b = load_bracket(sorted(crw_dir.glob("*.CRW")))
    noise = Pipeline(b).noise()
    assert noise.source == "optical-black"
    assert all(0.5 < f.sigma < 0.9 for f in noise.frames)
    assert noise.floor == pytest.approx(max(K_SIGMA * noise.sigma, RAW_MIN_FLOOR))
