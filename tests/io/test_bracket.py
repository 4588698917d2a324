"""Brackets: ordering, exposure-times files, capture warnings, bad brackets, real data sets."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from hdrcore.errors import BracketError, InputError
from hdrcore.io import load_bracket, read_exposure_times

from ._images import gradient, write_jpeg


def _frames(tmp_path: Path, times, **exif) -> list[Path]:
    paths = []
    for k, t in enumerate(times):
        scale = 0.3 * (k + 1)
        extra = {key: (v[k] if isinstance(v, list) else v) for key, v in exif.items()}
        paths.append(
            write_jpeg(tmp_path / f"f{k}.jpg", gradient(scale=scale, seed=k), exposure=t, **extra)
        )
    return paths


def test_sorted_darkest_first_by_exposure_time(tmp_path: Path) -> None:
    paths = _frames(tmp_path, [Fraction(1, 100), Fraction(1, 25), Fraction(1, 6)])
    b = load_bracket([paths[2], paths[0], paths[1]])
    assert [Path(p).name for p in b.paths] == ["f0.jpg", "f1.jpg", "f2.jpg"]
    assert b.order_source == "exposure"
    assert b.input_order == (1, 2, 0)
    assert "input-unsorted" in b.warning_codes()
    assert b.exif_ratio(0, 1) == pytest.approx(4.0)


def test_sorted_by_brightness_without_exif(tmp_path: Path) -> None:
    paths = _frames(tmp_path, [None, None, None])
    b = load_bracket(paths[::-1])
    assert [Path(p).name for p in b.paths] == ["f0.jpg", "f1.jpg", "f2.jpg"]
    assert b.order_source == "brightness"
    assert "no-exposure-times" in b.warning_codes()
    assert b.exposure_times == (None, None, None)
    assert b.exif_ratio(0, 1) is None


def test_capture_mistakes_are_warnings(tmp_path: Path) -> None:
    paths = _frames(
        tmp_path,
        [Fraction(1, 100), Fraction(1, 25), Fraction(1, 25)],
        f_number=[8.0, 8.0, 5.6],
        iso=[100, 200, 100],
        make="A",
        model=["X", "X", "Y"],
    )
    b = load_bracket(paths)
    codes = b.warning_codes()
    assert "aperture-changed" in codes
    assert "iso-changed" in codes
    assert "mixed-cameras" in codes
    # The EXIF exposure accounts for ISO and aperture (1/100 -> 1/25 s is exactly 2 stops on
    # the 1/3-stop APEX sequence, ISO 100 -> 200 one more).
    assert b.exif_ratio(0, 1) == pytest.approx(8.0)
    # f1 (1/25 s, ISO 200, f/8) and f2 (1/25 s, ISO 100, f/5.6 = 2^(5/2)) have the same full
    # exposure: a duplicate (a warning, not an error).
    dup = [w for w in b.warnings if w.code == "duplicate-exposure"]
    assert len(dup) == 1 and dup[0].frames == (1, 2)
    assert b.exif_ratio(1, 2) == pytest.approx(1.0)
    assert b.exif_ratio(1, 2, snapped=False) == pytest.approx((8 / 5.6) ** 2 / 2)
    iso = next(w for w in b.warnings if w.code == "iso-changed")
    assert "f0.jpg ISO 100, f1.jpg ISO 200, f2.jpg ISO 100" in iso.message
    assert "time x ISO / ISO_0, so it includes the ISO change" in iso.message
    ap = next(w for w in b.warnings if w.code == "aperture-changed")
    assert "includes the aperture change" in ap.message


def test_duplicate_exposure_warning(tmp_path: Path) -> None:
    paths = _frames(tmp_path, [Fraction(1, 100), Fraction(1, 100), Fraction(1, 10)])
    b = load_bracket(paths)
    dup = [w for w in b.warnings if w.code == "duplicate-exposure"]
    assert dup and "f0.jpg" in dup[0].message and "f1.jpg" in dup[0].message


def test_out_of_order_warning_when_brightness_contradicts_times(tmp_path: Path) -> None:
    # f2 is the brightest image but claims the shortest exposure.
    paths = _frames(tmp_path, [Fraction(1, 50), Fraction(1, 10), Fraction(1, 500)])
    b = load_bracket(paths)
    assert "out-of-order" in b.warning_codes()


def test_times_file_overrides_and_matches_by_name(tmp_path: Path) -> None:
    paths = _frames(tmp_path, [None, None, None])
    tf = tmp_path / "times.txt"
    tf.write_text("# name seconds\nf0.jpg 1/3049\nf1.jpg 0.5  # half\nf2.jpg 2\n")
    b = load_bracket(paths, exposure_times=tf)
    assert b.frames[0].meta.exposure_time == Fraction(1, 3049)
    assert b.frames[0].meta.exposure_time_source == "times-file"
    assert b.exposure_times[1:] == (0.5, 2.0)


def test_times_file_errors(tmp_path: Path) -> None:
    paths = _frames(tmp_path, [None, None])
    bad = tmp_path / "bad.txt"
    bad.write_text("f0.jpg 1 extra\n")
    with pytest.raises(InputError, match=r"bad\.txt: line 1 is not 'name seconds'"):
        read_exposure_times(bad)
    neg = tmp_path / "neg.txt"
    neg.write_text("f0.jpg -1\n")
    with pytest.raises(InputError, match=r"neg\.txt: line 1: bad exposure time"):
        read_exposure_times(neg)
    partial = tmp_path / "partial.txt"
    partial.write_text("f0.jpg 1\n")
    with pytest.raises(InputError, match=r"does not name every frame.*f1\.jpg"):
        load_bracket(paths, exposure_times=partial)
    with pytest.raises(InputError, match="exposure-times file not found"):
        load_bracket(paths, exposure_times=tmp_path / "none.txt")


def test_single_frame_is_an_error(tmp_path: Path) -> None:
    (p,) = _frames(tmp_path, [Fraction(1, 10)])
    with pytest.raises(BracketError, match=r"f0\.jpg: a bracket needs at least two frames"):
        load_bracket([p])
    # a single file that is no image says so (it said "needs at least two frames")
    notes = tmp_path / "notes.txt"
    notes.write_text("a list of shots")
    with pytest.raises(InputError, match=r"notes\.txt: not a recognised image"):
        load_bracket([notes])


def test_different_sizes_is_an_error(tmp_path: Path) -> None:
    a = write_jpeg(tmp_path / "a.jpg", gradient(24, 32))
    b = write_jpeg(tmp_path / "b.jpg", gradient(24, 30))
    with pytest.raises(BracketError, match=r"b\.jpg: frame size differs.*expected 32x24.*30x24"):
        load_bracket([a, b])


def test_rotated_frame_with_orientation_tag_matches(tmp_path: Path) -> None:
    img = gradient(24, 32)
    a = write_jpeg(tmp_path / "a.png", img, fmt="PNG")
    stored = np.ascontiguousarray(np.rot90(img, 1))  # camera stored it turned; tag 6 turns it back
    b = write_jpeg(tmp_path / "b.png", stored, orientation=6, fmt="PNG")
    br = load_bracket([a, b])
    assert br.shape == (24, 32)


def test_mixed_raw_and_jpeg_is_an_error(tmp_path: Path, crw_dir: Path) -> None:
    raw = crw_dir / "S40_CRW_0101.CRW"
    j = write_jpeg(tmp_path / "a.jpg", gradient(24, 32))
    with pytest.raises(BracketError):
        load_bracket([raw, j])


def test_same_file_twice(tmp_path: Path) -> None:
    (p,) = _frames(tmp_path, [Fraction(1, 10)])
    with pytest.raises(BracketError, match="the same file is given twice"):
        load_bracket([p, p])


def test_directory_expansion_and_empty_directory(tmp_path: Path) -> None:
    _frames(tmp_path, [Fraction(1, 10), Fraction(1, 40)])
    (tmp_path / "readme.txt").write_text("x")
    b = load_bracket([tmp_path])
    assert len(b) == 2
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match="directory holds no"):
        load_bracket([empty])


# --- real photographs ---------------------------------------------------------------------------


@pytest.mark.shared
def test_memorial_debevec(memorial_dir: Path) -> None:
    b = load_bracket([memorial_dir], exposure_times=memorial_dir / "exposure_times.txt")
    assert len(b) == 16
    assert b.shape == (768, 512)
    assert b.frames[0].meta.exposure_time == Fraction(1, 1024)
    assert b.frames[-1].meta.exposure_time == Fraction(32)
    assert Path(b.frames[0].path).name == "memorial0076.png"
    assert all(b.exif_ratio(k, k + 1) == pytest.approx(2.0) for k in range(15))
    assert b.bit_depth == 8 and not b.is_linear
    # The darkest scans (fog and scanner noise, 1 stop apart) are not brighter with time, but
    # they carry no brightness information, so the order by time stands.
    assert not {"out-of-order", "times-swapped"} & set(b.warning_codes())
    assert b.order_source == "exposure"


@pytest.mark.shared
def test_frobisher_exif(frobisher_dir: Path) -> None:
    b = load_bracket([frobisher_dir])
    assert [f.meta.exposure_time for f in b.frames] == [Fraction(1, 8), Fraction(1), Fraction(8)]
    assert all(f.meta.exposure_time_source == "exif" for f in b.frames)
    assert all(f.meta.f_number == 8 and f.meta.iso == 100 for f in b.frames)
    assert b.frames[0].meta.model == "EOS 5D Mark II"
    assert b.shape == (426, 640)
    assert b.warnings == ()


@pytest.mark.shared
@pytest.mark.parametrize("name", ["S40_CRW_0101.CRW", "G2_CRW_0304.CRW"])
def test_canon_crw_levels(crw_dir: Path, name: str) -> None:
    from hdrcore.io import load_frame

    f = load_frame(crw_dir / name)
    assert f.is_linear and f.meta.format == "raw"
    assert f.meta.white_level == 1023
    assert f.meta.black_level == (32.0, 32.0, 32.0)
    assert f.max_level == 1023 - 32
    assert f.bit_depth == 10
    assert f.cfa is not None and f.cfa.data.shape == (1720, 2312)
    assert f.cfa.black_level == (32.0, 32.0, 32.0, 32.0)
    assert f.meta.cfa_pattern == ((0, 1), (3, 2)) and f.meta.cfa_colors == "RGBG"
    assert f.levels.shape == (1720, 2312, 3)
    # Black is subtracted: levels are raw minus 32 and never exceed the white level.
    assert int(f.levels.max()) == int(f.cfa.data.max()) - 32
    lin = f.linear()
    assert lin.dtype == np.float32 and 0.0 <= lin.min() and lin.max() <= 1.0
    # The green plane from the CFA agrees with the demosaiced green on average.
    g = f.cfa.plane("G")
    assert g.mean() == pytest.approx(f.levels[..., 1].mean(), rel=0.02)
    assert f.meta.iso == 50
    assert f.meta.exposure_time is not None and f.meta.exposure_time_source == "libraw"


def test_frames_taken_far_apart_are_said_not_to_look_like_one_bracket() -> None:
    from datetime import datetime, timedelta
    from types import SimpleNamespace

    from hdrcore.io.bracket import CAPTURE_SPAN_S, _capture_span

    t0 = datetime(2024, 4, 1, 18, 50, 43)

    def frames(*offsets):
        return [
            SimpleNamespace(name=f"f{k}.jpg", meta=SimpleNamespace(capture_time=t0 + dt))
            for k, dt in enumerate(offsets)
        ]

    # a bracket of long exposures: minutes, no warning
    assert _capture_span(frames(timedelta(0), timedelta(minutes=5))) is None
    assert _capture_span(frames(timedelta(0))) is None
    w = _capture_span(frames(timedelta(days=287), timedelta(0), timedelta(seconds=2)))
    assert w is not None and w.code == "capture-span" and "287 days apart" in w.message
    assert "f1.jpg 2024-04-01 18:50:43" in w.message and w.frames == (0, 1, 2)
    w = _capture_span(frames(timedelta(0), timedelta(seconds=CAPTURE_SPAN_S + 60)))
    assert w is not None and "61 minutes" in w.message


def test_the_real_crw_files_are_not_one_bracket(crw_dir) -> None:
    from hdrcore.io import load_bracket

    codes = [w.code for w in load_bracket([crw_dir]).warnings]
    assert "capture-span" in codes


def test_the_real_brackets_have_no_capture_span_warning() -> None:
    from hdrcore.io import load_bracket

    from ..conftest import shared_dir

    for name in ("frobisher-colour-hdri", "handheld-pixel7-lab", "handheld-xperia-library"):
        codes = [w.code for w in load_bracket([shared_dir(name)]).warnings]
        assert "capture-span" not in codes, name
