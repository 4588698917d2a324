"""OpenEXR output and input: RGB half (default) or float, with provenance as attributes.

Attributes written (when known): ``exposureTimes`` (seconds, darkest first), ``exposureRatios``
(consecutive, estimated), ``hdrviewTransforms`` (JSON: per-frame 2x3 matrices to the reference),
``hdrviewSources`` (JSON: input file names), and ``hdrview`` (JSON with everything passed in
``metadata``). Half floats saturate at 65504; larger finite values are clipped there and the count
is recorded in ``hdrviewClippedHalf``.

Compression is lossless: PIZ by default (the wavelet coder made for grainy photographic images:
on a 24-megapixel merge it wrote 2x faster than ZIP and 4 % smaller), or ZIP, ZSTD or none. The
conversion to half floats runs over row blocks on two threads into one plane per channel (no
interleaved copy of the image) and OpenEXR compresses on two. A ``-0.0`` is written as ``0``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

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


def _storage(
    arr: np.ndarray, dtype: type, workers: int | None
) -> tuple[dict[str, np.ndarray], int]:
    """``arr``'s channels as three ``(H, W)`` planes (``"R"``, ``"G"``, ``"B"``) of non-negative
    finite ``dtype`` values (NaN and -inf -> 0, +inf -> HALF_MAX, half: finite values past
    HALF_MAX clipped there), converted over row blocks on ``workers`` threads; and how many
    values were clipped (half only).

    Planes rather than one interleaved ``(H, W, 3)`` copy: OpenEXR writes the same file from
    either (its channels are stored one after another in each line block), and a plane is a
    third of the size (a 24 MP half plane is the size of a freed 16-bit mosaic). The only
    temporaries are one float32 block per channel and thread."""
    h, w = arr.shape[:2]
    planes: dict[str, np.ndarray] = {name: np.empty((h, w), dtype) for name in "RGB"}
    half = dtype == np.float16

    def block(r0: int) -> int:
        with np.errstate(over="ignore"):  # float64 past float32's range: +inf, as a cast
            return _block(r0)

    def _block(r0: int) -> int:
        r1 = min(r0 + _ROWS, h)
        tmp = np.empty((r1 - r0, w), np.float32)
        over = 0
        for c, name in enumerate("RGB"):
            src = arr[r0:r1, :, c]
            if half:
                # fmax: NaN and -inf (and negatives) -> 0; +inf stays and is not a clipped value
                np.fmax(src, np.float32(0.0), out=tmp, casting="same_kind")
                n = int(np.count_nonzero(tmp > HALF_MAX))
                if n:
                    n -= int(np.count_nonzero(np.isposinf(tmp)))
                    np.minimum(tmp, np.float32(HALF_MAX), out=tmp)
                over += n
            else:
                np.copyto(tmp, src, casting="same_kind")
                np.nan_to_num(tmp, copy=False, nan=0.0, posinf=HALF_MAX, neginf=0.0)
                np.maximum(tmp, np.float32(0.0), out=tmp)
            planes[name][r0:r1] = tmp
        return over

    clipped = sum(thread_map(block, range(0, h, _ROWS), workers))
    return planes, clipped


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
) -> Path:
    """Write ``rgb`` (float, ``(H, W, 3)``, linear) to an OpenEXR file atomically.

    NaNs and negative values are written as 0 (radiance is non-negative). ``compression``: one
    of :data:`EXR_COMPRESSIONS` (all lossless). ``workers``: threads for the conversion and
    OpenEXR's compression (default up to two).
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
