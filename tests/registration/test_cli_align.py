"""``hdrcore align``: JSON shape and recovered motion on a simulated bracket; real tripod data."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hdrcore.cli import main
from hdrcore.registration import corner_error

ROOT = Path(__file__).resolve().parents[2]


def test_align_json_on_simulated_bracket(tmp_path, capsys):
    out = tmp_path / "sim"
    assert (
        main(
            [
                "simulate",
                str(out),
                "--size",
                "128x192",
                "--shift",
                "4",
                "--rotation",
                "0.5",
                "--bits",
                "12",
                "--response",
                "linear",
            ]
        )
        == 0
    )
    capsys.readouterr()
    code = main(
        [
            "align",
            str(out),
            "--times",
            str(out / "exposure_times.txt"),
            "--response",
            "linear",
            "--ratios",
            "exif",
            "--json",
        ]
    )
    js = json.loads(capsys.readouterr().out)
    assert code == 0
    assert js["reference"] == 1 and len(js["pairs"]) == 2 and len(js["to_reference"]) == 3
    keys = {
        "dark",
        "bright",
        "matrix",
        "dx",
        "dy",
        "angle_deg",
        "cost_before",
        "cost_after",
        "status",
        "message",
    }
    truth = json.loads((out / "truth.json").read_text())
    for pair, true_pair in zip(js["pairs"], truth["pairs"], strict=True):
        assert keys <= set(pair)
        assert pair["status"] == "ok"
        err = corner_error(np.array(pair["matrix"]), np.array(true_pair["matrix"]), (128, 192))
        assert err.max() < 0.1
    assert np.allclose(js["to_reference"][1], np.eye(2, 3))


def test_align_reference_and_shift_model(tmp_path, capsys):
    out = tmp_path / "sim"
    main(
        [
            "simulate",
            str(out),
            "--size",
            "128x192",
            "--shift",
            "3",
            "--bits",
            "12",
            "--response",
            "linear",
        ]
    )
    capsys.readouterr()
    main(
        [
            "align",
            str(out),
            "--times",
            str(out / "exposure_times.txt"),
            "--response",
            "linear",
            "--ratios",
            "exif",
            "--model",
            "shift",
            "--reference",
            "0",
            "--json",
        ]
    )
    js = json.loads(capsys.readouterr().out)
    assert js["reference"] == 0 and js["model"] == "shift"
    assert all(p["angle_deg"] == 0.0 for p in js["pairs"])


@pytest.mark.shared
def test_align_tripod_bracket_finds_near_zero_motion(frobisher_dir, capsys):
    code = main(["align", str(frobisher_dir), "--ratios", "exif", "--json"])
    js = json.loads(capsys.readouterr().out)
    assert code == 0
    for p in js["pairs"]:
        assert p["status"] == "ok"
        err = corner_error(np.array(p["matrix"]), np.eye(2, 3), (426, 640))
        assert err.max() < 1.5  # sRGB stands in for the camera's response here
