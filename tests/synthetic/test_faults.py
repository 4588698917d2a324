"""Faulty brackets (hdrcore.synthetic.faults) and masked DNG margins, read back from the files.

Ground truth: the generators' own model. A black frame is noise around the black level only
(no sample above 5 sigma over black; about 69 % of 8-bit samples at 0, ``P(N(0, 1) < 0.5)``);
a saturated frame holds only levels within 5 sigma of the largest (about 69 % exactly at it); a
times file with two frames' times exchanged reads back exchanged; a DNG with masked margins reads
back through LibRaw (rawpy) with ``raw_image`` larger than ``raw_image_visible``, the visible area
equal to the file written without margins, and margins holding the simulated read noise.
"""

from __future__ import annotations

import json
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
import rawpy
from PIL import Image

from hdrcore.errors import ParameterError
from hdrcore.io import read_exif, read_exposure_times
from hdrcore.synthetic import (
    DARK_RAW_12BIT,
    SEED_PROTOCOL,
    WIDE_RAW_14BIT,
    encode_dng,
    simulate_bracket,
    write_black_frames,
    write_bracket,
    write_dark_raw_bracket,
    write_dark_scene,
    write_duplicate_exposure,
    write_one_usable_frame,
    write_reference_bracket,
    write_saturated_frame,
    write_swapped_times,
    write_unregistrable_tripod,
    write_wide_raw_pair,
)
from hdrcore.synthetic.dng import add_masked_margins, parse_margins

SMALL = SEED_PROTOCOL.replace(shape=(48, 64))
THREE = SMALL.replace(exposure_times=(1.0, 4.0, 16.0))


def _png(path: Path) -> np.ndarray:
    return np.asarray(Image.open(path))


def _raw(path: Path) -> tuple[np.ndarray, np.ndarray, list[int], tuple[int, int]]:
    """(raw_image, raw_image_visible, black per channel, (top, left) margins) from LibRaw."""
    with rawpy.imread(str(path)) as raw:
        return (
            np.array(raw.raw_image, copy=True),
            np.array(raw.raw_image_visible, copy=True),
            [int(b) for b in raw.black_level_per_channel],
            (int(raw.sizes.top_margin), int(raw.sizes.left_margin)),
        )


def _robust_sigma(x: np.ndarray) -> float:
    """Standard deviation after clipping at 4 sigma (three passes), less rounding's 1/12."""
    v = np.asarray(x, np.float64).ravel()
    keep = np.ones(v.size, bool)
    for _ in range(3):
        m, s = v[keep].mean(), v[keep].std()
        keep = np.abs(v - m) < 4 * s
    return float(np.sqrt(max(v[keep].var() - 1 / 12, 0.0)))


# ------------------------------------------------------------------------------ reference


def test_reference_bracket_has_no_fault_and_signal_in_every_pair(tmp_path: Path) -> None:
    c = write_reference_bracket(tmp_path, SMALL.replace(scene="patches"))
    assert c.faults == () and c.usable_frames == tuple(range(6))
    assert c.pairs_with_signal() == tuple((k, k + 1) for k in range(5))
    for k, p in enumerate(c.frames):
        np.testing.assert_array_equal(_png(p), c.sim.frames[k])
    truth = json.loads(c.truth_file.read_text())
    assert truth["case"]["case"] == "reference"
    assert truth["exposure_times"] == list(c.exposure_times)
    assert c.relative_exposures == (1.0, 4.0, 16.0, 64.0, 256.0, 1024.0)
    assert c.index_of(str(c.frames[3])) == 3 and c.true_ratio(1, 3) == 16.0


# ------------------------------------------------------------------------------ black frames


def test_black_png_frames_are_noise_around_zero(tmp_path: Path) -> None:
    c = write_black_frames(tmp_path, (0, 2), THREE.replace(shape=(128, 128)))
    assert [f.index for f in c.faults] == [0, 2] and c.usable_frames == (1,)
    for k in (0, 2):
        lv = _png(c.frames[k])
        assert lv.max() <= 5  # no sample above 5 sigma over black
        assert 0.64 < np.mean(lv == 0) < 0.74  # P(N(0,1) < 0.5) = 0.69
        assert c.signal_fraction[k] == 0.0
    np.testing.assert_array_equal(_png(c.frames[1]), c.sim.frames[1])
    # EXIF keeps the nominal time; the truth says which frame is black and why.
    assert read_exif(c.frames[2]).exposure_time == Fraction(16)
    truth = json.loads(c.truth_file.read_text())
    assert [f["kind"] for f in truth["case"]["faults"]] == ["black", "black"]
    assert truth["case"]["usable_frames"] == [1]
    assert c.pairs_with_signal() == ()


