"""EXIF metadata of a frame, read with ExifRead; exact rationals, ``None`` when absent.

Exposure times are kept as :class:`fractions.Fraction` straight from the EXIF rational, so 1/3049 s
comes out as exactly ``Fraction(1, 3049)``, never a rounded float. Nothing is invented: a field the
file does not carry is ``None``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from datetime import datetime
from fractions import Fraction
from pathlib import Path
from typing import Any

__all__ = ["ExifData", "read_exif", "parse_exif_tags", "read_ciff_make_model"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ExifData:
    """The EXIF fields the pipeline uses. Every field is ``None`` when the file lacks it."""

    exposure_time: Fraction | None = None
    f_number: Fraction | None = None
    iso: int | None = None
    exposure_bias: Fraction | None = None
    make: str | None = None
    model: str | None = None
    capture_time: datetime | None = None
    orientation: int | None = None
    #: fraction of a second of ``capture_time`` (``SubSecTimeOriginal``: "123" -> 0.123)
    capture_subsec: float | None = None
    #: ``ColorSpace`` (1 sRGB, 65535 uncalibrated) and the DCF ``InteroperabilityIndex``
    #: ("R98" sRGB, "R03" Adobe RGB): how a camera marks Adobe RGB without a profile
    colour_space: int | None = None
    interop_index: str | None = None


def _first(tag: Any) -> Any:
    values = getattr(tag, "values", tag)
    if isinstance(values, (list, tuple)):
        return values[0] if values else None
    return values


def _fraction(tag: Any) -> Fraction | None:
    if tag is None:
        return None
    v = _first(tag)
    if v is None:
        return None
    num = getattr(v, "num", None)
    den = getattr(v, "den", None)
    try:
        if num is not None and den is not None:
            if int(den) == 0:
                return None
            return Fraction(int(num), int(den))
        return Fraction(str(v))
    except (ValueError, ZeroDivisionError, TypeError):
        return None


def _int(tag: Any) -> int | None:
    if tag is None:
        return None
    v = _first(tag)
    try:
        return int(v)
    except (TypeError, ValueError):
        return None


def _str(tag: Any) -> str | None:
    if tag is None:
        return None
    s = str(getattr(tag, "printable", tag)).strip().strip("\x00").strip()
    return s or None


def _time(tag: Any) -> datetime | None:
    s = _str(tag)
    if not s:
        return None
    for fmt in ("%Y:%m:%d %H:%M:%S", "%Y-%m-%d %H:%M:%S", "%Y:%m:%d %H:%M:%S.%f"):
        try:
            return datetime.strptime(s[:26], fmt)
        except ValueError:
            continue
    return None


def _subsec(tag: Any) -> float | None:
    s = _str(tag)
    if not s or not s.isdigit():
        return None
    return int(s) / 10 ** len(s)


def parse_exif_tags(tags: dict[str, Any]) -> ExifData:
    """Build :class:`ExifData` from an ExifRead tag dictionary."""

    def get(*names: str) -> Any:
        for n in names:
            if n in tags:
                return tags[n]
        return None

    exposure = _fraction(get("EXIF ExposureTime", "Image ExposureTime"))
    if exposure is not None and exposure <= 0:
        exposure = None
    fnum = _fraction(get("EXIF FNumber", "Image FNumber"))
    if fnum is not None and fnum <= 0:
        fnum = None
    iso = _int(get("EXIF ISOSpeedRatings", "EXIF PhotographicSensitivity", "Image ISOSpeedRatings"))
    if iso is not None and iso <= 0:
        iso = None
    return ExifData(
        exposure_time=exposure,
        f_number=fnum,
        iso=iso,
        exposure_bias=_fraction(get("EXIF ExposureBiasValue", "Image ExposureBiasValue")),
        make=_str(get("Image Make")),
        model=_str(get("Image Model")),
        capture_time=_time(
            get("EXIF DateTimeOriginal", "Image DateTimeOriginal", "Image DateTime")
        ),
        orientation=_int(get("Image Orientation")),
        capture_subsec=_subsec(get("EXIF SubSecTimeOriginal", "EXIF SubSecTime")),
        colour_space=_int(get("EXIF ColorSpace")),
        interop_index=_str(get("Interoperability InteroperabilityIndex")),
    )


def read_exif(path: str | Path) -> ExifData:
    """EXIF of the file at ``path``; empty :class:`ExifData` when it has none or is unparsable."""
    import exifread

    # ExifRead logs a warning for every file without EXIF (most PNGs); absence is normal here.
    logging.getLogger("exifread").setLevel(logging.ERROR)
    try:
        with open(path, "rb") as fh:
            tags = exifread.process_file(fh, details=False)
    except Exception as exc:  # ExifRead raises many types on odd files; metadata is optional
        log.debug("no EXIF in %s: %s", path, exc)
        return ExifData()
    return parse_exif_tags(tags or {})


#: CIFF (Canon's CRW): the record holding "Make\0Model\0" (ASCII type 0x0800, code 0x0a).
_CIFF_MAKE_MODEL = 0x080A


def read_ciff_make_model(path: str | Path) -> tuple[str | None, str | None]:
    """Make and model of a Canon CRW (CIFF) file, which ExifRead does not read (it holds no TIFF
    EXIF): the heap records' ``0x080a`` entry, found by walking the heaps (bounded: at most 8
    levels, entries within their heap); ``(None, None)`` for any other file or a damaged one.
    Format: Canon's CIFF 1.0r4 (a 26-byte header ``II``/``MM``, length, ``HEAPCCDR``; each heap's
    last four bytes point at its table of 10-byte entries ``tag, size, offset``)."""
    import struct

    try:
        with open(path, "rb") as fh:
            head = fh.read(14)
            if len(head) < 14 or head[6:14] != b"HEAPCCDR" or head[:2] not in (b"II", b"MM"):
                return None, None
            data = head + fh.read()
    except OSError:
        return None, None
    if len(data) < 26:
        return None, None
    e = "<" if data[:2] == b"II" else ">"

    def walk(start: int, end: int, depth: int) -> tuple[str | None, str | None] | None:
        if depth > 8 or end - start < 4 or end > len(data):
            return None
        (table,) = struct.unpack_from(e + "I", data, end - 4)
        at = start + table
        if at + 2 > end:
            return None
        (count,) = struct.unpack_from(e + "H", data, at)
        for k in range(min(count, (end - at - 2) // 10)):
            tag, size, offset = struct.unpack_from(e + "HII", data, at + 2 + 10 * k)
            if tag & 0xC000:  # data inside the entry: no make or model there
                continue
            lo, hi = start + offset, start + offset + size
            if hi > end or lo < start:
                continue
            if tag & 0x3FFF == _CIFF_MAKE_MODEL:
                parts = data[lo:hi].split(b"\0")
                words = [p.decode("latin-1").strip() for p in parts[:2]]
                make = words[0] if words and words[0] else None
                model = words[1] if len(words) > 1 and words[1] else None
                return make, model
            if tag & 0x3800 in (0x2800, 0x3000):  # a sub-heap
                found = walk(lo, hi, depth + 1)
                if found is not None:
                    return found
        return None

    (header,) = struct.unpack_from(e + "I", data, 2)
    return walk(header, len(data), 0) or (None, None)
