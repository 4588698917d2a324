"""Camera RAW frames through rawpy (LibRaw): linear, black-subtracted, native bit depth.

LibRaw only unpacks the mosaic (``raw_image_visible``, levels, CFA pattern, matrices, white
balance); the frame is demosaiced by our own compiled kernel (:mod:`hdrcore.demosaic`, method
``"malvar2004"`` by default), per-site black subtracted, rounded and held in ``0..max_level``:
camera RGB in raw units, no white balance, no colour conversion, no gamma, so ``levels / (white
- black)`` is linear exposure with 1.0 at clipping, and scaling the exposure scales the
demosaic. ``demosaic="libraw-ahd"`` (or the environment variable ``HDRCORE_RAW_DEMOSAIC``)
keeps the earlier path for comparison: LibRaw's ``postprocess`` (AHD) with no white balance
(``user_wb=[1,1,1,1]``), ``output_color=raw``, no gamma, no auto-brightness and
``no_auto_scale``.

``bench/bench_mosaic.py`` measures the cost of both (LibRaw's ``postprocess`` several times
ours on a 24 MP frame; figures in the README); across a bracket simulated from the real Canon
CRW files (x1, x2, x4) AHD moves B/G by 0.14-0.20 % while ours stays within 0.001 %.
Why Malvar-He-Cutler and not Hamilton-Adams by default, though the
latter has the higher PSNR on three of four simulated scenes and shows no zipper on the CRW
files' printed lines where Malvar does: merged per frame, the Hamilton-Adams frames of a
simulated landscape gave 5-8x the squared error at the reference exposure (next to a sky
clipped in every frame, Malvar's overshoot reaches the saturation level and the merge drops
those pixels; Hamilton-Adams' values stay below it and are kept).
``half_size`` always goes through LibRaw (2x2 binning). The untouched CFA data (sensor
orientation) stays available for the estimator and registration.

Two things are measured or repaired while the file is open:

* **White balance.** A file without an as-shot white balance (a DNG without AsShotNeutral: LibRaw
  reports ``camera_whitebalance == [0, 1, 0, 0]``) gets the colour matrix's neutral instead: the
  multipliers that make the camera's response to the D65 white equal, ``wb_c = 1 / (M XYZ_D65)_c``
  normalised to green, with ``M`` rawpy's ``rgb_xyz_matrix`` (camera <- XYZ); for a DNG whose
  ColorMatrix LibRaw keeps to itself (``rgb_xyz_matrix`` zero, ``color_matrix`` not), LibRaw's
  ``daylight_whitebalance``, the same quantity computed from that matrix; unity when the file has
  no matrix. :attr:`FrameMetadata.whitebalance_source` says which (:func:`matrix_neutral`).
* **Read noise.** The masked optical-black margins (``raw_image`` minus ``raw_image_visible``)
  record the black level plus read noise and no light; :func:`optical_black_noise` measures the
  noise there (:attr:`FrameMetadata.read_noise`).

LibRaw writes what it finds wrong with a file straight to the process's stderr (``name:
Unexpected end of file``); those lines are captured (:func:`hdrcore.io._capture.c_stderr`) and
said in plain words: in the error when the file cannot be decoded, else in
:attr:`FrameMetadata.decoder_messages`. The declared size is checked against the pixel limit
(:mod:`hdrcore.io.header`) after ``open_file``, before anything is unpacked.
"""

from __future__ import annotations

import logging
import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from ..errors import ImageReadError, ParameterError
from ._capture import c_stderr
from .exif import read_ciff_make_model, read_exif
from .frame import Frame, FrameMetadata, RawCFA, apply_orientation

__all__ = [
    "RAW_DEMOSAIC_METHODS",
    "RAW_EXTENSIONS",
    "D65_XYZ",
    "OpticalBlack",
    "read_raw",
    "is_raw_path",
    "libraw_error",
    "libraw_messages",
    "matrix_neutral",
    "optical_black_noise",
]

log = logging.getLogger(__name__)

RAW_EXTENSIONS = frozenset(
    ".dng .cr2 .cr3 .crw .nef .nrw .arw .srf .sr2 .orf .rw2 .raf .pef .srw .x3f .3fr .iiq .erf "
    ".kdc .dcr .mos .mrw .raw .rwl .gpr".split()
)

