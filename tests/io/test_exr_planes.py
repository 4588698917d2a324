"""The EXR writer's per-channel planes give the same file as one interleaved half-float copy.

:func:`hdrcore.io.write_exr` converts the radiance into three ``(H, W)`` planes over row blocks
(no ``(H, W, 3)`` copy); OpenEXR stores a scanline file's channels one after another in each
line block, so the bytes must be those of the one-shot write of the same values as one
``"RGB"`` array, the form the writer had before.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from hdrcore.errors import OutputError
from hdrcore.io import exr as exr_module
from hdrcore.io import read_exr, write_exr


def _reference_values(rgb: np.ndarray, half: bool) -> np.ndarray:
    """The stored values by the writer's rule, written out in whole-array numpy."""
    clean = np.nan_to_num(rgb.astype(np.float32), nan=0.0, posinf=65504.0, neginf=0.0)
    clean = np.maximum(clean, 0.0) + np.float32(0.0)  # (-0.0 is stored as 0)
    if half:
        return np.minimum(clean, 65504.0).astype(np.float16)
    return clean


def _one_shot(path: Path, values: np.ndarray, like: Path) -> None:
    """``values`` written in one call as one interleaved ``"RGB"`` array, with the header
    attributes of the file ``like``."""
    import OpenEXR

    with OpenEXR.File(str(like)) as exr:
        header = {
            k: v
            for k, v in exr.header().items()
            if k not in ("channels", "dataWindow", "displayWindow")
        }
    with OpenEXR.File(header, {"RGB": np.ascontiguousarray(values)}) as out:
        out.write(str(path))


@pytest.mark.parametrize("half", [True, False])
@pytest.mark.parametrize("compression", ["piz", "zip"])
def test_planes_write_the_bytes_of_the_interleaved_one_shot_write(
    tmp_path: Path, half: bool, compression: str
) -> None:
    rng = np.random.default_rng(7)
    # 700 rows: three conversion blocks of 256 and a short one, on two threads
    rgb = (10.0 ** rng.uniform(-6, 6, (700, 53, 3))).astype(np.float32)
    rgb[5, 5] = (np.nan, -np.inf, np.inf)
    rgb[7, 7] = (-0.0, 0.0, -3.0)
    rgb[699, 52] = (65504.0, 65519.0, 65520.0)  # (65519 rounds to 65504 in half; 65520 is clipped)
    ours = write_exr(
        tmp_path / "planes.exr",
        rgb,
        half=half,
        compression=compression,
        exposure_times=[0.01, 0.04],
        metadata={"reference": 1},
        workers=2,
    )
    expected = _reference_values(rgb, half)
    _one_shot(tmp_path / "one.exr", expected, like=ours)
    assert ours.read_bytes() == (tmp_path / "one.exr").read_bytes()
    back, attrs = read_exr(ours)
    np.testing.assert_array_equal(back, expected.astype(np.float32))
    # finite values past the half range are counted; +inf is not a clipped value
    over = np.isfinite(rgb) & (rgb > 65504.0)
    assert attrs["hdrviewClippedHalf"] == (int(np.count_nonzero(over)) if half else 0)


def test_float64_input_converts_as_float32(tmp_path: Path) -> None:
    rng = np.random.default_rng(8)
    rgb64 = 10.0 ** rng.uniform(-6, 6, (300, 20, 3))
    rgb64[0, 0] = (1e300, -1e300, 70000.0)
    a, attrs_a = read_exr(write_exr(tmp_path / "a.exr", rgb64))
    with np.errstate(over="ignore"):
        rgb32 = rgb64.astype(np.float32)
    b, attrs_b = read_exr(write_exr(tmp_path / "b.exr", rgb32))
    np.testing.assert_array_equal(a, b)
    # 1e300 becomes +inf in float32: written as 65504, not counted; 70000 is counted
    over = (rgb64 > 65504.0) & (rgb64 <= np.finfo(np.float32).max)
    assert attrs_a["hdrviewClippedHalf"] == attrs_b["hdrviewClippedHalf"] == np.count_nonzero(over)


