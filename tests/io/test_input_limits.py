"""Bad input at the file boundary (issue 13, point 6): symbolic-link loops, absurd exposure
times, frames larger than the pixel limit (read from the header, never decoded), and what LibRaw
prints on stderr, caught and said in plain words."""

from __future__ import annotations

import os
import struct
import threading
import warnings
import zlib
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
import tifffile
from PIL import Image

from hdrcore.errors import FrameTooLargeError, ImageReadError, InputError
from hdrcore.io import MAX_FRAME_PIXELS, frame_pixels, load_bracket, load_frame
from hdrcore.io._capture import c_stderr
from hdrcore.io.times import parse_seconds, read_exposure_times
from hdrcore.synthetic.dng import write_dng

from ._images import gradient, write_jpeg


def huge_png(path: Path, width: int, height: int) -> Path:
    """A PNG of a few dozen bytes whose header declares ``width x height`` (its data is cut
    short: anything that decodes it fails, anything that allocates it allocates gigabytes)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data))
            + kind
            + data
            + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
        )

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", ihdr)
        + chunk(b"IDAT", zlib.compress(b"\0" * (1 + 3 * 64)))
        + chunk(b"IEND", b"")
    )
    return path


def _loop(tmp_path: Path, name: str) -> Path:
    a, b = tmp_path / name, tmp_path / f"{name}-back"
    a.symlink_to(b.name)
    b.symlink_to(a.name)
    return a


def _pngs(folder: Path, n: int = 2) -> list[Path]:
    folder.mkdir(exist_ok=True)
    return [
        write_jpeg(folder / f"f{k}.png", gradient(24, 32, scale=1.0 / (k + 1)), fmt="PNG")
        for k in range(n)
    ]


# --- symbolic links ------------------------------------------------------------------------------


def test_symlink_loop_as_a_frame(tmp_path: Path) -> None:
    a, b = _pngs(tmp_path)
    loop = _loop(tmp_path, "loop.png")
    with pytest.raises(InputError, match=r"loop\.png: symbolic link loop"):
        load_bracket([loop, a])
    with pytest.raises(InputError, match=r"loop\.png: symbolic link loop"):
        load_frame(loop)


def test_folder_holding_a_symlink_loop(tmp_path: Path) -> None:
    folder = tmp_path / "br"
    _pngs(folder)
    _loop(folder, "x.png")
    with pytest.raises(InputError, match=r"br/x\.png: symbolic link loop"):
        load_bracket([folder])


def test_folder_holding_a_broken_link_and_a_subfolder(tmp_path: Path) -> None:
    folder = tmp_path / "br"
    _pngs(folder)
    (folder / "sub.png").mkdir()  # a folder named like an image is not a frame: left out
    assert len(load_bracket([folder])) == 2
    (folder / "gone.png").symlink_to("nowhere.png")
    with pytest.raises(
        InputError,
        match=r"gone\.png: broken symbolic link \(it points to "
        r"nowhere\.png",
    ):
        load_bracket([folder])


def test_times_file_that_is_a_symlink_loop(tmp_path: Path) -> None:
    frames = _pngs(tmp_path)
    loop = _loop(tmp_path, "times.txt")
    with pytest.raises(InputError, match=r"times\.txt: exposure-times file: symbolic link loop"):
        load_bracket(frames, exposure_times=loop)


# --- exposure times ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("value", "why"),
    [
        ("1e400", "longer than 1e5 s"),
        ("inf", "not a number"),
        ("nan", "not a number"),
        ("1e-400", "shorter than 1e-7 s"),
        ("-1", "zero or negative"),
        ("0", "zero or negative"),
        ("2e5", "longer than 1e5 s"),
        ("1/0", "not a number"),
    ],
)
def test_times_out_of_range_are_refused(tmp_path: Path, value: str, why: str) -> None:
    t = tmp_path / "times.txt"
    t.write_text(f"# frames\nf0.png 1/8\nf1.png {value}\n")
    pattern = rf"times\.txt: line 3: bad exposure time, {why}.*found '{value}'"
    with pytest.raises(InputError, match=pattern):
        read_exposure_times(t)
    with pytest.raises(ValueError, match=why):
        parse_seconds(value)


def test_times_at_the_ends_of_the_range_are_kept(tmp_path: Path) -> None:
    assert parse_seconds("1e-7") == Fraction(1, 10_000_000)
    assert parse_seconds("100000") == 100_000
    assert parse_seconds("1/32000") == Fraction(1, 32000)


def test_times_given_as_a_mapping_are_checked(tmp_path: Path) -> None:
    frames = _pngs(tmp_path)
    with pytest.raises(InputError, match=r"bad exposure time for f1\.png, longer than 1e5 s"):
        load_bracket(frames, exposure_times={"f0.png": 0.1, "f1.png": 1e300})
    with pytest.raises(InputError, match=r"f0\.png, not a number"):
        load_bracket(frames, exposure_times={"f0.png": float("nan"), "f1.png": 0.1})


def test_times_file_that_is_not_utf8(tmp_path: Path) -> None:
    t = tmp_path / "times.txt"
    t.write_bytes(b"f0.png 1/8\nf1.png 1/\xff\n")
    with pytest.raises(InputError, match=r"times\.txt: line 2 is not UTF-8 text.*byte 0xff"):
        read_exposure_times(t)


# --- the pixel limit -----------------------------------------------------------------------------


def test_frame_pixels_reads_every_format_from_its_header(tmp_path: Path) -> None:
    img = gradient(24, 32)
    png = write_jpeg(tmp_path / "a.png", img, fmt="PNG")
    jpg = write_jpeg(tmp_path / "a.jpg", img, orientation=6, make="Cam", model="X")
    prog = tmp_path / "p.jpg"
    Image.fromarray(img).save(prog, "JPEG", progressive=True)
    tif = tmp_path / "a.tif"
    tifffile.imwrite(tif, np.zeros((24, 32, 3), np.uint16))
    planar = tmp_path / "planar.tif"
    tifffile.imwrite(
        planar, np.zeros((3, 24, 32), np.uint16), planarconfig="separate", photometric="rgb"
    )
    dng = write_dng(tmp_path / "a.dng", np.full((24, 32), 1000, np.uint16), exposure_time=0.01)
    for p in (png, jpg, prog, tif, planar, dng):
        assert frame_pixels(p) == (32, 24), p.name  # as stored: the JPEG's tag 6 is not applied
    assert frame_pixels(huge_png(tmp_path / "big.png", 20000, 10000)) == (20000, 10000)


def test_frame_pixels_bad_input(tmp_path: Path) -> None:
    (tmp_path / "notes.png").write_text("not a picture")
    with pytest.raises(ImageReadError, match=r"notes\.png: not a recognised image"):
        frame_pixels(tmp_path / "notes.png")
    (tmp_path / "cut.jpg").write_bytes(b"\xff\xd8\xff\xe0\x00\x10JFIF")
    with pytest.raises(ImageReadError, match=r"cut\.jpg: JPEG header is damaged"):
        frame_pixels(tmp_path / "cut.jpg")
    with pytest.raises(InputError, match=r"gone\.png: file not found"):
        frame_pixels(tmp_path / "gone.png")


def test_huge_png_is_refused_from_its_header(tmp_path: Path) -> None:
    big = huge_png(tmp_path / "big.png", 20000, 10000)
    (small,) = _pngs(tmp_path / "s", 1)
    with pytest.raises(
        FrameTooLargeError,
        match=r"big\.png: frame is 200\.0 MP \(20000x10000\), more than the limit "
        r"of 160 MP$",
    ) as info:
        load_bracket([small, big])
    assert (info.value.width, info.value.height, info.value.limit) == (20000, 10000, 160_000_000)
    assert MAX_FRAME_PIXELS == 160_000_000


@pytest.mark.parametrize("fmt", ["png", "jpg", "tif", "dng"])
def test_max_pixels_applies_to_every_reader(tmp_path: Path, fmt: str) -> None:
    if fmt == "tif":
        p = tmp_path / "a.tif"
        tifffile.imwrite(p, np.zeros((24, 32, 3), np.uint8))
    elif fmt == "dng":
        p = write_dng(tmp_path / "a.dng", np.full((24, 32), 1000, np.uint16), exposure_time=0.01)
    else:
        p = write_jpeg(
            tmp_path / f"a.{fmt}", gradient(24, 32), fmt="PNG" if fmt == "png" else "JPEG"
        )
    with pytest.raises(
        FrameTooLargeError,
        match=r"frame is 0\.0 MP \(32x24\), more than the "
        r"limit of 0\.0007 MP",
    ):
        load_frame(p, max_pixels=700)
    assert load_frame(p, max_pixels=768).shape == (24, 32)
    assert load_frame(p, max_pixels=0).shape == (24, 32)


def test_pillow_limit_never_fires_before_ours(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 100)  # Pillow would warn at 100, fail at 200
    (p,) = _pngs(tmp_path, 1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load_frame(p).shape == (24, 32)
    assert Image.MAX_IMAGE_PIXELS == MAX_FRAME_PIXELS
    load_frame(p, max_pixels=0)
    assert Image.MAX_IMAGE_PIXELS is None


# --- orientation ---------------------------------------------------------------------------------


def _write(path: Path, rgb: np.ndarray, orientation: int | None, exposure: Fraction) -> Path:
    if path.suffix == ".tif":
        extratags = [] if orientation is None else [(274, "H", 1, orientation, True)]
        tifffile.imwrite(path, rgb, photometric="rgb", extratags=extratags)
        return path
    fmt = "PNG" if path.suffix == ".png" else "JPEG"
    return write_jpeg(path, rgb, orientation=orientation, exposure=exposure, fmt=fmt)


@pytest.mark.parametrize("ext", [".jpg", ".png", ".tif"])
def test_camera_turned_mid_bracket_gets_one_orientation(tmp_path: Path, ext: str) -> None:
    """The pixels are stored alike (32x24); one frame's tag says 6: all are shown as stored."""
    img = gradient(24, 32)
    paths = [
        _write(tmp_path / f"f{k}{ext}", (img * s).astype(np.uint8), tag, Fraction(1, 2**k))
        for k, (s, tag) in enumerate([(0.3, 1), (0.6, 6), (1.0, 1)])
    ]
    b = load_bracket(paths)
    assert b.shape == (24, 32)
    assert [f.meta.orientation for f in b.frames] == [1, 1, 1]
    (w,) = [w for w in b.warnings if w.code == "orientation-differs"]
    assert "f1" in w.message and "tag 6" in w.message and "f0" not in w.message
    assert [b.frames[k].name for k in w.frames] == [f"f1{ext}"]


