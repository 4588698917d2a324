"""RAW reading: white balance when the file records none, read noise from the optical black."""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from hdrcore.cli import main
from hdrcore.io import load_bracket, load_frame
from hdrcore.io.raw import (
    D65_XYZ,
    _fallback_whitebalance,
    matrix_neutral,
    optical_black_noise,
)
from hdrcore.merge.colour import colour_conversion
from hdrcore.synthetic import simulate_bracket, write_bracket
from hdrcore.synthetic.dng import SRGB_XYZ_TO_CAMERA, write_dng

# A camera <- XYZ matrix that is not sRGB's: its D65 neutral is (1.339, 1, 1.054).
CAMERA = ((0.9, -0.2, 0.1), (-0.3, 1.2, 0.1), (0.0, 0.1, 0.8))


def _neutral_by_hand(m) -> tuple[float, float, float]:
    cam = np.asarray(m, float) @ np.asarray(D65_XYZ)
    return (cam[1] / cam[0], 1.0, cam[1] / cam[2])


def _cfa(h: int = 64, w: int = 96, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(300, 3000, (h, w)).astype(np.uint16)


def _retag(path: Path, tag: int, typ: int, new_tag: int) -> None:
    """Rename one IFD0 entry (an unknown tag id is ignored by LibRaw)."""
    data = bytearray(path.read_bytes())
    i = bytes(data).find(struct.pack("<HH", tag, typ))
    assert i > 0
    data[i : i + 2] = struct.pack("<H", new_tag)
    path.write_bytes(bytes(data))


def _zero_as_shot_neutral(path: Path) -> None:
    """Set the numerators of a DNG's AsShotNeutral (50728, 3 RATIONALs) to zero."""
    data = bytearray(path.read_bytes())
    assert data[:2] == b"II"
    i = bytes(data).find(struct.pack("<HHI", 50728, 5, 3))
    assert i > 0
    (offset,) = struct.unpack_from("<I", data, i + 8)
    for k in range(3):
        struct.pack_into("<I", data, offset + 8 * k, 0)
    path.write_bytes(bytes(data))


# --- white balance --------------------------------------------------------------------------


def test_matrix_neutral_formula() -> None:
    assert matrix_neutral(CAMERA) == pytest.approx(_neutral_by_hand(CAMERA))
    assert matrix_neutral(CAMERA) == pytest.approx((1.3394, 1.0, 1.0542), abs=1e-4)
    # sRGB's own XYZ -> RGB matrix sees D65 as neutral already.
    assert matrix_neutral(SRGB_XYZ_TO_CAMERA) == pytest.approx((1.0, 1.0, 1.0), abs=1e-3)
    # rawpy's 4x3 layout (last row zero) works too.
    assert matrix_neutral([*CAMERA, (0, 0, 0)]) == pytest.approx(matrix_neutral(CAMERA))
    assert matrix_neutral(None) is None
    assert matrix_neutral(np.zeros((4, 3))) is None
    assert matrix_neutral(-np.eye(3)) is None  # no positive response to white
    assert matrix_neutral(np.full((3, 3), np.nan)) is None


@pytest.mark.parametrize("wb", [(0.5, 1.0, 0.7), (1.0, 1.0, 1.0)])
def test_as_shot_white_balance_is_kept(tmp_path: Path, wb) -> None:
    p = write_dng(
        tmp_path / "a.dng", _cfa(), exposure_time=0.01, as_shot_neutral=wb, color_matrix=CAMERA
    )
    m = load_frame(p).meta
    assert m.whitebalance_source == "as-shot"
    assert m.camera_whitebalance[:3] == pytest.approx((1 / wb[0], 1.0, 1 / wb[2]), rel=1e-6)


def test_zero_as_shot_neutral_uses_the_matrix_neutral(tmp_path: Path) -> None:
    p = write_dng(tmp_path / "a.dng", _cfa(), exposure_time=0.01, color_matrix=CAMERA)
    _zero_as_shot_neutral(p)
    import rawpy

    with rawpy.imread(str(p)) as raw:  # what LibRaw makes of it
        assert list(raw.camera_whitebalance)[:3] == [0.0, 1.0, 0.0]
    m = load_frame(p).meta
    assert m.whitebalance_source == "matrix-neutral"
    # The DNG ColorMatrix rounded to 4 decimals by the writer.
    assert m.camera_whitebalance == pytest.approx(_neutral_by_hand(CAMERA), rel=1e-3)
    assert json.loads(json.dumps(m.to_json()))["whitebalance_source"] == "matrix-neutral"
    # The merge's colour conversion accepts it.
    conv = colour_conversion(None, m.camera_whitebalance)
    assert np.all(np.isfinite(conv.matrix))


def test_missing_as_shot_neutral_and_matrix_gives_unity(tmp_path: Path) -> None:
    p = write_dng(tmp_path / "a.dng", _cfa(), exposure_time=0.01)
    _retag(p, 50728, 5, 65000)  # AsShotNeutral gone
    assert load_frame(p).meta.whitebalance_source == "matrix-neutral"
    _retag(p, 50721, 10, 65001)  # ColorMatrix1 gone too
    m = load_frame(p).meta
    assert m.whitebalance_source == "unity"
    assert m.camera_whitebalance == (1.0, 1.0, 1.0)


def test_fallback_prefers_rgb_xyz_matrix() -> None:
    # A camera file (LibRaw fills rgb_xyz_matrix from its tables) with zero multipliers.
    raw = SimpleNamespace(color_matrix=np.zeros((3, 4)), daylight_whitebalance=[0, 0, 0, 0])
    wb, source = _fallback_whitebalance(raw, np.asarray(CAMERA))
    assert source == "matrix-neutral" and wb == pytest.approx(_neutral_by_hand(CAMERA))
    wb, source = _fallback_whitebalance(raw, np.zeros((3, 3)))
    assert (wb, source) == ((1.0, 1.0, 1.0), "unity")


@pytest.fixture(scope="module")
def no_wb_bracket(tmp_path_factory: pytest.TempPathFactory) -> Path:
    sim = simulate_bracket(
        scene="patches",
        shape=(64, 96),
        exposure_times=(1 / 64, 1 / 16, 1 / 4),
        bits=12,
        noise_sigma=1.0,
        keep_linear=True,
        seed=2,
    )
    out = tmp_path_factory.mktemp("nowb")
    written = write_bracket(out, sim, fmt="dng")
    for p in written.frames:
        _zero_as_shot_neutral(Path(p))
    return out


def test_bracket_warns_about_missing_white_balance(no_wb_bracket: Path) -> None:
    b = load_bracket([no_wb_bracket])
    (w,) = [w for w in b.warnings if w.code == "no-white-balance"]
    assert w.frames == (0, 1, 2)
    assert w.message.startswith(
        "frame00.dng, frame01.dng, frame02.dng record no as-shot white balance"
    )
    assert "the colour matrix's D65 neutral is used instead" in w.message
    assert all(f.meta.whitebalance_source == "matrix-neutral" for f in b.frames)


def test_merge_of_a_bracket_without_white_balance_completes(
    no_wb_bracket: Path, tmp_path: Path
) -> None:
    rc = main(["merge", str(no_wb_bracket), "-o", str(tmp_path / "out.exr"), "--quiet"])
    assert rc in (0, 1)
    assert (tmp_path / "out.exr").stat().st_size > 0


# --- read noise from the optical black ------------------------------------------------------


def _sensor(
    rng,
    *,
    sigma: float,
    shape=(400, 600),
    active=(10, 12, 380, 560),
    black=64.0,
    banding: float = 0.0,
) -> np.ndarray:
    h, w = shape
    x = black + rng.normal(0, sigma, shape) + rng.normal(0, banding, (h, 1))
    top, left, ah, aw = active
    x[top : top + ah, left : left + aw] += 1000.0  # light in the active area only
    return np.clip(np.rint(x), 0, 4095).astype(np.uint16)


@pytest.mark.parametrize("sigma", [0.5, 0.7, 1.0, 2.0, 5.0])
def test_optical_black_sigma_on_integer_levels(sigma: float) -> None:
    rng = np.random.default_rng(int(sigma * 10))
    data = _sensor(rng, sigma=sigma, banding=1.5)
    ob = optical_black_noise(data, top=10, left=12, height=380, width=560, black_level=64)
    assert ob is not None
    # Row banding of 1.5 levels and the rounding to integers are both taken out.
    assert ob.sigma == pytest.approx(sigma, rel=0.04)
    assert abs(ob.offset) < 0.5  # the banding moves the mean of the 12 top and bottom rows
    assert set(ob.margins) == {"left", "right", "top", "bottom"}


def test_optical_black_ignores_filler_hot_pixels_and_site_offsets() -> None:
    rng = np.random.default_rng(7)
    data = _sensor(rng, sigma=0.8).astype(np.int32)
    data[:, -2:] = 64  # constant filler columns
    data[3, 100] = 4000  # a hot pixel
    data[:, 0::2] += 1  # one column parity (two CFA sites) a level higher
    ob = optical_black_noise(
        data.astype(np.uint16),
        top=10,
        left=12,
        height=380,
        width=560,
        black_level=[65, 64, 65, 64],
        pattern=np.array([[0, 1], [2, 3]]),
    )
    assert ob is not None and ob.sigma == pytest.approx(0.8, rel=0.05)
    assert abs(ob.offset) < 0.1  # per-site blacks subtracted
    # With one black level for all sites the offset shows half a level, the noise is unchanged.
    ob1 = optical_black_noise(
        data.astype(np.uint16), top=10, left=12, height=380, width=560, black_level=64
    )
    assert ob1.offset == pytest.approx(0.5, abs=0.1) and ob1.sigma == pytest.approx(ob.sigma)


def test_optical_black_absent_or_too_small() -> None:
    data = np.full((50, 60), 64, np.uint16)
    assert optical_black_noise(data, top=0, left=0, height=50, width=60) is None
    # A 5-pixel left margin minus the 4-pixel guard: 1 column of 50 pixels, under 400.
    assert optical_black_noise(data, top=0, left=5, height=50, width=55) is None


@pytest.mark.parametrize(("sigma", "masked"), [(0.7, False), (3.0, False), (1.0, True)])
def test_dng_with_masked_margins(tmp_path: Path, sigma: float, masked: bool) -> None:
    sim = simulate_bracket(
        scene="patches",
        shape=(256, 384),
        exposure_times=(1 / 64, 1 / 4),
        bits=12,
        noise_sigma=sigma,
        keep_linear=True,
        seed=1,
    )
    write_bracket(tmp_path, sim, fmt="dng", margins=(16, 16, 16, 16), masked_areas=masked)
    b = load_bracket([tmp_path])
    for f in b.frames:
        m = f.meta
        assert m.read_noise_source == "optical-black"
        assert m.read_noise == pytest.approx(sigma, rel=0.03)
        if masked:
            # LibRaw measures the black on MaskedAreas and keeps the integer part of the mean:
            # the margins sit 0..1 level above it.
            assert 0.0 <= m.optical_black_offset < 1.0
        else:
            assert abs(m.optical_black_offset) < 0.05
        js = json.loads(json.dumps(m.to_json()))
        assert js["read_noise"] == pytest.approx(m.read_noise)
        assert js["read_noise_source"] == "optical-black"


def test_dng_without_margins_has_no_read_noise(tmp_path: Path) -> None:
    p = write_dng(tmp_path / "a.dng", _cfa(), exposure_time=0.01)
    m = load_frame(p).meta
    assert m.read_noise is None and m.read_noise_source is None
    assert m.optical_black_offset is None
    assert m.to_json()["read_noise"] is None


@pytest.mark.shared
@pytest.mark.parametrize(
    ("name", "low", "high"),
    # Measured: S40 0.646, G2 0.731 levels (10 bits, quantisation removed; 0.708 and 0.785
    # with it), on 95k margin pixels (left, right and top margins; 2 filler columns dropped).
    [("S40_CRW_0101.CRW", 0.60, 0.69), ("G2_CRW_0304.CRW", 0.69, 0.78)],
)
def test_canon_crw_read_noise(crw_dir: Path, name: str, low: float, high: float) -> None:
    m = load_frame(crw_dir / name).meta
    assert m.read_noise_source == "optical-black"
    assert low < m.read_noise < high
    assert math.sqrt(m.read_noise**2 + 1 / 12) == pytest.approx(0.75, abs=0.06)
    # LibRaw's black level (32) agrees with the optical black within 0.2 level.
    assert abs(m.optical_black_offset) < 0.2
    assert m.whitebalance_source == "as-shot"


def _ciff(make_model: bytes, order: str = "<") -> bytes:
    """A minimal Canon CIFF file: the header, a root heap holding one sub-heap (0x300a, as
    Canon's image properties) that holds the make/model record (0x080a)."""
    sub = make_model + b"\0" * (len(make_model) % 2)
    table = len(sub)
    sub += struct.pack(order + "H", 1) + struct.pack(order + "HII", 0x080A, len(make_model), 0)
    sub += struct.pack(order + "I", table)
    root = sub
    table = len(root)
    root += struct.pack(order + "H", 1) + struct.pack(order + "HII", 0x300A, len(sub), 0)
    root += struct.pack(order + "I", table)
    head = (b"II" if order == "<" else b"MM") + struct.pack(order + "I", 26) + b"HEAPCCDR"
    head += struct.pack(order + "I", 0x00010002) + b"\0" * 8
    return head + root


def test_crw_make_and_model_from_ciff_records(tmp_path: Path) -> None:
    """Canon's CRW files hold CIFF records, no TIFF EXIF: make and model are read from the
    0x080a record, in either byte order; a damaged file or another format gives None."""
    from hdrcore.io.exif import read_ciff_make_model

    for order in "<>":
        p = tmp_path / f"x{order == '<'}.crw"
        p.write_bytes(_ciff(b"Canon\0Canon PowerShot Test\0", order))
        assert read_ciff_make_model(p) == ("Canon", "Canon PowerShot Test")
    broken = tmp_path / "broken.crw"
    broken.write_bytes(_ciff(b"Canon\0Canon PowerShot Test\0")[:-3])
    assert read_ciff_make_model(broken) == (None, None)
    (tmp_path / "n.jpg").write_bytes(b"\xff\xd8\xff\xe0" + b"\0" * 40)
    assert read_ciff_make_model(tmp_path / "n.jpg") == (None, None)


def test_real_crw_files_name_their_cameras(crw_dir) -> None:
    """The real CRW files (exiftool reads Canon PowerShot S40 and G2): their frames carry make
    and model, so a bracket of the two is found to mix cameras."""
    from hdrcore.io.exif import read_ciff_make_model

    s40, g2 = crw_dir / "S40_CRW_0101.CRW", crw_dir / "G2_CRW_0304.CRW"
    assert read_ciff_make_model(s40) == ("Canon", "Canon PowerShot S40")
    frame = load_frame(s40)
    assert (frame.meta.make, frame.meta.model) == ("Canon", "Canon PowerShot S40")
    assert frame.meta.camera == "Canon PowerShot S40"
    b = load_bracket([s40, g2])
    assert "mixed-cameras" in b.warning_codes()
