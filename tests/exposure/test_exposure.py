"""Exposure ratios from histograms (Cerman & Hlavac 2006, section 5) against synthetic truth."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrcore.errors import ParameterError
from hdrcore.exposure import (
    EXPOSURE_METHODS,
    ExposureRatioResult,
    bracket_exposures,
    bracket_exposures_from_histograms,
    bracket_histograms,
    exposure_ratio,
    exposure_ratio_frames,
    srgb_lut,
)
from hdrcore.histogram import histograms
from hdrcore.synthetic import simulate_bracket

SEED_TIMES = (1.0, 4.0, 16.0, 64.0, 256.0, 1024.0)


@pytest.fixture(scope="module")
def seed_bracket():
    # The seed's protocol (section 5.3): six frames, times 1..1024 (x4), linear, 256 levels,
    # Gaussian noise of 1 level. The paper reports 4.0178 for the darkest pair (0.45 % off).
    return simulate_bracket(
        scene="window", shape=(192, 288), exposure_times=SEED_TIMES, bits=8, noise_sigma=1.0, seed=1
    )


def test_seed_protocol_darkest_pair(seed_bracket) -> None:
    r = exposure_ratio_frames(seed_bracket.frames[0], seed_bracket.frames[1], 255)
    assert r.ok, r.message
    assert abs(r.ratio / 4.0 - 1) < 0.0045  # at least as good as the paper's 4.0178
    paper = exposure_ratio_frames(
        seed_bracket.frames[0], seed_bracket.frames[1], 255, method="Cerman 2006"
    )
    assert abs(paper.ratio / 4.0 - 1) < 0.0045
    assert paper.method == "Cerman 2006"
    # Diagnostics the inspector draws.
    assert r.iterates[0] == r.initial_ratio and r.iterates[-1] == pytest.approx(r.ratio)
    assert r.inlier_mask.shape == r.residuals.shape == r.equations.x.shape
    assert set(np.unique(r.equations.direction)) == {0, 1}
    assert len(r.channel_ratios) == 3 and not r.channels_disagree
    assert len(r.btfs) == 3


@pytest.mark.parametrize("bits,tol", [(8, 0.003), (12, 0.0005), (14, 0.0005)])
def test_synthetic_truth_tripod(bits: int, tol: float) -> None:
    b = simulate_bracket(
        scene="patches",
        shape=(128, 192),
        exposure_times=(1.0, 4.0, 16.0),
        bits=bits,
        noise_sigma=1.0,
        seed=2,
    )
    res = bracket_exposures(b.frames, b.max_level, exposure_times=b.exposure_times)
    assert res.ok, res.message
    np.testing.assert_allclose(res.relative_exposures, [1, 4, 16], rtol=2 * tol)
    for p in res.pairs:
        assert abs(p.ratio / 4 - 1) < tol
    assert all(abs(m) < 0.01 for m in res.mismatch_stops)


def test_hand_held_pairs_are_accurate_or_flagged() -> None:
    b = simulate_bracket(
        scene="night",
        shape=(192, 288),
        exposure_times=(1.0, 4.0, 16.0, 64.0),
        bits=12,
        noise_sigma=1.0,
        max_shift=4,
        max_rotation_deg=0.2,
        seed=3,
    )
    res = bracket_exposures(b.frames, b.max_level)
    for p in res.pairs:
        assert np.isfinite(p.ratio)
        assert p.ok or p.status in ("uncertain", "inconsistent", "channels-disagree", "unstable")
        if abs(p.ratio / 4 - 1) > 0.01:
            assert not p.ok


def test_identical_frames_give_one() -> None:
    b = simulate_bracket(scene="landscape", shape=(64, 96), exposure_times=(4.0,), bits=8, seed=4)
    for method in EXPOSURE_METHODS:
        r = exposure_ratio_frames(b.frames[0], b.frames[0], 255, method=method)
        assert r.ratio == pytest.approx(1.0, abs=1e-9)


def test_no_overlap_is_not_ok_with_message() -> None:
    b = simulate_bracket(
        scene="window", shape=(64, 96), exposure_times=(1.0, 5000.0), bits=8, seed=5
    )
    r = exposure_ratio_frames(b.frames[0], b.frames[1], 255)
    assert not r.ok
    assert r.status == "no-overlap"
    assert "do not overlap enough" in r.message
    assert np.isnan(r.ratio)


def test_all_saturated_or_black_frame_gives_no_signal() -> None:
    # A black or saturated frame is a status of its pair (issue 12), not an exception.
    good = simulate_bracket(shape=(32, 48), exposure_times=(1.0,), seed=6).frames[0]
    white = np.full_like(good, 255)
    black = np.zeros_like(good)
    r = exposure_ratio(histograms(good, 255), histograms(white, 255), dark=2, bright=3)
    assert r.status == "no-signal" and not r.ok and np.isnan(r.ratio)
    assert "frames 2 and 3" in r.message
    assert "brighter frame is entirely saturated" in r.message
    assert "expected pixels between noise floor 5.1 and saturation 247.35, found none" in r.message
    r = exposure_ratio_frames(black, good, 255)
    assert r.status == "no-signal" and "darker frame is entirely black" in r.message
    assert r.to_json()["ci95_low"] is None


def test_bad_parameters() -> None:
    h = np.ones((3, 256), np.int64)
    with pytest.raises(ParameterError, match="unknown exposure method"):
        exposure_ratio(h, h, method="nope")
    with pytest.raises(ParameterError, match="noise floor < saturation"):
        exposure_ratio(h, h, saturation=10, noise_floor=20)
    with pytest.raises(ParameterError, match="same shape"):
        exposure_ratio(h, np.ones((3, 128), np.int64))
    with pytest.raises(ParameterError, match="linearisation table"):
        exposure_ratio(h, h, lut=np.linspace(0, 1, 100))


def test_refit_from_cached_histograms() -> None:
    b = simulate_bracket(shape=(96, 144), exposure_times=(1.0, 4.0, 16.0), bits=12, seed=7)
    hists = bracket_histograms(b.frames, b.max_level)
    a = bracket_exposures_from_histograms(hists, saturation=3800, noise_floor=60)
    c = bracket_exposures_from_histograms(hists, saturation=3500, noise_floor=120)
    assert a.saturation == 3800 and c.noise_floor == 120
    for r in (a, c):
        np.testing.assert_allclose(r.ratios, [4, 4], rtol=2e-3)


def test_srgb_linearisation() -> None:
    b = simulate_bracket(
        shape=(128, 192),
        exposure_times=(1.0, 2.0),
        bits=8,
        response="srgb",
        noise_sigma=0.5,
        seed=8,
    )
    h = [histograms(f, 255) for f in b.frames]
    r = exposure_ratio(h[0], h[1], lut=srgb_lut(255))
    assert abs(r.ratio / 2 - 1) < 0.01
    raw = exposure_ratio(h[0], h[1])  # treated as linear: clearly wrong
    assert abs(raw.ratio / 2 - 1) > 0.05


def test_channel_disagreement_flagged() -> None:
    b = simulate_bracket(shape=(128, 192), exposure_times=(1.0, 4.0), bits=12, seed=9)
    bright = b.frames[1].astype(np.int64)
    bright[..., 2] = np.clip(np.rint(bright[..., 2] * 1.05), 0, 4095)  # a colour cast
    r = exposure_ratio_frames(b.frames[0], bright.astype(np.uint16), 4095)
    assert r.channels_disagree
    assert r.status == "channels-disagree"


@settings(max_examples=15, deadline=None)
@given(scale=st.integers(1, 50), ratio=st.sampled_from([2.0, 3.0, 4.0, 8.0]))
def test_scale_invariance(scale: int, ratio: float) -> None:
    # Multiplying every count by a constant (a bigger picture of the same scene) changes nothing.
    rng = np.random.default_rng(0)
    x = np.exp(rng.normal(np.log(0.05), 1.0, 20000))
    dark = np.clip(np.rint(x * 4095), 0, 4095).astype(np.int64)
    bright = np.clip(np.rint(x * ratio * 4095), 0, 4095).astype(np.int64)
    hd = np.bincount(dark, minlength=4096)
    hb = np.bincount(bright, minlength=4096)
    a = exposure_ratio(hd, hb)
    b = exposure_ratio(hd * scale, hb * scale)
    assert a.ratio == pytest.approx(b.ratio, rel=1e-9)
    assert abs(a.ratio / ratio - 1) < 2e-3


def _pair_histograms(seed: int, bits: int, ratio: float) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    top = (1 << bits) - 1
    x = np.exp(rng.normal(np.log(rng.uniform(0.02, 0.2)), rng.uniform(0.5, 1.5), 50_000))
    dark = np.clip(np.rint(x * top + rng.normal(0, 1, x.size)), 0, top).astype(np.int64)
    bright = np.clip(np.rint(x * ratio * top + rng.normal(0, 1, x.size)), 0, top).astype(np.int64)
    return np.bincount(dark, minlength=top + 1), np.bincount(bright, minlength=top + 1)


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    bits=st.sampled_from([8, 12]),
    ratio=st.floats(1.3, 8.0),
)
def test_swapping_a_pair_inverts_the_ratio(seed: int, bits: int, ratio: float) -> None:
    """Issue 17's property: the pair given the other way round gives the inverse ratio within
    what each estimate claims, unless an estimate says it is not sure: a swapped 8-bit pair 7.7x
    apart once measured 1/4.02 'uncertain' against 7.71 'ok' (a test below); never two 'ok' of
    which one lies outside the other's 95 % interval. The fit regresses bright on dark values, so
    the two directions differ slightly: over 597 random 8- and 12-bit pairs both 'ok' the gap was
    at most 0.044 % and at most 0.28 of the narrower interval's half-width; the search once found
    0.10 %, 0.51 of it (seed 34, the regression test below)."""
    hd, hb = _pair_histograms(seed, bits, ratio)
    a, b = exposure_ratio(hd, hb), exposure_ratio(hb, hd)
    if a.status == "ok" and b.status == "ok":
        assert abs(np.log(a.ratio * b.ratio)) < _narrower_half_width(a, b), (
            a.ratio,
            1 / b.ratio,
        )
        assert abs(np.log(a.ratio / ratio)) < 0.02


def _narrower_half_width(*results: ExposureRatioResult) -> float:
    """The smaller half-width, in natural log units, of the results' 95 % intervals."""
    return min(float(np.log(r.interval[1] / r.interval[0])) / 2 for r in results)