def test_orientation_tie_goes_to_the_first_frame(tmp_path: Path) -> None:
    img = gradient(24, 32)
    a = _write(tmp_path / "a.png", img, 8, Fraction(1, 4))
    b = _write(tmp_path / "b.png", img // 3, None, Fraction(1, 16))
    br = load_bracket([a, b])
    assert br.shape == (32, 24)  # a's tag 8 turns both
    np.testing.assert_array_equal(br.frames[1].levels[..., 0], np.rot90(img)[..., 0])
    (w,) = [w for w in br.warnings if w.code == "orientation-differs"]
    assert w.message.startswith("b.png has orientation tag 1")


def test_raw_frames_with_different_flips_get_one_orientation(tmp_path: Path) -> None:
    cfa = np.random.default_rng(0).uniform(300, 3000, (32, 48)).astype(np.uint16)
    paths = [
        write_dng(
            tmp_path / f"f{k}.dng", cfa // (3 - k), exposure_time=2.0**k / 100, orientation=tag
        )
        for k, tag in enumerate([6, 1, 6])
    ]
    b = load_bracket(paths)
    assert b.shape == (48, 32) and {f.meta.orientation for f in b.frames} == {6}
    assert (
        "f1.dng has orientation tag 1"
        in b.warnings[b.warning_codes().index("orientation-differs")].message
    )
    alone = load_frame(paths[1])
    assert alone.shape == (32, 48) and alone.meta.orientation == 1


def test_size_error_names_the_odd_frame(tmp_path: Path) -> None:
    odd = write_jpeg(tmp_path / "a_odd.png", gradient(24, 30), fmt="PNG")
    b = write_jpeg(tmp_path / "b.png", gradient(24, 32), fmt="PNG")
    c = write_jpeg(tmp_path / "c.png", gradient(24, 32) // 2, fmt="PNG")
    with pytest.raises(
        Exception,
        match=r"a_odd\.png: frame size differs from the other frames "
        r"\(expected 32x24 like b\.png, c\.png, found 30x24\)",
    ):
        load_bracket([odd, b, c])


def test_size_error_of_a_frame_turned_by_90_degrees_says_so(tmp_path: Path) -> None:
    a = write_jpeg(tmp_path / "a.png", gradient(24, 32), fmt="PNG")
    b = write_jpeg(tmp_path / "b.png", gradient(24, 32) // 2, fmt="PNG")
    c = write_jpeg(tmp_path / "c.png", gradient(32, 24), fmt="PNG")
    with pytest.raises(
        Exception,
        match=r"c\.png: frame size differs from the other frames \(the same size turned by 90 "
        r"degrees: a frame rotated in an editor\?\) \(expected 32x24 like a\.png, b\.png, "
        r"found 24x32\)",
    ):
        load_bracket([a, b, c])


def test_a_raw_frame_among_pngs_is_named_for_its_kind_before_its_size(tmp_path: Path) -> None:
    """A RAW file among JPEG/PNG frames differs in size as well: the error says it is RAW."""
    a = write_jpeg(tmp_path / "a.png", gradient(24, 32), fmt="PNG")
    b = write_jpeg(tmp_path / "b.png", gradient(24, 32) // 2, fmt="PNG")
    raw = _dng(tmp_path / "c.dng")
    with pytest.raises(
        Exception,
        match=r"c\.dng: cannot mix RAW and non-linear \(JPEG/PNG/TIFF\) frames in one bracket",
    ):
        load_bracket([a, b, raw])


def test_size_error_after_orientation_says_so(tmp_path: Path) -> None:
    """Stored sizes differ (no common orientation), and the tag turns one frame across."""
    a = write_jpeg(tmp_path / "a.png", gradient(24, 32), fmt="PNG")
    b = write_jpeg(tmp_path / "b.png", gradient(24, 32) // 2, fmt="PNG")
    c = write_jpeg(tmp_path / "c.png", gradient(24, 30), orientation=6, fmt="PNG")
    with pytest.raises(
        Exception,
        match=r"c\.png: frame size differs from the other frames once "
        r"turned by its orientation tag 6",
    ):
        load_bracket([a, b, c])


# --- LibRaw on stderr ----------------------------------------------------------------------------


def _dng(path: Path, exposure: float = 0.01) -> Path:
    cfa = np.random.default_rng(1).uniform(300, 3000, (128, 192)).astype(np.uint16)
    return write_dng(path, cfa, exposure_time=exposure)


def test_truncated_dng_is_one_error_and_nothing_on_stderr(tmp_path: Path, capfd) -> None:
    full = _dng(tmp_path / "full.dng").read_bytes()
    cut = tmp_path / "cut.dng"
    cut.write_bytes(full[: len(full) * 9 // 10])
    capfd.readouterr()
    with pytest.raises(
        ImageReadError,
        match=r"cut\.dng: RAW file is damaged: the file ends "
        r"before its image data does \(truncated\)$",
    ):
        load_frame(cut)
    assert capfd.readouterr().err == ""


def test_libraw_output_of_a_decoded_file_becomes_a_warning(
    tmp_path: Path, monkeypatch, capfd
) -> None:
    import rawpy

    a, b = _dng(tmp_path / "a.dng", 0.01), _dng(tmp_path / "b.dng", 0.04)
    real = rawpy.imread

    def chatty(path, *args, **kwargs):
        if path.endswith("b.dng"):
            os.write(2, f"{path}: data corrupted at 1234\n".encode())
        return real(path, *args, **kwargs)

    monkeypatch.setattr(rawpy, "imread", chatty)
    capfd.readouterr()
    br = load_bracket([a, b])
    assert capfd.readouterr().err == ""
    assert br.frames[1].meta.decoder_messages == ("its image data is corrupt (from byte 1234)",)
    (w,) = [w for w in br.warnings if w.code == "decoder-messages"]
    assert w.message.startswith("b.dng: its image data is corrupt") and w.frames == (1,)


def test_stderr_capture_is_shared_by_threads_and_passes_other_lines_on(capfd) -> None:
    capfd.readouterr()
    got: dict[str, list[str]] = {}
    started = threading.Barrier(2)

    def read(name: str) -> None:
        with c_stderr(name) as said:
            started.wait()
            os.write(2, f"{name}: Unexpected end of file\n".encode())
            started.wait()
        got[name] = said

    threads = [threading.Thread(target=read, args=(n,)) for n in ("x.dng", "xy.dng")]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    with c_stderr("z.dng"):
        os.write(2, b"someone else's line\n")
    assert got == {"x.dng": ["Unexpected end of file"], "xy.dng": ["Unexpected end of file"]}
    assert capfd.readouterr().err == "someone else's line\n"