def test_black_jpeg_frame_stays_black(tmp_path: Path) -> None:
    c = write_black_frames(tmp_path, 0, THREE.replace(fmt="jpeg"))
    lv = _png(c.frames[0])
    assert lv.max() <= 5 and lv.mean() < 1.0


@pytest.mark.parametrize("bits", [12, 14])
def test_black_dng_frame_is_read_noise_around_the_black_level(tmp_path: Path, bits: int) -> None:
    spec = THREE.replace(fmt="dng", bits=bits, noise_sigma=2.0, shape=(128, 128))
    c = write_black_frames(tmp_path, 1, spec)
    _, vis, black, _ = _raw(c.frames[1])
    assert set(black) == {1 << (bits - 4)}
    d = vis.astype(np.float64) - black[0]
    assert np.abs(d).max() <= 5 * 2.0
    assert abs(d.mean()) < 0.1 and _robust_sigma(d) == pytest.approx(2.0, rel=0.05)
    _, vis0, _, _ = _raw(c.frames[0])
    assert vis0.max() > black[0] + 50  # the other frames keep their light
    assert c.usable_frames == (0, 2)


# ------------------------------------------------------------------ saturated, duplicate, times


def test_saturated_frame_is_at_the_clipping_level(tmp_path: Path) -> None:
    c = write_saturated_frame(tmp_path, spec=THREE.replace(shape=(128, 128)))
    lv = _png(c.frames[2])
    assert lv.min() >= 255 - 5 and lv.min() >= 0.97 * 255
    assert 0.64 < np.mean(lv == 255) < 0.74
    assert c.faults[0].kind == "saturated" and c.usable_frames == (0, 1)
    assert c.signal_fraction[2] == 0.0


def test_saturated_dng_frame_sits_at_the_white_level(tmp_path: Path) -> None:
    c = write_saturated_frame(tmp_path, 0, THREE.replace(fmt="dng", bits=12))
    _, vis, _, _ = _raw(c.frames[0])
    assert vis.min() >= 4095 - 5 and vis.max() == 4095


def test_duplicate_exposure_has_two_frames_of_one_time_and_independent_noise(
    tmp_path: Path,
) -> None:
    c = write_duplicate_exposure(tmp_path, 1, THREE)
    assert c.exposure_times == (1.0, 4.0, 4.0, 16.0)
    times = read_exposure_times(c.times_file)
    assert times["frame01.png"] == times["frame02.png"] == Fraction(4)
    a, b = _png(c.frames[1]).astype(float), _png(c.frames[2]).astype(float)
    assert not np.array_equal(a, b)
    d = (a - b)[(a > 10) & (a < 240)]
    assert abs(d.mean()) < 0.1 and np.std(d) == pytest.approx(np.sqrt(2), rel=0.15)
    assert c.true_ratio(1, 2) == 1.0 and c.usable_frames == (0, 1, 2, 3)
    assert (1, 2) in c.pairs_with_signal()


def test_swapped_times_file_exchanges_two_frames_times(tmp_path: Path) -> None:
    c = write_swapped_times(tmp_path, (1, 2), THREE)
    assert c.times_file.name == "exposure_times_swapped.txt"
    swapped = read_exposure_times(c.times_file)
    true = read_exposure_times(tmp_path / "exposure_times.txt")
    assert [swapped[f"frame0{k}.png"] for k in range(3)] == [1, 16, 4]
    assert [true[f"frame0{k}.png"] for k in range(3)] == [1, 4, 16]
    assert [read_exif(p).exposure_time for p in c.frames] == [1, 4, 16]
    assert c.listed_times == (1.0, 16.0, 4.0) and c.exposure_times == (1.0, 4.0, 16.0)
    truth = json.loads(c.truth_file.read_text())
    assert truth["exposure_times"] == [1.0, 4.0, 16.0]
    assert truth["case"]["times_file_exposure_times"] == [1.0, 16.0, 4.0]