def test_a_failed_write_leaves_no_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """An error while the planes are converted or written: no output, no temporary file."""

    def failing(*args: object, **kwargs: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(exr_module, "_storage", failing)
    with pytest.raises(OSError):
        write_exr(tmp_path / "o.exr", np.ones((4, 4, 3), np.float32))
    assert os.listdir(tmp_path) == []

    import OpenEXR

    class Broken:
        def __init__(self, *args: object) -> None:
            pass

        def __enter__(self) -> Broken:
            return self

        def __exit__(self, *args: object) -> None:
            pass

        def write(self, path: str) -> None:
            Path(path).write_bytes(b"partial")
            raise OSError(28, "No space left on device")

    monkeypatch.undo()
    monkeypatch.setattr(OpenEXR, "File", Broken)
    (tmp_path / "o.exr").write_bytes(b"previous")
    with pytest.raises(OutputError, match="cannot write the output"):
        write_exr(tmp_path / "o.exr", np.ones((4, 4, 3), np.float32), force=True)
    assert os.listdir(tmp_path) == ["o.exr"]
    assert (tmp_path / "o.exr").read_bytes() == b"previous"


@pytest.mark.parametrize("half", [True, False])
@pytest.mark.parametrize("rows", [1, 255, 256, 700])
def test_overwrite_input_writes_the_same_file_in_the_arrays_memory(
    tmp_path: Path, half: bool, rows: int
) -> None:
    """``overwrite_input``: the half floats are made over the radiance itself, block by block
    in row order (a block's half values land on rows already read); the file is the one
    written from a copy, whatever the number of rows against the block size (256)."""
    rng = np.random.default_rng(rows)
    rgb = (10.0 ** rng.uniform(-6, 6, (rows, 37, 3))).astype(np.float32)
    rgb[0, 0] = (np.nan, -np.inf, np.inf)
    rgb[rows - 1, 36] = (-1.0, 1e9, 65519.0)
    kept = rgb.copy()
    copied = write_exr(tmp_path / "copy.exr", rgb, half=half, workers=2)
    np.testing.assert_array_equal(rgb, kept)  # (without the flag the input is untouched)
    overwritten = write_exr(tmp_path / "over.exr", rgb, half=half, overwrite_input=True)
    assert overwritten.read_bytes() == copied.read_bytes()
    if half:
        # the first half of its memory now holds the half floats written
        stored = rgb.reshape(-1).view(np.float16)[: rgb.size].reshape(rows, 37, 3)
        np.testing.assert_array_equal(stored, _reference_values(kept, half=True))
    else:
        np.testing.assert_array_equal(rgb, _reference_values(kept, half=False))


def test_overwrite_input_copies_what_it_cannot_overwrite(tmp_path: Path) -> None:
    """A view that is not C-contiguous (a crop), float64 or read-only data: copied, untouched."""
    rng = np.random.default_rng(9)
    full = (10.0 ** rng.uniform(-3, 3, (300, 40, 3))).astype(np.float32)
    kept = full.copy()
    crop = full[10:290, 5:35]
    a = write_exr(tmp_path / "a.exr", crop, overwrite_input=True)
    b = write_exr(tmp_path / "b.exr", np.ascontiguousarray(kept[10:290, 5:35]))
    assert a.read_bytes() == b.read_bytes()
    np.testing.assert_array_equal(full, kept)
    frozen = kept.copy()
    frozen.setflags(write=False)
    write_exr(tmp_path / "c.exr", frozen, overwrite_input=True)
    np.testing.assert_array_equal(frozen, kept)
    as64 = kept.astype(np.float64)
    write_exr(tmp_path / "d.exr", as64, overwrite_input=True)
    np.testing.assert_array_equal(as64, kept.astype(np.float64))


def test_the_compiled_half_cast_is_numpys_to_the_bit() -> None:
    """:func:`hdrcore.io.exr._half_block` against numpy's cast: every float32 exponent from
    below the smallest subnormal half to 65504, each with its 2**13 low significand patterns
    around the half's rounding bit (every tie, even and odd), random significands, and the
    values the writer cleans (NaN, infinities, negatives, -0.0, past HALF_MAX)."""
    rng = np.random.default_rng(5)
    top = int(np.float32(65504.0).view(np.uint32))
    exps = np.arange(0, (top >> 23) + 1, dtype=np.uint32) << 23
    low = np.arange(1 << 14, dtype=np.uint32)  # bits 0-13: the rounding bit and below
    high = rng.integers(0, 1 << 9, (len(exps), 4), dtype=np.uint32) << 14
    bits = (exps[:, None, None] | high[:, :, None] | low[None, None, :]).ravel()
    bits = np.concatenate([bits, rng.integers(0, top + 1, 1 << 20, dtype=np.uint32)])
    bits = bits[bits <= top]
    values = bits.view(np.float32)
    out = np.empty(values.size, np.uint16)
    assert exr_module._half_block(values, out) == 0
    np.testing.assert_array_equal(out, values.astype(np.float16).view(np.uint16))
    special = np.array(
        [np.nan, -np.inf, np.inf, -1.0, -0.0, 0.0, 1e9, 65519.0, 65520.0, 70000.0, 5.96e-8],
        np.float32,
    )
    out = np.empty(special.size, np.uint16)
    clipped = exr_module._half_block(special, out)
    assert clipped == 4  # 1e9, 65519 (rounds past 65504), 65520, 70000; not +inf
    np.testing.assert_array_equal(
        out, _reference_values(special[None, None], True).ravel().view(np.uint16)
    )
