"""Reading single frames: formats, bit depths, EXIF (exact rationals), orientation, bad input."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
import tifffile

from hdrcore.errors import ImageReadError, InputError
from hdrcore.io import apply_orientation, load_frame, read_exif

from ._images import gradient, write_jpeg


def test_jpeg_exif_exact_rational(tmp_path: Path) -> None:
    p = write_jpeg(
        tmp_path / "a.jpg",
        gradient(),
        exposure=Fraction(1, 3049),
        f_number=5.6,
        iso=400,
        make="Maker",
        model="Model X",
    )
    f = load_frame(p)
    assert f.meta.exposure_time == Fraction(1, 3049)  # exact, not 0.000328
    assert f.meta.exposure_time_source == "exif"
    assert f.meta.f_number == Fraction(28, 5)
    assert f.meta.iso == 400
    assert f.meta.camera == "Maker Model X"
    assert f.levels.dtype == np.uint16 and f.max_level == 255 and f.bit_depth == 8
    assert not f.is_linear


def test_missing_exif_is_none_not_invented(tmp_path: Path) -> None:
    p = write_jpeg(tmp_path / "a.png", gradient(), fmt="PNG")
    f = load_frame(p)
    assert f.meta.exposure_time is None
    assert f.meta.exposure_time_source is None
    assert f.meta.iso is None and f.meta.f_number is None


@pytest.mark.parametrize("orientation", [1, 2, 3, 4, 5, 6, 7, 8])
def test_exif_orientation_applied(tmp_path: Path, orientation: int) -> None:
    stored = gradient(12, 20)
    p = write_jpeg(tmp_path / "o.png", stored, orientation=orientation, fmt="PNG")
    f = load_frame(p)
    expected = apply_orientation(stored, orientation)
    assert f.meta.orientation == orientation
    np.testing.assert_array_equal(f.levels, expected.astype(np.uint16))


def test_orientation_semantics() -> None:
    # A 2x3 image with a marker at the top-left; tag 6 means "rotate 90 CW to view".
    img = np.zeros((2, 3), np.uint8)
    img[0, 0] = 1
    rot = apply_orientation(img, 6)
    assert rot.shape == (3, 2)
    assert rot[0, 1] == 1  # top-left goes to top-right after a clockwise quarter turn
    assert apply_orientation(img, 8)[2, 0] == 1  # counter-clockwise: to bottom-left
    assert apply_orientation(img, 3)[1, 2] == 1


def test_png16_keeps_16_bits(tmp_path: Path) -> None:
    import imagecodecs

    rng = np.random.default_rng(1)
    data = rng.integers(0, 65536, (10, 14, 3), dtype=np.uint16)
    p = tmp_path / "a.png"
    p.write_bytes(imagecodecs.png_encode(data))
    f = load_frame(p)
    assert f.bit_depth == 16 and f.max_level == 65535
    np.testing.assert_array_equal(f.levels, data)


def test_tiff16_and_tiff8_and_orientation(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    data16 = rng.integers(0, 65536, (10, 14, 3), dtype=np.uint16)
    p16 = tmp_path / "a.tif"
    tifffile.imwrite(p16, data16, photometric="rgb", extratags=[(274, 3, 1, 6, True)])
    f = load_frame(p16)
    assert f.bit_depth == 16
    np.testing.assert_array_equal(f.levels, apply_orientation(data16, 6))
    data8 = rng.integers(0, 256, (10, 14, 3), dtype=np.uint8)
    p8 = tmp_path / "b.tiff"
    tifffile.imwrite(p8, data8, photometric="rgb", compression="zlib")
    f8 = load_frame(p8)
    assert f8.bit_depth == 8 and f8.max_level == 255
    np.testing.assert_array_equal(f8.levels, data8)


def test_tiff_exposure_time_in_ifd0(tmp_path: Path) -> None:
    data = np.full((8, 8, 3), 100, np.uint16)
    p = tmp_path / "t.tif"
    tifffile.imwrite(p, data, photometric="rgb", extratags=[(33434, 5, 1, (1, 3049), True)])
    assert read_exif(p).exposure_time == Fraction(1, 3049)


def test_greyscale_replicated(tmp_path: Path) -> None:
    from PIL import Image

    g = (np.arange(200).reshape(10, 20) % 256).astype(np.uint8)
    p = tmp_path / "g.png"
    Image.fromarray(g).save(p)
    f = load_frame(p)
    assert f.levels.shape == (10, 20, 3)
    np.testing.assert_array_equal(f.levels[..., 1], g)


# --- bad input ---------------------------------------------------------------------------------


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"nope\.jpg: file not found"):
        load_frame(tmp_path / "nope.jpg")


def test_not_an_image(tmp_path: Path) -> None:
    p = tmp_path / "notes.jpg"
    p.write_text("this is not a picture\n")
    with pytest.raises(ImageReadError, match=r"notes\.jpg: not a recognised image"):
        load_frame(p)


def test_empty_file(tmp_path: Path) -> None:
    p = tmp_path / "empty.png"
    p.write_bytes(b"")
    with pytest.raises(ImageReadError, match=r"empty\.png: file is empty"):
        load_frame(p)


def test_truncated_jpeg(tmp_path: Path) -> None:
    p = write_jpeg(tmp_path / "full.jpg", gradient(64, 64))
    data = p.read_bytes()
    q = tmp_path / "cut.jpg"
    q.write_bytes(data[: len(data) // 2])
    with pytest.raises(ImageReadError, match=r"cut\.jpg: image data is damaged or truncated"):
        load_frame(q)


def test_truncated_png16(tmp_path: Path) -> None:
    import imagecodecs

    data = np.random.default_rng(0).integers(0, 65536, (64, 64, 3), dtype=np.uint16)
    raw = imagecodecs.png_encode(data)
    q = tmp_path / "cut16.png"
    q.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(ImageReadError, match=r"cut16\.png: PNG data is damaged or truncated"):
        load_frame(q)


def test_truncated_raw(tmp_path: Path, crw_dir: Path) -> None:
    src = crw_dir / "S40_CRW_0101.CRW"
    q = tmp_path / "cut.CRW"
    data = src.read_bytes()
    q.write_bytes(data[:200_000])
    with pytest.raises(ImageReadError, match=r"cut\.CRW: .*(truncated|damaged)"):
        load_frame(q)
    q2 = tmp_path / "cut90.CRW"
    q2.write_bytes(data[: int(len(data) * 0.9)])
    with pytest.raises(ImageReadError, match=r"cut90\.CRW: .*(truncated|damaged)"):
        load_frame(q2)


def test_garbage_with_raw_extension(tmp_path: Path) -> None:
    q = tmp_path / "fake.dng"
    q.write_bytes(b"\x00" * 5000)
    with pytest.raises(ImageReadError, match=r"fake\.dng: .*RAW"):
        load_frame(q)


def test_directory_is_not_a_frame(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not a regular file"):
        load_frame(tmp_path)