def test_swapped_times_in_exif_too(tmp_path: Path) -> None:
    c = write_swapped_times(tmp_path, (0, 2), THREE, in_exif=True)
    assert [read_exif(p).exposure_time for p in c.frames] == [16, 4, 1]
    assert c.exif_times == (16.0, 4.0, 1.0)
    true = read_exposure_times(tmp_path / "exposure_times.txt")
    assert [true[f"frame0{k}.png"] for k in range(3)] == [1, 4, 16]
    truth = json.loads(c.truth_file.read_text())
    assert truth["exposure_times"] == [1.0, 4.0, 16.0]
    assert [f["true_exposure_time"] for f in truth["frames"]] == [1.0, 4.0, 16.0]


# ------------------------------------------------------------------------- dark brackets


def test_unregistrable_tripod_darkest_frame_has_little_signal(tmp_path: Path) -> None:
    c = write_unregistrable_tripod(tmp_path, SMALL.replace(max_shift=5.0), darkest_signal=0.005)
    assert 0.002 < c.signal_fraction[0] < 0.01
    assert c.signal_fraction[-1] > 0.05
    assert all(np.allclose(m, np.eye(2, 3)) for m in c.sim.to_reference)  # a tripod
    assert (0, 1) not in c.pairs_with_signal() and c.usable_frames == tuple(range(6))


def test_one_usable_frame(tmp_path: Path) -> None:
    c = write_one_usable_frame(tmp_path, spec=THREE.replace(shape=(64, 64)))
    assert c.usable_frames == (1,)
    assert [f.kind for f in c.faults] == ["black", "saturated"]
    assert _png(c.frames[0]).max() <= 5 and _png(c.frames[2]).min() >= 250


@pytest.mark.parametrize("n_black", [1, 2])
def test_dark_scene_shortest_frames_are_black(tmp_path: Path, n_black: int) -> None:
    c = write_dark_scene(tmp_path, n_black, SMALL.replace(scene="patches"))
    for k in range(n_black):
        assert _png(c.frames[k]).max() <= 5, k
        assert c.faults[k].kind == "black"
    assert _png(c.frames[n_black + 1]).max() > 10
    assert c.signal_fraction[-1] > 0.1
    assert c.sim.key < 1e-3  # nothing replaced: the scene is dark


def test_dark_raw_bracket_darkest_frame_peaks_at_one_and_a_half_percent(tmp_path: Path) -> None:
    c = write_dark_raw_bracket(tmp_path, DARK_RAW_12BIT.replace(shape=(64, 96)))
    t = c.exposure_times
    assert all(b / a == 4.0 for a, b in zip(t, t[1:], strict=False))  # 2 stops apart
    peak = float(c.sim.linear_frames[0].max()) * (4095 - 256)
    assert peak == pytest.approx(0.015 * 4095, rel=1e-3)  # ~61 levels above black
    _, vis, black, _ = _raw(c.frames[0])
    d = vis.astype(float) - black[0]
    assert 50 < d.max() < 82  # below the old default floor (2 % of 4095)
    assert c.faults == () and c.signal_fraction[0] > 0.01


def test_wide_raw_pair_is_fourteen_bits_six_stops_apart(tmp_path: Path) -> None:
    c = write_wide_raw_pair(tmp_path, WIDE_RAW_14BIT.replace(shape=(64, 96)))
    assert c.true_ratio(0, 1) == 64.0
    _, vis, black, _ = _raw(c.frames[1])
    assert black[0] == 1024 and vis.max() == 16383


# --------------------------------------------------------------------------- DNG margins


def _margin_bracket(tmp_path: Path, **kw) -> tuple[Path, Path]:
    sim = simulate_bracket(
        shape=(64, 96),
        exposure_times=(1 / 64, 1 / 16),
        bits=12,
        noise_sigma=3.0,
        keep_linear=True,
        seed=4,
    )
    plain = write_bracket(tmp_path / "plain", sim, "dng")
    masked = write_bracket(tmp_path / "masked", sim, "dng", **kw)
    return plain.frames[0], masked.frames[0]


