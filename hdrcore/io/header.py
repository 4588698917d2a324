"""A frame's size read from its header, before any pixel is decoded, and the pixel limit.

A small file can declare an enormous image (a PNG of a few hundred bytes that says 20000x20000
needs 2.4 GB once decoded), so every reader checks the declared size against a limit first:
:data:`MAX_FRAME_PIXELS` unless the caller sets its own (``max_pixels``; 0 means no limit).
PNG and JPEG sizes come from their own headers (the IHDR chunk, the SOF marker), TIFF from
tifffile's first page, RAW from LibRaw's ``sizes`` after ``open_file`` (which unpacks nothing).
Pillow's own decompression-bomb limit is raised to ours before Pillow decodes a frame, so it
never fires first (:func:`allow_pillow_pixels`).
"""

from __future__ import annotations

import os
import struct
import threading
from pathlib import Path

from ..errors import FrameTooLargeError, ImageReadError
from ._capture import c_stderr, reading
from ._paths import input_file

__all__ = ["MAX_FRAME_PIXELS", "frame_pixels", "check_frame_pixels", "pixel_limit"]

#: Largest frame read by default, in pixels: 160 MP holds the 151 MP (14204 x 10652) of
#: today's largest medium-format backs; a 16-bit RGB frame of that size is about 1 GB decoded.
MAX_FRAME_PIXELS = 160_000_000

_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
# JPEG start-of-frame markers: SOF0..SOF15 except DHT (C4), JPG (C8) and DAC (CC).
_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
_STANDALONE = frozenset(range(0xD0, 0xDA)) | {0x01}


def pixel_limit(max_pixels: int | None) -> int:
    """The limit in force: :data:`MAX_FRAME_PIXELS` for ``None``, 0 for none."""
    return MAX_FRAME_PIXELS if max_pixels is None else max(0, int(max_pixels))


def _png_size(path: Path) -> tuple[int, int]:
    with open(path, "rb") as fh:
        head = fh.read(24)
    if len(head) < 24 or head[12:16] != b"IHDR":
        raise ImageReadError("PNG header is damaged or truncated", path=path)
    return struct.unpack(">II", head[16:24])


def _jpeg_size(path: Path) -> tuple[int, int]:
    """Width and height from the first SOF marker (the segments before it are skipped)."""
    with open(path, "rb") as fh:
        if fh.read(2) != b"\xff\xd8":
            raise ImageReadError("JPEG header is damaged", path=path)
        while True:
            byte = fh.read(1)
            if not byte:
                break
            if byte != b"\xff":
                continue
            marker = fh.read(1)
            while marker == b"\xff":  # fill bytes
                marker = fh.read(1)
            if not marker:
                break
            code = marker[0]
            if code in _STANDALONE or code == 0x00:
                continue
            if code == 0xD9 or code == 0xDA:  # end of image, start of scan: no SOF before it
                break
            length_bytes = fh.read(2)
            if len(length_bytes) < 2:
                break
            (length,) = struct.unpack(">H", length_bytes)
            if code in _SOF:
                body = fh.read(5)
                if len(body) < 5:
                    break
                height, width = struct.unpack(">HH", body[1:5])
                if width == 0 or height == 0:  # height in a later DNL marker: rare, unsupported
                    raise ImageReadError(
                        "JPEG header gives no image size", path=path, found=f"{width}x{height}"
                    )
                return width, height
            fh.seek(length - 2, os.SEEK_CUR)
    raise ImageReadError("JPEG header is damaged or truncated (no frame header found)", path=path)


def _tiff_size(path: Path) -> tuple[int, int]:
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            page = tif.pages.first
            return int(page.imagewidth), int(page.imagelength)
    except Exception as exc:  # tifffile raises TiffFileError, ValueError, struct.error, ...
        raise ImageReadError(f"TIFF header is damaged ({exc})", path=path) from exc


def _raw_size(path: Path) -> tuple[int, int]:
    import rawpy

    from .raw import libraw_error

    failure: rawpy.LibRawError | None = None
    with c_stderr(path) as said:  # filled when the block ends
        try:
            with rawpy.imread(str(path)) as raw:  # LibRaw's open_file: the header, no unpack
                sizes = raw.sizes
                width, height = int(sizes.width), int(sizes.height)
        except rawpy.LibRawError as exc:
            failure = exc
    if failure is not None:
        raise libraw_error(path, failure, said) from failure
    return width, height


_HEADER_READERS = {"png": _png_size, "jpeg": _jpeg_size, "tiff": _tiff_size}


def image_size(path: Path, fmt: str) -> tuple[int, int]:
    """``(width, height)`` from the header of a ``"png"``, ``"jpeg"`` or ``"tiff"`` file."""
    return _HEADER_READERS[fmt](path)


def frame_pixels(path: str | os.PathLike) -> tuple[int, int]:
    """``(width, height)`` of the frame at ``path`` as stored (before its EXIF orientation),
    read from the header only: no pixel data is decoded and nothing large is allocated.

    Raises :class:`~hdrcore.errors.InputError` (or its :class:`~hdrcore.errors.ImageReadError`)
    when the file cannot be read or is not a JPEG, PNG, TIFF or RAW file.
    """
    from .ldr import sniff_format
    from .raw import is_raw_path

    p = input_file(path)
    with reading(p):
        if is_raw_path(p):
            return _raw_size(p)
        try:
            fmt = sniff_format(p)
        except OSError as exc:
            raise ImageReadError(f"cannot read file ({exc.strerror})", path=p) from exc
        if fmt is not None:
            return image_size(p, fmt)
    raise ImageReadError(
        "not a recognised image",
        path=p,
        expected="JPEG, PNG, TIFF or a camera RAW file (.dng, .cr2, .nef, ...)",
    )


def check_frame_pixels(
    path: str | os.PathLike, width: int, height: int, max_pixels: int | None
) -> None:
    """Raise :class:`~hdrcore.errors.FrameTooLargeError` when ``width x height`` is more than
    the limit (:func:`pixel_limit` of ``max_pixels``)."""
    limit = pixel_limit(max_pixels)
    if limit and int(width) * int(height) > limit:
        raise FrameTooLargeError(path, width=width, height=height, limit=limit)


_PILLOW_LOCK = threading.Lock()


def allow_pillow_pixels(max_pixels: int | None) -> None:
    """Raise Pillow's ``Image.MAX_IMAGE_PIXELS`` (never lower it) to the limit in force, so
    its decompression-bomb warning or error never fires before our own check, which has
    already passed when Pillow decodes; no limit (0) switches Pillow's off too."""
    from PIL import Image

    limit = pixel_limit(max_pixels)
    with _PILLOW_LOCK:
        current = Image.MAX_IMAGE_PIXELS
        if current is None:
            return
        if limit == 0:
            Image.MAX_IMAGE_PIXELS = None
        elif limit > current:
            Image.MAX_IMAGE_PIXELS = limit
