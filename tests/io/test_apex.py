"""APEX snapping of nominal EXIF times and f-numbers (hdrcore.io.apex) and its use on frames.

Reference values: the APEX system (ASA PH2.5-1960) puts shutter speeds at ``2^-Tv`` and
f-numbers at ``2^(Av/2)`` with ``Tv``, ``Av`` on a 1/3- or 1/2-stop grid; the nominal values are
the dial markings cameras write into EXIF (Canon, Nikon and Sony manuals list the same tables).
"""

from __future__ import annotations

import json
import math
from fractions import Fraction
from pathlib import Path

import pytest

from hdrcore.io import load_bracket, load_frame
from hdrcore.io.apex import (
    HALF_STOP,
    SEQUENCES,
    THIRD_STOP,
    bracket_sequence,
    nominal_exposure_times,
    nominal_f_numbers,
    snap_exposure_time,
    snap_f_number,
)

from ._images import gradient, write_jpeg

F = Fraction


@pytest.mark.parametrize(
    ("nominal", "actual"),
    [
        ("1/640", 2 ** (-28 / 3)),  # 1/645.1
        ("1/15", 1 / 16),
        ("1/125", 2.0**-7),
        ("1/10", 2 ** (-10 / 3)),
        ("1/5", 2 ** (-7 / 3)),
        ("1/6", 2 ** (-8 / 3)),
        ("1/13", 2 ** (-11 / 3)),
        ("30", 32.0),
        ("0.3", 2 ** (-5 / 3)),
        ("1.3", 2 ** (1 / 3)),
        ("10/13", 2 ** (-1 / 3)),  # Nikon's 1/1.3 s
        ("1/8000", 2.0**-13),
        ("1/1000", 2.0**-10),
    ],
)
def test_third_stop_times(nominal: str, actual: float) -> None:
    value, seq = snap_exposure_time(F(nominal))
    assert seq == THIRD_STOP
    assert value == pytest.approx(actual, rel=1e-12)


@pytest.mark.parametrize(
    ("nominal", "actual"),
    [
        ("1/750", 2**-9.5),
        ("1/90", 2**-6.5),
        ("1/45", 2**-5.5),
        ("1/350", 2**-8.5),
        ("0.7", 2**-0.5),
        ("1.5", 2**0.5),
        ("3", 2**1.5),
    ],
)
def test_half_stop_times(nominal: str, actual: float) -> None:
    value, seq = snap_exposure_time(F(nominal))
    assert seq == HALF_STOP
    assert value == pytest.approx(actual, rel=1e-12)


def test_values_nominal_in_both_sequences_follow_the_preference() -> None:
    # 1/6 s: 2^(-8/3) on the 1/3-stop dial, 2^(-5/2) on the 1/2-stop dial.
    assert snap_exposure_time(F(1, 6)) == (pytest.approx(2 ** (-8 / 3)), THIRD_STOP)
    assert snap_exposure_time(F(1, 6), HALF_STOP) == (pytest.approx(2**-2.5), HALF_STOP)
    assert snap_exposure_time(F(1, 10), HALF_STOP)[0] == pytest.approx(2**-3.5)
    # A value of one table only ignores the preference.
    assert snap_exposure_time(F(1, 640), HALF_STOP)[1] == THIRD_STOP
    assert snap_exposure_time(F(1, 750), THIRD_STOP)[1] == HALF_STOP


def test_exact_times_are_kept() -> None:
    # Pixel 7 writes exact times (1/802.8 s as 622797/500000000); the simulator writes 1/1024.
    for t in (F(622797, 500_000_000), F(1, 1024), F(1, 3049), F(19995759, 500_000_000)):
        value, seq = snap_exposure_time(t)
        assert seq is None and value == float(t)


def test_every_table_entry_is_its_grid_value_rounded() -> None:
    for seq, steps in ((THIRD_STOP, 3), (HALF_STOP, 2)):
        for t in nominal_exposure_times(seq):
            value, got = snap_exposure_time(t, seq)
            assert got == seq
            # On the grid, and the nominal value is that grid point rounded: within 0.25 stop
            # (Canon's half-stop 0.3" for 2^-1.5 s = 0.354 s is the farthest, 0.24 stop).
            assert math.log2(value) * steps == pytest.approx(round(math.log2(value) * steps))
            assert abs(math.log2(value / float(t))) < 0.25, (seq, t)
        for n in nominal_f_numbers(seq):
            value, got = snap_f_number(n, seq)
            assert got == seq
            assert abs(math.log2(value / float(n))) < 0.1, (seq, n)


def test_f_numbers() -> None:
    assert snap_f_number(F("5.6")) == (pytest.approx(2**2.5), THIRD_STOP)
    assert snap_f_number(F(11)) == (pytest.approx(2**3.5), THIRD_STOP)
    assert snap_f_number(F(8)) == (8.0, THIRD_STOP)
    assert snap_f_number(F("6.3"))[0] == pytest.approx(2 ** (8 / 3))  # Av = 16/3
    assert snap_f_number(F("1.85")) == (1.85, None)  # Pixel 7: a lens property, not a dial value


def test_bracket_sequence_votes() -> None:
    assert bracket_sequence([F(1, 4), F(1, 5), F(1, 15)]) == THIRD_STOP  # 1/5: 1/3 only
    assert bracket_sequence([F(1, 6), F(1, 90)]) == HALF_STOP  # 1/90: 1/2 only
    assert bracket_sequence([F(1, 8), F(1), F(8)]) == THIRD_STOP  # full stops: the default
    assert bracket_sequence([F(1, 803), None]) is None  # nothing nominal
    assert bracket_sequence([]) is None


