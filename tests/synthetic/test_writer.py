"""write_bracket: every format loads back through hdrcore.io with exact exposure times.

Ground truth is the SimulatedBracket itself: PNG/TIFF levels come back exactly (8-bit) or through
the documented 16-bit mapping; DNG levels come back as the linear frames times the raw max level
within quantisation (noise off); truth.json and exposure_times.txt agree with the simulation.
"""

from __future__ import annotations

import json
from fractions import Fraction
from pathlib import Path

import exifread
import numpy as np
import pytest
import rawpy

from hdrcore.errors import OutputError, ParameterError
from hdrcore.io import load_bracket, read_exif, read_exposure_times
from hdrcore.synthetic import mosaic, simulate_bracket, write_bracket
from hdrcore.synthetic.writer import frame_file_levels

SHAPE = (48, 72)
TIMES = (1 / 3049, 4 / 3049, 16 / 3049)
EXACT = (Fraction(1, 3049), Fraction(4, 3049), Fraction(16, 3049))


def _sim(bits: int = 8, **kw) -> object:
    args = dict(shape=SHAPE, exposure_times=TIMES, bits=bits, noise_sigma=0, seed=2)
    args.update(kw)
    return simulate_bracket(**args)


@pytest.mark.parametrize("fmt", ["png", "tiff", "jpeg"])
def test_8bit_formats_load_back_with_exact_times(tmp_path: Path, fmt: str) -> None:
    sim = _sim(8)
    w = write_bracket(tmp_path, sim, fmt)
    b = load_bracket([str(p) for p in w.frames])
    assert [f.meta.exposure_time for f in b.frames] == list(EXACT)
    assert all(f.meta.exposure_time_source == "exif" for f in b.frames)
    assert b.warnings == ()
    for f, lv in zip(b.frames, sim.frames, strict=True):
        assert f.max_level == 255 and f.meta.make == "hdrview" and f.meta.model == "simulator"
        if fmt == "jpeg":
            # Lossy, but quality 95 without chroma subsampling stays close on average.
            assert np.abs(f.levels.astype(float) - lv).mean() < 3.0
        else:
            np.testing.assert_array_equal(f.levels, lv)


@pytest.mark.parametrize("fmt", ["png", "tiff"])
def test_16bit_scaled_levels_map_back_to_native(tmp_path: Path, fmt: str) -> None:
    sim = _sim(12)
    w = write_bracket(tmp_path, sim, fmt)
    assert w.file_max_level == 65535
    b = load_bracket([str(p) for p in w.frames])
    for f, lv in zip(b.frames, sim.frames, strict=True):
        assert f.max_level == 65535
        np.testing.assert_array_equal(np.rint(f.levels * (4095 / 65535)), lv)
        assert int(f.levels.max()) == 65535  # saturation stays at the top of the range
    truth = json.loads(w.truth.read_text())
    assert truth["file_levels"] == "round(level * 65535 / 4095)"


def test_16bit_keep_stores_native_levels(tmp_path: Path) -> None:
    sim = _sim(14)
    w = write_bracket(tmp_path, sim, "png", sixteen_bit="keep")
    assert w.file_max_level == 16383
    b = load_bracket([str(p) for p in w.frames])
    for f, lv in zip(b.frames, sim.frames, strict=True):
        np.testing.assert_array_equal(f.levels, lv)


def test_dng_bracket_loads_as_linear_raw(tmp_path: Path) -> None:
    sim = _sim(12, keep_linear=True)
    w = write_bracket(tmp_path, sim, "dng")
    assert [p.name for p in w.frames] == ["frame00.dng", "frame01.dng", "frame02.dng"]
    b = load_bracket([str(p) for p in w.frames])
    assert b.is_linear and b.max_level == 3839
    assert [f.meta.exposure_time for f in b.frames] == list(EXACT)
    for f, lin in zip(b.frames, sim.linear_frames, strict=True):
        assert f.meta.black_level == (256.0, 256.0, 256.0) and f.meta.white_level == 4095
        cfa = f.cfa
        assert cfa is not None
        site_values = (cfa.data.astype(float) - 256) / 3839
        assert np.abs(site_values - mosaic(lin, "RGGB")).max() <= 0.5 / 3839 + 1e-6
    truth = json.loads(w.truth.read_text())
    assert truth["raw"]["black_level"] == [256] * 4 and truth["raw"]["white_level"] == 4095
    assert truth["file_max_level"] == 3839 and truth["format"] == "dng"


