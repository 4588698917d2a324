"""``ratios --noise-sigma`` runs through the pipeline; ``response`` shares its colour exclusion.

Issue 17, point 5: both commands had their own mask parsing and ``ratios --noise-sigma``
re-fitted the ratios outside the pipeline. ``--noise-sigma`` is now ``PipelineParams.noise_sigma``
(the refined estimator's noise matching); these tests hold it to the old direct call, which
gave byte-identical JSON on frobisher, the demo and the memorial scans (with and without
``--exclude-colour``). ``response`` stays outside the pipeline (its ``--cutoff``, ``--order``,
``--no-monotone`` have no pipeline field; it fits RAW frames, which the pipeline takes as
linear; it needs exposure times, which the pipeline would estimate) but parses
``--exclude-colour`` and masks with the pipeline's own code.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from hdrcore.cli import main
from hdrcore.cli.response import exclusion_mask
from hdrcore.exposure import bracket_exposures
from hdrcore.io import load_bracket
from hdrcore.pipeline import Pipeline, PipelineParams
from hdrcore.response import recover_response


@pytest.fixture
def png_bracket(tmp_path: Path, capsys) -> Path:
    out = tmp_path / "sim"
    assert (
        main(
            [
                "simulate",
                str(out),
                "--size",
                "64x96",
                "--bits",
                "8",
                "--format",
                "png",
                "--response",
                "gamma",
                "--frames",
                "3",
                "--noise",
                "2",
                "--seed",
                "4",
            ]
        )
        == 0
    )
    capsys.readouterr()
    for f in sorted(out.glob("*.png")):  # a border mark, as in the memorial scans
        a = np.asarray(Image.open(f).convert("RGB")).copy()
        a[:6] = (0, 0, 255)
        Image.fromarray(a).save(f)
    return out


def _ratios(capsys, *argv: str) -> dict:
    main(["ratios", *argv, "--json"])
    return json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("sigma", [0.5, 4.0])
def test_noise_sigma_through_the_pipeline_is_the_old_direct_fit(png_bracket, capsys, sigma):
    times = str(png_bracket / "exposure_times.txt")
    got = _ratios(
        capsys,
        str(png_bracket),
        "--times",
        times,
        "--exclude-colour",
        "0,0,255",
        "--noise-sigma",
        str(sigma),
    )
    # the old path: the pipeline's saturation, noise floor and curve, the ratios fitted again
    bracket = load_bracket([str(png_bracket)], exposure_times=times)
    pres = Pipeline(
        bracket, PipelineParams(exclude_colour=(0, 0, 255), registration_previews=False)
    ).run(until="ratios")
    levels = [f.levels for f in pres.bracket.frames]
    mask = exclusion_mask(levels, (0, 0, 255))
    old = bracket_exposures(
        levels,
        pres.bracket.max_level,
        exposure_times=[float(f.meta.exposure_time) for f in pres.bracket.frames],
        mask=mask,
        saturation=pres.saturation,
        noise_floor=pres.noise_floor,
        lut=pres.lut,
        noise_sigma=sigma,
    )
    assert [p["ratio"] for p in got["pairs"]] == [p.ratio for p in old.pairs]
    assert [p["status"] for p in got["pairs"]] == [p.status for p in old.pairs]
    assert got["masked_fraction"] == pytest.approx(6 / 64)


def test_noise_sigma_changes_the_fit_and_reruns_only_the_ratios(png_bracket, capsys) -> None:
    times = str(png_bracket / "exposure_times.txt")
    small = _ratios(capsys, str(png_bracket), "--times", times, "--noise-sigma", "0.5")
    large = _ratios(capsys, str(png_bracket), "--times", times, "--noise-sigma", "4")
    assert [p["ratio"] for p in small["pairs"]] != [p["ratio"] for p in large["pairs"]]
    bracket = load_bracket([str(png_bracket)], exposure_times=times)
    pipe = Pipeline(bracket, PipelineParams(registration_previews=False))
    pipe.run(until="ratios")
    again = pipe.run(pipe.params.replace(noise_sigma=4.0), until="ratios")
    assert again.stages_run == ("ratios",)
    assert [p.ratio for p in again.exposures.pairs] == [p["ratio"] for p in large["pairs"]]


def test_response_masks_like_the_pipeline(png_bracket, capsys) -> None:
    times = str(png_bracket / "exposure_times.txt")
    rc = main(
        [
            "response",
            str(png_bracket),
            "--times",
            times,
            "--method",
            "debevec-histogram",
            "--exclude-colour",
            "0,0,255",
            "--workers",
            "1",
            "--json",
        ]
    )
    got = json.loads(capsys.readouterr().out)
    assert rc == 0
    bracket = load_bracket([str(png_bracket)], exposure_times=times)
    levels = [f.levels for f in bracket.frames]
    mask = exclusion_mask(levels, (0, 0, 255))
    assert mask.sum() == 58 * 96 and not mask[:6].any()
    direct = recover_response(
        levels,
        [float(t) for t in bracket.exposure_times],
        method="debevec-histogram",
        max_level=bracket.max_level,
        cutoff=0.98,
        mask=mask,
    )
    assert np.array_equal(np.array([c["g"] for c in got["channels"]]), direct.g)
    unmasked = recover_response(
        levels,
        [float(t) for t in bracket.exposure_times],
        method="debevec-histogram",
        max_level=bracket.max_level,
        cutoff=0.98,
    )
    assert not np.array_equal(unmasked.g, direct.g)  # the mark does change the fit
