"""Write a simulated bracket to disk: frames, ``truth.json`` and ``exposure_times.txt``.

Formats (the file holds the frame at its native bit depth unless said otherwise):

``png``
    8-bit frames as 8-bit PNG. Deeper frames as 16-bit PNG, by default *scaled* to the full 16-bit
    range, ``round(level * 65535 / max_level)`` (so a loader that reads a 16-bit file as 0..65535
    sees the same relative values and clipping at 65535); ``sixteen_bit="keep"`` stores the native
    levels unchanged in the 16-bit container instead.
``tiff``
    as ``png`` (8-bit or 16-bit RGB, uncompressed).
``jpeg``
    8-bit frames only (quality 95, no chroma subsampling); JPEG's own lossy coding adds error.
``dng``
    linear response only: a Bayer-CFA DNG per frame (see :mod:`hdrcore.synthetic.dng`). The raw
    numbers are made from the bracket's noiseless linear frames (``simulate_bracket(...,
    keep_linear=True)``) with the same noise model (shot noise from ``shot_noise_full_well``,
    Gaussian read noise of ``noise_sigma`` raw units), so they are not the same draw as
    ``sim.frames``. Black-subtracted values are ``x * (white - max(black))``. With ``margins``
    the stored image also has masked optical-black margins (black level plus the same read
    noise) around the active area, with the DNG ActiveArea and MaskedAreas tags
    (:func:`hdrcore.synthetic.dng.add_masked_margins`); the active area holds the same numbers
    as without margins.

Every frame carries its exposure time in EXIF (ExposureTime in the EXIF IFD, an exact rational):
PNG in an ``eXIf`` chunk, JPEG in APP1, TIFF and DNG in an EXIF sub-IFD. ``exposure_times.txt``
has one ``name seconds`` line per frame with the exact fraction (``1/512``), the format of
``../shared/data/*/exposure_times.txt`` that :func:`hdrcore.io.read_exposure_times` reads.

All files are written atomically; an existing file is refused unless ``force``.
"""

from __future__ import annotations

import io
import json
import os
import struct
import zlib
from dataclasses import dataclass
from datetime import datetime, timedelta
from fractions import Fraction
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import OutputError, ParameterError
from ..io.atomic import atomic_write, check_output_path
from .camera import SimulatedBracket
from .dng import (
    TiffTag,
    add_masked_margins,
    as_rational,
    default_black_level,
    encode_dng,
    encode_tiff,
    exif_payload,
    exif_tags,
    linear_to_raw,
    mosaic,
    parse_margins,
)

__all__ = ["FORMATS", "WrittenBracket", "write_bracket", "frame_file_levels"]

FORMATS: dict[str, str] = {"png": ".png", "tiff": ".tiff", "jpeg": ".jpg", "dng": ".dng"}

_CAPTURE_START = datetime(2006, 2, 6, 12, 0, 0)


@dataclass(frozen=True)
class WrittenBracket:
    """Where :func:`write_bracket` put things."""

    directory: Path
    format: str
    frames: tuple[Path, ...]
    exposure_times: tuple[Fraction, ...]
    truth: Path
    times_file: Path
    file_max_level: int


def frame_file_levels(
    levels: np.ndarray, bits: int, fmt: str, sixteen_bit: str = "scale"
) -> np.ndarray:
    """The integer values a ``png``/``tiff``/``jpeg`` file stores for native ``levels`` at ``bits``.

    uint8 for 8-bit frames; otherwise uint16, scaled to 0..65535 (``"scale"``) or unchanged
    (``"keep"``). JPEG takes 8-bit frames only.
    """
    if sixteen_bit not in ("scale", "keep"):
        raise ParameterError(
            "unknown 16-bit mapping", expected="'scale' or 'keep'", found=repr(sixteen_bit)
        )
    arr = np.asarray(levels)
    if bits == 8:
        return arr.astype(np.uint8)
    if fmt == "jpeg":
        raise ParameterError(
            "JPEG holds 8-bit frames only",
            expected="bits 8 for jpeg (or png/tiff/dng)",
            found=f"{bits}-bit frames",
        )
    if sixteen_bit == "keep" or bits == 16:
        return arr.astype(np.uint16)
    max_level = (1 << bits) - 1
    return np.rint(arr.astype(np.float64) * (65535.0 / max_level)).astype(np.uint16)


def _png_with_exif(image: np.ndarray, exif: bytes) -> bytes:
    from ..io.preview import encode_png

    png = encode_png(image)
    # Insert an eXIf chunk right after IHDR (signature 8 bytes + IHDR chunk 25 bytes).
    body = b"eXIf" + exif
    chunk = struct.pack(">I", len(exif)) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)
    return png[:33] + chunk + png[33:]


