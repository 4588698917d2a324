"""Weighting functions, the ghost statistic and the fast float16 rounding."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.errors import ParameterError
from hdrcore.merge import WEIGHTS, NoiseModel, ghost_score_from_moments, weights
from hdrcore.merge.maps import provenance_summary, to_float16_nonnegative


def test_hat_is_debevecs_triangle():
    z = np.linspace(0, 1, 11, dtype=np.float32)
    w = weights(z, z, 1.0, np.ones_like(z), "hat")
    np.testing.assert_allclose(w, 1 - np.abs(2 * z - 1), atol=1e-7)
    assert w[5] == 1 and w[0] == 0 and w[-1] == 0


def test_noise_aware_weight_grows_with_exposure_time():
    x = np.full(4, 0.3, np.float32)
    var = np.full(4, 1e-4, np.float32)
    short = weights(x, x, 1.0, var, "noise-aware")
    long = weights(x, x, 4.0, var, "noise-aware")
    np.testing.assert_allclose(long / short, 16.0)


def test_registry_and_dispatcher():
    assert set(WEIGHTS) == {"hat", "gaussian", "noise-aware", "uniform", "hat-noise-aware"}
    z = np.array([0.5], np.float32)
    assert weights(z, z, 1.0, z, "Gaussian")[0] == pytest.approx(1.0)
    # the triangle times dt^2 / var: level 0.25 -> 0.5; dt = 2, var = 0.5 -> x 8
    q = np.array([0.25], np.float32)
    v = np.array([0.5], np.float32)
    assert weights(q, q, 2.0, v, "hat-noise-aware")[0] == pytest.approx(4.0)
    assert weights(q, q, 2.0, v, "hat-noise-aware")[0] == pytest.approx(
        weights(q, q, 2.0, v, "hat")[0] * weights(q, q, 2.0, v, "noise-aware")[0]
    )
    with pytest.raises(ParameterError, match="unknown weighting method 'box'"):
        weights(z, z, 1.0, z, "box")
    with pytest.raises(ParameterError, match="exposure time must be positive"):
        weights(z, z, 0.0, z, "hat")


def test_noise_model_is_validated():
    with pytest.raises(ParameterError, match="read noise"):
        NoiseModel(read_noise=-1)
    with pytest.raises(ParameterError, match="full well"):
        NoiseModel(full_well=0)
    assert NoiseModel(full_well=1000).shot_gain == pytest.approx(1e-3)


def test_ghost_score_is_zero_for_agreeing_frames_and_large_for_disagreeing_ones():
    w = np.array([[2.0, 2.0, 2.0], [2.0, 2.0, 2.0], [1.0, 1.0, 1.0]], np.float32)
    e_agree = np.full((3, 3), 0.5, np.float32)
    # moments of two frames with E = 0.5 and 0.5 (agree), 0.5 and 1.5 (disagree), one frame
    we = np.array([[1.0] * 3, [2.0] * 3, [0.5] * 3], np.float32)
    wee = np.array([[0.5] * 3, [(0.25 + 2.25)] * 3, [0.25] * 3], np.float32)
    wv = np.full((3, 3), 2e-4, np.float32)
    score = ghost_score_from_moments(w, we, wee, wv, model_error=0.0)
    assert score[0] == pytest.approx(0.0, abs=1e-3)
    assert score[1] > 100
    assert score[2] == pytest.approx(0.0, abs=1e-3)
    assert e_agree.shape == (3, 3)


def test_float16_rounding_matches_numpy():
    rng = np.random.default_rng(0)
    x = np.concatenate(
        [rng.random(10000), np.exp(rng.uniform(-9, 11, 10000)), [0.0, 1.0, 65504.0, 1e6]]
    ).astype(np.float32)
    got = to_float16_nonnegative(x.copy()).astype(np.float64)
    ref = np.minimum(x, 65504).astype(np.float16).astype(np.float64)
    np.testing.assert_allclose(got, ref, rtol=2.0**-10)
    np.testing.assert_allclose(got, np.minimum(x, 65504), rtol=2.0**-11)


def test_provenance_summary():
    shares = np.zeros((2, 2, 2), np.float16)
    shares[0, 0] = 1
    shares[1, 1] = 1
    s = provenance_summary(shares)
    assert s["mean_share"] == [0.5, 0.5]
    assert s["dominant_fraction"] == [0.5, 0.5]
