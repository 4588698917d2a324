"""What consecutive frames' per-pixel colour difference is made of (issue 15): a perfect curve
still leaves the frames' own pixel noise, which :func:`noise_consistency` measures from each
frame alone; a curve whose channels disagree leaves an excess over it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hdrcore.merge import merge
from hdrcore.merge.colour_check import colour_check, noise_consistency, srgb_decode_lut
from hdrcore.synthetic import simulate_bracket

TIMES = (1.0, 2.0, 4.0, 8.0, 16.0)
SRGB = np.tile(srgb_decode_lut(255), (3, 1))
# red 4.5 % too steep in ln: a pair one stop apart reads 3 % redder in the brighter frame
RED_OFF = np.stack([srgb_decode_lut(255) ** 1.045, srgb_decode_lut(255), srgb_decode_lut(255)])


def _frames(sigma: float, scene: str = "window", seed: int = 1):
    sim = simulate_bracket(
        scene=scene,
        shape=(300, 450),
        exposure_times=TIMES,
        bits=8,
        response="srgb",
        noise_sigma=sigma,
        seed=seed,
    )
    return [np.asarray(f).astype(np.uint8) for f in sim.frames]


def _median(pairs, name):
    return float(np.nanmedian([getattr(p, name) for p in pairs]))


@pytest.mark.parametrize("sigma", [1.0, 3.0])
def test_the_exact_curve_leaves_the_noise_and_nothing_beyond(sigma) -> None:
    frames = _frames(sigma)
    pairs = noise_consistency(frames, SRGB, max_level=255, reference=2)
    assert len(pairs) == len(TIMES) - 1 and all(p.n_pixels > 1000 for p in pairs)
    flat, noise = _median(pairs, "flat"), _median(pairs, "noise")
    # the frames' own noise predicts the pair's difference (measured within 1-3 %)
    assert noise == pytest.approx(flat, rel=0.1)
    assert _median(pairs, "excess") < 0.003
    # more noise, a larger per-pixel difference with the same exact curve
    assert flat > (0.02 if sigma == 3.0 else 0.007)


def test_a_channel_error_shows_as_an_excess_over_the_noise() -> None:
    frames = _frames(1.0)
    exact = noise_consistency(frames, SRGB, max_level=255, reference=2)
    off = noise_consistency(frames, RED_OFF, max_level=255, reference=2)
    # the noise is each frame's own: about the same through either curve
    assert _median(off, "noise") == pytest.approx(_median(exact, "noise"), rel=0.1)
    assert _median(off, "excess") > 0.004 > _median(exact, "excess")
    # dividing out gains that undo nothing changes nothing; the balance is divided out per frame
    same = noise_consistency(frames, SRGB, max_level=255, reference=2, gains=np.ones((5, 3)))
    assert [p.to_json() for p in same] == [p.to_json() for p in exact]


def test_the_colour_check_reports_it_beside_the_per_pixel_figure() -> None:
    frames = _frames(1.0, scene="patches", seed=3)
    res = merge(frames, TIMES, response=SRGB, max_level=255)
    cc = colour_check(frames, res.radiance, SRGB, max_level=255, reference=2)
    assert len(cc.frame_pairs_noise) == len(TIMES) - 1
    assert cc.frame_noise == pytest.approx(cc.frame_consistency, rel=0.2)
    assert cc.frame_consistency_excess < 0.003
    assert "own pixel noise makes" in cc.message
    d = json.loads(json.dumps(cc.to_json()))
    assert d["frame_noise"] == pytest.approx(cc.frame_noise)
    assert len(d["frame_pairs_noise"]) == len(TIMES) - 1


def test_too_small_or_too_few_pixels_give_no_figure() -> None:
    tiny = [np.full((2, 2, 3), 128, np.uint8)] * 2
    assert noise_consistency(tiny, SRGB, max_level=255, reference=0) == ()
    dark = [np.zeros((40, 60, 3), np.uint8)] * 3
    pairs = noise_consistency(dark, SRGB, max_level=255, reference=1)
    assert all(np.isnan(p.flat) and p.n_pixels == 0 for p in pairs)