#: Demosaic methods of :func:`read_raw`: ours (:data:`hdrcore.demosaic.DEMOSAIC_METHODS`) and
#: LibRaw's AHD through ``postprocess``.
RAW_DEMOSAIC_METHODS = (
    "malvar2004",
    "hamilton-adams",
    "rcd",
    "malvar2004-clamped",
    "bilinear",
    "libraw-ahd",
)
DEFAULT_RAW_DEMOSAIC = "malvar2004"

# LibRaw flip codes to EXIF orientation values (bit 4 transposes, bit 2 flips the rows, bit 1
# the columns; checked against LibRaw's output for DNGs of every EXIF value).
_FLIP_TO_ORIENTATION = {0: 1, 1: 2, 2: 4, 3: 3, 4: 5, 5: 8, 6: 6, 7: 7}


#: CIE 1931 2-degree XYZ of the D65 white, Y = 1 (the white of sRGB, whose primaries the
#: merge's colour conversion normalises the camera matrix to).
D65_XYZ = (0.95047, 1.0, 1.08883)
#: Pixels of the optical-black margins next to the active area that are left out: the first
#: columns and rows beside the image pick up stray light and smear (the Canon CRW files' column
#: next to the active area sits 1 level above the others).
OPTICAL_BLACK_GUARD = 4
#: Fewest optical-black pixels worth a read-noise estimate (its relative error is then about
#: 1 / sqrt(2 * 400) = 3.5 %).
OPTICAL_BLACK_MIN_SAMPLES = 400


def is_raw_path(path: str | Path) -> bool:
    return Path(path).suffix.lower() in RAW_EXTENSIONS


def _valid_multipliers(wb: Sequence[float]) -> bool:
    v = np.asarray(wb, dtype=np.float64).ravel()[:3]
    return v.size == 3 and bool(np.all(np.isfinite(v)) and np.all(v > 0))


def matrix_neutral(
    rgb_xyz_matrix: np.ndarray | Sequence[Sequence[float]] | None,
) -> tuple[float, float, float] | None:
    """White-balance multipliers (R, G, B; G = 1) that make the camera's D65 response neutral.

    ``rgb_xyz_matrix`` is rawpy's camera <- XYZ matrix (3x3, or the first 3 rows of 4x3); the
    camera sees the D65 white as ``cam = M @ D65_XYZ`` and ``wb_c = cam_G / cam_c``. ``None`` when
    the matrix is missing, all zeros, not finite, or gives a non-positive response.
    """
    if rgb_xyz_matrix is None:
        return None
    m = np.asarray(rgb_xyz_matrix, dtype=np.float64)
    if m.ndim != 2 or m.shape[1] != 3 or m.shape[0] < 3:
        return None
    m = m[:3]
    if not np.all(np.isfinite(m)) or not np.any(m != 0):
        return None
    cam = m @ np.asarray(D65_XYZ)
    if not np.all(np.isfinite(cam)) or np.any(cam <= 0):
        return None
    wb = cam[1] / cam
    return (float(wb[0]), 1.0, float(wb[2]))


@dataclass(frozen=True)
class OpticalBlack:
    """Read noise measured on the masked optical-black margins of a RAW file.

    ``sigma``: the read noise in raw levels, quantisation removed (``sqrt(var - 1/12)``, the
    noise before the ADC rounds it, as the merge's noise model adds quantisation itself).
    ``offset``: the mean of the margin pixels minus the black level (about 0 when the black
    level is right). ``samples``: margin pixels used; ``margins``: which margins they came from.
    """

    sigma: float
    offset: float
    samples: int
    margins: tuple[str, ...]


