"""A bracket without exposure times whose darkest frames are too dark for their histograms to be
measured: the response is fitted without them and the bracket merges (it used to stop with
"frames must be ordered darkest first")."""

from __future__ import annotations

import numpy as np

from hdrcore.pipeline import _rising_from_brightest


def test_frames_kept_are_those_that_fall_from_the_brightest_down() -> None:
    rel = np.array([1.0, 0.47, 2.1, 0.20, 0.05, 0.10, 0.2, 0.42, 0.84, 1.79])
    assert _rising_from_brightest(rel) == [4, 5, 6, 7, 8, 9]
    assert _rising_from_brightest(np.array([1.0, 2.0, 4.0])) == [0, 1, 2]
    assert _rising_from_brightest(np.array([3.0, 2.0, 1.0])) == [2]


def test_memorial_without_times_merges(memorial_dir, tmp_path, capsys) -> None:
    """By default its blue border marks are left out (marker colour): the four darkest scans
    are then black, the others double per frame and none moves."""
    import json

    from hdrcore.cli import main

    rep = tmp_path / "m.json"
    rc = main(
        ["merge", str(memorial_dir), "-o", str(tmp_path / "m.exr"), "--report", str(rep), "--quiet"]
    )
    assert rc == 0, capsys.readouterr().err
    report = json.loads(rep.read_text())
    rel = [f["relative_exposure"] for f in report["frames"]]
    assert len(rel) >= 10
    assert np.all(np.abs(np.diff(np.log2(rel)) - 1) < 0.1), rel  # 1 stop apart
    assert all(abs(q["dx"]) < 1 and abs(q["dy"]) < 1 for q in report["registration"]["pairs"])


def test_memorial_marks_kept_the_darkest_frames_are_left_out_of_the_response(
    memorial_dir, tmp_path, capsys
) -> None:
    """With the marks taken for scene (a colour to exclude that is not there), the darkest
    frames' histograms do not rise with their brightness: the response is fitted without them
    (and says which), and their pairs, whose motion nothing verifies, are not ok."""
    import json

    from hdrcore.cli import main

    rep = tmp_path / "m.json"
    rc = main(
        [
            "merge",
            str(memorial_dir),
            "-o",
            str(tmp_path / "m.exr"),
            "--report",
            str(rep),
            "--exclude-colour",
            "1,2,3",
            "--quiet",
        ]
    )
    err = capsys.readouterr().err
    report = json.loads(rep.read_text())
    # merged; exit 1 when a pair could not be registered (two of this bracket's: the darkest
    # frames hold almost nothing to register), as the command's help says
    failed = any(v["code"] == "registration-failed" for v in report["verdicts"])
    assert rc == (1 if failed else 0), err
    assert report["status"] == ("stage-failed" if failed else "ok")
    assert "fitted without frames" in report["response"]["message"]
    statuses = {(q["dark"], q["bright"]): q["status"] for q in report["registration"]["pairs"]}
    assert all(statuses[(k, k + 1)] != "ok" for k in (1, 2, 3)), statuses
