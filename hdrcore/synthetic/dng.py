"""Bayer-CFA DNG files from simulated linear sensor values, so the RAW path is tested end to end.

The sensor model follows the seed's simulation protocol (Cerman & Hlavac 2006, sections 4.2 and
5.3) with a linear response: a linear RGB frame ``x`` (1.0 = saturation) is mosaicked through a
colour filter array, scaled by one gain for every site and offset by the (per-site) black level,
``raw = black + s(x) * (white - max(black))``, with optional photon shot noise (before the
saturation ``s``) and Gaussian read noise (in raw units), then rounded and clipped to
``[0, white]``. So black-subtracted raw values are ``x * max_level`` with ``max_level = white -
max(black)`` (the loader's ``max_level``) at every site; values below black occur, as on sensors.

The file is a single-IFD DNG (IFD0 holds the uncompressed 16-bit CFA strip and the DNG tags) with an
EXIF sub-IFD for the exposure (ExposureTime as an exact rational, FNumber, ISO, DateTimeOriginal).
It is written by the small TIFF encoder below rather than a library, so every tag is under control
and ExifRead finds the EXIF fields where cameras put them. LibRaw (rawpy) reads these files back
with the written pattern, black and white levels; ExifRead returns the exposure time exactly.

Tag layout (TIFF type in brackets):

IFD0: NewSubFileType 254 [LONG] 0; ImageWidth 256, ImageLength 257 [LONG]; BitsPerSample 258
[SHORT] 16; Compression 259 [SHORT] 1; PhotometricInterpretation 262 [SHORT] 32803 (CFA);
Make 271, Model 272 [ASCII]; StripOffsets 273 [LONG]; Orientation 274 [SHORT]; SamplesPerPixel 277
[SHORT] 1; RowsPerStrip 278 [LONG]; StripByteCounts 279 [LONG]; PlanarConfiguration 284 [SHORT] 1;
Software 305, DateTime 306 [ASCII]; CFARepeatPatternDim 33421 [SHORT] 2,2;
CFAPattern 33422 [BYTE] x4;
ExifIFD 34665 [LONG]; DNGVersion 50706 [BYTE] 1.4.0.0; DNGBackwardVersion 50707 [BYTE] 1.1.0.0;
UniqueCameraModel 50708 [ASCII]; CFAPlaneColor 50710 [BYTE] 0,1,2; CFALayout 50711 [SHORT] 1;
BlackLevelRepeatDim 50713 [SHORT] 1,1 or 2,2; BlackLevel 50714 [LONG] x1 or x4;
WhiteLevel 50717 [LONG]; ColorMatrix1 50721 [SRATIONAL] x9; AsShotNeutral 50728 [RATIONAL] x3;
CalibrationIlluminant1 50778 [SHORT] 21 (D65).

EXIF IFD: ExposureTime 33434 [RATIONAL]; FNumber 33437 [RATIONAL]; ISOSpeedRatings 34855 [SHORT];
ExifVersion 36864 [UNDEFINED] "0230"; DateTimeOriginal 36867 [ASCII].

Masked optical-black margins (optional, :func:`add_masked_margins`): real sensors store masked
pixels around the active area; they hold the black level plus read noise and no light. The
stored image is then larger than the active area and IFD0 also carries ActiveArea 50829 [LONG]
top, left, bottom, right and, unless left out, MaskedAreas 50830 [LONG] one top, left, bottom,
right rectangle per margin. LibRaw (0.22) reads them as a camera's: ``raw.raw_image`` is the
whole stored image, ``raw.raw_image_visible`` the active area, ``raw.sizes.top_margin`` /
``left_margin`` its offset. With MaskedAreas, LibRaw also *measures* the black level from the
masked pixels (per CFA site, the integer part of their mean, so up to 1 DN below the written
BlackLevel: what ``raw.black_level_per_channel`` then reports); with ActiveArea alone it reports
the BlackLevel tag. Margins above and left of the active area are even, so the CFA phase is the
same in stored and active coordinates (LibRaw indexes the masked sites in stored coordinates).

References: Adobe, "Digital Negative (DNG) Specification", version 1.4.0.0, 2012; TIFF 6.0;
EXIF 2.3. J. Cerman, V. Hlavac, "Exposure time estimation for high dynamic range imaging with
hand held camera", Computer Vision Winter Workshop, 2006.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import datetime
from fractions import Fraction
from pathlib import Path

import numpy as np

from ..errors import ParameterError
from ..io._tiff import (  # noqa: F401 -- the encoder lives in io; re-exported here
    TiffTag,
    _encode_ifd,
    _exif_time,
    as_rational,
    encode_tiff,
    exif_tags,
)
from ..io.dng import SRGB_XYZ_TO_CAMERA  # noqa: F401 -- re-exported

__all__ = [
    "CFA_PATTERNS",
    "MaskedSensor",
    "SRGB_XYZ_TO_CAMERA",
    "TiffTag",
    "add_masked_margins",
    "as_rational",
    "cfa_channel_map",
    "default_black_level",
    "encode_dng",
    "encode_tiff",
    "exif_payload",
    "exif_tags",
    "linear_to_raw",
    "mosaic",
    "parse_margins",
    "write_dng",
]

# Colour of each site of the repeat cell, row-major (0 red, 1 green, 2 blue: DNG CFAPattern):
# the four 2x2 Bayer cells and Fujifilm's 6x6 X-Trans cell (dcraw's ``xtrans_abs``: 20 green,
# 8 red, 8 blue sites), which DNGs converted from RAF files carry (CFARepeatPatternDim 6x6).
CFA_PATTERNS: dict[str, tuple[int, ...]] = {
    "RGGB": (0, 1, 1, 2),
    "BGGR": (2, 1, 1, 0),
    "GRBG": (1, 0, 2, 1),
    "GBRG": (1, 2, 0, 1),
    "XTRANS": (
        *(1, 1, 0, 1, 1, 2),
        *(1, 1, 2, 1, 1, 0),
        *(2, 0, 1, 0, 2, 1),
        *(1, 1, 2, 1, 1, 0),
        *(1, 1, 0, 1, 1, 2),
        *(0, 2, 1, 2, 0, 1),
    ),
}

# XYZ (D65) -> linear sRGB: the simulated camera's native space is linear sRGB, so ColorMatrix1
# with AsShotNeutral (1, 1, 1) makes colour maths come out as the identity (from hdrcore.io.dng).

_DEFAULT_TIME = datetime(2006, 2, 6, 12, 0, 0)


def _pattern(name: str) -> tuple[int, ...]:
    key = str(name).upper()
    if key not in CFA_PATTERNS:
        raise ParameterError(
            f"unknown CFA pattern {name!r}",
            expected=f"one of {', '.join(CFA_PATTERNS)}",
            found=repr(name),
        )
    return CFA_PATTERNS[key]


def cfa_channel_map(pattern: str, shape: tuple[int, int]) -> np.ndarray:
    """``(H, W)`` int array: the colour channel (0 R, 1 G, 2 B) sampled at each pixel."""
    cells = _pattern(pattern)
    side = _side(cells)
    cell = np.array(cells, np.int64).reshape(side, side)
    h, w = int(shape[0]), int(shape[1])
    return np.tile(cell, (-(-h // side), -(-w // side)))[:h, :w]


def _side(cells: tuple[int, ...]) -> int:
    """Side of a square repeat cell of ``cells`` sites (2 Bayer, 6 X-Trans)."""
    return math.isqrt(len(cells))


def mosaic(rgb: np.ndarray, pattern: str = "RGGB") -> np.ndarray:
    """Sample an ``(H, W, 3)`` frame through a CFA (Bayer or X-Trans): ``(H, W)``, same dtype."""
    arr = np.asarray(rgb)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise ParameterError(
            "mosaic needs an RGB frame", expected="(H, W, 3)", found=str(arr.shape)
        )
    idx = cfa_channel_map(pattern, arr.shape[:2])
    return np.take_along_axis(arr, idx[..., None], axis=2)[..., 0]


def default_black_level(bits: int) -> int:
    """A camera-like black level for a ``bits`` ADC: 1/16 of full scale (256 at 12, 1024 at 14)."""
    if not 8 <= int(bits) <= 16:
        raise ParameterError("unsupported raw bit depth", expected="8..16", found=str(bits))
    return 1 << (int(bits) - 4)


def _black_per_site(black_level: int | Sequence[int]) -> tuple[int, int, int, int]:
    vals = tuple(int(v) for v in np.ravel(black_level))
    if np.ndim(black_level) == 0:
        return (vals[0],) * 4
    if len(vals) != 4:
        raise ParameterError(
            "per-site black level needs one value per 2x2 CFA site",
            expected="4 values (row-major)",
            found=str(len(vals)),
        )
    return vals


def _check_levels(black: tuple[int, ...], white: int) -> None:
    if not 0 < white <= 65535:
        raise ParameterError("white level out of range", expected="1..65535", found=str(white))
    if min(black) < 0 or max(black) >= white:
        raise ParameterError(
            "black level must be >= 0 and below the white level",
            found=f"black {black}, white {white}",
        )


def linear_to_raw(
    linear_cfa: np.ndarray,
    *,
    black_level: int | Sequence[int],
    white_level: int,
    noise_sigma: float = 0.0,
    shot_noise_full_well: float | None = None,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Raw sensor numbers ``(H, W)`` uint16 from mosaicked linear values (1.0 = saturation).

    ``raw = round(black + s(x + shot) * (white - max(black)) + read)``, clipped to
    ``[0, white]``, so ``(raw - black) / (white - max(black))`` recovers ``x`` within quantisation.
    ``black_level`` is one value or four (one per 2x2 CFA site, row-major); ``noise_sigma`` is the
    read noise in raw units; ``shot_noise_full_well`` (electrons at saturation) adds photon noise.
    """
    x = np.asarray(linear_cfa, np.float64)
    if x.ndim != 2:
        raise ParameterError("linear CFA data must be (H, W)", found=str(x.shape))
    if not np.all(np.isfinite(x)):
        raise ParameterError("linear values must be finite")
    black = _black_per_site(black_level)
    white = int(white_level)
    _check_levels(black, white)
    if noise_sigma < 0:
        raise ParameterError("noise sigma must be >= 0", found=str(noise_sigma))
    if shot_noise_full_well is not None and shot_noise_full_well <= 0:
        raise ParameterError("full-well capacity must be > 0", found=str(shot_noise_full_well))
    rng = rng if rng is not None else np.random.default_rng(0)
    h, w = x.shape
    b = np.tile(np.array(black, np.float64).reshape(2, 2), ((h + 1) // 2, (w + 1) // 2))[:h, :w]
    x = np.clip(x, 0.0, 1.0)
    if shot_noise_full_well is not None:
        x = x + rng.standard_normal(x.shape) * np.sqrt(x / shot_noise_full_well)
    raw = b + np.clip(x, 0.0, 1.0) * float(white - max(black))
    if noise_sigma > 0:
        raw = raw + rng.standard_normal(raw.shape) * noise_sigma
    return np.clip(np.rint(raw), 0, white).astype(np.uint16)


Rect = tuple[int, int, int, int]
"""A rectangle as DNG writes it: top, left, bottom, right (bottom and right exclusive)."""


def parse_margins(margins: int | Sequence[int]) -> Rect:
    """``(top, left, bottom, right)`` masked margins in pixels from one value or four.

    Top and left must be even (the CFA phase stays that of the active area); all are >= 0.
    """
    vals = tuple(int(v) for v in np.ravel(margins))
    if np.ndim(margins) == 0:
        vals = (vals[0],) * 4
    if len(vals) != 4 or min(vals) < 0:
        raise ParameterError(
            "masked margins are one value or four (top, left, bottom, right), each >= 0",
            expected="e.g. 8 or (8, 16, 4, 6)",
            found=str(margins),
        )
    if vals[0] % 2 or vals[1] % 2:
        raise ParameterError(
            "top and left masked margins must be even (the CFA pattern is that of the active area)",
            expected="even top and left",
            found=f"top {vals[0]}, left {vals[1]}",
        )
    return vals


@dataclass(frozen=True, eq=False)
class MaskedSensor:
    """A stored sensor image with masked optical-black margins around its active area.

    ``data`` ``(H + top + bottom, W + left + right)`` uint16 is what the DNG stores;
    ``active_area`` the DNG ActiveArea (top, left, bottom, right) of the ``(H, W)`` active pixels;
    ``masked_areas`` the DNG MaskedAreas rectangles (the non-empty margins); ``noise_sigma`` the
    read noise the margins were filled with (raw units).
    """

    data: np.ndarray
    active_area: Rect
    masked_areas: tuple[Rect, ...]
    noise_sigma: float

    @property
    def active(self) -> np.ndarray:
        """The active area's raw numbers (a view of ``data``)."""
        t, left, b, r = self.active_area
        return self.data[t:b, left:r]

    @property
    def margin_mask(self) -> np.ndarray:
        """``(H', W')`` bool: True on the masked pixels."""
        mask = np.zeros(self.data.shape, bool)
        for t, left, b, r in self.masked_areas:
            mask[t:b, left:r] = True
        return mask


def add_masked_margins(
    active_cfa: np.ndarray,
    margins: int | Sequence[int],
    *,
    black_level: int | Sequence[int],
    white_level: int,
    noise_sigma: float,
    rng: np.random.Generator | None = None,
) -> MaskedSensor:
    """Surround raw numbers ``active_cfa`` ``(H, W)`` with masked optical-black margins.

    The margins hold what masked pixels record: the (per-site) black level plus Gaussian read
    noise of ``noise_sigma`` raw units, rounded and clipped to ``[0, white]`` as
    :func:`linear_to_raw` does; ``margins`` is one value or ``(top, left, bottom, right)``
    (:func:`parse_margins`). The active area is copied unchanged, so drawing the margins after
    the active area from the same ``rng`` leaves the active numbers as they were.
    """
    data = np.asarray(active_cfa)
    if data.ndim != 2 or data.dtype.kind not in "ui":
        raise ParameterError(
            "active CFA data must be integer (H, W)", found=f"{data.dtype} {data.shape}"
        )
    top, left, bottom, right = parse_margins(margins)
    black = _black_per_site(black_level)
    white = int(white_level)
    _check_levels(black, white)
    if noise_sigma < 0:
        raise ParameterError("noise sigma must be >= 0", found=str(noise_sigma))
    rng = rng if rng is not None else np.random.default_rng(0)
    h, w = data.shape
    hh, ww = h + top + bottom, w + left + right
    # Even top/left: the stored image's 2x2 sites are those of the active area.
    b = np.tile(np.array(black, np.float64).reshape(2, 2), ((hh + 1) // 2, (ww + 1) // 2))[:hh, :ww]
    full = b + (rng.standard_normal((hh, ww)) * noise_sigma if noise_sigma > 0 else 0.0)
    out = np.clip(np.rint(full), 0, white).astype(np.uint16)
    out[top : top + h, left : left + w] = data
    rects = [
        (0, 0, top, ww),  # above
        (top + h, 0, hh, ww),  # below
        (top, 0, top + h, left),  # left of the active area
        (top, left + w, top + h, ww),  # right of it
    ]
    masked = tuple(r for r in rects if r[2] > r[0] and r[3] > r[1])
    return MaskedSensor(
        data=out,
        active_area=(top, left, top + h, left + w),
        masked_areas=masked,
        noise_sigma=float(noise_sigma),
    )


def _check_areas(
    shape: tuple[int, int], active: Rect | None, masked: Sequence[Rect]
) -> tuple[Rect | None, tuple[Rect, ...]]:
    h, w = shape

    def inside(r: Sequence[int], what: str) -> Rect:
        vals = tuple(int(v) for v in r)
        if len(vals) != 4 or not (0 <= vals[0] < vals[2] <= h and 0 <= vals[1] < vals[3] <= w):
            raise ParameterError(
                f"{what} must be a non-empty (top, left, bottom, right) inside the stored image",
                expected=f"within {h}x{w}",
                found=str(tuple(r)),
            )
        return vals

    if active is None:
        if masked:
            raise ParameterError(
                "MaskedAreas need an ActiveArea",
                expected="active_area given",
                found=f"{len(masked)} masked areas",
            )
        return None, ()
    act = inside(active, "the active area")
    if act[0] % 2 or act[1] % 2:
        raise ParameterError(
            "the active area must start on an even row and column",
            found=f"top {act[0]}, left {act[1]}",
        )
    rects = tuple(inside(r, "a masked area") for r in masked)
    if len(rects) > 8:
        raise ParameterError("at most 8 masked areas (what LibRaw reads)", found=str(len(rects)))
    for r in rects:
        if r[0] < act[2] and act[0] < r[2] and r[1] < act[3] and act[1] < r[3]:
            raise ParameterError(
                "a masked area overlaps the active area", found=f"masked {r}, active {act}"
            )
    return act, rects


def exif_payload(
    *,
    exposure_time: Fraction | float | None,
    f_number: Fraction | float | None = 8,
    iso: int | None = 100,
    capture_time: datetime | None = None,
    make: str = "hdrview",
    model: str = "simulator",
    orientation: int = 1,
) -> bytes:
    """EXIF block (a TIFF structure without image) for JPEG APP1 / PNG eXIf chunks."""
    ifd0 = [
        TiffTag(271, 2, make),
        TiffTag(272, 2, model),
        TiffTag(274, 3, (int(orientation),)),
        TiffTag(305, 2, "hdrcore simulator"),
    ]
    return encode_tiff(
        ifd0, exif=exif_tags(exposure_time, f_number, iso, capture_time or _DEFAULT_TIME)
    )


def encode_dng(
    cfa: np.ndarray,
    *,
    exposure_time: Fraction | float,
    pattern: str = "RGGB",
    black_level: int | Sequence[int] = 256,
    white_level: int = 4095,
    f_number: Fraction | float = 8,
    iso: int = 100,
    capture_time: datetime | None = None,
    orientation: int = 1,
    make: str = "hdrview",
    model: str = "simulator",
    as_shot_neutral: Sequence[float] = (1.0, 1.0, 1.0),
    color_matrix: Sequence[Sequence[float]] = SRGB_XYZ_TO_CAMERA,
    active_area: Rect | None = None,
    masked_areas: Sequence[Rect] = (),
) -> bytes:
    """Bytes of a DNG holding the raw CFA numbers ``cfa`` ``(H, W)`` (see the module docstring),
    or, for ``(H, W, 3)``, a LinearRaw DNG of three samples a pixel (as iPhone ProRAW and Adobe's
    linear DNGs store them; ``pattern`` unused, one black level).

    ``black_level`` is one value or four (per 2x2 site, row-major, written with
    BlackLevelRepeatDim 2x2). ``exposure_time`` is written as an exact rational.
    ``active_area`` (top, left, bottom, right; even top and left) marks ``cfa`` as a stored image
    larger than the active area and ``masked_areas`` its masked optical-black rectangles (up to
    8); :func:`add_masked_margins` makes all three. Both default to none: the whole image active.
    """
    data = np.asarray(cfa)
    linear = data.ndim == 3 and data.shape[2] == 3  # LinearRaw: three samples a pixel
    if (data.ndim != 2 and not linear) or data.shape[0] < 2 or data.shape[1] < 2:
        raise ParameterError(
            "CFA data must be (H, W) with H, W >= 2 (or (H, W, 3): LinearRaw)",
            found=str(data.shape),
        )
    if data.dtype.kind not in "ui":
        raise ParameterError("CFA data must be integers", found=str(data.dtype))
    cells = _pattern(pattern)
    black = _black_per_site(black_level)
    white = int(white_level)
    _check_levels(black, white)
    if data.size and (int(data.min()) < 0 or int(data.max()) > white):
        raise ParameterError(
            "CFA values outside [0, white level]", found=f"{int(data.min())}..{int(data.max())}"
        )
    if int(orientation) not in range(1, 9):
        raise ParameterError(
            "orientation must be an EXIF value", expected="1..8", found=str(orientation)
        )
    h, w = data.shape[:2]
    act, rects = _check_areas((h, w), active_area, masked_areas)
    when = capture_time or _DEFAULT_TIME
    uniform = len(set(black)) == 1
    if linear and not uniform:
        raise ParameterError("a LinearRaw DNG takes one black level", found=str(black))
    spp = 3 if linear else 1
    if linear:  # PhotometricInterpretation LinearRaw; BlackLevel one value per sample
        layout = [TiffTag(50713, 3, (1, 1)), TiffTag(50714, 4, black[:1] * 3)]
    else:
        layout = [
            TiffTag(33421, 3, (_side(cells),) * 2),
            TiffTag(33422, 1, bytes(cells)),
            TiffTag(50710, 1, bytes((0, 1, 2))),
            TiffTag(50711, 3, (1,)),
            TiffTag(50713, 3, (1, 1) if uniform else (2, 2)),
            TiffTag(50714, 4, black[:1] if uniform else black),
        ]
    ifd0 = [
        TiffTag(254, 4, (0,)),
        TiffTag(256, 4, (w,)),
        TiffTag(257, 4, (h,)),
        TiffTag(258, 3, (16,) * spp),
        TiffTag(259, 3, (1,)),
        TiffTag(262, 3, (34892 if linear else 32803,)),
        TiffTag(271, 2, make),
        TiffTag(272, 2, model),
        TiffTag(274, 3, (int(orientation),)),
        TiffTag(277, 3, (spp,)),
        TiffTag(278, 4, (h,)),
        TiffTag(284, 3, (1,)),
        TiffTag(305, 2, "hdrcore simulator"),
        TiffTag(306, 2, _exif_time(when)),
        TiffTag(50706, 1, bytes((1, 4, 0, 0))),
        TiffTag(50707, 1, bytes((1, 1, 0, 0))),
        TiffTag(50708, 2, f"{make} {model}"),
        *layout,
        TiffTag(50717, 4, (white,)),
        TiffTag(
            50721,
            10,
            tuple(Fraction(round(float(v) * 10000), 10000) for row in color_matrix for v in row),
        ),
        TiffTag(50728, 5, tuple(as_rational(v, what="AsShotNeutral") for v in as_shot_neutral)),
        TiffTag(50778, 3, (21,)),
    ]
    if act is not None:
        ifd0.append(TiffTag(50829, 4, act))
    if rects:
        ifd0.append(TiffTag(50830, 4, tuple(v for r in rects for v in r)))
    exif = exif_tags(exposure_time, f_number, iso, when)
    image = np.ascontiguousarray(data, dtype="<u2").tobytes()
    return encode_tiff(ifd0, exif=exif, image=image)


def write_dng(
    path: str | os.PathLike,
    cfa: np.ndarray,
    *,
    force: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
    **kwargs,
) -> Path:
    """Write :func:`encode_dng` ``(cfa, **kwargs)`` to ``path`` atomically.

    Refuses an existing file unless ``force`` (:class:`~hdrcore.errors.OutputError`).
    """
    from ..io.atomic import atomic_write

    data = encode_dng(cfa, **kwargs)
    return atomic_write(path, lambda tmp: tmp.write_bytes(data), force=force, inputs=inputs)
