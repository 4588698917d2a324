"""``hdrcore response``: JSON shape, plot/save outputs (atomic, no overwrite), clear errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from hdrcore.cli import main
from hdrcore.response import ResponseCurve

from ._truth import SEED_TIMES, rms, seed_bracket, truth_g


@pytest.fixture
def bracket_dir(tmp_path):
    b = seed_bracket("gamma", 1.0)
    lines = []
    for k, (f, t) in enumerate(zip(b.frames, SEED_TIMES, strict=True)):
        name = f"frame{k}.png"
        Image.fromarray(f.astype(np.uint8)).save(tmp_path / name)
        lines.append(f"{name} {t:g}")
    (tmp_path / "times.txt").write_text("\n".join(lines) + "\n")
    return tmp_path


def _files(d):
    return [str(d / f"frame{k}.png") for k in range(len(SEED_TIMES))]


@pytest.mark.parametrize("method", ["debevec-histogram", "grossberg2003"])
def test_json_output(bracket_dir, capsys, method) -> None:
    rc = main(
        [
            "response",
            *_files(bracket_dir),
            "--times",
            str(bracket_dir / "times.txt"),
            "--method",
            method,
            "--json",
        ]
    )
    assert rc == 0
    d = json.loads(capsys.readouterr().out)
    assert d["method"] == method
    assert d["exposure_ratios"] == pytest.approx([4.0] * 5)
    assert len(d["channels"]) == 3
    ch = d["channels"][1]
    assert ch["levels"] == list(range(256)) and len(ch["g"]) == 256
    assert ch["g"][0] == 0 and ch["g"][-1] == 1
    assert rms(np.array(ch["g"]), truth_g("gamma"))[0] < 0.01


def test_plot_and_save(bracket_dir, capsys) -> None:
    plot, saved = bracket_dir / "g.png", bracket_dir / "g.json"
    args = [
        "response",
        *_files(bracket_dir),
        "--times",
        str(bracket_dir / "times.txt"),
        "--plot",
        str(plot),
        "--save",
        str(saved),
    ]
    assert main(args) == 0
    assert Image.open(plot).format == "PNG"
    out = capsys.readouterr().out
    # the default (auto) prints the curve it chose; the saved curve is that one
    chosen = out.split("method ", 1)[1].split(":", 1)[0]
    assert ResponseCurve.load(saved).method == chosen
    assert json.loads(saved.read_text())["selection"]["chosen"] == chosen
    assert "exposure ratios" in out
    assert main(args) == 2
    assert "use --force" in capsys.readouterr().err
    assert main([*args, "--force"]) == 0
    assert (
        main(
            [
                "response",
                *_files(bracket_dir),
                "--times",
                str(bracket_dir / "times.txt"),
                "--plot",
                _files(bracket_dir)[0],
                "--force",
            ]
        )
        == 2
    )
    assert "input" in capsys.readouterr().err


def test_outputs_checked_before_decoding(bracket_dir, tmp_path, capsys, monkeypatch) -> None:
    import hdrcore.cli.response as response_cli

    def no_decoding(*_args, **_kwargs):
        raise AssertionError("decoded before the outputs were checked")

    monkeypatch.setattr(response_cli, "load_bracket_from_args", no_decoding)
    kept = tmp_path / "curve.json"
    kept.write_text("keep")
    assert (
        main(
            [
                "response",
                *_files(bracket_dir),
                "--times",
                str(bracket_dir / "times.txt"),
                "--save",
                str(kept),
            ]
        )
        == 2
    )
    assert "use --force" in capsys.readouterr().err and kept.read_text() == "keep"


def test_errors(bracket_dir, capsys) -> None:
    files = _files(bracket_dir)
    assert (
        main(["response", *files, "--times", str(bracket_dir / "times.txt"), "--method", "nope"])
        == 2
    )
    err = capsys.readouterr().err
    assert "debevec1997" in err and "grossberg2003" in err
    assert main(["response", files[0], "--times", str(bracket_dir / "times.txt")]) == 2
    assert "at least two frames" in capsys.readouterr().err
    assert main(["response", *files, "--method", "debevec1997"]) == 2  # PNGs carry no times
    assert "exposure times" in capsys.readouterr().err
    # the pipeline's --exclude-colour (one parsing for every command): a usage error
    with pytest.raises(SystemExit):
        main(
            [
                "response",
                *files,
                "--times",
                str(bracket_dir / "times.txt"),
                "--exclude-colour",
                "1,2",
            ]
        )
    assert "three non-negative integer levels" in capsys.readouterr().err