def _strip_residuals(strip: np.ndarray) -> tuple[float, int, float, int]:
    """Within-row sums over one margin strip (float, black already subtracted): the sum of
    squared residuals from each row's mean, its degrees of freedom, and the sum and count of the
    values kept (outliers beyond 5 sigma, i.e. hot or dead pixels, left out)."""
    # Lines (rows or columns) that never change are filler, not sensor pixels.
    keep_rows = np.ptp(strip, axis=1) > 0 if strip.shape[1] > 1 else np.ones(len(strip), bool)
    keep_cols = np.ptp(strip, axis=0) > 0 if strip.shape[0] > 1 else np.ones(strip.shape[1], bool)
    x = strip[np.ix_(keep_rows, keep_cols)]
    if x.size < 2:
        return 0.0, 0, 0.0, 0
    r = x - np.median(x, axis=1, keepdims=True)
    # The MAD of integer levels is 0 or 1 when sigma < 1; 0.5 level is the floor of its scale.
    scale = max(1.4826 * float(np.median(np.abs(r))), 0.5)
    keep = np.abs(r) <= 6.0 * scale
    for _ in range(3):
        n = keep.sum(axis=1)
        mean = np.where(n > 0, np.where(keep, x, 0.0).sum(axis=1) / np.maximum(n, 1), 0.0)
        r = x - mean[:, None]
        ss = float(np.where(keep, r * r, 0.0).sum())
        dof = int(np.maximum(n - 1, 0).sum())
        if dof <= 0:
            return 0.0, 0, 0.0, 0
        keep = np.abs(r) <= max(5.0 * math.sqrt(ss / dof), 2.5)
    n = keep.sum(axis=1)
    mean = np.where(n > 0, np.where(keep, x, 0.0).sum(axis=1) / np.maximum(n, 1), 0.0)
    r = x - mean[:, None]
    ss = float(np.where(keep, r * r, 0.0).sum())
    dof = int(np.maximum(n - 1, 0).sum())
    return ss, dof, float(np.where(keep, x, 0.0).sum()), int(keep.sum())


def optical_black_noise(
    raw_image: np.ndarray,
    *,
    top: int,
    left: int,
    height: int,
    width: int,
    black_level: float | Sequence[float] = 0.0,
    pattern: np.ndarray | None = None,
    guard: int = OPTICAL_BLACK_GUARD,
    min_samples: int = OPTICAL_BLACK_MIN_SAMPLES,
) -> OpticalBlack | None:
    """Read noise of a sensor from its masked margins, or ``None`` without enough of them.

    ``raw_image`` is the whole stored mosaic (rawpy ``raw_image``); the active area is
    ``height x width`` at ``(top, left)`` (rawpy ``sizes``). The margins are the strips left,
    right, above and below the active area (its rows or columns only, no corners), ``guard``
    pixels away from it. ``black_level`` is one value or one per colour index of ``pattern``
    (the 2x2 CFA of the active area, rawpy ``raw_pattern``).

    Each strip is taken row by row and CFA site by site: the mean of each row's pixels of one
    column parity (of that strip) is removed, so row banding, an offset between margins or
    between sites do not count as noise, and the variance is pooled as
    ``sum(r^2) / sum(n_row - 1)`` (unbiased for the removed means). Pixels beyond 5 sigma are
    left out, and lines that never change (filler columns) too. The median absolute deviation
    alone cannot do this: on integer levels with sigma below 1 level it is 0 or 1. The rounding
    to integer levels adds 1/12 to the variance (Sheppard), which is taken off.
    """
    data = np.asarray(raw_image)
    if data.ndim != 2:
        return None
    hh, ww = data.shape
    bottom, right = top + height, left + width
    rects = {
        "left": (top, bottom, 0, left - guard),
        "right": (top, bottom, right + guard, ww),
        "top": (0, top - guard, left, right),
        "bottom": (bottom + guard, hh, left, right),
    }
    blacks = np.atleast_1d(np.asarray(black_level, dtype=np.float64))
    ss = 0.0
    dof = 0
    total = 0.0
    count = 0
    used = []
    for name, (r0, r1, c0, c1) in rects.items():
        r0, c0 = max(r0, 0), max(c0, 0)
        r1, c1 = min(r1, hh), min(c1, ww)
        if r1 - r0 < 1 or c1 - c0 < 1:
            continue
        strip = data[r0:r1, c0:c1].astype(np.float64)
        if blacks.size == 1 or pattern is None:
            strip -= float(blacks.mean())
        else:
            pat = np.asarray(pattern, dtype=np.int64)
            rows = (np.arange(r0, r1) - top) % 2
            cols = (np.arange(c0, c1) - left) % 2
            strip -= blacks[pat[rows[:, None], cols[None, :]]]
        # Each row of a strip crosses two CFA sites, one per column parity: their means are
        # removed separately, so a per-site offset (a black level off by a fraction, as LibRaw's
        # integer black measured on MaskedAreas) is not noise either.
        found = False
        for sub in (strip[:, 0::2], strip[:, 1::2]):
            s, d, t, c = _strip_residuals(sub)
            if d > 0:
                ss, dof, total, count = ss + s, dof + d, total + t, count + c
                found = True
        if found:
            used.append(name)
    if count < min_samples or dof <= 0:
        return None
    var = ss / dof
    return OpticalBlack(
        sigma=math.sqrt(max(var - 1.0 / 12.0, 0.0)),
        offset=total / count,
        samples=count,
        margins=tuple(used),
    )


