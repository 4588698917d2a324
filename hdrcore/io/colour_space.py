"""The RGB colour space a JPEG, PNG or TIFF frame is encoded in: its embedded ICC profile's
name, else the EXIF ColorSpace tag (with the DCF interoperability index for Adobe RGB).

Phones save Display P3 (iPhones, recent Android phones) and cameras set to it save Adobe RGB;
merged as if they were sRGB, their saturated colours come out dull or shifted. The name is read
from the profile's description tag (ICC v2 ``desc`` or v4 ``mluc``): the profiles these files
carry are the standard ones, named as such. A profile of another name is reported as it is and
the frame is treated as sRGB (:func:`known_space` gives ``None``).
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import NamedTuple

from .exif import ExifData

__all__ = ["ColourSpace", "exif_space", "file_colour_space", "icc_description", "known_space"]

#: Words in an ICC profile's description -> the working-space name
#: (:data:`hdrcore.merge.colour.WORKING_SPACES`), first match wins.
_NAMES = (
    ("display p3", "Display P3"),
    ("p3", "Display P3"),
    ("adobe rgb", "Adobe RGB (1998)"),
    ("adobergb", "Adobe RGB (1998)"),
    ("prophoto", "ProPhoto RGB"),
    ("romm", "ProPhoto RGB"),
    ("2020", "Rec.2020"),
    ("srgb", "sRGB"),
    ("61966-2", "sRGB"),
)


class ColourSpace(NamedTuple):
    """``name``: a working-space name, or ``None`` (not stated, or a profile we do not know:
    ``source`` then holds its description); ``source``: where it was read."""

    name: str | None
    source: str | None


def icc_description(icc: bytes) -> str | None:
    """The description of an ICC profile (v2 ``desc``, v4 ``mluc``), or ``None``."""
    if len(icc) < 132:
        return None
    try:
        (count,) = struct.unpack_from(">I", icc, 128)
        for i in range(min(count, 200)):
            sig, off, size = struct.unpack_from(">4sII", icc, 132 + 12 * i)
            if sig != b"desc" or off + size > len(icc) or size < 12:
                continue
            kind = icc[off : off + 4]
            if kind == b"desc":  # v2: ASCII count, then the text
                (n,) = struct.unpack_from(">I", icc, off + 8)
                text = icc[off + 12 : off + 12 + n].split(b"\0")[0]
                return text.decode("latin-1").strip() or None
            if kind == b"mluc":  # v4: records of (language, country, length, offset), UTF-16BE
                (records,) = struct.unpack_from(">I", icc, off + 8)
                if records < 1:
                    return None
                length, start = struct.unpack_from(">II", icc, off + 20)
                text = icc[off + start : off + start + length]
                return text.decode("utf-16-be", "replace").strip("\0 ") or None
            return None
    except struct.error:
        return None
    return None


def known_space(description: str | None) -> str | None:
    """The working-space name a profile description names, or ``None``."""
    if not description:
        return None
    low = description.lower()
    for word, name in _NAMES:
        if word in low:
            return name
    return None


def _icc_bytes(path: Path, fmt: str) -> bytes | None:
    if fmt == "tiff":
        import tifffile

        try:
            with tifffile.TiffFile(path) as tif:
                page = tif.pages.first  # a TiffPage (page 0 is never a TiffFrame)
                tag = page.tags.get(34675)  # InterColorProfile
                return None if tag is None else bytes(tag.value)
        except Exception:  # the pixels' reader reports a damaged file
            return None
    from PIL import Image

    try:
        with Image.open(path) as im:
            icc = im.info.get("icc_profile")
            return bytes(icc) if icc else None
    except Exception:
        return None


def exif_space(colour_space: int | None, interop_index: str | None) -> str | None:
    """EXIF ColorSpace 1 is sRGB; 65535 (uncalibrated) with the DCF interoperability index
    "R03" is Adobe RGB (how cameras mark it without a profile); else ``None``."""
    if colour_space == 1:
        return "sRGB"
    if colour_space == 0xFFFF and (interop_index or "").strip("\0 ") == "R03":
        return "Adobe RGB (1998)"
    return None


def file_colour_space(path: str | Path, fmt: str, exif: ExifData | None = None) -> ColourSpace:
    """The colour space ``path`` (a ``fmt`` "jpeg", "png" or "tiff" file, whose EXIF is
    ``exif``) is encoded in."""
    p = Path(path)
    icc = _icc_bytes(p, fmt)
    if icc:
        desc = icc_description(icc)
        name = known_space(desc)
        return ColourSpace(name, f"ICC profile '{desc}'" if desc else "ICC profile (unnamed)")
    if exif is not None:
        name = exif_space(exif.colour_space, exif.interop_index)
        if name is not None:
            return ColourSpace(name, "EXIF ColorSpace")
    return ColourSpace(None, None)