def _tiff_rgb(image: np.ndarray, exif_kwargs: dict) -> bytes:
    h, w = image.shape[:2]
    bps = 16 if image.dtype == np.uint16 else 8
    when: datetime = exif_kwargs["capture_time"]
    ifd0 = [
        TiffTag(254, 4, (0,)),
        TiffTag(256, 4, (w,)),
        TiffTag(257, 4, (h,)),
        TiffTag(258, 3, (bps, bps, bps)),
        TiffTag(259, 3, (1,)),
        TiffTag(262, 3, (2,)),
        TiffTag(271, 2, "hdrview"),
        TiffTag(272, 2, "simulator"),
        TiffTag(274, 3, (1,)),
        TiffTag(277, 3, (3,)),
        TiffTag(278, 4, (h,)),
        TiffTag(284, 3, (1,)),
        TiffTag(305, 2, "hdrcore simulator"),
        TiffTag(306, 2, when.strftime("%Y:%m:%d %H:%M:%S")),
    ]
    exif = exif_tags(
        exif_kwargs["exposure_time"], exif_kwargs["f_number"], exif_kwargs["iso"], when
    )
    data = np.ascontiguousarray(image, dtype="<u2" if bps == 16 else np.uint8).tobytes()
    return encode_tiff(ifd0, exif=exif, image=data)


def _write_bytes(path: Path, data: bytes) -> None:
    path.write_bytes(data)


def _jpeg(image: np.ndarray, exif: bytes, quality: int) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image, np.uint8), "RGB").save(
        buf, "JPEG", quality=int(quality), subsampling=0, exif=b"Exif\x00\x00" + exif
    )
    return buf.getvalue()