def test_dng_noise_follows_the_simulation_parameters(tmp_path: Path) -> None:
    sim = _sim(14, keep_linear=True, noise_sigma=6.0, scene="patches")
    w = write_bracket(tmp_path, sim, "dng")
    clean = write_bracket(tmp_path / "clean", _sim(14, keep_linear=True, scene="patches"), "dng")
    with rawpy.imread(str(w.frames[0])) as a, rawpy.imread(str(clean.frames[0])) as c:
        d = a.raw_image_visible.astype(float) - c.raw_image_visible.astype(float)
        mid = (c.raw_image_visible > 1100) & (c.raw_image_visible < 16000)
    assert d[mid].std() == pytest.approx(6.0, rel=0.1)


def test_truth_and_times_files(tmp_path: Path) -> None:
    sim = _sim(8, max_shift=3, max_rotation_deg=0.5)
    w = write_bracket(tmp_path, sim, "png")
    times = read_exposure_times(w.times_file)
    assert times == {"frame00.png": EXACT[0], "frame01.png": EXACT[1], "frame02.png": EXACT[2]}
    truth = json.loads(w.truth.read_text())
    assert truth["ratios"] == pytest.approx([4.0, 4.0])
    assert [f["file"] for f in truth["frames"]] == ["frame00.png", "frame01.png", "frame02.png"]
    assert [f["exposure_time_exact"] for f in truth["frames"]] == ["1/3049", "4/3049", "16/3049"]
    np.testing.assert_allclose(truth["pairs"][1]["matrix"], sim.pair_matrix(1, 2))
    np.testing.assert_allclose(truth["frames"][0]["to_reference"], sim.to_reference[0])
    assert truth["exposure_times_file"] == "exposure_times.txt"
    # The same times as a times-file override give the same bracket.
    b = load_bracket([str(p) for p in w.frames], exposure_times=w.times_file)
    assert [f.meta.exposure_time for f in b.frames] == list(EXACT)


def test_exif_is_in_the_exif_ifd(tmp_path: Path) -> None:
    w = write_bracket(tmp_path, _sim(8), "tiff")
    with open(w.frames[0], "rb") as fh:
        tags = exifread.process_file(fh, details=False)
    t = tags["EXIF ExposureTime"].values[0]
    assert (t.num, t.den) == (1, 3049)
    assert read_exif(w.frames[1]).exposure_time == Fraction(4, 3049)


def test_existing_output_is_refused_unless_force(tmp_path: Path) -> None:
    sim = _sim(8)
    w = write_bracket(tmp_path, sim, "png")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    with pytest.raises(OutputError, match=r"frame00\.png: output exists; use --force"):
        write_bracket(tmp_path, _sim(8, seed=5), "png")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    # Only truth.json in the way: refused before any frame is written.
    for p in (*w.frames, w.times_file):
        p.unlink()
    with pytest.raises(OutputError, match=r"truth\.json: output exists"):
        write_bracket(tmp_path, sim, "png")
    assert [p.name for p in tmp_path.iterdir()] == ["truth.json"]
    write_bracket(tmp_path, _sim(8, seed=5), "png", force=True)
    assert w.frames[1].read_bytes() != before["frame01.png"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp files left


def test_outdir_is_created_but_must_not_be_a_file(tmp_path: Path) -> None:
    w = write_bracket(tmp_path / "a" / "b", _sim(8), "png")
    assert w.directory.is_dir() and len(w.frames) == 3
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputError, match=r"file: output directory is a file"):
        write_bracket(tmp_path / "file", _sim(8), "png")


@pytest.mark.parametrize(
    ("sim_kw", "fmt", "message"),
    [
        (dict(bits=8), "gif", r"unknown output format 'gif'.*png, tiff, jpeg, dng"),
        (dict(bits=12), "jpeg", r"JPEG holds 8-bit frames only.*found 12-bit"),
        (dict(bits=12, response="gamma", keep_linear=True), "dng", r"linear response"),
        (dict(bits=12), "dng", r"needs the linear sensor values.*keep_linear=True"),
    ],
)
def test_bad_writer_input(tmp_path: Path, sim_kw: dict, fmt: str, message: str) -> None:
    with pytest.raises(ParameterError, match=message):
        write_bracket(tmp_path, _sim(**sim_kw), fmt)
    assert list(tmp_path.iterdir()) == []


def test_frame_file_levels_bad_mapping() -> None:
    with pytest.raises(ParameterError, match=r"unknown 16-bit mapping.*'scale' or 'keep'"):
        frame_file_levels(np.zeros((2, 2, 3), np.uint16), 12, "png", "shift")
