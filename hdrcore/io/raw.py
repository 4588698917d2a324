"""Camera RAW frames through rawpy (LibRaw): linear, black-subtracted, native bit depth.

The demosaiced frame is LibRaw's ``postprocess`` with no white balance (``user_wb=[1,1,1,1]``), no
colour conversion (``output_color=raw``), no gamma, no auto-brightness and no scaling
(``no_auto_scale``), so its 16-bit output is camera RGB in raw units with the per-channel black
level already subtracted: ``levels / (white - black)`` is linear exposure with 1.0 at clipping.
The untouched CFA data (sensor orientation) stays available for the estimator and registration.
"""

from __future__ import annotations

import logging
from fractions import Fraction
from pathlib import Path

import numpy as np

from ..errors import ImageReadError
from .exif import read_exif
from .frame import Frame, FrameMetadata, RawCFA

__all__ = ["RAW_EXTENSIONS", "read_raw", "is_raw_path"]

log = logging.getLogger(__name__)

RAW_EXTENSIONS = frozenset(
    ".dng .cr2 .cr3 .crw .nef .nrw .arw .srf .sr2 .orf .rw2 .raf .pef .srw .x3f .3fr .iiq .erf "
    ".kdc .dcr .mos .mrw .raw .rwl .gpr".split()
)

# LibRaw flip codes to EXIF orientation values.
_FLIP_TO_ORIENTATION = {0: 1, 3: 3, 5: 8, 6: 6}


def is_raw_path(path: str | Path) -> bool:
    return Path(path).suffix.lower() in RAW_EXTENSIONS


def read_raw(path: str | Path, *, half_size: bool = False, keep_cfa: bool = True) -> Frame:
    """Read a camera RAW file as a linear :class:`Frame` (see module docstring).

    ``half_size`` demosaics by 2x2 binning (fast, for previews); ``keep_cfa`` keeps the raw mosaic.
    """
    import rawpy

    p = Path(path)
    try:
        raw = rawpy.imread(str(p))
    except (rawpy.LibRawFileUnsupportedError, rawpy.LibRawIOError) as exc:
        raise ImageReadError(
            f"LibRaw cannot read it: not a camera RAW file, or truncated ({exc})", path=p
        ) from exc
    except rawpy.LibRawError as exc:
        raise ImageReadError(f"RAW file is damaged or truncated ({exc})", path=p) from exc
    try:
        with raw:
            if raw.num_colors < 3 or raw.raw_type != rawpy.RawType.Flat:
                raise ImageReadError(
                    "unsupported RAW layout", path=p, expected="a Bayer CFA sensor",
                    found=f"{raw.num_colors} colours, {raw.raw_type}",
                )
            white = int(raw.white_level)
            black = tuple(float(b) for b in raw.black_level_per_channel)
            colors = raw.color_desc.decode("ascii", "replace")
            pattern = np.array(raw.raw_pattern, dtype=np.int64)
            cam_wb = tuple(float(v) for v in raw.camera_whitebalance)
            xyz = np.asarray(raw.rgb_xyz_matrix, float)[:3]
            flip = int(raw.sizes.flip)
            other = raw.other
            cfa = None
            if keep_cfa:
                cfa = RawCFA(
                    data=np.array(raw.raw_image_visible, copy=True),
                    pattern=pattern,
                    colors=colors,
                    black_level=black,
                    white_level=white,
                )
            try:
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
                raise ImageReadError(f"RAW data is damaged or truncated ({exc})", path=p) from exc
    except rawpy.LibRawError as exc:
        raise ImageReadError(f"RAW file is damaged or truncated ({exc})", path=p) from exc

    # Per output channel (R, G, B) black levels: LibRaw's colour indices follow color_desc.
    def black_of(letter: str) -> float:
        vals = [black[i] for i, c in enumerate(colors[: len(black)]) if c == letter]
        return max(vals) if vals else 0.0

    black_rgb = tuple(black_of(c) for c in "RGB")
    channel_max = tuple(int(white - b) for b in black_rgb)
    max_level = int(min(channel_max))
    if max_level <= 0:
        raise ImageReadError(
            "RAW white level is not above the black level", path=p,
            found=f"white {white}, black {black}",
        )
    bit_depth = int(np.ceil(np.log2(white + 1)))

    exif = read_exif(p)
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
    # (saturated) samples, so they are held at each channel's largest level.
    for c in range(3):
        np.minimum(levels[..., c], channel_max[c], out=levels[..., c])
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
        make=exif.make,
        model=exif.model,
        capture_time=capture,
        orientation=_FLIP_TO_ORIENTATION.get(flip, exif.orientation),
        black_level=black_rgb,
        white_level=white,
        channel_max_levels=channel_max,
        camera_whitebalance=cam_wb,
        rgb_xyz_matrix=tuple(tuple(float(v) for v in row) for row in xyz),
        cfa_pattern=tuple(tuple(int(v) for v in row) for row in pattern),
        cfa_colors=colors,
    )
    return Frame(levels=levels, meta=meta, cfa=cfa)
