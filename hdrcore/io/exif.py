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

__all__ = ["ExifData", "read_exif", "parse_exif_tags"]

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