def test_bad_input() -> None:
    with pytest.raises(ValueError, match="exposure time must be positive"):
        snap_exposure_time(F(0))
    with pytest.raises(ValueError, match="f-number must be positive"):
        snap_f_number(F(-2))
    with pytest.raises(ValueError, match=r"unknown APEX sequence 'third'.*1/3-stop"):
        snap_exposure_time(F(1, 15), "third")
    assert set(SEQUENCES) == {THIRD_STOP, HALF_STOP}


# --- on frames and brackets -----------------------------------------------------------------


def test_frame_keeps_the_tag_and_gives_the_snapped_value(tmp_path: Path) -> None:
    p = write_jpeg(tmp_path / "a.jpg", gradient(), exposure=F(1, 640), f_number=5.6, iso=100)
    m = load_frame(p).meta
    assert m.exposure_time == F(1, 640)  # the tag as read
    assert m.exposure_time_apex == pytest.approx(2 ** (-28 / 3))
    assert m.exposure_time_sequence == THIRD_STOP
    assert m.exposure_time_actual == m.exposure_time_apex
    assert m.f_number_apex == pytest.approx(2**2.5)
    js = json.loads(json.dumps(m.to_json()))
    assert js["exposure_time"] == pytest.approx(1 / 640)
    assert js["exposure_time_exact"] == "1/640"
    assert js["exposure_time_apex"] == pytest.approx(2 ** (-28 / 3))
    assert js["exposure_time_sequence"] == "1/3-stop"


def test_exact_exif_time_is_not_snapped(tmp_path: Path) -> None:
    p = write_jpeg(tmp_path / "a.jpg", gradient(), exposure=F(622797, 500_000_000))
    m = load_frame(p).meta
    assert m.exposure_time_apex is None and m.exposure_time_sequence is None
    assert m.exposure_time_actual == float(F(622797, 500_000_000))


def _pair(folder: Path, t0: Fraction, t1: Fraction) -> list[Path]:
    folder.mkdir(exist_ok=True)
    return [
        write_jpeg(folder / "a.jpg", gradient(scale=0.3, seed=0), exposure=t0),
        write_jpeg(folder / "b.jpg", gradient(scale=0.9, seed=1), exposure=t1),
    ]


def test_bracket_exif_exposures_snapped_by_default(tmp_path: Path) -> None:
    b = load_bracket(_pair(tmp_path, F(1, 640), F(1, 160)))
    assert b.apex_sequence == THIRD_STOP
    assert b.exif_exposures() == (pytest.approx(2 ** (-28 / 3)), pytest.approx(2 ** (-22 / 3)))
    assert b.exif_ratio(0, 1) == pytest.approx(4.0)  # exactly two stops on the dial
    assert b.exif_exposures(snapped=False) == (pytest.approx(1 / 640), pytest.approx(1 / 160))
    assert b.exif_ratio(0, 1, snapped=False) == pytest.approx(4.0)
    # 1/6 -> 1/8 s: 1.333 as written, 2^(1/3) = 1.260 on the dial.
    c = load_bracket(_pair(tmp_path / "c", F(1, 8), F(1, 6)))
    assert c.exif_ratio(0, 1) == pytest.approx(2 ** (1 / 3))
    assert c.exif_ratio(0, 1, snapped=False) == pytest.approx(8 / 6)


def test_ambiguous_value_takes_the_brackets_sequence(tmp_path: Path) -> None:
    # 1/90 s exists only on the half-stop dial, so this camera's 1/6 s is 2^-2.5 (0.177 s).
    paths = [
        write_jpeg(tmp_path / "a.jpg", gradient(scale=0.2, seed=0), exposure=F(1, 90)),
        write_jpeg(tmp_path / "b.jpg", gradient(scale=0.9, seed=1), exposure=F(1, 6)),
    ]
    b = load_bracket(paths)
    assert [f.meta.exposure_time_sequence for f in b.frames] == [HALF_STOP, HALF_STOP]
    assert b.frames[1].meta.exposure_time_apex == pytest.approx(2**-2.5)
    assert b.exif_ratio(0, 1) == pytest.approx(2**4)
    # Alone, the same 1/6 s file takes the 1/3-stop default.
    assert load_frame(paths[1]).meta.exposure_time_apex == pytest.approx(2 ** (-8 / 3))


def test_times_file_is_never_snapped(tmp_path: Path) -> None:
    paths = _pair(tmp_path, F(1, 640), F(1, 160))
    tf = tmp_path / "times.txt"
    tf.write_text("a.jpg 1/15\nb.jpg 1/4\n")
    b = load_bracket(paths, exposure_times=tf)
    assert all(f.meta.exposure_time_source == "times-file" for f in b.frames)
    assert all(f.meta.exposure_time_apex is None for f in b.frames)
    assert b.apex_sequence is None
    assert b.exif_exposures() == (pytest.approx(1 / 15), pytest.approx(1 / 4))
    assert b.exif_exposures() == b.exif_exposures(snapped=False)


@pytest.mark.shared
def test_memorial_times_file_exact(memorial_dir: Path) -> None:
    b = load_bracket([memorial_dir], exposure_times=memorial_dir / "exposure_times.txt")
    assert b.apex_sequence is None
    assert b.exif_exposures() == tuple(2.0**k for k in range(-10, 6))


@pytest.mark.shared
def test_frobisher_full_stops_unchanged(frobisher_dir: Path) -> None:
    # 1/8, 1 and 8 s are full stops: their actual values equal the nominal ones.
    b = load_bracket([frobisher_dir])
    assert b.apex_sequence == THIRD_STOP
    assert b.exif_exposures() == (0.125, 1.0, 8.0)
    assert [f.meta.f_number_apex for f in b.frames] == [8.0, 8.0, 8.0]