def test_a_swapped_pair_within_its_interval_is_not_a_disagreement() -> None:
    # the property's counterexample under its first tolerance (a fixed 0.1 %)
    hd, hb = _pair_histograms(34, 8, 6.138462488345911)
    a, b = exposure_ratio(hd, hb), exposure_ratio(hb, hd)
    assert a.status == b.status == "ok"
    gap = abs(np.log(a.ratio * b.ratio))
    assert 9e-4 < gap < 0.6 * _narrower_half_width(a, b)  # measured 0.10 % against 0.20 %
    assert abs(a.ratio / 6.138462488345911 - 1) < 0.01


def test_a_swapped_pair_that_misses_the_inverse_says_so() -> None:
    # the example the property's search found: ratio and bit depth drawn from the seed first
    rng = np.random.default_rng(10)
    ratio = rng.uniform(1.3, 8.0)
    bits = int(rng.choice([8, 12]))
    top = (1 << bits) - 1
    x = np.exp(rng.normal(np.log(rng.uniform(0.02, 0.2)), rng.uniform(0.5, 1.5), 50_000))
    dark = np.clip(np.rint(x * top + rng.normal(0, 1, x.size)), 0, top).astype(np.int64)
    bright = np.clip(np.rint(x * ratio * top + rng.normal(0, 1, x.size)), 0, top).astype(np.int64)
    hd, hb = np.bincount(dark, minlength=top + 1), np.bincount(bright, minlength=top + 1)
    a, b = exposure_ratio(hd, hb), exposure_ratio(hb, hd)
    assert bits == 8 and abs(ratio - 7.705) < 1e-3
    assert a.status == "ok" and abs(a.ratio / ratio - 1) < 0.01
    assert abs(np.log(a.ratio * b.ratio)) > 0.1  # measured 7.71 against 1 / 4.02
    assert b.status != "ok"
