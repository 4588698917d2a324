"""``hdrcore ratios``: JSON fields of the issue and ``--mask-colour`` on a simulated PNG bracket."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from hdrcore.cli import main
from hdrcore.cli.ratios import colour_mask


def _simulate(tmp_path, capsys):
    out = tmp_path / "sim"
    assert (
        main(
            [
                "simulate",
                str(out),
                "--size",
                "96x144",
                "--bits",
                "8",
                "--format",
                "png",
                "--response",
                "linear",
                "--scene",
                "patches",
                "--seed",
                "3",
            ]
        )
        == 0
    )
    capsys.readouterr()
    return out


def test_ratios_json_and_mask_colour(tmp_path, capsys) -> None:
    out = _simulate(tmp_path, capsys)
    files = sorted(out.glob("*.png"))
    # Paint a pure blue border into every frame, as in memorial-debevec.
    for f in files:
        a = np.asarray(Image.open(f).convert("RGB")).copy()
        a[:12] = (0, 0, 255)
        Image.fromarray(a).save(f)
    args = [
        "ratios",
        str(out),
        "--times",
        str(out / "exposure_times.txt"),
        "--response",
        "linear",
        "--json",
    ]
    main(args)
    plain = json.loads(capsys.readouterr().out)
    main(args + ["--mask-colour", "0,0,255"])
    masked = json.loads(capsys.readouterr().out)
    # the painted border is found without the option (the pipeline's marker colour)
    assert plain["marker_colour"] == [0, 0, 255] and masked["marker_colour"] is None
    assert plain["masked_fraction"] == pytest.approx(12 / 96, abs=0.01)
    assert masked["masked_fraction"] == pytest.approx(12 / 96, abs=0.01)
    keys = {
        "dark",
        "bright",
        "ratio",
        "initial_ratio",
        "iterations",
        "equations",
        "inliers",
        "exif_ratio",
        "mismatch_stops",
        "std_error",
        "region_std_error",
        "status",
        "message",
    }
    for pair in masked["pairs"]:
        assert keys <= set(pair)
        assert abs(pair["ratio"] / pair["exif_ratio"] - 1) < 0.01
    assert [p["ratio"] for p in masked["pairs"]] == [p["ratio"] for p in plain["pairs"]]
    # ... and taken for scene when another colour is named: the ratios change
    main(args + ["--mask-colour", "1,2,3"])
    kept = json.loads(capsys.readouterr().out)
    assert [p["ratio"] for p in masked["pairs"]] != [p["ratio"] for p in kept["pairs"]]


def test_mask_colour_is_validated(tmp_path, capsys) -> None:
    out = _simulate(tmp_path, capsys)
    with pytest.raises(SystemExit):
        main(["ratios", str(out), "--mask-colour", "0,0"])
    assert "three" in capsys.readouterr().err
    frames = [np.zeros((4, 5, 3), np.uint16), np.full((4, 5, 3), 7, np.uint16)]
    frames[1][0, 0] = (0, 0, 255)
    m = colour_mask(frames, (0, 0, 255))
    assert m.sum() == 19 and not m[0, 0]


def test_registered_ratios_of_a_handheld_bracket(capsys) -> None:
    from pathlib import Path

    demo = Path(__file__).resolve().parents[2] / "assets" / "demo"
    truth = json.loads((demo / "truth.json").read_text())["ratios"]
    assert main(["ratios", str(demo), "--json"]) == 1  # hand-held: histograms are unstable
    hist = json.loads(capsys.readouterr().out)
    assert main(["ratios", str(demo), "--registered", "--json"]) == 0
    reg = json.loads(capsys.readouterr().out)
    assert reg["method"] == "registered pixels" and hist["method"] != reg["method"]
    for h, r, t in zip(hist["pairs"], reg["pairs"], truth, strict=True):
        assert r["status"] == "ok" and abs(r["ratio"] / t - 1) < 0.003, r
        assert abs(r["ratio"] / t - 1) <= abs(h["ratio"] / t - 1) + 1e-4
    assert main(["ratios", str(demo), "--registered", "--noise-sigma", "1"]) == 2
    assert "--noise-sigma applies to the histogram estimate" in capsys.readouterr().err
