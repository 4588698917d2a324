"""The fast search's learnt step factor (``fast._step_scale``) and the cached candidates of
``select_samples``."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.io import load_bracket
from hdrcore.registration import fast, register_pair
from hdrcore.registration._problem import prepare, select_samples
from tests.conftest import shared_dir


def _parabola(minimum: float):
    """A cost ``(a - minimum)^2`` along a step of length 1 from ``a = 0``: its start, slope
    there and value at the step's end."""
    return minimum**2, -2.0 * minimum, (1.0 - minimum) ** 2


@pytest.mark.parametrize(
    ("mu", "minimum", "expected"),
    [
        (1.0, 1.0, 1.0),  # the step landed on the minimum: unchanged
        (1.0, 1.5, 1.5),  # the minimum 1.5 steps away: the factor follows it
        (1.0, 3.0, 2.0),  # at most doubled at a time
        (3.0, 3.0, fast.MAX_STEP_SCALE),  # and never above the cap
        (2.0, 0.7, 1.4),  # a step too long shortens the factor
        (1.0, 0.5, 1.0),  # never below the plain Gauss-Newton step
    ],
)
def test_step_scale_follows_the_parabola(mu: float, minimum: float, expected: float) -> None:
    before, slope, after = _parabola(minimum)
    assert fast._step_scale(mu, before, slope, after) == pytest.approx(expected)


def test_step_scale_ignores_a_cost_that_is_not_a_convex_parabola() -> None:
    # no curvature left (or an uphill "slope"): the factor is kept as it is
    assert fast._step_scale(1.7, 1.0, -0.5, 0.5) == 1.7
    assert fast._step_scale(1.7, 1.0, 0.5, 2.0) == 1.7


def _pixel7_pair():
    """The real Pixel 7 bracket's two darkest frames, green channel decoded with sRGB."""
    d = shared_dir("handheld-pixel7-lab")
    b = load_bracket([d / "original_5.jpg", d / "original_4.jpg"])
    v = np.arange(256) / 255.0
    lut = np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4).astype(np.float32)
    dark, bright = (f.levels[..., 1] for f in b.frames)
    ratio = b.frames[1].exposure_time / b.frames[0].exposure_time
    return dark, bright, float(ratio), lut


@pytest.mark.parametrize("model", ["similarity", "homography"])
def test_the_learnt_step_needs_fewer_full_resolution_steps(monkeypatch, model: str) -> None:
    """On a real phone pair Gauss-Newton's curvature is over-estimated (the best step was 2.5-3
    times the step at every full-resolution iteration): the learnt factor ends in fewer steps
    there (measured: similarity 10 instead of 19, homography 20-21 instead of 38) at a motion
    whose eq. 6 cost on the independent evaluation samples is about as low.

    How close depends on the machine: where each search stops follows the floating-point
    rounding of the compiled sums. On the machines of earlier sessions the learnt search's cost
    was no higher (within 1e-4) and its similarity the plain search's to 0.01 px. On an AMD
    EPYC machine (2026-12-07) its similarity stops 0.1 px from the plain search's end, the cost
    0.77 % higher (a level ends when the plain step is below the tolerance, which under-states
    the distance left by the learnt factor; ending on the step taken instead reaches the plain
    search's cost and motion to 0.005 px, but moves the real tripod frobisher's default motion
    from 0.085 to 0.117 px, over the 0.1 px the merge applies, so its frames would be resampled
    by noise: not kept yet, see the README's registration section); its
    homography ends in another shallow minimum of a cost that is flat along a perspective
    direction, 0.2 % higher and 0.24 px away at a corner (a 100 times tighter tolerance keeps
    it there). Hence 1 % on the cost and 0.15 px at the corners."""
    dark, bright, ratio, lut = _pixel7_pair()
    opts = dict(saturation=0.9, noise_floor=0.004, lut=lut, model=model, previews=False)
    learnt = register_pair(dark, bright, ratio, **opts)
    monkeypatch.setattr(fast, "MAX_STEP_SCALE", 1.0)
    plain = register_pair(dark, bright, ratio, **opts)
    assert learnt.status == plain.status == "ok"
    full_res = [sum(1 for lv in r.level_history if lv == 0) for r in (learnt, plain)]
    assert full_res[0] < 0.75 * full_res[1]
    assert learnt.cost_after <= plain.cost_after * (1.0 + 1e-2)
    if model == "similarity":
        corners = np.array([[0, 0, 1], [4031, 0, 1], [0, 2267, 1], [4031, 2267, 1]], float).T
        a, b = learnt.homography @ corners, plain.homography @ corners
        assert np.max(np.hypot(*(a[:2] / a[2] - b[:2] / b[2]))) < 0.15


def test_cached_candidates_select_the_same_samples() -> None:
    rng = np.random.default_rng(3)
    dark = rng.uniform(0.05, 0.2, (200, 300)).astype(np.float32)
    bright = np.clip(4.0 * dark, 0.0, 1.0)
    data = prepare(dark, bright, 4.0, saturation=0.95, noise_floor=0.01, threshold=0.1)
    motion = np.array([[1.0, 0.0, 0.7], [0.0, 1.0, -0.4], [0.0, 0.0, 1.0]])
    first = select_samples(data, 0, 5_000, motion=motion)
    assert data.candidates  # kept for the next selection on this level
    again = select_samples(data, 0, 5_000, motion=motion)
    fresh = select_samples(
        prepare(dark, bright, 4.0, saturation=0.95, noise_floor=0.01, threshold=0.1),
        0,
        5_000,
        motion=motion,
    )
    for s in (again, fresh):
        np.testing.assert_array_equal(s.x, first.x)
        np.testing.assert_array_equal(s.y, first.y)
        np.testing.assert_array_equal(s.b, first.b)
    # and the samples come in raster order (the searches' reads stay local)
    order = first.y * 300 + first.x
    assert np.all(np.diff(order) > 0)
