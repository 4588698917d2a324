"""The calibrated 95 % interval of a pair's ratio and the ok rule (hdrcore.exposure.interval).

Truth from the simulator (known exposure times, hence known ratios); the constants are measured
by bench/bench_coverage.py, these tests check the behaviour they must give.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hdrcore.exposure import bracket_exposures, exposure_ratio_frames, srgb_lut
from hdrcore.exposure.interval import (
    OK_TOLERANCE,
    band_spread,
    brightness_band_ratios,
    ci95_relative,
    interval,
    judge,
)
from hdrcore.exposure.registered import bracket_exposures_from_pixels, exposure_ratio_registered
from hdrcore.exposure.result import ExposureEquations
from hdrcore.synthetic import SCENES, simulate_bracket


def test_interval_contains_the_truth_of_a_simple_pair() -> None:
    b = simulate_bracket(
        scene="window",
        shape=(120, 160),
        exposure_times=(1.0, 4.0),
        bits=12,
        noise_sigma=1.0,
        seed=3,
    )
    r = exposure_ratio_registered(b.frames[0], b.frames[1], b.max_level, np.eye(2, 3))
    lo, hi = r.interval
    assert r.ok, r.message
    assert lo < 4.0 < hi and lo < r.ratio < hi
    assert r.ci95_relative <= OK_TOLERANCE
    assert "95 % interval" in r.message and "registered pixels" in r.message
    d = r.to_json()
    assert d["ci95_low"] == pytest.approx(lo) and d["ci95_high"] == pytest.approx(hi)
    assert d["ci95_relative"] == pytest.approx(r.ci95_relative)
    assert d["ci95_basis"] == "jack-knife"
    # The histogram estimate of a bracket carries the region jack-knife too.
    h = bracket_exposures(b.frames, b.max_level).pairs[0]
    assert h.ci95_basis == "jack-knife" and h.interval[0] < 4.0 < h.interval[1]


def test_wrong_linearisation_is_not_ok() -> None:
    # Linear frames read through the sRGB curve: the ratio is off by tens of per cent, and
    # the ratio changes with brightness, which widens the interval beyond any tolerance.
    b = simulate_bracket(
        scene="window", shape=(120, 160), exposure_times=(1.0, 4.0), bits=8, noise_sigma=1.0, seed=1
    )
    r = exposure_ratio_registered(b.frames[0], b.frames[1], 255, np.eye(2, 3), lut=srgb_lut(255))
    assert abs(r.ratio / 4.0 - 1) > 0.1
    assert not r.ok and r.status == "uncertain"
    assert r.band_spread > 0.01 and "changes with brightness" in r.message
    assert not r.interval[0] <= 4.0 <= r.interval[1] or r.ci95_relative > 0.05


def test_interval_widens_with_noise() -> None:
    halves = []
    for sigma in (0.5, 4.0, 16.0):
        b = simulate_bracket(
            scene="patches",
            shape=(120, 160),
            exposure_times=(1.0, 4.0),
            bits=12,
            noise_sigma=sigma,
            seed=2,
        )
        halves.append(
            exposure_ratio_registered(
                b.frames[0], b.frames[1], b.max_level, np.eye(2, 3)
            ).ci95_relative
        )
    assert halves[0] < halves[1] < halves[2], halves


def test_non_linear_input_has_a_model_error_floor_growing_with_the_stops() -> None:
    b = simulate_bracket(
        scene="window",
        shape=(120, 160),
        exposure_times=(1.0, 2.0, 8.0),
        bits=8,
        response="srgb",
        noise_sigma=1.0,
        seed=4,
    )
    lin = exposure_ratio_frames(b.frames[0], b.frames[1], 255)
    nl1 = exposure_ratio_frames(b.frames[0], b.frames[1], 255, lut=srgb_lut(255))
    nl3 = exposure_ratio_frames(b.frames[0], b.frames[2], 255, lut=srgb_lut(255))
    assert not lin.non_linear and nl1.non_linear
    assert nl1.model_error > lin.model_error
    assert nl3.model_error == pytest.approx(3 * nl1.model_error, rel=0.02)
    assert nl3.to_json()["non_linear"] is True


def test_tolerance_decides_between_ok_and_uncertain() -> None:
    b = simulate_bracket(
        scene="night", shape=(120, 160), exposure_times=(1.0, 4.0), bits=12, noise_sigma=1.0, seed=5
    )
    r = exposure_ratio_registered(b.frames[0], b.frames[1], b.max_level, np.eye(2, 3))
    assert r.ok
    strict = exposure_ratio_registered(
        b.frames[0], b.frames[1], b.max_level, np.eye(2, 3), max_relative_error=r.ci95_relative / 2
    )
    assert strict.status == "uncertain" and "is wider than" in strict.message
    assert judge(strict, tolerance=OK_TOLERANCE).status == "ok"
    assert judge(r) is r  # idempotent: nothing changed


def test_judge_after_the_jackknife_widens_the_interval() -> None:
    b = simulate_bracket(
        scene="window",
        shape=(120, 160),
        exposure_times=(1.0, 4.0),
        bits=12,
        noise_sigma=1.0,
        seed=6,
    )
    r = exposure_ratio_frames(b.frames[0], b.frames[1], b.max_level)
    assert r.ok and r.ci95_basis == "fit"
    wide = replace(r, region_std_error=0.02 * r.ratio)  # as a bracket function adds it
    assert wide.ci95_relative > 0.03 and wide.ci95_basis == "jack-knife"
    judged = judge(wide)
    assert judged.status == "uncertain" and "jack-knife" in judged.message
    # Other statuses are not the interval's to decide.
    assert judge(replace(wide, status="unstable")).status == "unstable"


def test_band_ratios_of_exact_and_brightness_dependent_equations() -> None:
    x = np.geomspace(0.01, 0.2, 64)
    eqs = ExposureEquations(
        x=x,
        y=4 * x,
        weights=np.ones(64),
        direction=np.zeros(64, np.int8),
        channel=np.zeros(64, np.int8),
        level=x * 255,
    )
    exact = brightness_band_ratios(eqs, np.ones(64, bool), ratio_of_sums=False)
    assert len(exact) == 4 and np.allclose(exact, 4.0) and band_spread(exact) < 1e-12
    bent = replace(eqs, y=4 * x**0.95)  # a response off in its exponent
    kb = brightness_band_ratios(bent, np.ones(64, bool), ratio_of_sums=False)
    assert np.all(np.diff(kb) < 0) and band_spread(kb) > 0.02
    assert brightness_band_ratios(eqs, np.zeros(64, bool), ratio_of_sums=True) == ()


def test_interval_of_an_unknown_ratio() -> None:
    assert ci95_relative(float("nan"), 0.1, 0.1, method="x") == float("inf")
    assert all(np.isnan(v) for v in interval(4.0, float("inf")))


def test_coverage_over_simulated_pairs_is_within_a_loose_band() -> None:
    # Hand-held 12-bit brackets, ratios from the registered pixels with the true motion: the
    # intervals of the ok pairs must contain the truth about 95 % of the time (here at least
    # 80 % of 40 pairs), and must not be so wide that few pairs are ok.
    times = (1.0, 4.0, 16.0, 64.0, 256.0, 1024.0)
    covered, ok, halves = [], [], []
    for scene in SCENES:
        for seed in (11, 12):
            b = simulate_bracket(
                scene=scene,
                shape=(128, 192),
                exposure_times=times,
                bits=12,
                noise_sigma=1.0,
                seed=seed,
                max_shift=10.0,
                max_rotation_deg=0.5,
            )
            mats = [b.pair_matrix(k, k + 1) for k in range(len(times) - 1)]
            res = bracket_exposures_from_pixels(
                b.frames, b.max_level, mats, non_consecutive=False, noise_floor=4.0
            )
            for p in res.pairs:
                if p.ok:
                    lo, hi = p.interval
                    covered.append(lo <= 4.0 <= hi)
                    halves.append(p.ci95_relative)
                ok.append(p.ok)
    assert np.mean(ok) >= 0.5, f"only {np.mean(ok):.0%} of the pairs are ok"
    assert np.mean(covered) >= 0.8, f"coverage {np.mean(covered):.0%} of {len(covered)} pairs"
    assert np.median(halves) < 0.004
