"""``--force`` never destroys an input (issue 13, point 2): the times list, a response curve and
the other outputs are protected like the frames, outputs are compared once resolved, and every
refusal comes before anything is decoded or written."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

import hdrcore.cli._common as common
from hdrcore.cli import main
from hdrcore.synthetic import simulate_bracket, write_bracket


@pytest.fixture()
def bracket(tmp_path: Path) -> Path:
    sim = simulate_bracket(
        scene="patches",
        shape=(64, 96),
        exposure_times=(1 / 64, 1 / 16, 1 / 4),
        bits=8,
        response="gamma",
        noise_sigma=1.0,
        seed=3,
    )
    out = tmp_path / "br"
    write_bracket(out, sim, fmt="png")
    (out / "exposure_times.txt").write_text("frame00.png 1/64\nframe01.png 1/16\nframe02.png 1/4\n")
    return out


@pytest.fixture()
def no_decoding(monkeypatch):
    """Fail the test if a frame is decoded: refusals must come first."""

    def refuse(*_a, **_k):
        raise AssertionError("a frame was decoded before the refusal")

    monkeypatch.setattr(common, "load_bracket", refuse)


@pytest.mark.parametrize("force", [False, True])
def test_report_over_the_times_list_is_refused(bracket, tmp_path, capsys, no_decoding, force):
    times = bracket / "exposure_times.txt"
    before = times.read_bytes()
    args = [
        "merge",
        str(bracket / "frame00.png"),
        str(bracket / "frame01.png"),
        str(bracket / "frame02.png"),
        "--times",
        str(times),
        "-o",
        str(tmp_path / "o.exr"),
        "--report",
        str(times),
        "--quiet",
    ] + (["--force"] if force else [])
    assert main(args) == 2
    assert "input" in capsys.readouterr().err
    assert times.read_bytes() == before
    assert not (tmp_path / "o.exr").exists()


@pytest.mark.parametrize("force", [False, True])
def test_output_over_a_response_curve_is_refused(bracket, tmp_path, capsys, no_decoding, force):
    curve = tmp_path / "curve.json"
    curve.write_text('{"not": "read: the refusal comes first"}')
    before = curve.read_bytes()
    args = [
        "merge",
        *(str(bracket / f"frame0{k}.png") for k in range(3)),
        "--response",
        str(curve),
        "-o",
        str(tmp_path / "o.exr"),
        "--report",
        str(curve),
        "--quiet",
    ]
    assert main(args + (["--force"] if force else [])) == 2
    assert curve.read_bytes() == before


@pytest.mark.parametrize("force", [False, True])
@pytest.mark.parametrize("alias", ["./{name}", "{dir}/../{base}/{name}", "link"])
def test_two_outputs_that_are_one_file_are_refused(
    bracket, tmp_path, capsys, no_decoding, force, alias
):
    exr = tmp_path / "f.exr"
    exr.write_bytes(b"an earlier result")
    before = exr.read_bytes()
    if alias == "link":
        report = tmp_path / "link.json"
        os.symlink(exr, report)
    else:
        report = Path(alias.format(name="f.exr", dir=tmp_path, base=tmp_path.name))
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        args = ["merge", str(bracket), "-o", str(exr), "--report", str(report), "--quiet"]
        assert main(args + (["--force"] if force else [])) == 2
    finally:
        os.chdir(cwd)
    assert "two outputs" in capsys.readouterr().err
    assert exr.read_bytes() == before


def test_hard_linked_output_over_a_frame_is_refused(bracket, tmp_path, capsys, no_decoding):
    frame = bracket / "frame01.png"
    before = frame.read_bytes()
    link = tmp_path / "x.exr"
    os.link(frame, link)
    assert main(["merge", str(bracket), "-o", str(link), "--force", "--quiet"]) == 2
    assert frame.read_bytes() == before


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write in any folder")
def test_unwritable_output_folder_is_refused_before_decoding(
    bracket, tmp_path, capsys, no_decoding
):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        assert (
            main(
                [
                    "merge",
                    str(bracket),
                    "-o",
                    str(tmp_path / "o.exr"),
                    "--preview",
                    str(ro / "p.png"),
                    "--quiet",
                ]
            )
            == 2
        )
        assert "cannot write" in capsys.readouterr().err
        assert not (tmp_path / "o.exr").exists()
    finally:
        ro.chmod(0o755)
        shutil.rmtree(ro)


def test_unwritable_preview_folder_is_refused_before_decoding_as_any_user(
    bracket, tmp_path, capsys, no_decoding, monkeypatch
):
    """The same refusal when the tests run as root: the folder reports no write access (a
    read-only file system does that even for root)."""
    ro = tmp_path / "ro"
    ro.mkdir()
    real = os.access
    monkeypatch.setattr(
        os,
        "access",
        lambda p, mode, *a, **k: (
            False if Path(p).resolve() == ro.resolve() else real(p, mode, *a, **k)
        ),
    )
    assert (
        main(
            [
                "merge",
                str(bracket),
                "-o",
                str(tmp_path / "o.exr"),
                "--preview",
                str(ro / "p.png"),
                "--quiet",
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert "cannot write in the output folder" in err and "ro" in err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o.exr").exists()


def test_a_write_that_fails_midway_is_one_line_and_leaves_nothing(
    bracket, tmp_path, capsys, monkeypatch
):
    """The disk fills up during the EXR write: exit 2, one line naming the output, no
    temporary file, no output."""
    import errno

    import hdrcore.io.atomic as atomic

    class FullDisk:
        """The os module as atomic_write sees it, with a rename that finds the disk full (only
        there: numba's cache and every other os.replace in the process keep working)."""

        def __getattr__(self, name):
            return getattr(os, name)

        @staticmethod
        def replace(src, dst):
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(atomic, "os", FullDisk())
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    rc = main(
        [
            "merge",
            str(bracket),
            "--times",
            str(bracket / "exposure_times.txt"),
            "-o",
            str(out_dir / "o.exr"),
            "--quiet",
        ]
    )
    monkeypatch.undo()
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "o.exr: cannot write the output (No space left on device)" in err
    assert "internal error" not in err and len(err.strip().splitlines()) == 1
    assert list(out_dir.iterdir()) == []


def test_a_normal_merge_still_writes_all_outputs(bracket, tmp_path, capsys):
    out = tmp_path / "o.exr"
    rc = main(
        [
            "merge",
            str(bracket),
            "--times",
            str(bracket / "exposure_times.txt"),
            "-o",
            str(out),
            "--report",
            str(tmp_path / "o.json"),
            "--quiet",
        ]
    )
    assert rc == 0, capsys.readouterr().err
    assert out.stat().st_size > 0 and (tmp_path / "o.json").stat().st_size > 0


def test_sigterm_during_the_write_leaves_no_temporary_file(bracket, tmp_path):
    """The program is stopped by SIGTERM while its EXR sits in a temporary file: the temporary
    file is removed, no output appears, the exit status is 128 + 15."""
    import signal
    import subprocess
    import sys
    import time

    marker = tmp_path / "writing"
    script = (
        "import os, sys, time, pathlib\n"
        "import hdrcore.io.atomic as a\n"
        "real = a.os.replace\n"
        "def slow(src, dst):\n"
        f"    pathlib.Path({str(marker)!r}).write_text(str(src))\n"
        "    time.sleep(60)\n"
        "    real(src, dst)\n"
        "a.os.replace = slow\n"
        "from hdrcore.cli import main\n"
        "sys.argv = ['hdrcore'] + sys.argv[1:]\n"
        "sys.exit(main())\n"
    )
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            script,
            "merge",
            str(bracket),
            "-o",
            str(out_dir / "o.exr"),
            "--quiet",
        ],
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 120
    while not marker.exists():
        assert proc.poll() is None, proc.stderr.read()
        assert time.monotonic() < deadline, "the merge never reached its write"
        time.sleep(0.05)
    assert Path(marker.read_text()).exists()  # the temporary EXR is there
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert "terminated" in err
    assert list(out_dir.iterdir()) == []  # neither the output nor a temporary file
