"""Outputs: OpenEXR round trip with attributes, PNG, atomic writes and refusals."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from hdrcore.errors import ImageReadError, OutputError, ParameterError
from hdrcore.io import atomic_write, read_exr, write_exr, write_png


def _radiance(h: int = 20, w: int = 30) -> np.ndarray:
    rng = np.random.default_rng(0)
    return (10.0 ** rng.uniform(-4, 4, (h, w, 3))).astype(np.float32)


def test_exr_float32_round_trip_exact(tmp_path: Path) -> None:
    rgb = _radiance()
    p = write_exr(
        tmp_path / "o.exr",
        rgb,
        half=False,
        exposure_times=[0.01, 0.04, 0.16],
        exposure_ratios=[4.0, 3.9],
        transforms=[np.eye(2, 3)] * 3,
        sources=["/x/a.dng", "b.dng"],
        metadata={"reference": 1},
    )
    back, attrs = read_exr(p)
    np.testing.assert_array_equal(back, rgb)
    assert attrs["exposureTimes"] == pytest.approx([0.01, 0.04, 0.16])
    assert attrs["exposureRatios"] == pytest.approx([4.0, 3.9])
    assert attrs["hdrviewTransforms"][0] == [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    assert attrs["hdrviewSources"] == ["a.dng", "b.dng"]
    assert attrs["hdrview"] == {"reference": 1}


def test_exr_half_round_trip_within_half_precision(tmp_path: Path) -> None:
    rgb = _radiance()
    rgb[0, 0, 0] = 1e6  # beyond half range: clipped and counted
    back, attrs = read_exr(write_exr(tmp_path / "h.exr", rgb))
    expected = np.minimum(rgb, 65504.0).astype(np.float16).astype(np.float32)
    np.testing.assert_array_equal(back, expected)
    assert attrs["hdrviewClippedHalf"] == 1
    ok = rgb < 60000
    assert np.max(np.abs(back[ok] / rgb[ok] - 1)) < 1e-3  # 10-bit mantissa


@pytest.mark.parametrize("compression", ["piz", "zip", "zstd", "none"])
@pytest.mark.parametrize("half", [True, False])
def test_exr_every_compression_lossless_over_many_row_blocks(
    tmp_path: Path, compression: str, half: bool
) -> None:
    """Every compression round-trips exactly, across several conversion blocks (600 rows,
    blocks of 256) and both threads; NaN and -inf become 0, +inf and values past the half
    range become 65504 (counted when clipped), negatives 0."""
    rng = np.random.default_rng(3)
    rgb = (10.0 ** rng.uniform(-5, 5, (600, 41, 3))).astype(np.float32)
    rgb[5, 5] = (np.nan, -np.inf, np.inf)
    rgb[599, 40] = (-2.0, 1e9, 0.0)
    back, attrs = read_exr(
        write_exr(
            tmp_path / f"{compression}.exr", rgb, half=half, compression=compression, workers=2
        )
    )
    clean = np.nan_to_num(rgb, nan=0.0, posinf=65504.0, neginf=0.0)
    clean = np.maximum(clean, 0.0)
    if half:
        assert attrs["hdrviewClippedHalf"] == int(np.count_nonzero(clean > 65504.0))
        clean = np.minimum(clean, 65504.0).astype(np.float16).astype(np.float32)
    np.testing.assert_array_equal(back, clean)
    with pytest.raises(ParameterError, match="EXR compression"):
        write_exr(tmp_path / "bad.exr", rgb, compression="jpeg")
    assert not (tmp_path / "bad.exr").exists()


def test_exr_rejects_bad_arrays(tmp_path: Path) -> None:
    with pytest.raises(ParameterError, match=r"\(H, W, 3\)"):
        write_exr(tmp_path / "x.exr", np.zeros((4, 4), np.float32))
    with pytest.raises(ParameterError, match="floating point"):
        write_exr(tmp_path / "x.exr", np.zeros((4, 4, 3), np.uint8))
    assert not (tmp_path / "x.exr").exists()


def test_read_exr_errors(tmp_path: Path) -> None:
    p = tmp_path / "bad.exr"
    p.write_bytes(b"not an exr")
    with pytest.raises(ImageReadError, match=r"bad\.exr: not a readable OpenEXR"):
        read_exr(p)


def test_existing_output_refused_without_force(tmp_path: Path) -> None:
    p = tmp_path / "o.exr"
    p.write_bytes(b"precious")
    with pytest.raises(OutputError, match=r"o\.exr: output exists; use --force"):
        write_exr(p, _radiance())
    assert p.read_bytes() == b"precious"
    write_exr(p, _radiance(), force=True)
    assert read_exr(p)[0].shape == (20, 30, 3)


def test_input_never_overwritten_even_with_force(tmp_path: Path) -> None:
    src = tmp_path / "in.png"
    src.write_bytes(b"frame")
    with pytest.raises(OutputError, match="refusing to overwrite an input file"):
        write_png(src, np.zeros((4, 4, 3), np.uint8), force=True, inputs=[src])
    assert src.read_bytes() == b"frame"


def test_atomic_write_leaves_nothing_on_failure(tmp_path: Path) -> None:
    target = tmp_path / "out.bin"

    def failing(tmp: Path) -> None:
        tmp.write_bytes(b"half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        atomic_write(target, failing)
    assert os.listdir(tmp_path) == []


def test_missing_output_directory(tmp_path: Path) -> None:
    with pytest.raises(OutputError, match="output directory does not exist"):
        write_png(tmp_path / "no" / "x.png", np.zeros((2, 2), np.uint8))


def test_png_8_and_16_bit(tmp_path: Path) -> None:
    from hdrcore.io import load_frame

    img8 = np.random.default_rng(0).integers(0, 256, (6, 7, 3), dtype=np.uint8)
    f = load_frame(write_png(tmp_path / "a.png", img8))
    np.testing.assert_array_equal(f.levels, img8)
    img16 = np.random.default_rng(1).integers(0, 65536, (6, 7, 3), dtype=np.uint16)
    f16 = load_frame(write_png(tmp_path / "b.png", img16))
    np.testing.assert_array_equal(f16.levels, img16)
    with pytest.raises(ParameterError, match="uint8 or uint16"):
        write_png(tmp_path / "c.png", img8.astype(np.float32))


def test_output_permissions_follow_umask(tmp_path: Path) -> None:
    old = os.umask(0o022)
    try:
        p = write_png(tmp_path / "perm.png", np.zeros((2, 2), np.uint8))
    finally:
        os.umask(old)
    assert (p.stat().st_mode & 0o777) == 0o644
