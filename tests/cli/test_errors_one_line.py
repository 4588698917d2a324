"""Every expected failure is one line on stderr and exit 2 (issue 13, point 6), naming the file
and what is wrong; what the libraries say on the way is said once in our words, or not at all.

stderr is read at the descriptor (``capfd``): LibRaw writes there from C, past ``sys.stderr``.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import warnings
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
import tifffile
from PIL import Image

from hdrcore.cli import main
from hdrcore.cli._chatter import library_chatter, log_words, warning_words
from hdrcore.io._capture import reading
from hdrcore.synthetic import simulate_bracket, write_bracket
from hdrcore.synthetic.dng import write_dng
from tests.io._images import gradient, write_jpeg
from tests.io.test_input_limits import huge_png

ROOT = Path(__file__).resolve().parents[2]


def one_line_error(capfd, argv: list[str], *names: str) -> str:
    """Run the program; it must exit 2 with exactly one stderr line naming ``names``."""
    capfd.readouterr()
    rc = main([str(a) for a in argv])
    err = capfd.readouterr().err
    lines = err.strip().splitlines()
    assert rc == 2, err
    assert len(lines) == 1, err
    assert "Traceback" not in err and "internal error" not in err
    for name in names:
        assert name in lines[0], lines[0]
    return lines[0]


@pytest.fixture()
def pngs(tmp_path: Path) -> list[Path]:
    return [
        write_jpeg(tmp_path / f"f{k}.png", gradient(24, 32, scale=1.0 / (k + 1)), fmt="PNG")
        for k in range(2)
    ]


def _loop(where: Path, name: str) -> Path:
    a, b = where / name, where / f"{name}-back"
    a.symlink_to(b.name)
    b.symlink_to(a.name)
    return a


# --- 1. symbolic-link loops ----------------------------------------------------------------------


def test_symlink_loop_as_a_frame(tmp_path, pngs, capfd) -> None:
    loop = _loop(tmp_path, "a.png")
    line = one_line_error(capfd, ["info", loop, pngs[0]], "a.png", "symbolic link loop")
    assert line == (
        f"hdrcore: error: {loop}: symbolic link loop (the link leads back to "
        "itself, never to a file)"
    )


def test_folder_holding_a_symlink_loop(tmp_path, pngs, capfd) -> None:
    _loop(tmp_path, "x.png")
    one_line_error(capfd, ["info", tmp_path], "x.png", "symbolic link loop")


def test_times_file_that_is_a_symlink_loop(tmp_path, pngs, capfd) -> None:
    loop = _loop(tmp_path, "times.txt")
    one_line_error(
        capfd,
        ["info", *pngs, "--times", loop],
        "times.txt",
        "exposure-times file: symbolic link loop",
    )


# --- 2. exposure times out of range --------------------------------------------------------------


@pytest.mark.parametrize("value", ["1e400", "inf", "nan", "1e-400", "-1", "0"])
def test_bad_time_in_the_times_file(tmp_path, pngs, capfd, value) -> None:
    t = tmp_path / "times.txt"
    t.write_text(f"f0.png {value}\nf1.png 1/10\n")
    line = one_line_error(
        capfd,
        ["info", *pngs, "--times", t],
        "times.txt",
        "line 1: bad exposure time",
        f"found '{value}'",
    )
    if value == "1e400":
        assert "longer than 1e5 s" in line


def test_bad_time_inline_for_simulate(tmp_path, capfd) -> None:
    one_line_error(
        capfd,
        ["simulate", tmp_path / "sim", "--times", "1/100,1e400"],
        "--times",
        "longer than 1e5 s",
        "found '1e400'",
    )
    assert not (tmp_path / "sim").exists()


def test_times_file_that_is_not_utf8(tmp_path, pngs, capfd) -> None:
    t = tmp_path / "times.txt"
    t.write_bytes(b"f0.png 1/8\nf1.png 1/\xff\n")
    one_line_error(capfd, ["info", *pngs, "--times", t], "times.txt", "line 2 is not UTF-8")


# --- 3. the pixel limit --------------------------------------------------------------------------


def test_huge_frame_is_refused_from_its_header(tmp_path, pngs, capfd) -> None:
    big = huge_png(tmp_path / "big.png", 20000, 10000)
    line = one_line_error(capfd, ["info", big, pngs[0]])
    assert line == (
        f"hdrcore: error: {big}: frame is 200.0 MP (20000x10000), more than the "
        "limit of 160 MP; --max-pixels 2e8 raises it"
    )


def test_max_pixels_option(tmp_path, pngs, capfd) -> None:
    one_line_error(
        capfd,
        ["ratios", *pngs, "--max-pixels", "7e2"],
        "f0.png",
        "frame is 0.0 MP (32x24), more than the limit of 0.0007 MP",
        "--max-pixels 7.7e2 raises it",
    )
    capfd.readouterr()
    assert main(["info", *map(str, pngs), "--max-pixels", "7.7e2"]) == 0
    assert main(["info", *map(str, pngs), "--max-pixels", "0"]) == 0


@pytest.mark.parametrize("value", ["abc", "-1", "inf"])
def test_bad_max_pixels_is_a_one_line_usage_error(pngs, capfd, value) -> None:
    capfd.readouterr()
    with pytest.raises(SystemExit) as info:
        main(["info", *map(str, pngs), "--max-pixels", value])
    lines = capfd.readouterr().err.strip().splitlines()
    assert info.value.code == 2 and len(lines) == 1
    assert lines[0].startswith("hdrcore info: error: argument --max-pixels")


def test_missing_argument_is_a_one_line_usage_error(pngs, capfd) -> None:
    capfd.readouterr()
    with pytest.raises(SystemExit) as info:
        main(["merge", *map(str, pngs)])
    lines = capfd.readouterr().err.strip().splitlines()
    assert info.value.code == 2 and lines == [
        "hdrcore merge: error: the following arguments are required: -o/--output "
        "(see 'hdrcore merge --help')"
    ]


# --- 4. orientation ------------------------------------------------------------------------------


def test_camera_turned_mid_bracket_is_a_warning_not_a_size_error(tmp_path, capfd) -> None:
    img = gradient(24, 32)
    paths = [
        write_jpeg(
            tmp_path / f"f{k}.jpg",
            (img * s).astype(np.uint8),
            orientation=tag,
            exposure=Fraction(1, 2 ** (4 - k)),
        )
        for k, (s, tag) in enumerate([(0.3, 1), (0.6, 6), (1.0, 1)])
    ]
    capfd.readouterr()
    assert main(["info", *map(str, paths)]) == 0
    captured = capfd.readouterr()
    (line,) = captured.err.strip().splitlines()
    assert line.startswith(
        "hdrcore: warning: f1.jpg has orientation tag 6 (turned 90° clockwise), the others 1"
    )
    assert captured.out.count("32x24") == 3


def test_size_error_names_the_odd_frame(tmp_path, capfd) -> None:
    odd = write_jpeg(tmp_path / "a.jpg", gradient(24, 30))
    others = [
        write_jpeg(tmp_path / f"{n}.jpg", gradient(24, 32, 1 / k)) for k, n in ((1, "b"), (2, "c"))
    ]
    line = one_line_error(capfd, ["info", odd, *others])
    assert line.startswith(f"hdrcore: error: {odd}: frame size differs from the other frames")
    assert "expected 32x24 like b.jpg, c.jpg, found 30x24" in line


# --- 5. library chatter --------------------------------------------------------------------------


def _dng_bracket(folder: Path) -> list[Path]:
    folder.mkdir(exist_ok=True)
    cfa = np.random.default_rng(1).uniform(300, 1000, (96, 128)).astype(np.uint16)
    return [
        write_dng(folder / f"f{k}.dng", cfa * (k + 1), exposure_time=0.01 * (k + 1))
        for k in range(3)
    ]


def test_truncated_raw_is_one_line(tmp_path, capfd) -> None:
    a, b, _ = _dng_bracket(tmp_path)
    data = a.read_bytes()
    cut = tmp_path / "cut.dng"
    cut.write_bytes(data[: len(data) * 9 // 10])
    line = one_line_error(capfd, ["info", cut, b])
    assert line == (
        f"hdrcore: error: {cut}: RAW file is damaged: the file ends before its "
        "image data does (truncated)"
    )


def test_truncated_raw_in_a_separate_process(tmp_path) -> None:
    """The program as run from a shell: LibRaw's own line never reaches the terminal."""
    a, b, _ = _dng_bracket(tmp_path)
    data = a.read_bytes()
    (tmp_path / "cut.dng").write_bytes(data[: len(data) // 2])
    a.unlink()
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run(
        [sys.executable, "-m", "hdrcore.cli", "info", "cut.dng", b.name],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    assert proc.stderr.splitlines() == [
        "hdrcore: error: cut.dng: RAW file is damaged: the file ends before its image data "
        "does (truncated)"
    ]


def test_normal_raw_merge_says_nothing_but_our_lines(tmp_path, capfd) -> None:
    sim = simulate_bracket(
        scene="patches",
        shape=(64, 96),
        exposure_times=(1 / 64, 1 / 16, 1 / 4),
        bits=12,
        response="linear",
        noise_sigma=1.0,
        seed=3,
        keep_linear=True,
    )
    write_bracket(tmp_path / "br", sim, fmt="dng")
    capfd.readouterr()
    with warnings.catch_warnings():
        warnings.simplefilter("default")  # as `python -W default`: nothing filtered out first
        rc = main(
            [
                "merge",
                str(tmp_path / "br"),
                "-o",
                str(tmp_path / "o.exr"),
                "--preview",
                str(tmp_path / "o.png"),
                "--quiet",
            ]
        )
    err = capfd.readouterr().err
    assert rc == 0, err
    assert all(line.startswith("hdrcore: ") for line in err.splitlines()), err


def test_damaged_exif_is_said_once_with_the_file(tmp_path, capfd) -> None:
    paths = []
    for k in range(2):
        p = tmp_path / f"e{k}.jpg"
        exif = Image.Exif()
        exif[0x010F] = "Cam"
        Image.fromarray(gradient(48, 64, scale=1 / (k + 1))).save(p, exif=exif)
        data = bytearray(p.read_bytes())
        i = data.find(b"Exif\x00\x00")
        data[i + 10 : i + 14] = b"\xff\xff\xff\x7f"  # the first IFD's offset points past the end
        p.write_bytes(bytes(data))
        paths.append(p)
    capfd.readouterr()
    assert main(["info", *map(str, paths)]) == 0
    err = capfd.readouterr().err.splitlines()
    said = [line for line in err if "EXIF metadata is damaged" in line]
    # once per file (two files decode at a time, so in either order)
    assert sorted(line.split(": ")[2] for line in said) == [str(paths[0]), str(paths[1])]
    assert all(line.startswith("hdrcore: warning: ") for line in err)
    assert not any("UserWarning" in line or "warnings.warn" in line for line in err)


def test_tifffile_chatter_about_a_failing_file_is_not_printed(tmp_path, capfd) -> None:
    good = tmp_path / "g.tif"
    tifffile.imwrite(good, np.zeros((24, 32, 3), np.uint16))
    whole = tmp_path / "w.tif"
    tifffile.imwrite(whole, np.ones((240, 320, 3), np.uint16), description="x" * 100)
    cut = tmp_path / "cut.tif"
    cut.write_bytes(whole.read_bytes()[:200])  # tags whose values lie past the end
    one_line_error(capfd, ["info", cut, good], "cut.tif")


def test_empty_and_unreadable_frames_and_folders(tmp_path, pngs, capfd) -> None:
    empty = tmp_path / "empty.png"
    empty.write_bytes(b"")
    one_line_error(capfd, ["info", empty, pngs[0]], "empty.png", "file is empty")
    sub = tmp_path / "sub"
    sub.mkdir()
    one_line_error(capfd, ["info", sub, pngs[0]], "sub", "directory holds no")
    one_line_error(capfd, ["info", tmp_path / "gone.png", pngs[0]], "gone.png", "not found")


def test_a_lone_missing_path_is_not_found_not_a_one_frame_bracket(tmp_path, capfd) -> None:
    # a mistyped folder read "a bracket needs at least two frames (found 1 frame(s))"
    for cmd in ("merge", "ratios", "info"):
        args = [cmd, tmp_path / "no-such-folder"] + (["-o", tmp_path / "o.exr"] * (cmd == "merge"))
        line = one_line_error(capfd, args, "no-such-folder", "file or folder not found")
        assert "two frames" not in line


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root reads any file")
def test_file_we_may_not_read(tmp_path, pngs, capfd) -> None:
    pngs[1].chmod(0)
    try:
        one_line_error(capfd, ["info", *pngs], "f1.png", "permission denied")
    finally:
        pngs[1].chmod(0o644)


def test_permission_denied_as_the_system_says_it(pngs, capfd, monkeypatch) -> None:
    """The same refusal as above, for runs as root: the read fails as it would for a user."""
    import errno

    import hdrcore.io.bracket as bracket

    real = bracket.sniff_format

    def refuse(path):
        if path.name == "f1.png":
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return real(path)

    monkeypatch.setattr(bracket, "sniff_format", refuse)
    one_line_error(capfd, ["info", *pngs], "f1.png", "cannot read file: permission denied")


# --- the rewording itself ------------------------------------------------------------------------


def test_warning_words() -> None:
    from PIL.Image import DecompressionBombWarning

    pil = "/site-packages/PIL/TiffImagePlugin.py"
    assert warning_words("Image size exceeds limit", DecompressionBombWarning, pil) is None
    assert "EXIF metadata is damaged" in warning_words(
        "Possibly corrupt EXIF data.", UserWarning, pil
    )
    assert warning_words("divide by zero", RuntimeWarning, "/x/numpy/core/f.py") is None
    assert warning_words("old", DeprecationWarning, "/x/y.py") is None
    assert warning_words("something\nmore", UserWarning, "/x/y.py") == "something (UserWarning)"
    record = logging.LogRecord("tifffile", logging.ERROR, "", 0, "bad tag", None, None)
    assert log_words(record) == "its TIFF structure is damaged (tifffile: bad tag)"
    record.levelno = logging.INFO
    assert log_words(record) is None


def test_python_warnings_name_the_file_being_read(capfd) -> None:
    capfd.readouterr()
    with library_chatter():
        with reading("x.jpg"):
            warnings.warn("Possibly corrupt EXIF data.", UserWarning)  # noqa: B028
            warnings.warn("Possibly corrupt EXIF data.", UserWarning)  # noqa: B028
        warnings.warn("colour chatter", UserWarning)  # noqa: B028
        logging.getLogger("hdrcore.test").warning("our own line")
        logging.getLogger("hdrcore.test").info("not shown")
    assert capfd.readouterr().err.splitlines() == [
        "hdrcore: warning: x.jpg: Possibly corrupt EXIF data. (UserWarning)",
        "hdrcore: warning: colour chatter (UserWarning)",
        "hdrcore: warning: our own line",
    ]
