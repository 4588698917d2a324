"""``hdrcore simulate``: files, JSON on stdout, and one-line errors with exit code 2."""

from __future__ import annotations

import json
import re
from fractions import Fraction
from pathlib import Path

import pytest

from hdrcore.cli import main
from hdrcore.cli.simulate import bracket_times, parse_size, parse_times
from hdrcore.errors import ParameterError
from hdrcore.io import load_bracket


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_simulate_dng_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out_dir = tmp_path / "b"
    code, out, err = _run(
        capsys,
        "simulate",
        str(out_dir),
        "--format",
        "dng",
        "--stops",
        "2",
        "--frames",
        "3",
        "--size",
        "64x96",
        "--shift",
        "4",
        "--rotation",
        "0.5",
        "--seed",
        "3",
        "--json",
    )
    assert code == 0, err
    doc = json.loads(out)
    assert doc["format"] == "dng" and doc["bits"] == 12 and doc["file_max_level"] == 3839
    assert [f["exposure_time_exact"] for f in doc["frames"]] == ["1/256", "1/64", "1/16"]
    assert doc["ratios"] == [4.0, 4.0]
    assert len(doc["pairs"]) == 2
    b = load_bracket([f["file"] for f in doc["frames"]])
    assert [str(f.meta.exposure_time) for f in b.frames] == ["1/256", "1/64", "1/16"]
    assert b.shape == (64, 96)
    assert (out_dir / "truth.json").is_file() and (out_dir / "exposure_times.txt").is_file()


def test_simulate_png_times_and_response(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = _run(
        capsys,
        "simulate",
        str(tmp_path),
        "--times",
        "1/500,1/125",
        "--response",
        "gamma",
        "--size",
        "32x48",
    )
    assert code == 0, err
    assert "frame00.png  t=1/500 s" in out
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert truth["response"] == "gamma" and truth["bits"] == 8


def test_simulate_key_sets_the_exposure_scale(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = _run(
        capsys,
        "simulate",
        str(tmp_path),
        "--times",
        "1,2",
        "--key",
        "0.01",
        "--size",
        "32x48",
        "--json",
    )
    assert code == 0, err
    assert json.loads(out)["key"] == 0.01
    assert json.loads((tmp_path / "truth.json").read_text())["key"] == 0.01


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--format", "dng", "--response", "gamma"], r"DNG frames need a linear response"),
        (["--format", "jpeg", "--bits", "12"], r"JPEG holds 8-bit frames only"),
        (["--size", "12x3"], r"--size out of range"),
        (["--size", "big"], r"bad --size.*HxW"),
        (["--times", "1,x"], r"bad exposure time in --times.*'x'"),
        (["--times", "1,-2"], r"exposure times must be positive"),
        (["--stops", "0"], r"--stops must be positive"),
        (["--shift", "-1"], r"--shift and --rotation are maxima"),
        (["--key", "0"], r"--key must be positive"),
    ],
)
def test_simulate_bad_arguments(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    code, out, err = _run(capsys, "simulate", str(tmp_path / "x"), "--size", "32x48", *args)
    assert code == 2
    assert err.startswith("hdrcore: error: ") and len(err.strip().splitlines()) == 1
    assert re.search(message, err), err


def test_simulate_refuses_existing_output(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _run(capsys, "simulate", str(tmp_path), "--size", "32x48")[0] == 0
    code, _, err = _run(capsys, "simulate", str(tmp_path), "--size", "32x48")
    assert code == 2 and "frame00.png: output exists; use --force" in err
    assert _run(capsys, "simulate", str(tmp_path), "--size", "32x48", "--force")[0] == 0


def test_parsers() -> None:
    assert parse_size("480x720") == (480, 720)
    assert parse_times("1/3049, 0.5") == (Fraction(1, 3049), Fraction(1, 2))
    assert bracket_times(2, 4, Fraction(1, 256)) == tuple(Fraction(1, 256) * 4**k for k in range(4))
    assert bracket_times(1.5, 2, Fraction(1, 8))[1] == Fraction(2**1.5 / 8).limit_denominator(
        1_000_000
    )
    with pytest.raises(ParameterError, match=r"--frames out of range"):
        bracket_times(2, 0, Fraction(1))
