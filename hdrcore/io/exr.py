"""OpenEXR output and input: RGB half (default) or float, with provenance as attributes.

Attributes written (when known): ``exposureTimes`` (seconds, darkest first), ``exposureRatios``
(consecutive, estimated), ``hdrviewTransforms`` (JSON: per-frame 2x3 matrices to the reference),
``hdrviewSources`` (JSON: input file names), and ``hdrview`` (JSON with everything passed in
``metadata``). Half floats saturate at 65504; larger finite values are clipped there and the count
is recorded in ``hdrviewClippedHalf``.

Compression is lossless: PIZ by default (the wavelet coder made for grainy photographic images:
on a 24-megapixel merge it wrote 2x faster than ZIP and 4 % smaller), or ZIP, ZSTD or none. The
conversion to half floats runs over row blocks on two threads into one plane per channel (no
interleaved copy of the image), or with ``overwrite_input`` in the image's own memory by one
compiled pass; OpenEXR compresses on two threads (OpenEXR 3.5.3: PIZ of 24 MP of noise 1.05-1.11
s on one thread, 0.63-0.71 s on two; a real 9 MP merge 0.30-0.37 -> 0.18-0.20 s). A ``-0.0`` is
written as ``0``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._numba import njit as _njit
from .._threads import thread_map, worker_count
from ..errors import ImageReadError, InputError, ParameterError, validate_method
from .atomic import atomic_write

__all__ = ["write_exr", "read_exr", "HALF_MAX", "EXR_COMPRESSIONS"]

HALF_MAX = 65504.0

EXR_COMPRESSIONS: dict[str, str] = {
    "piz": "lossless wavelet coding for grainy (photographic) images: the default",
    "zip": "lossless zlib over 16 scan lines",
    "zstd": "lossless Zstandard",
    "none": "uncompressed",
}
"""Lossless OpenEXR compressions by name (``write_exr(..., compression=)``)."""

_ROWS = 256  # rows per block of the half-float conversion


def _clean(src: np.ndarray, tmp: np.ndarray, half: bool) -> int:
    """``src`` into the float32 ``tmp`` (same shape) as the values stored: NaN, -inf and
    negatives -> 0, +inf -> HALF_MAX, half: finite values past HALF_MAX clipped there; return
    how many were clipped (half only)."""
    if not half:
        np.copyto(tmp, src, casting="same_kind")
        np.nan_to_num(tmp, copy=False, nan=0.0, posinf=HALF_MAX, neginf=0.0)
        np.maximum(tmp, np.float32(0.0), out=tmp)
        return 0
    # fmax: NaN and -inf (and negatives) -> 0; +inf stays and is not a clipped value
    with np.errstate(over="ignore"):  # float64 past float32's range: +inf, as a cast
        np.fmax(src, np.float32(0.0), out=tmp, casting="same_kind")
    n = int(np.count_nonzero(tmp > HALF_MAX))
    if n:
        n -= int(np.count_nonzero(np.isposinf(tmp)))
        np.minimum(tmp, np.float32(HALF_MAX), out=tmp)
    return n


def _storage(
    arr: np.ndarray, dtype: type, workers: int | None
) -> tuple[dict[str, np.ndarray], int]:
    """``arr``'s channels as three ``(H, W)`` planes (``"R"``, ``"G"``, ``"B"``) of the values
    stored (:func:`_clean`), converted over row blocks on ``workers`` threads; and how many
    values were clipped (half only).

    Planes rather than one interleaved ``(H, W, 3)`` copy: OpenEXR writes the same file from
    either (its channels are stored one after another in each line block), and a plane is a
    third of the size. The only temporaries are one float32 block per thread."""
    h, w = arr.shape[:2]
    planes: dict[str, np.ndarray] = {name: np.empty((h, w), dtype) for name in "RGB"}
    half = dtype == np.float16

    def block(r0: int) -> int:
        r1 = min(r0 + _ROWS, h)
        tmp = np.empty((r1 - r0, w), np.float32)
        over = 0
        for c, name in enumerate("RGB"):
            over += _clean(arr[r0:r1, :, c], tmp, half)
            planes[name][r0:r1] = tmp
        return over

    clipped = sum(thread_map(block, range(0, h, _ROWS), workers))
    return planes, clipped


@_njit
def _half_bits(f):  # pragma: no cover - compiled
    """The float16 bits of the non-negative float32 of bits ``f`` (uint32) up to 65504,
    rounded to nearest, ties to even, subnormals kept: numpy's ``astype(np.float16)``
    (``npy_floatbits_to_halfbits``) to the bit over every such float32 (all 1,199,562,753,
    checked once; the tests check every exponent and the ties). Selects, no branches."""
    f_exp = f & np.uint32(0x7F800000)
    f_sig = f & np.uint32(0x007FFFFF)
    # normal halves: the exponent rebased, the significand rounded at bit 13
    h_exp = (f_exp - np.uint32(0x38000000)) >> np.uint32(13)
    tie = (f_sig & np.uint32(0x3FFF)) == np.uint32(0x1000)
    normal = h_exp + ((f_sig + (np.uint32(0) if tie else np.uint32(0x1000))) >> np.uint32(13))
    # subnormal halves: the significand with its leading one shifted down by the exponent
    sh = min(np.uint32(113) - (f_exp >> np.uint32(23)), np.uint32(24))
    s_sig = (np.uint32(0x00800000) + f_sig) >> sh
    s_tie = ((s_sig & np.uint32(0x3FFF)) == np.uint32(0x1000)) and (f & np.uint32(0x7FF)) == 0
    sub = (s_sig + (np.uint32(0) if s_tie else np.uint32(0x1000))) >> np.uint32(13)
    r = normal if f_exp > np.uint32(0x38000000) else sub
    return np.uint16(r if f_exp >= np.uint32(0x33000000) else np.uint32(0))


@_njit
def _half_block(src, dst):  # pragma: no cover - compiled
    """:func:`_clean` and the cast to half of a float32 block in one pass: ``src`` (1-D
    float32) into the float16 bits ``dst`` (uint16, same length); NaN, -inf, negatives and
    -0.0 -> 0, values past HALF_MAX -> HALF_MAX (+inf too); returns how many finite values
    were clipped."""
    top = np.float32(HALF_MAX)
    inf = np.float32(np.inf)
    clipped = 0
    for i in range(src.size):
        v = src[i]
        v = v if v > np.float32(0.0) else np.float32(0.0)
        clipped += (v > top) & (v != inf)
        v = min(v, top)
        dst[i] = _half_bits(np.float32(v).view(np.uint32))
    return clipped


def _storage_in_place(arr: np.ndarray, half: bool) -> tuple[dict[str, np.ndarray], int]:
    """The values stored (:func:`_clean`) written over ``arr`` itself (C-contiguous float32
    ``(H, W, 3)``, whose values are lost): half floats go into the first half of its memory as
    one interleaved ``(H, W, 3)`` array, float32 in place. Row blocks in order, one thread: a
    block's half values land on bytes of rows already read (row ``r`` ends at byte ``6 W (r +
    1)`` of the half array, before the end of the float row, ``12 W (r + 1)``). Half floats
    are made by a compiled pass (:func:`_half_block`: the same bits as numpy's cast, which
    runs in software; 24 MP of lognormal radiance 0.29 -> 0.11 s, the same bytes)."""
    h, w = arr.shape[:2]
    if not half:
        tmp = np.empty((min(_ROWS, h), w, 3), np.float32)
        for r0 in range(0, h, _ROWS):
            r1 = min(r0 + _ROWS, h)
            _clean(arr[r0:r1], tmp[: r1 - r0], half)
            arr[r0:r1] = tmp[: r1 - r0]
        return {"RGB": arr}, 0
    flat = arr.reshape(-1)
    bits = flat.view(np.uint16)[: arr.size]  # the first half of the memory
    tmp16 = np.empty(min(_ROWS, h) * w * 3, np.uint16)
    clipped = 0
    for r0 in range(0, h, _ROWS):
        r1 = min(r0 + _ROWS, h)
        e0, e1 = 3 * w * r0, 3 * w * r1
        block = tmp16[: e1 - e0]
        clipped += int(_half_block(flat[e0:e1], block))
        bits[e0:e1] = block
    return {"RGB": bits.view(np.float16).reshape(h, w, 3)}, clipped


def _validate_rgb(rgb: np.ndarray) -> np.ndarray:
    arr = np.asarray(rgb)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ParameterError("EXR image must be (H, W, 3)", found=str(arr.shape))
    if not np.issubdtype(arr.dtype, np.floating):
        raise ParameterError("EXR image must be floating point", found=str(arr.dtype))
    return arr


def write_exr(
    path: str | os.PathLike,
    rgb: np.ndarray,
    *,
    half: bool = True,
    exposure_times: Sequence[float] | None = None,
    exposure_ratios: Sequence[float] | None = None,
    transforms: Sequence[Any] | None = None,
    sources: Sequence[str] | None = None,
    metadata: Mapping[str, Any] | None = None,
    force: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
    compression: str = "piz",
    workers: int | None = None,
    overwrite_input: bool = False,
) -> Path:
    """Write ``rgb`` (float, ``(H, W, 3)``, linear) to an OpenEXR file atomically.

    NaNs and negative values are written as 0 (radiance is non-negative). ``compression``: one
    of :data:`EXR_COMPRESSIONS` (all lossless). ``workers``: threads for the conversion and
    OpenEXR's compression (default up to two). ``overwrite_input``: ``rgb`` may be overwritten
    (its values are lost, written or not) when it is a C-contiguous float32 array: the half
    floats are made in its own memory, no copy of the image (as scipy's ``overwrite_a``);
    other arrays are copied as without it. The file is the same.
    """
    import OpenEXR

    arr = _validate_rgb(rgb)
    key = validate_method(compression, EXR_COMPRESSIONS, "EXR compression")
    codes = {
        "piz": OpenEXR.PIZ_COMPRESSION,
        "zip": OpenEXR.ZIP_COMPRESSION,
        "zstd": OpenEXR.ZSTD_COMPRESSION,
        "none": OpenEXR.NO_COMPRESSION,
    }
    if (
        overwrite_input
        and arr.dtype == np.float32
        and arr.flags.c_contiguous
        and arr.flags.writeable
    ):
        data, clipped = _storage_in_place(arr, half)
    else:
        data, clipped = _storage(arr, np.float16 if half else np.float32, workers)

    header: dict[str, Any] = {
        "compression": codes[key],
        "type": OpenEXR.scanlineimage,
    }
    if exposure_times is not None:
        header["exposureTimes"] = [float(t) for t in exposure_times]
    if exposure_ratios is not None:
        header["exposureRatios"] = [float(r) for r in exposure_ratios]
    if transforms is not None:
        header["hdrviewTransforms"] = json.dumps([np.asarray(m).tolist() for m in transforms])
    if sources is not None:
        header["hdrviewSources"] = json.dumps([Path(s).name for s in sources])
    if metadata:
        header["hdrview"] = json.dumps(metadata, default=_json_default)
    header["hdrviewClippedHalf"] = clipped

    def writer(tmp: Path) -> None:
        previous = OpenEXR.global_thread_count()
        OpenEXR.set_global_thread_count(worker_count(workers))
        try:
            with OpenEXR.File(header, data) as exr:
                exr.write(str(tmp))
        finally:
            OpenEXR.set_global_thread_count(previous)

    return atomic_write(path, writer, force=force, inputs=inputs)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    return str(obj)


def read_exr(path: str | os.PathLike) -> tuple[np.ndarray, dict[str, Any]]:
    """Read an RGB OpenEXR file: ``(rgb float32 (H, W, 3), attributes)``.

    JSON attributes written by :func:`write_exr` are decoded.
    """
    import OpenEXR

    p = Path(path)
    if not p.is_file():
        raise InputError("file not found", path=p)
    try:
        with OpenEXR.File(str(p)) as exr:
            header = dict(exr.header())
            channels = exr.channels()
            if "RGB" in channels:
                rgb = np.asarray(channels["RGB"].pixels)
            elif all(c in channels for c in "RGB"):
                rgb = np.stack([np.asarray(channels[c].pixels) for c in "RGB"], axis=-1)
            else:
                raise ImageReadError(
                    "EXR has no RGB channels", path=p, found=", ".join(channels.keys())
                )
    except ImageReadError:
        raise
    except Exception as exc:  # OpenEXR raises RuntimeError/ValueError on damaged files
        raise ImageReadError(f"not a readable OpenEXR file ({exc})", path=p) from exc
    attrs: dict[str, Any] = {}
    for key, value in header.items():
        if key in ("hdrview", "hdrviewTransforms", "hdrviewSources") and isinstance(value, str):
            try:
                attrs[key] = json.loads(value)
            except json.JSONDecodeError:
                attrs[key] = value
        else:
            attrs[key] = value
    return rgb.astype(np.float32), attrs
