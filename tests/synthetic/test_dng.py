"""DNG written by the simulator and read back through rawpy (LibRaw) and ExifRead.

Ground truth: the linear values written. Reading back, ``(raw_image_visible - black) / (white -
max(black))`` must equal them within quantisation (half a level), and the CFA pattern, black and
white levels and the exposure time (an exact rational, 1/3049) must come back exactly.
"""

from __future__ import annotations

from datetime import datetime
from fractions import Fraction
from pathlib import Path

import exifread
import numpy as np
import pytest
import rawpy
import tifffile

from hdrcore.errors import OutputError, ParameterError
from hdrcore.synthetic import (
    CFA_PATTERNS,
    default_black_level,
    encode_dng,
    linear_to_raw,
    mosaic,
    simulate_bracket,
    write_dng,
)
from hdrcore.synthetic.dng import as_rational, cfa_channel_map

SHAPE = (48, 64)
POSTPROCESS = dict(
    gamma=(1, 1),
    no_auto_bright=True,
    output_bps=16,
    user_wb=[1, 1, 1, 1],
    output_color=rawpy.ColorSpace.raw,
    no_auto_scale=True,
    user_flip=0,
)


def _linear(shape: tuple[int, int] = SHAPE, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(0.0, 1.0, (*shape, 3))


def _letters(raw: rawpy.RawPy) -> str:
    desc = raw.color_desc.decode()
    return "".join(desc[int(i)] for i in raw.raw_pattern.ravel())


def test_mosaic_picks_the_pattern_colour_at_each_site() -> None:
    rgb = np.zeros((12, 18, 3))
    rgb[..., 0], rgb[..., 1], rgb[..., 2] = 10, 20, 30
    for name, cell in CFA_PATTERNS.items():
        side = 6 if name == "XTRANS" else 2
        m = mosaic(rgb, name)
        expect = (np.array(cell).reshape(side, side) + 1) * 10
        np.testing.assert_array_equal(m[:side, :side], expect)
        np.testing.assert_array_equal(m, np.tile(expect, (12 // side, 18 // side)))
        np.testing.assert_array_equal(
            cfa_channel_map(name, (12, 18)),
            np.tile(np.array(cell).reshape(side, side), (12 // side, 18 // side)),
        )


def test_default_black_levels() -> None:
    assert default_black_level(12) == 256
    assert default_black_level(14) == 1024
    with pytest.raises(ParameterError, match=r"unsupported raw bit depth.*8\.\.16.*found 20"):
        default_black_level(20)


def test_linear_to_raw_scale_offset_and_clipping() -> None:
    x = np.array([[0.0, 0.5], [1.0, 2.0]])
    raw = linear_to_raw(x, black_level=256, white_level=4095)
    np.testing.assert_array_equal(raw, [[256, 256 + 1920], [4095, 4095]])  # 0.5 * 3839 = 1919.5
    assert raw.dtype == np.uint16


def test_read_noise_can_go_below_black_and_has_its_sigma() -> None:
    x = np.full((200, 200), 0.0)
    raw = linear_to_raw(
        x, black_level=256, white_level=4095, noise_sigma=4.0, rng=np.random.default_rng(1)
    )
    d = raw.astype(float) - 256
    assert d.std() == pytest.approx(4.0, rel=0.05)
    assert d.min() < 0


@pytest.mark.parametrize("pattern", sorted(CFA_PATTERNS))
@pytest.mark.parametrize(("bits", "white"), [(12, 4095), (14, 16383)])
def test_round_trip_values_pattern_levels_and_time(
    tmp_path: Path, pattern: str, bits: int, white: int
) -> None:
    black = default_black_level(bits)
    lin = _linear()
    cfa_lin = mosaic(lin, pattern)
    raw_in = linear_to_raw(cfa_lin, black_level=black, white_level=white)
    p = write_dng(
        tmp_path / "f.dng",
        raw_in,
        exposure_time=Fraction(1, 3049),
        pattern=pattern,
        black_level=black,
        white_level=white,
    )
    with rawpy.imread(str(p)) as raw:
        data = raw.raw_image_visible.astype(np.float64)
        assert data.shape == SHAPE
        np.testing.assert_array_equal(raw.raw_image_visible, raw_in)
        assert list(raw.black_level_per_channel) == [black] * 4
        assert raw.white_level == white
        assert _letters(raw) == "".join("RGB"[c] for c in CFA_PATTERNS[pattern])
        assert raw.raw_type == rawpy.RawType.Flat
        assert raw.sizes.flip == 0
    back = (data - black) / (white - black)
    assert np.abs(back - cfa_lin).max() <= 0.5 / (white - black) + 1e-12


def test_per_site_black_levels_come_back_per_colour(tmp_path: Path) -> None:
    black = (250, 256, 262, 270)  # row-major sites of GBRG: G, B, R, G
    lin = _linear()
    raw_in = linear_to_raw(mosaic(lin, "GBRG"), black_level=black, white_level=4095)
    p = write_dng(
        tmp_path / "f.dng",
        raw_in,
        exposure_time=0.01,
        pattern="GBRG",
        black_level=black,
        white_level=4095,
    )
    with rawpy.imread(str(p)) as raw:
        per_colour = dict(zip(raw.color_desc.decode(), raw.black_level_per_channel, strict=True))
        by_site = [int(raw.black_level_per_channel[i]) for i in raw.raw_pattern.ravel()]
        assert by_site == list(black)
        assert per_colour["R"] == 262 and per_colour["B"] == 256
        sites = np.tile(np.array(black).reshape(2, 2), (SHAPE[0] // 2, SHAPE[1] // 2))
        back = (raw.raw_image_visible - sites) / (4095 - max(black))
    assert np.abs(back - mosaic(lin, "GBRG")).max() <= 0.5 / (4095 - 270) + 1e-12


def test_exposure_time_is_exact_in_exifread(tmp_path: Path) -> None:
    raw_in = linear_to_raw(mosaic(_linear()), black_level=256, white_level=4095)
    when = datetime(2020, 5, 17, 8, 30, 15)
    p = write_dng(
        tmp_path / "f.dng",
        raw_in,
        exposure_time=1 / 3049,
        f_number=Fraction(28, 10),
        iso=400,
        capture_time=when,
    )
    with open(p, "rb") as fh:
        tags = exifread.process_file(fh, details=False)
    t = tags["EXIF ExposureTime"].values[0]
    assert (t.num, t.den) == (1, 3049)
    f = tags["EXIF FNumber"].values[0]
    assert Fraction(f.num, f.den) == Fraction(14, 5)
    assert tags["EXIF ISOSpeedRatings"].values[0] == 400
    assert str(tags["EXIF DateTimeOriginal"]) == "2020:05:17 08:30:15"
    assert str(tags["Image Make"]) == "hdrview" and str(tags["Image Model"]) == "simulator"
    assert tags["Image Orientation"].values[0] == 1
    with rawpy.imread(str(p)) as raw:
        # LibRaw's own shutter value is a float; the exact rational comes from ExifRead.
        assert raw.other.shutter_speed == pytest.approx(1 / 3049, rel=1e-6)


def test_dng_tags_as_written(tmp_path: Path) -> None:
    raw_in = linear_to_raw(mosaic(_linear()), black_level=256, white_level=4095)
    p = write_dng(tmp_path / "f.dng", raw_in, exposure_time=Fraction(1, 250))
    with tifffile.TiffFile(p) as tif:
        tags = {t.code: t.value for t in tif.pages[0].tags}
    assert tags[262] == 32803 and tags[258] == 16 and tags[259] == 1
    assert bytes(tags[50706]) == bytes((1, 4, 0, 0))
    assert tuple(tags[33421]) == (2, 2) and bytes(tags[33422]) == bytes((0, 1, 1, 2))
    assert tuple(tags[50710]) == (0, 1, 2) and tags[50711] == 1
    assert tags[50714] == 256 and tags[50717] == 4095
    assert tags[50708] == "hdrview simulator" and tags[50778] == 21
    assert tags[34665]["ExposureTime"] == (1, 250)


def test_colour_matrix_makes_camera_rgb_the_output_rgb(tmp_path: Path) -> None:
    # ColorMatrix1 = XYZ->linear sRGB and AsShotNeutral = 1: LibRaw's camera->sRGB is identity.
    raw_in = linear_to_raw(mosaic(_linear()), black_level=256, white_level=4095)
    p = write_dng(tmp_path / "f.dng", raw_in, exposure_time=0.5)
    with rawpy.imread(str(p)) as raw:
        np.testing.assert_allclose(raw.color_matrix[:, :3], np.eye(3), atol=1e-3)
        np.testing.assert_allclose(raw.camera_whitebalance[:3], [1, 1, 1])


def test_postprocess_gives_black_subtracted_values_in_flat_areas(tmp_path: Path) -> None:
    # This is how hdrcore.io decodes RAW: no WB, no colour conversion, no gamma, no scaling.
    lin = np.empty((64, 96, 3))
    lin[:, :48] = (0.05, 0.3, 0.6)
    lin[:, 48:] = (0.7, 0.45, 0.12)
    raw_in = linear_to_raw(mosaic(lin, "RGGB"), black_level=256, white_level=4095)
    p = write_dng(tmp_path / "f.dng", raw_in, exposure_time=Fraction(1, 60))
    with rawpy.imread(str(p)) as raw:
        rgb = raw.postprocess(**POSTPROCESS)
    assert rgb.dtype == np.uint16 and rgb.shape == (64, 96, 3)
    for cols, value in ((slice(4, 40), lin[0, 0]), (slice(56, 92), lin[0, -1])):
        got = rgb[4:-4, cols].reshape(-1, 3).astype(float)
        np.testing.assert_allclose(got.mean(axis=0), value * 3839, atol=1.0)
        assert np.abs(got - value * 3839).max() <= 1.0


def test_simulated_bracket_through_dng_keeps_exposure_ratios(tmp_path: Path) -> None:
    sim = simulate_bracket(
        shape=SHAPE, exposure_times=(1 / 64, 1 / 16), noise_sigma=0, keep_linear=True
    )
    means = []
    for k, lin in enumerate(sim.linear_frames):
        raw_in = linear_to_raw(mosaic(lin), black_level=256, white_level=4095)
        p = write_dng(tmp_path / f"f{k}.dng", raw_in, exposure_time=sim.exposure_times[k])
        with rawpy.imread(str(p)) as raw:
            means.append(raw.raw_image_visible.astype(float) - 256)
    ok = (means[0] > 50) & (means[1] < 3800)
    assert np.median(means[1][ok] / means[0][ok]) == pytest.approx(4.0, rel=5e-3)


def test_write_dng_refuses_to_overwrite(tmp_path: Path) -> None:
    raw_in = linear_to_raw(mosaic(_linear()), black_level=256, white_level=4095)
    p = write_dng(tmp_path / "f.dng", raw_in, exposure_time=1.0)
    before = p.read_bytes()
    with pytest.raises(OutputError, match=r"f\.dng: output exists"):
        write_dng(p, raw_in // 2, exposure_time=1.0)
    assert p.read_bytes() == before
    write_dng(p, raw_in // 2, exposure_time=1.0, force=True)
    assert p.read_bytes() != before
    assert sorted(x.name for x in tmp_path.iterdir()) == ["f.dng"]


def test_rational_conversion() -> None:
    assert as_rational(1 / 3049) == Fraction(1, 3049)
    assert as_rational(0.125) == Fraction(1, 8)
    assert as_rational(Fraction(7, 3)) == Fraction(7, 3)
    assert as_rational(30) == 30


@pytest.mark.parametrize(
    ("cfa", "kwargs", "message"),
    [
        (np.zeros((4, 4, 4), np.uint16), {}, r"CFA data must be \(H, W\)"),
        (np.zeros((4, 4), np.float32), {}, r"CFA data must be integers"),
        (np.full((4, 4), 5000, np.uint16), {}, r"CFA values outside \[0, white level\].*5000"),
        (np.zeros((4, 4), np.uint16), {"pattern": "RGBW"}, r"unknown CFA pattern 'RGBW'"),
        (np.zeros((4, 4), np.uint16), {"black_level": 5000}, r"black level must be >= 0"),
        (np.zeros((4, 4), np.uint16), {"black_level": (1, 2)}, r"one value per 2x2 CFA site"),
        (np.zeros((4, 4), np.uint16), {"white_level": 70000}, r"white level out of range"),
        (np.zeros((4, 4), np.uint16), {"exposure_time": 0}, r"exposure time must be positive"),
        (np.zeros((4, 4), np.uint16), {"orientation": 9}, r"orientation must be an EXIF value"),
    ],
)
def test_bad_dng_input(cfa: np.ndarray, kwargs: dict, message: str) -> None:
    kw: dict = {"exposure_time": 1.0}
    kw.update(kwargs)
    with pytest.raises(ParameterError, match=message):
        encode_dng(cfa, **kw)


def test_bad_linear_to_raw_input() -> None:
    with pytest.raises(ParameterError, match=r"linear CFA data must be \(H, W\)"):
        linear_to_raw(np.zeros((4, 4, 3)), black_level=0, white_level=255)
    with pytest.raises(ParameterError, match=r"linear values must be finite"):
        linear_to_raw(np.full((4, 4), np.nan), black_level=0, white_level=255)
    with pytest.raises(ParameterError, match=r"full-well capacity must be > 0"):
        linear_to_raw(np.zeros((4, 4)), black_level=0, white_level=255, shot_noise_full_well=0)
    with pytest.raises(ParameterError, match=r"mosaic needs an RGB frame"):
        mosaic(np.zeros((4, 4)))


@pytest.mark.parametrize(("orientation", "flip"), [(1, 0), (3, 3), (6, 6), (8, 5)])
def test_orientation_reaches_libraw(tmp_path: Path, orientation: int, flip: int) -> None:
    # LibRaw's flip codes: 0 none, 3 rotate 180, 6 rotate 90 CW, 5 rotate 90 CCW.
    raw_in = linear_to_raw(mosaic(_linear()), black_level=256, white_level=4095)
    p = write_dng(tmp_path / "f.dng", raw_in, exposure_time=1.0, orientation=orientation)
    with rawpy.imread(str(p)) as raw:
        assert raw.sizes.flip == flip
        np.testing.assert_array_equal(raw.raw_image_visible, raw_in)  # the mosaic is untouched
