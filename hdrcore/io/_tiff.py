"""A small TIFF encoder (little-endian, classic TIFF): directory entries, IFDs, EXIF tags.

Used to write DNG files (:mod:`hdrcore.io.dng`) and by the simulator's DNG/JPEG/PNG writers
(:mod:`hdrcore.synthetic.dng`).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from fractions import Fraction

import numpy as np

from ..errors import ParameterError

_TYPES = {  # TIFF type code -> (struct format of one value, size in bytes)
    1: ("B", 1),  # BYTE
    2: ("c", 1),  # ASCII
    3: ("H", 2),  # SHORT
    4: ("I", 4),  # LONG
    5: ("II", 8),  # RATIONAL
    7: ("B", 1),  # UNDEFINED
    10: ("ii", 8),  # SRATIONAL
}


@dataclass(frozen=True)
class TiffTag:
    """One TIFF directory entry: numeric ``tag``, TIFF ``type`` code and its ``values``.

    ASCII values are a ``str`` (NUL-terminated on encoding); rationals are ``Fraction``s.
    """

    tag: int
    type: int
    values: tuple | str | bytes

    def payload(self) -> tuple[int, bytes]:
        """(count, little-endian bytes) of the value."""
        if self.type == 2:
            data = str(self.values).encode("ascii") + b"\x00"
            return len(data), data
        if self.type in (1, 7) and isinstance(self.values, bytes):
            return len(self.values), self.values
        vals = tuple(self.values)
        fmt, _ = _TYPES[self.type]
        if self.type in (5, 10):
            flat: list[int] = []
            for v in vals:
                f = Fraction(v)
                flat += [f.numerator, f.denominator]
            return len(vals), struct.pack("<" + fmt[0] * len(flat), *flat)
        return len(vals), struct.pack("<" + fmt * len(vals), *(int(v) for v in vals))


def _encode_ifd(tags: Sequence[TiffTag], offset: int, next_ifd: int = 0) -> bytes:
    """Bytes of one IFD placed at ``offset``, followed by its out-of-line values."""
    tags = sorted(tags, key=lambda t: t.tag)
    n = len(tags)
    data_at = offset + 2 + 12 * n + 4
    entries = [struct.pack("<H", n)]
    extra = bytearray()
    for t in tags:
        count, payload = t.payload()
        if len(payload) <= 4:
            entries.append(struct.pack("<HHI", t.tag, t.type, count) + payload.ljust(4, b"\x00"))
        else:
            if len(extra) % 2:
                extra += b"\x00"
            entries.append(struct.pack("<HHII", t.tag, t.type, count, data_at + len(extra)))
            extra += payload
    if len(extra) % 2:
        extra += b"\x00"
    entries.append(struct.pack("<I", next_ifd))
    return b"".join(entries) + bytes(extra)


def encode_tiff(
    ifd0: Sequence[TiffTag],
    *,
    exif: Sequence[TiffTag] = (),
    image: bytes = b"",
) -> bytes:
    """A little-endian TIFF: header, IFD0, optional EXIF IFD, then ``image`` as one strip.

    When ``image`` is given, StripOffsets (273) and StripByteCounts (279) are filled in; when
    ``exif`` is given, the ExifIFD pointer (34665) is. Other tags are written as they are.
    """
    auto = {273, 279, 34665}
    base = [t for t in ifd0 if t.tag not in auto]

    def build(strip_at: int, exif_at: int) -> list[TiffTag]:
        tags = list(base)
        if image:
            tags += [TiffTag(273, 4, (strip_at,)), TiffTag(279, 4, (len(image),))]
        if exif:
            tags.append(TiffTag(34665, 4, (exif_at,)))
        return tags

    # Sizes do not depend on the pointer values (all inline LONGs): lay out, then fill in.
    ifd0_len = len(_encode_ifd(build(0, 0), 8))
    exif_at = 8 + ifd0_len
    exif_bytes = _encode_ifd(exif, exif_at) if exif else b""
    strip_at = exif_at + len(exif_bytes)
    strip_at += strip_at % 2
    ifd0_bytes = _encode_ifd(build(strip_at, exif_at), 8)
    out = bytearray(b"II*\x00" + struct.pack("<I", 8))
    out += ifd0_bytes + exif_bytes
    out += b"\x00" * (strip_at - len(out))
    out += image
    return bytes(out)


def as_rational(value: Fraction | float | int, *, what: str = "value") -> Fraction:
    """An exact fraction that fits a TIFF RATIONAL (32-bit numerator and denominator).

    Fractions stay as they are; floats become the simplest fraction within 1e-6 relative (so
    ``1/3049`` as a float is written as 1/3049).
    """
    if isinstance(value, Fraction):
        f = value
    else:
        v = float(value)
        if not np.isfinite(v):
            raise ParameterError(f"{what} must be finite", found=str(value))
        f = Fraction(v).limit_denominator(1_000_000)
    if f < 0 or f.numerator > 0xFFFFFFFF or f.denominator > 0xFFFFFFFF:
        f2 = f.limit_denominator(0xFFFF)
        if f2 < 0 or f2.numerator > 0xFFFFFFFF:
            raise ParameterError(f"{what} does not fit a TIFF rational", found=str(value))
        f = f2
    return f


def _exif_time(t: datetime) -> str:
    return t.strftime("%Y:%m:%d %H:%M:%S")


def exif_tags(
    exposure_time: Fraction | float | None,
    f_number: Fraction | float | None,
    iso: int | None,
    capture_time: datetime | None,
) -> list[TiffTag]:
    """EXIF-IFD entries: ExifVersion, ExposureTime (exact), FNumber, ISO, DateTimeOriginal."""
    tags = [TiffTag(36864, 7, b"0230")]
    if exposure_time is not None:
        t = as_rational(exposure_time, what="exposure time")
        if t <= 0:
            raise ParameterError("exposure time must be positive", found=str(exposure_time))
        tags.append(TiffTag(33434, 5, (t,)))
    if f_number is not None:
        tags.append(TiffTag(33437, 5, (as_rational(f_number, what="f-number"),)))
    if iso is not None:
        tags.append(TiffTag(34855, 3, (int(iso),)))
    if capture_time is not None:
        tags.append(TiffTag(36867, 2, _exif_time(capture_time)))
    return tags
