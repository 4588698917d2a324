"""JPEG, PNG and TIFF frames (8 or 16 bits per channel): integer levels, upright, EXIF read.

Pillow decodes 8-bit JPEG/PNG; 16-bit PNG goes through imagecodecs (Pillow narrows 16-bit RGB to
8 bits) and TIFF through tifffile. The EXIF orientation is applied here, once, so every later stage
sees upright pixels. Values stay integer code values: they are non-linear until a camera response
is applied. The size the header declares is checked against the pixel limit before any decoder
runs (:mod:`hdrcore.io.header`).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np

from ..errors import ImageReadError
from .colour_space import file_colour_space
from .exif import ExifData, read_exif
from .frame import Frame, FrameMetadata, apply_orientation
from .header import allow_pillow_pixels, check_frame_pixels, image_size

if TYPE_CHECKING:
    import tifffile

__all__ = ["read_ldr", "sniff_format"]

_MAGIC = (
    (b"\xff\xd8\xff", "jpeg"),
    (b"\x89PNG\r\n\x1a\n", "png"),
    (b"II*\x00", "tiff"),
    (b"MM\x00*", "tiff"),
)


def sniff_format(path: Path) -> str | None:
    """``"jpeg"``, ``"png"``, ``"tiff"`` from the file's first bytes, or ``None``."""
    with open(path, "rb") as fh:
        head = fh.read(16)
    for magic, fmt in _MAGIC:
        if head.startswith(magic):
            return fmt
    return None


def _png_bit_depth(path: Path) -> int:
    with open(path, "rb") as fh:
        head = fh.read(33)
    if len(head) < 25 or head[12:16] != b"IHDR":
        raise ImageReadError("PNG header is damaged", path=path)
    return int(head[24])


def _to_rgb(arr: np.ndarray, path: Path) -> np.ndarray:
    if arr.ndim == 2:
        return np.repeat(arr[..., None], 3, axis=2)
    if arr.ndim == 3 and arr.shape[2] in (3, 4):
        return arr[..., :3]
    if arr.ndim == 3 and arr.shape[2] == 2:  # grey + alpha
        return np.repeat(arr[..., :1], 3, axis=2)
    if arr.ndim == 3 and arr.shape[2] == 1:
        return np.repeat(arr, 3, axis=2)
    raise ImageReadError(
        "unsupported pixel layout", path=path, expected="grey, RGB or RGBA", found=str(arr.shape)
    )


def _decode_pillow(path: Path, max_pixels: int | None) -> np.ndarray:
    from PIL import Image, UnidentifiedImageError

    allow_pillow_pixels(max_pixels)
    try:
        with Image.open(path) as opened:
            opened.load()
            im: Image.Image = opened
            if im.mode in ("P", "PA", "CMYK", "YCbCr", "LAB", "HSV", "1"):
                im = im.convert("RGB")
            if im.mode in ("I;16", "I;16B", "I;16L", "I"):
                arr = np.asarray(im).astype(np.uint16)
            else:
                arr = np.asarray(im)
    except UnidentifiedImageError as exc:
        raise ImageReadError("not an image Pillow can read", path=path) from exc
    except Image.DecompressionBombError as exc:  # only if Pillow's limit was lowered meanwhile
        raise ImageReadError(
            f"Pillow refuses to decode it as too large ({exc})", path=path
        ) from exc
    except (OSError, SyntaxError, ValueError) as exc:
        raise ImageReadError(f"image data is damaged or truncated ({exc})", path=path) from exc
    return arr


def _decode_png16(path: Path) -> np.ndarray:
    import imagecodecs

    try:
        return np.asarray(imagecodecs.png_decode(path.read_bytes()))
    except Exception as exc:  # imagecodecs raises its own PngError and others
        raise ImageReadError(f"PNG data is damaged or truncated ({exc})", path=path) from exc


def _decode_tiff(path: Path) -> tuple[np.ndarray, int | None]:
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            page = cast("tifffile.TiffPage", tif.pages[0])  # page 0 is never a TiffFrame
            orient_tag = page.tags.get(274)
            orientation = int(orient_tag.value) if orient_tag is not None else None
            arr = page.asarray()
    except Exception as exc:  # tifffile raises TiffFileError, ValueError, OSError, ...
        raise ImageReadError(f"TIFF data is damaged or unsupported ({exc})", path=path) from exc
    return arr, orientation


def read_ldr(path: str | Path, fmt: str | None = None, *, max_pixels: int | None = None) -> Frame:
    """Read a JPEG, PNG or TIFF frame as integer levels ``(H, W, 3)`` uint16, upright.

    ``max_pixels``: the pixel limit (:func:`hdrcore.io.header.pixel_limit`; ``None`` the
    default, 0 none), checked from the header before anything is decoded.
    """
    p = Path(path)
    fmt = fmt or sniff_format(p)
    if fmt is None:
        raise ImageReadError(
            "not a recognised image", path=p, expected="JPEG, PNG, TIFF or a camera RAW file"
        )
    check_frame_pixels(p, *image_size(p, fmt), max_pixels)
    exif: ExifData = read_exif(p)
    space = file_colour_space(p, fmt, exif)
    orientation = exif.orientation
    if fmt == "png" and _png_bit_depth(p) == 16:
        arr = _decode_png16(p)
    elif fmt == "tiff":
        arr, tiff_orientation = _decode_tiff(p)
        orientation = orientation if orientation is not None else tiff_orientation
    else:
        arr = _decode_pillow(p, max_pixels)

    if arr.dtype == np.uint8:
        bit_depth = 8
    elif arr.dtype == np.uint16:
        bit_depth = 16
    else:
        raise ImageReadError(
            "unsupported sample type",
            path=p,
            expected="8- or 16-bit integers",
            found=str(arr.dtype),
        )
    if arr.size == 0 or min(arr.shape[:2]) < 2:
        raise ImageReadError("image is empty", path=p, found=str(arr.shape))
    rgb = _to_rgb(arr, p)
    rgb = apply_orientation(rgb, orientation)
    levels = np.ascontiguousarray(rgb, dtype=np.uint16)
    max_level = (1 << bit_depth) - 1
    meta = FrameMetadata(
        path=str(p),
        format=fmt,
        bit_depth=bit_depth,
        max_level=max_level,
        is_linear=False,
        exposure_time=exif.exposure_time,
        exposure_time_source="exif" if exif.exposure_time is not None else None,
        f_number=exif.f_number,
        iso=exif.iso,
        exposure_bias=exif.exposure_bias,
        make=exif.make,
        model=exif.model,
        capture_time=exif.capture_time,
        orientation=orientation,
        black_level=(0.0, 0.0, 0.0),
        white_level=max_level,
        channel_max_levels=(max_level,) * 3,
        colour_space=space.name,
        colour_space_source=space.source,
    )
    return Frame(levels=levels, meta=meta)
