"""Locally tone-mapped brackets (phones): detected, said in words, merged without a cast."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hdrcore.io import load_bracket
from hdrcore.merge.colour_check import chromaticity, srgb_decode_lut
from hdrcore.pipeline import Pipeline, PipelineParams
from hdrcore.response.local_tonemap import LTM_SPREAD, local_tone_mapping
from hdrcore.synthetic import simulate_bracket, write_bracket

TIMES = (1 / 64, 1 / 16, 1 / 4, 1.0)


def _sim(strength: float, seed: int = 1, **kw):
    return simulate_bracket(
        scene="window",
        shape=(192, 288),
        exposure_times=TIMES,
        bits=8,
        response="srgb",
        noise_sigma=1.0,
        seed=seed,
        local_tonemap=strength,
        **kw,
    )


def test_spread_of_the_transfer_across_regions() -> None:
    lut = srgb_decode_lut(255)
    flat = local_tone_mapping(list(_sim(0.0).frames), lut, max_level=255)
    assert not flat.detected and flat.spread < 1.06
    assert "one global response fits" in flat.message
    ltm = local_tone_mapping(list(_sim(0.6).frames), lut, max_level=255)
    assert ltm.detected and ltm.spread > LTM_SPREAD
    assert "locally tone-mapped" in ltm.message and f"{ltm.spread:.2f}x" in ltm.message
    assert json.loads(json.dumps(ltm.to_json()))["detected"] is True


def test_local_tonemap_strength_is_checked() -> None:
    from hdrcore.errors import ParameterError

    with pytest.raises(ParameterError, match="local_tonemap"):
        _sim(1.5)


@pytest.fixture(scope="module")
def ltm_result(tmp_path_factory):
    sim = _sim(0.6, seed=2, max_shift=3, max_rotation_deg=0.3)
    out = tmp_path_factory.mktemp("ltm")
    write_bracket(out, sim, fmt="png")
    b = load_bracket(sorted(out.glob("*.png")), exposure_times=out / "exposure_times.txt")
    return sim, Pipeline(b, PipelineParams(registration_previews=False)).run()


def test_locally_tone_mapped_bracket_is_detected_and_said(ltm_result) -> None:
    _, r = ltm_result
    check = r.colour["check"]
    assert check["local_tone_mapping"]["detected"]
    codes = [v.code for v in r.verdicts]
    assert "locally-tone-mapped" in codes
    text = next(v.message for v in r.verdicts if v.code == "locally-tone-mapped")
    assert "compromise" in text and "exposure fusion" in text
    assert r.preview is not None and r.preview.method == "exposure-fusion"
    assert r.preview.image.dtype == np.uint8 and r.preview.image.shape[2] == 3
    json.dumps(r.to_report())


def test_locally_tone_mapped_bracket_merges_without_a_cast(ltm_result) -> None:
    """The simulated tone mapping changes brightness, not colour: the merge must keep the
    scene's chromaticity (no cast: the median signed shift of r and g stays under 0.002; the
    per-channel histogram response of the same frames merges with a shift of 0.004 and a
    median error of 0.0096, the chosen response without the colour anchoring with 0.012)."""
    sim, r = ltm_result
    ref = sim.frames[sim.reference]
    well = np.all((ref > 25) & (ref < 230), axis=-1)
    got = chromaticity(r.radiance[well])
    truth = chromaticity(sim.radiance[well])
    shift = np.nanmedian(got - truth, axis=0)
    assert np.all(np.abs(shift) < 0.002), shift
    assert np.nanmedian(np.hypot(*(got - truth).T)) < 0.0075
    # and the colour check says the same in its own terms
    assert r.colour["check"]["after"]["merge_error_srgb"] < 0.01
