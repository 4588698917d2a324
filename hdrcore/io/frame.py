"""The frame: integer levels at native bit depth plus everything known about how they were made."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from datetime import datetime
from fractions import Fraction
from typing import Any

import numpy as np

from ..errors import ParameterError

__all__ = ["FrameMetadata", "RawCFA", "Frame", "apply_orientation", "undo_orientation"]


@dataclass(frozen=True)
class FrameMetadata:
    """What is known about a frame. ``None`` means unknown, never a guess.

    ``exposure_time_source`` says where the time came from: ``"exif"`` (an exact rational),
    ``"libraw"`` (LibRaw's shutter value, APEX-derived, when the file has no TIFF EXIF),
    ``"times-file"`` (a ``name seconds`` list) or ``None``.
    ``black_level`` is per colour channel in raw units (zeros for JPEG/PNG/TIFF); ``max_level`` is
    the largest level a pixel can take after black subtraction (``white_level - black``).

    ``exposure_time_apex`` is the camera's actual time when the EXIF time is a rounded nominal
    value of an APEX sequence (1/640 s -> ``2^(-28/3)`` s), named by ``exposure_time_sequence``
    (``"1/3-stop"`` or ``"1/2-stop"``); both ``None`` when the time is exact (a phone's 1/802.8
    s, a times file, LibRaw's APEX-derived value). ``f_number_apex`` likewise (f/5.6 -> 5.657).
    See :mod:`hdrcore.io.apex`; :attr:`exposure_time_actual` is the value to compute with.

    RAW only: ``camera_whitebalance`` holds the multipliers used, ``whitebalance_source`` says
    where they came from: ``"as-shot"`` (the file's), ``"matrix-neutral"`` (the file had none:
    the colour matrix's D65 neutral) or ``"unity"`` (neither). ``read_noise`` is the read noise
    in raw levels (quantisation excluded) measured on the masked optical-black margins
    (``read_noise_source == "optical-black"``), ``None`` when the file has no margins;
    ``optical_black_offset`` is those pixels' mean minus ``black_level`` (about 0 when LibRaw's
    black level is right).

    ``orientation`` is the EXIF orientation the levels were turned by (the file's own tag, or
    the bracket's when the frames' tags disagree: see :func:`hdrcore.io.load_bracket`).
    ``colour_space`` (JPEG, PNG, TIFF): the RGB space the levels are encoded in, a name of
    :data:`hdrcore.merge.colour.WORKING_SPACES` read from the file's ICC profile or EXIF
    (:mod:`hdrcore.io.colour_space`), ``None`` when not stated or not known (taken as sRGB);
    ``colour_space_source`` says where it was read (a profile we do not know: its name).
    ``decoder_messages``: what the decoder said about the file while decoding it anyway (LibRaw:
    "its image data is corrupt (from byte 1328385)"), in plain words; empty when it said nothing.
    """

    path: str
    format: str
    bit_depth: int
    max_level: int
    is_linear: bool
    exposure_time: Fraction | None = None
    exposure_time_source: str | None = None
    f_number: Fraction | None = None
    iso: int | None = None
    exposure_bias: Fraction | None = None
    make: str | None = None
    model: str | None = None
    capture_time: datetime | None = None
    orientation: int | None = None
    black_level: tuple[float, ...] = (0.0, 0.0, 0.0)
    white_level: int | None = None
    channel_max_levels: tuple[int, ...] | None = None
    camera_whitebalance: tuple[float, ...] | None = None
    rgb_xyz_matrix: tuple[tuple[float, ...], ...] | None = None
    cfa_pattern: tuple[tuple[int, ...], ...] | None = None
    cfa_colors: str | None = None
    exposure_time_apex: float | None = None
    exposure_time_sequence: str | None = None
    f_number_apex: float | None = None
    whitebalance_source: str | None = None
    read_noise: float | None = None
    read_noise_source: str | None = None
    optical_black_offset: float | None = None
    decoder_messages: tuple[str, ...] = ()
    colour_space: str | None = None
    colour_space_source: str | None = None

    @property
    def exposure_time_actual(self) -> float | None:
        """Seconds to compute with: the APEX-snapped time when the tag is nominal, else the tag."""
        if self.exposure_time_apex is not None:
            return self.exposure_time_apex
        return None if self.exposure_time is None else float(self.exposure_time)

    @property
    def f_number_actual(self) -> float | None:
        """The APEX-snapped f-number when the tag is nominal, else the tag."""
        if self.f_number_apex is not None:
            return self.f_number_apex
        return None if self.f_number is None else float(self.f_number)

    @property
    def camera(self) -> str | None:
        """Make and model in one name; a model that names its make already (Canon's "Canon
        PowerShot G2") is the name alone."""
        if self.make and self.model and self.model.lower().startswith(self.make.lower()):
            return self.model
        parts = [p for p in (self.make, self.model) if p]
        return " ".join(parts) if parts else None

    def to_json(self) -> dict:
        """JSON-ready dictionary (fractions as strings and floats)."""

        def frac(v: Fraction | None) -> str | None:
            return None if v is None else str(v)

        return {
            "path": self.path,
            "format": self.format,
            "bit_depth": self.bit_depth,
            "max_level": self.max_level,
            "is_linear": self.is_linear,
            "exposure_time": None if self.exposure_time is None else float(self.exposure_time),
            "exposure_time_exact": frac(self.exposure_time),
            "exposure_time_source": self.exposure_time_source,
            "f_number": None if self.f_number is None else float(self.f_number),
            "iso": self.iso,
            "exposure_bias": None if self.exposure_bias is None else float(self.exposure_bias),
            "make": self.make,
            "model": self.model,
            "capture_time": None if self.capture_time is None else self.capture_time.isoformat(),
            "orientation": self.orientation,
            "black_level": list(self.black_level),
            "white_level": self.white_level,
            "exposure_time_apex": self.exposure_time_apex,
            "exposure_time_sequence": self.exposure_time_sequence,
            "f_number_apex": self.f_number_apex,
            "camera_whitebalance": (
                None if self.camera_whitebalance is None else list(self.camera_whitebalance)
            ),
            "whitebalance_source": self.whitebalance_source,
            "read_noise": self.read_noise,
            "read_noise_source": self.read_noise_source,
            "optical_black_offset": self.optical_black_offset,
            "decoder_messages": list(self.decoder_messages),
            "colour_space": self.colour_space,
            "colour_space_source": self.colour_space_source,
        }


@dataclass(frozen=True, eq=False)
class RawCFA:
    """The sensor's colour-filter-array data, untouched: sensor orientation, black not subtracted.

    ``pattern[r][c]`` is the colour index (into ``colors``, e.g. ``"RGBG"``) of the pixel at
    ``(r % 2, c % 2)``; ``black_level[i]`` belongs to colour index ``i``.
    """

    data: np.ndarray
    pattern: np.ndarray
    colors: str
    black_level: tuple[float, ...]
    white_level: int

    def plane(self, colour: str = "G") -> np.ndarray:
        """Half-resolution plane of one colour, black-subtracted, float32 in raw units.

        For green (two sites per 2x2 cell) the two sites are averaged.
        """
        h, w = self.data.shape
        h2, w2 = h // 2 * 2, w // 2 * 2
        sites = []
        for r in range(2):
            for c in range(2):
                idx = int(self.pattern[r, c])
                if self.colors[idx] == colour:
                    block = self.data[r:h2:2, c:w2:2].astype(np.float32)
                    sites.append(block - np.float32(self.black_level[idx]))
        if not sites:
            raise ParameterError(f"colour {colour!r} not in CFA", found=self.colors)
        return np.clip(sum(sites) / len(sites), 0, None).astype(np.float32)


_ORIENT_OPS = {
    1: (),
    2: ("fliplr",),
    3: ("rot180",),
    4: ("flipud",),
    5: ("transpose",),
    6: ("rot270",),
    7: ("transverse",),
    8: ("rot90",),
}


def apply_orientation(image: np.ndarray, orientation: int | None) -> np.ndarray:
    """Rotate/flip ``image`` (H, W[, C]) so it displays upright per the EXIF orientation tag.

    Tag values: 1 normal, 2 mirrored, 3 rotated 180, 4 flipped, 5 transposed, 6 rotate 90 CW to
    view, 7 transverse, 8 rotate 90 CCW to view. Unknown values leave the image as it is.
    """
    if orientation is None or orientation == 1 or orientation not in _ORIENT_OPS:
        return image
    if orientation == 2:
        out = image[:, ::-1]
    elif orientation == 3:
        out = image[::-1, ::-1]
    elif orientation == 4:
        out = image[::-1]
    elif orientation == 5:
        out = np.swapaxes(image, 0, 1)
    elif orientation == 6:
        out = np.swapaxes(image, 0, 1)[:, ::-1]
    elif orientation == 7:
        out = np.swapaxes(image, 0, 1)[::-1, ::-1]
    else:  # 8
        out = np.swapaxes(image, 0, 1)[::-1]
    return np.ascontiguousarray(out)


def undo_orientation(image: np.ndarray, orientation: int | None) -> np.ndarray:
    """The inverse of :func:`apply_orientation`: the image as stored, before the tag's turn."""
    inverse = orientation if orientation is None else {6: 8, 8: 6}.get(orientation, orientation)
    return apply_orientation(image, inverse)


@dataclass(frozen=True, eq=False)
class Frame:
    """One exposure: integer ``levels`` ``(H, W, 3)`` uint16 at native bit depth, upright.

    For RAW the levels are demosaiced camera RGB with the black level subtracted per channel (no
    white balance, no gamma, no scaling), so ``levels / max_level`` is linear sensor exposure with
    1.0 at the white level. For JPEG/PNG/TIFF they are the file's code values (non-linear until a
    response is applied).
    """

    levels: np.ndarray
    meta: FrameMetadata
    cfa: RawCFA | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.levels.ndim != 3 or self.levels.shape[2] != 3:
            raise ParameterError("frame levels must be (H, W, 3)", found=str(self.levels.shape))
        self.levels.setflags(write=False)

    @property
    def path(self) -> str:
        return self.meta.path

    @property
    def name(self) -> str:
        from pathlib import Path

        return Path(self.meta.path).name

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.levels.shape[0]), int(self.levels.shape[1]))

    @property
    def max_level(self) -> int:
        return self.meta.max_level

    @property
    def bit_depth(self) -> int:
        return self.meta.bit_depth

    @property
    def is_linear(self) -> bool:
        return self.meta.is_linear

    @property
    def exposure_time(self) -> float | None:
        t = self.meta.exposure_time
        return None if t is None else float(t)

    def linear(self, dtype: type = np.float32) -> np.ndarray:
        """Linear exposure ``levels / max_level`` (RAW frames only; others need a response)."""
        if not self.is_linear:
            raise ParameterError(
                "frame is not linear; apply a camera response first",
                expected="a RAW frame",
                found=f"{self.meta.format} ({self.meta.path})",
            )
        return self.levels.astype(dtype) * dtype(1.0 / self.max_level)

    def mean_level(self) -> float:
        """Mean level relative to ``max_level`` (used to order frames without EXIF)."""
        step = max(1, int(np.sqrt(self.levels.size / 3 / 65536)))
        return float(self.levels[::step, ::step].mean()) / self.max_level

    def with_exposure_time(self, seconds: Fraction | float, source: str) -> Frame:
        """The frame with its time replaced (e.g. from a times file): such a time is exact, so
        any APEX-snapped value of the old tag goes."""
        t = seconds if isinstance(seconds, Fraction) else Fraction(str(seconds))
        return self.with_meta(
            exposure_time=t,
            exposure_time_source=source,
            exposure_time_apex=None,
            exposure_time_sequence=None,
        )

    def with_meta(self, **changes: Any) -> Frame:
        """The same levels with some metadata fields replaced."""
        return Frame(levels=self.levels, meta=replace(self.meta, **changes), cfa=self.cfa)