def _fallback_whitebalance(raw, xyz: np.ndarray) -> tuple[tuple[float, ...], str]:
    """Multipliers for a file without an as-shot white balance, and their source."""
    neutral = matrix_neutral(xyz)
    if neutral is not None:
        return neutral, "matrix-neutral"
    # DNG: LibRaw keeps the file's ColorMatrix out of rgb_xyz_matrix but derives color_matrix
    # and daylight_whitebalance (its pre_mul, 1 / (M XYZ_D65) as above) from it.
    rgb_cam = np.asarray(raw.color_matrix, dtype=np.float64)
    daylight = tuple(float(v) for v in raw.daylight_whitebalance)[:3]
    if np.any(rgb_cam != 0) and np.all(np.isfinite(rgb_cam)) and _valid_multipliers(daylight):
        return (daylight[0] / daylight[1], 1.0, daylight[2] / daylight[1]), "matrix-neutral"
    return (1.0, 1.0, 1.0), "unity"


_DATA_CORRUPTED = re.compile(r"data corrupted at (\d+)", re.IGNORECASE)


def libraw_messages(said: Sequence[str]) -> list[str]:
    """LibRaw's stderr lines about a file (name removed) in plain words."""
    out = []
    for text in said:
        m = _DATA_CORRUPTED.search(text)
        if "unexpected end of file" in text.lower():
            words = "the file ends before its image data does (truncated)"
        elif m:
            words = f"its image data is corrupt (from byte {m.group(1)})"
        else:
            words = f"LibRaw says: {text}"
        if words not in out:
            out.append(words)
    return out


def _exception_text(exc: BaseException) -> str:
    arg = exc.args[0] if exc.args else ""
    if isinstance(arg, bytes):
        arg = arg.decode("utf-8", "replace")
    return str(arg) or type(exc).__name__


def libraw_error(path: str | Path, exc: BaseException, said: Sequence[str] = ()) -> ImageReadError:
    """The one-line error for a RAW file LibRaw failed on: what LibRaw printed about the file
    (``said``, captured from stderr) in plain words, else its exception's text."""
    import rawpy

    words = libraw_messages(said)
    if isinstance(exc, rawpy.LibRawFileUnsupportedError):
        message = "not a camera RAW file LibRaw can read (unknown format, or the header is damaged)"
    elif isinstance(exc, (rawpy.LibRawTooBigError, rawpy.LibRawUnsufficientMemoryError)):
        message = f"RAW file is too large to decode ({_exception_text(exc)})"
    elif words:
        message = "RAW file is damaged: " + "; ".join(words)
    else:
        message = f"RAW file is damaged or truncated (LibRaw: {_exception_text(exc)})"
    return ImageReadError(message, path=path)


def _linear_raw_levels(
    image: np.ndarray, white: int, black: Sequence[float], colors: str
) -> np.ndarray:
    """``(H, W, 3)`` uint16 levels of a LinearRaw image (rawpy ``raw_image_visible``, three or
    more samples a pixel): each channel's black level subtracted, held at the frame's largest
    level (:func:`_channel_levels`), as the mosaic paths give them."""
    black_rgb, _, max_level = _channel_levels(white, black, colors)
    out = np.empty(image.shape[:2] + (3,), np.uint16)
    for c in range(3):
        plane = image[..., c].astype(np.float32) - np.float32(black_rgb[c])
        np.clip(np.rint(plane), 0, max(max_level, 0), out=plane)
        out[..., c] = plane
    return out


def _is_bayer(pattern: np.ndarray, colors: str) -> bool:
    """Whether rawpy's ``raw_pattern`` and ``color_desc`` describe a 2x2 Bayer cell."""
    from ..demosaic import bayer_channels

    try:
        bayer_channels(pattern, colors)
    except ParameterError:
        return False
    return True


def _channel_levels(
    white: int, black: Sequence[float], colors: str
) -> tuple[tuple[float, float, float], tuple[int, int, int], int]:
    """Per output channel (R, G, B) black levels (LibRaw's colour indices follow
    ``colors``), each channel's largest level ``white - black``, and the frame's (their
    smallest)."""

    def black_of(letter: str) -> float:
        vals = [black[i] for i, c in enumerate(colors[: len(black)]) if c == letter]
        return max(vals) if vals else 0.0

    r, g, b = (black_of(c) for c in "RGB")
    channel_max = (int(white - r), int(white - g), int(white - b))
    return (r, g, b), channel_max, int(min(channel_max))