def write_bracket(
    outdir: str | os.PathLike,
    sim: SimulatedBracket,
    fmt: str = "png",
    force: bool = False,
    *,
    sixteen_bit: str = "scale",
    jpeg_quality: int = 95,
    cfa_pattern: str = "RGGB",
    black_level: int | tuple[int, int, int, int] | None = None,
    white_level: int | None = None,
    f_number: float = 8.0,
    iso: int = 100,
    stem: str = "frame",
    margins: int | tuple[int, int, int, int] | None = None,
    masked_areas: bool = True,
) -> WrittenBracket:
    """Write ``sim`` to ``outdir``: ``{stem}NN.ext`` frames, ``truth.json``, ``exposure_times.txt``.

    ``fmt`` is one of :data:`FORMATS`. For ``dng``, ``black_level`` defaults to
    :func:`~hdrcore.synthetic.dng.default_black_level` of ``sim.bits`` (256 at 12 bits) and
    ``white_level`` to ``2**bits - 1``; ``margins`` (one value or top, left, bottom, right; top
    and left even) adds masked optical-black margins around the active area, with the
    MaskedAreas tag unless ``masked_areas`` is False (then LibRaw reports the margins but takes
    the black level from the BlackLevel tag instead of measuring it there). Every output path is
    checked before anything is written: an existing file raises
    :class:`~hdrcore.errors.OutputError` naming it, unless ``force``.
    """
    key = str(fmt).lower()
    if key in ("jpg",):
        key = "jpeg"
    if key in ("tif",):
        key = "tiff"
    if key not in FORMATS:
        raise ParameterError(
            f"unknown output format {fmt!r}",
            expected=f"one of {', '.join(FORMATS)}",
            found=repr(fmt),
        )
    n = len(sim.frames)
    if key == "jpeg" and sim.bits != 8:
        raise ParameterError(
            "JPEG holds 8-bit frames only",
            expected="bits 8 for jpeg (or png/tiff/dng)",
            found=f"{sim.bits}-bit frames",
        )
    if key == "dng":
        if sim.response != "linear":
            raise ParameterError(
                "DNG frames need a linear response (RAW data is linear)",
                expected="'linear'",
                found=repr(sim.response),
            )
        if len(sim.linear_frames) != n:
            raise ParameterError(
                "DNG output needs the linear sensor values",
                expected="simulate_bracket(..., keep_linear=True)",
                found="no linear frames",
            )
    margin_rect = None
    if margins is not None:
        if key != "dng":
            raise ParameterError(
                "masked margins are a RAW (DNG) feature", expected="fmt 'dng'", found=repr(key)
            )
        margin_rect = parse_margins(margins)
    out = Path(outdir)
    if out.exists() and not out.is_dir():
        raise OutputError("output directory is a file", path=out, expected="a directory")
    out.mkdir(parents=True, exist_ok=True)

    width = max(2, len(str(n - 1)))
    names = [f"{stem}{k:0{width}d}{FORMATS[key]}" for k in range(n)]
    frame_paths = [out / name for name in names]
    truth_path = out / "truth.json"
    times_path = out / "exposure_times.txt"
    for p in [*frame_paths, truth_path, times_path]:
        check_output_path(p, force=force)

    times = tuple(as_rational(t, what="exposure time") for t in sim.exposure_times)
    captures = [_CAPTURE_START + timedelta(seconds=2 * k) for k in range(n)]

    raw_info: dict[str, Any] | None = None
    if key == "dng":
        black = black_level if black_level is not None else default_black_level(sim.bits)
        white = int(white_level) if white_level is not None else sim.max_level
        black_sites: tuple[int, ...] = (
            (black,) * 4 if isinstance(black, (int, np.integer)) else tuple(int(b) for b in black)
        )
        file_max = int(white - max(black_sites))
        raw_info = {
            "cfa_pattern": cfa_pattern.upper(),
            "black_level": [int(b) for b in black_sites],
            "black_level_layout": "per 2x2 CFA site, row-major",
            "white_level": white,
            "max_level": file_max,
            "read_noise_sigma": sim.noise_sigma,
            "read_noise_units": "raw numbers (DN)",
            "mapping": "raw = black + clip(x + shot, 0, 1) * (white - max(black)) + read noise",
        }
        if margin_rect is not None:
            top, left, bottom, right = margin_rect
            h, w = sim.frames[0].shape[:2]
            raw_info["masked_margins"] = {
                "top": top,
                "left": left,
                "bottom": bottom,
                "right": right,
                "stored_shape": [h + top + bottom, w + left + right],
                "active_area": [top, left, top + h, left + w],
                "masked_areas_tag": bool(masked_areas),
                "content": "black level + read noise of read_noise_sigma (no light)",
                "libraw_black": "measured from the masked pixels (integer part of their mean "
                "per CFA site)"
                if masked_areas
                else "the BlackLevel tag",
            }
    elif sim.bits == 8:
        file_max = 255
    elif sixteen_bit == "keep" or sim.bits == 16:
        file_max = sim.max_level
    else:
        file_max = 65535

    for k, path in enumerate(frame_paths):
        meta: dict[str, Any] = {
            "exposure_time": times[k],
            "f_number": f_number,
            "iso": iso,
            "capture_time": captures[k],
        }
        if raw_info is not None:
            rng = np.random.default_rng([sim.seed, 104729, k])
            cfa = linear_to_raw(
                mosaic(sim.linear_frames[k], cfa_pattern),
                black_level=black_sites,
                white_level=raw_info["white_level"],
                noise_sigma=sim.noise_sigma,
                shot_noise_full_well=sim.shot_noise_full_well,
                rng=rng,
            )
            areas: dict[str, Any] = {}
            if margin_rect is not None:
                # Drawn after the active area from the same generator: its numbers are unchanged.
                sensor = add_masked_margins(
                    cfa,
                    margin_rect,
                    black_level=black_sites,
                    white_level=raw_info["white_level"],
                    noise_sigma=sim.noise_sigma,
                    rng=rng,
                )
                cfa = sensor.data
                areas = {
                    "active_area": sensor.active_area,
                    "masked_areas": sensor.masked_areas if masked_areas else (),
                }
            data = encode_dng(
                cfa,
                pattern=cfa_pattern,
                black_level=black_sites,
                white_level=raw_info["white_level"],
                **areas,
                **meta,
            )
        else:
            image = frame_file_levels(sim.frames[k], sim.bits, key, sixteen_bit)
            exif = exif_payload(**meta)
            if key == "png":
                data = _png_with_exif(image, exif)
            elif key == "tiff":
                data = _tiff_rgb(image, meta)
            else:
                data = _jpeg(image, exif, jpeg_quality)
        atomic_write(path, partial(_write_bytes, data=data), force=force)

    lines = ["# name seconds (exact; written by the hdrcore simulator, ground truth in truth.json)"]
    lines += [f"{name} {t}  # {float(t):.9g}" for name, t in zip(names, times, strict=True)]
    times_text = "\n".join(lines) + "\n"
    atomic_write(times_path, lambda tmp: tmp.write_text(times_text, encoding="utf-8"), force=force)

    truth = sim.truth()
    truth["format"] = key
    truth["file_max_level"] = file_max
    if key in ("png", "tiff") and sim.bits not in (8, 16):
        truth["file_levels"] = (
            f"round(level * 65535 / {sim.max_level})"
            if file_max == 65535
            else "native levels in a 16-bit container"
        )
    if raw_info is not None:
        truth["raw"] = raw_info
    truth["frames"] = [
        {
            "index": k,
            "file": names[k],
            "exposure_time": float(times[k]),
            "exposure_time_exact": str(times[k]),
            "to_reference": np.asarray(sim.to_reference[k]).tolist(),
        }
        for k in range(n)
    ]
    truth["exposure_times_file"] = times_path.name
    text = json.dumps(truth, indent=2) + "\n"
    atomic_write(truth_path, lambda tmp: tmp.write_text(text, encoding="utf-8"), force=force)
    return WrittenBracket(
        directory=out,
        format=key,
        frames=tuple(frame_paths),
        exposure_times=times,
        truth=truth_path,
        times_file=times_path,
        file_max_level=file_max,
    )