def test_dng_margins_read_back_through_libraw(tmp_path: Path) -> None:
    plain, masked = _margin_bracket(tmp_path, margins=(8, 16, 6, 10))
    full, vis, black, (top, left) = _raw(masked)
    _, vis0, black0, _ = _raw(plain)
    assert full.shape == (64 + 8 + 6, 96 + 16 + 10) and vis.shape == (64, 96)
    assert (top, left) == (8, 16)
    np.testing.assert_array_equal(vis, vis0)  # the active area is what was written before
    np.testing.assert_array_equal(full[8:72, 16:112], vis0)
    margin = np.ones(full.shape, bool)
    margin[8:72, 16:112] = False
    d = full[margin].astype(float) - 256
    assert abs(d.mean()) < 0.1
    assert _robust_sigma(d) == pytest.approx(3.0, rel=0.05)
    # MaskedAreas: LibRaw measures the black level there (integer part of the mean per site).
    assert black0 == [256] * 4 and all(b in (255, 256) for b in black)
    truth = json.loads((masked.parent / "truth.json").read_text())
    assert truth["raw"]["masked_margins"]["active_area"] == [8, 16, 72, 112]


def test_dng_margins_without_masked_areas_keep_the_black_level_tag(tmp_path: Path) -> None:
    _, masked = _margin_bracket(tmp_path, margins=4, masked_areas=False)
    full, vis, black, margins = _raw(masked)
    assert full.shape == (72, 104) and vis.shape == (64, 96) and margins == (4, 4)
    assert black == [256] * 4


def test_masked_margins_helper_and_bad_areas() -> None:
    act = np.full((4, 6), 300, np.uint16)
    s = add_masked_margins(
        act,
        (2, 2, 0, 1),
        black_level=64,
        white_level=1023,
        noise_sigma=0,
        rng=np.random.default_rng(0),
    )
    assert s.data.shape == (6, 9) and s.active_area == (2, 2, 6, 8)
    assert s.masked_areas == ((0, 0, 2, 9), (2, 0, 6, 2), (2, 8, 6, 9))
    np.testing.assert_array_equal(s.active, act)
    assert np.all(s.data[s.margin_mask] == 64) and s.margin_mask.sum() == 54 - 24
    with pytest.raises(ParameterError, match="top and left masked margins must be even"):
        parse_margins((3, 2, 2, 2))
    with pytest.raises(ParameterError, match="one value or four"):
        parse_margins((2, 2))
    with pytest.raises(ParameterError, match="overlaps the active area"):
        encode_dng(
            s.data,
            exposure_time=0.01,
            black_level=64,
            white_level=1023,
            active_area=s.active_area,
            masked_areas=[(0, 0, 4, 9)],
        )
    with pytest.raises(ParameterError, match="inside the stored image"):
        encode_dng(
            s.data, exposure_time=0.01, black_level=64, white_level=1023, active_area=(0, 0, 8, 9)
        )
    with pytest.raises(ParameterError, match="MaskedAreas need an ActiveArea"):
        encode_dng(
            s.data,
            exposure_time=0.01,
            black_level=64,
            white_level=1023,
            masked_areas=[(0, 0, 2, 9)],
        )


def test_margins_are_for_dng_only(tmp_path: Path) -> None:
    sim = simulate_bracket(shape=(32, 32), exposure_times=(1.0, 4.0), seed=1)
    with pytest.raises(ParameterError, match="masked margins are a RAW"):
        write_bracket(tmp_path, sim, "png", margins=8)


# --------------------------------------------------------------------------------- bad input


def test_bad_positions_and_parameters_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ParameterError, match=r"black frame position out of range.*0\.\.2"):
        write_black_frames(tmp_path / "a", 3, THREE)
    with pytest.raises(ParameterError, match="repeats a frame"):
        write_black_frames(tmp_path / "b", (0, -3), THREE)
    with pytest.raises(ParameterError, match="swap names two frames"):
        write_swapped_times(tmp_path / "c", (0, 1, 2), THREE)  # type: ignore[arg-type]
    with pytest.raises(ParameterError, match=r"n_black frames must leave at least one"):
        write_dark_scene(tmp_path / "d", 3, THREE)
    with pytest.raises(ParameterError, match="darkest_peak is a fraction"):
        write_dark_raw_bracket(tmp_path / "e", darkest_peak=1.5)
    with pytest.raises(ParameterError, match="a RAW case writes DNG"):
        write_dark_raw_bracket(tmp_path / "f", THREE)
    with pytest.raises(ParameterError, match="darkest_signal is a fraction"):
        write_unregistrable_tripod(tmp_path / "g", THREE, darkest_signal=0.0)