def read_raw(
    path: str | Path,
    *,
    half_size: bool = False,
    keep_cfa: bool = True,
    max_pixels: int | None = None,
    demosaic: str | None = None,
) -> Frame:
    """Read a camera RAW file as a linear :class:`Frame` (see module docstring).

    ``half_size`` demosaics by 2x2 binning (fast, for previews); ``keep_cfa`` keeps the raw mosaic.
    ``max_pixels``: the pixel limit (:func:`hdrcore.io.header.pixel_limit`; ``None`` the
    default, 0 none), checked from the header before anything is unpacked. ``demosaic``: one of
    :data:`RAW_DEMOSAIC_METHODS` (``None``: the environment variable ``HDRCORE_RAW_DEMOSAIC``
    when set, else ``"malvar2004"``; the variable selects LibRaw's path for a comparison
    run).
    """
    import rawpy

    from ..demosaic import demosaic as demosaic_mosaic
    from .header import check_frame_pixels

    method = demosaic or os.environ.get("HDRCORE_RAW_DEMOSAIC") or DEFAULT_RAW_DEMOSAIC
    if method not in RAW_DEMOSAIC_METHODS:
        where = "" if demosaic else " (environment variable HDRCORE_RAW_DEMOSAIC)"
        raise ParameterError(
            f"unknown RAW demosaic method {method!r}{where}",
            expected=", ".join(RAW_DEMOSAIC_METHODS),
            found=repr(method),
        )
    p = Path(path)
    failure: rawpy.LibRawError | None = None
    with c_stderr(p) as said:  # filled when the block ends
        try:
            with rawpy.imread(str(p)) as raw:
                sizes = raw.sizes
                check_frame_pixels(p, int(sizes.width), int(sizes.height), max_pixels)
                # LinearRaw (iPhone ProRAW, Adobe's linear DNG, a merged float DNG): three
                # linear values a pixel already, read as they are stored.
                stack = raw.raw_type == rawpy.RawType.Stack and raw.num_colors == 3
                if raw.num_colors < 3 or (raw.raw_type != rawpy.RawType.Flat and not stack):
                    raise ImageReadError(
                        "unsupported RAW layout",
                        path=p,
                        expected="a colour filter array (Bayer, X-Trans) or LinearRaw RGB",
                        found=f"{raw.num_colors} colours, {raw.raw_type}",
                    )
                white = int(raw.white_level)
                black = tuple(float(b) for b in raw.black_level_per_channel)
                colors = raw.color_desc.decode("ascii", "replace")
                pattern = (
                    np.zeros((0, 0), np.int64)
                    if stack
                    else np.array(raw.raw_pattern, dtype=np.int64)
                )
                # A 2x2 Bayer cell: our mosaic paths. Anything else (Fujifilm's 6x6 X-Trans)
                # goes through LibRaw's own demosaic, and keeps no mosaic (every reader of
                # Frame.cfa takes a Bayer cell).
                bayer = not stack and _is_bayer(pattern, colors)
                cam_wb = tuple(float(v) for v in raw.camera_whitebalance)
                xyz = np.asarray(raw.rgb_xyz_matrix, float)[:3]
                wb_source = "as-shot"
                if not _valid_multipliers(cam_wb):
                    cam_wb, wb_source = _fallback_whitebalance(raw, xyz)
                    log.info(
                        "%s: no as-shot white balance (LibRaw reports %s); using %s %s",
                        p.name,
                        list(raw.camera_whitebalance),
                        wb_source,
                        cam_wb,
                    )
                ob = optical_black_noise(
                    raw.raw_image,
                    top=int(sizes.top_margin),
                    left=int(sizes.left_margin),
                    height=int(sizes.height),
                    width=int(sizes.width),
                    black_level=black,
                    pattern=pattern if bayer else None,
                )
                flip = int(sizes.flip)
                other = raw.other
                cfa = None
                if keep_cfa and bayer:
                    cfa = RawCFA(
                        data=np.array(raw.raw_image_visible, copy=True),
                        pattern=pattern,
                        colors=colors,
                        black_level=black,
                        white_level=white,
                    )
                if not bayer and not stack and method != "libraw-ahd":
                    log.info(
                        "%s: %dx%d colour filter array (not Bayer): LibRaw's demosaic, not %s",
                        p.name,
                        *pattern.shape,
                        method,
                    )
                ours = (
                    bayer
                    and method != "libraw-ahd"
                    and not half_size
                    and float(sizes.pixel_aspect) in (0.0, 1.0)
                )
                # Our demosaic holds its output at the frame's largest level itself (below),
                # but for RCD, whose passes start from the first pass's levels.
                held = (ours and method != "rcd") or stack
                if stack:
                    rgb = _linear_raw_levels(raw.raw_image_visible, white, black, colors)
                    rgb = apply_orientation(rgb, _FLIP_TO_ORIENTATION.get(flip, 1))
                elif ours:
                    # The mosaic only: no LibRaw postprocess (GIL released in our kernel).
                    mosaic = raw.raw_image_visible if cfa is None else cfa.data
                    top = _channel_levels(white, black, colors)[2] if held else white - min(black)
                    rgb = demosaic_mosaic(
                        mosaic,
                        pattern,
                        colors,
                        method=method,
                        black_level=black,
                        max_level=max(top, 1),
                        dtype=np.uint16,
                    )
                    rgb = apply_orientation(rgb, _FLIP_TO_ORIENTATION.get(flip, 1))
                else:
                    rgb = raw.postprocess(
                        gamma=(1, 1),
                        no_auto_bright=True,
                        output_bps=16,
                        user_wb=[1.0, 1.0, 1.0, 1.0],
                        output_color=rawpy.ColorSpace.raw,
                        no_auto_scale=True,
                        half_size=half_size,
                    )
        except rawpy.LibRawError as exc:
            failure = exc
    if failure is not None:
        raise libraw_error(p, failure, said) from failure
    messages = libraw_messages(said)
    black_rgb, channel_max, max_level = _channel_levels(white, black, colors)
    if max_level <= 0:
        raise ImageReadError(
            "RAW white level is not above the black level",
            path=p,
            found=f"white {white}, black {black}",
        )
    bit_depth = int(np.ceil(np.log2(white + 1)))

    exif = read_exif(p)
    make, model = exif.make, exif.model
    if make is None and model is None:  # a Canon CRW: CIFF records, no TIFF EXIF
        make, model = read_ciff_make_model(p)
    exposure = exif.exposure_time
    source = "exif" if exposure is not None else None
    if exposure is None and other is not None and other.shutter_speed > 0:
        exposure = Fraction(float(other.shutter_speed)).limit_denominator(100_000)
        source = "libraw"
    iso = exif.iso
    if iso is None and other is not None and other.iso_speed > 0:
        iso = int(round(other.iso_speed))
    fnum = exif.f_number
    if fnum is None and other is not None and other.aperture > 0:
        fnum = Fraction(float(other.aperture)).limit_denominator(1000)
    capture = exif.capture_time
    if capture is None and other is not None:
        capture = other.timestamp

    levels = np.ascontiguousarray(rgb, dtype=np.uint16)
    # Demosaicing can overshoot the white level near clipped areas; such values are clipped
    # (saturated) samples. Every channel is held at the frame's largest level, the smallest of
    # the channels' (per-channel black levels differ by a level or so, e.g. when LibRaw measures
    # them on masked pixels: 255/255/255/256); a channel with a lower black loses that level.
    # Our demosaic holds its output there itself (it clips before it rounds, so at an integer
    # level the levels are the same): no pass over the levels after it.
    if not held:
        np.minimum(levels, np.uint16(max_level), out=levels)
    meta = FrameMetadata(
        path=str(p),
        format="raw",
        bit_depth=bit_depth,
        max_level=max_level,
        is_linear=True,
        exposure_time=exposure,
        exposure_time_source=source,
        f_number=fnum,
        iso=iso,
        exposure_bias=exif.exposure_bias,
        make=make,
        model=model,
        capture_time=capture,
        orientation=_FLIP_TO_ORIENTATION.get(flip, exif.orientation),
        black_level=black_rgb,
        white_level=white,
        channel_max_levels=channel_max,
        camera_whitebalance=cam_wb,
        whitebalance_source=wb_source,
        read_noise=None if ob is None else ob.sigma,
        read_noise_source=None if ob is None else "optical-black",
        optical_black_offset=None if ob is None else ob.offset,
        rgb_xyz_matrix=tuple(tuple(float(v) for v in row) for row in xyz),
        cfa_pattern=None if stack else tuple(tuple(int(v) for v in row) for row in pattern),
        cfa_colors=colors,
        decoder_messages=tuple(messages),
    )
    return Frame(levels=levels, meta=meta, cfa=cfa)
