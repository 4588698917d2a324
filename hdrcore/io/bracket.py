"""A bracket: frames of one scene at different exposures, darkest first, with capture warnings.

A frame's recorded exposure is ``t x ISO / ISO_0 x (N_0 / N)^2`` (:func:`recorded_exposures`):
phones bracket with exposure compensation and change the ISO, several frames can share one time.
Nominal EXIF times and f-numbers are taken at their APEX values (1/640 s is ``2^(-28/3)`` s,
:mod:`hdrcore.io.apex`); times from a times file are exact and used as given. Frames are ordered
by that exposure, unless their pixels clearly say otherwise (:func:`brightness_order`): then the
pixels win, each frame keeps the time it was given, and a ``times-swapped`` or ``out-of-order``
warning names the files.

Capture mistakes (aperture or ISO changed between frames, duplicate exposures, frames whose
brightness contradicts their exposure times, mixed cameras, missing EXIF or white balance) are
reported as :class:`BracketWarning` objects on the bracket, never as crashes: the estimator can
still measure the real exposure ratios from the histograms. Things that make a bracket
impossible (one frame, different sizes, a mix of RAW and non-linear frames) raise
:class:`BracketError`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from fractions import Fraction
from functools import cmp_to_key
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from .._threads import thread_map
from ..errors import BracketError, ImageReadError, InputError
from ._capture import reading
from ._paths import input_file, path_problem, resolved
from .apex import bracket_sequence, snap_exposure_time, snap_f_number
from .frame import Frame, FrameMetadata, apply_orientation, undo_orientation
from .header import frame_pixels
from .ldr import read_ldr, sniff_format
from .raw import is_raw_path, read_raw
from .times import read_exposure_times, times_from_mapping

K = TypeVar("K")

__all__ = [
    "BracketWarning",
    "Bracket",
    "load_frame",
    "load_bracket",
    "expand_paths",
    "recorded_exposures",
    "snap_frames",
    "brightness_order",
]

IMAGE_EXTENSIONS = frozenset({".jpg", ".jpeg", ".png", ".tif", ".tiff"})

#: Two recorded exposures closer than this (in stops) are the same exposure: 1/24 stop (2.9 %)
#: covers the rounding of nominal ISO values (ISO 500 is 2^(7/3) x 100 = 504), while the
#: smallest bracketing step is 1/3 stop.
DUPLICATE_EXPOSURE_STOPS = 1.0 / 24.0
#: Frame ``b`` is *clearly* brighter than frame ``a`` when, over the same pixels, it is brighter
#: at more pixels than it is darker by this fraction of all pixels (and brighter on average).
#: Correctly ordered pairs of the real brackets of ../shared/data score 0.65-0.98 (1/3-stop phone
#: pairs of the Xperia bracket: 0.65-0.96); the darkest film scans of memorial, fog and scanner
#: noise with 1-stop steps, score -0.37 .. 0.28 (they carry no brightness information), so 0.5
#: separates them.
CLEAR_ORDER_SCORE = 0.5
_BRIGHTNESS_SAMPLES = 65536


@dataclass(frozen=True)
class BracketWarning:
    """A capture mistake: ``code`` is a short stable word, ``message`` says it in plain words."""

    code: str
    message: str
    frames: tuple[int, ...] = ()

    def to_json(self) -> dict:
        return {"code": self.code, "message": self.message, "frames": list(self.frames)}


@dataclass(frozen=True, eq=False)
class Bracket:
    """Frames sorted darkest first; ``input_order[k]`` is frame ``k``'s index in the given list.

    ``order_source`` is ``"exposure"`` (the recorded exposure, time x ISO x aperture) or
    ``"brightness"`` (no times, or times the pixels contradict: see the warnings).
    """

    frames: tuple[Frame, ...]
    warnings: tuple[BracketWarning, ...]
    order_source: str
    input_order: tuple[int, ...]

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def shape(self) -> tuple[int, int]:
        return self.frames[0].shape

    @property
    def is_linear(self) -> bool:
        return self.frames[0].is_linear

    @property
    def max_level(self) -> int:
        return self.frames[0].max_level

    @property
    def bit_depth(self) -> int:
        return self.frames[0].bit_depth

    @property
    def paths(self) -> tuple[str, ...]:
        return tuple(f.path for f in self.frames)

    @property
    def exposure_times(self) -> tuple[float | None, ...]:
        """Exposure times in seconds as recorded (EXIF or times file); ``None`` where unknown."""
        return tuple(f.exposure_time for f in self.frames)

    @property
    def has_exposure_times(self) -> bool:
        return all(t is not None for t in self.exposure_times)

    @property
    def apex_sequence(self) -> str | None:
        """The APEX sequence (``"1/3-stop"``, ``"1/2-stop"``) of the frames' nominal EXIF times,
        ``None`` when no time was snapped (exact times, a times file)."""
        seqs = {s for f in self.frames if (s := f.meta.exposure_time_sequence) is not None}
        if not seqs:
            return None
        return next(iter(seqs)) if len(seqs) == 1 else ", ".join(sorted(seqs))

    def exif_exposures(self, snapped: bool = True) -> tuple[float | None, ...]:
        """Recorded exposure ``t * (ISO / ISO_0) * (N_0 / N)^2`` relative to frame 0's settings.

        ``snapped`` (default) uses the APEX-snapped time and f-number where the tags are nominal
        values (:mod:`hdrcore.io.apex`), ``snapped=False`` the tags as read. See
        :func:`recorded_exposures`; ``None`` where the exposure time is unknown.
        """
        return recorded_exposures([f.meta for f in self.frames], snapped=snapped)

    def exif_ratio(self, dark: int, bright: int, snapped: bool = True) -> float | None:
        """Exposure ratio the metadata implies for frames ``bright`` over ``dark``, or ``None``."""
        e = self.exif_exposures(snapped)
        ed, eb = e[dark], e[bright]
        if ed is None or eb is None or ed == 0:
            return None
        return eb / ed

    def warning_codes(self) -> tuple[str, ...]:
        return tuple(w.code for w in self.warnings)


def _colour_space_warnings(frames: Sequence[Frame]) -> list[BracketWarning]:
    """Frames whose profile names a colour space we do not know (taken as sRGB), and frames
    that name different spaces (the merge uses the one most of them name)."""
    out = []
    unknown = [
        k
        for k, f in enumerate(frames)
        if not f.meta.is_linear and f.meta.colour_space is None and f.meta.colour_space_source
    ]
    if unknown:
        f = frames[unknown[0]]
        out.append(
            BracketWarning(
                "colour-space-unknown",
                f"{f.name} carries an {f.meta.colour_space_source}, a colour space hdrcore does "
                "not convert: its colours are taken as sRGB (export the frames in sRGB, Display "
                "P3 or Adobe RGB)",
                tuple(unknown),
            )
        )
    spaces = [(f.name, f.meta.colour_space or "sRGB") for f in frames if not f.meta.is_linear]
    if len({space for _, space in spaces}) > 1:
        out.append(
            BracketWarning(
                "colour-space-differs",
                "the frames are encoded in different colour spaces ("
                + ", ".join(f"{name} {space}" for name, space in spaces)
                + "): the merge takes them all as the one most of them use",
                tuple(range(len(frames))),
            )
        )
    return out


def expand_paths(paths: Iterable[str | os.PathLike]) -> list[Path]:
    """Expand directories into their image files (sorted by name); keep files as given.

    A folder's entry named like an image (``.jpg``, ``.png``, ``.tif``, a RAW extension) that is
    a symbolic link leading nowhere (a loop, a missing target) is an :class:`InputError`: it was
    meant as a frame. Sub-folders are left out.
    """
    out: list[Path] = []
    for item in paths:
        p = Path(item)
        if p.is_dir():
            try:
                entries = sorted(p.iterdir())
            except OSError as exc:
                raise InputError(
                    f"cannot list the folder: {path_problem(p, exc)}", path=p
                ) from None
            found = []
            for c in entries:
                if not (c.suffix.lower() in IMAGE_EXTENSIONS or is_raw_path(c)):
                    continue
                try:
                    if c.is_file():
                        found.append(c)
                    elif c.is_symlink() and not c.exists():  # a loop or a broken link
                        c.stat()
                except OSError as exc:
                    raise InputError(path_problem(c, exc), path=c) from None
            if not found:
                raise InputError("directory holds no JPEG, PNG, TIFF or RAW files", path=p)
            out.extend(found)
        else:
            out.append(p)
    return out


def load_frame(
    path: str | os.PathLike, *, raw_half_size: bool = False, max_pixels: int | None = None
) -> Frame:
    """Read one frame, choosing the reader from the file's content (RAW by extension).

    A nominal EXIF time (and f-number) also gets its APEX-snapped value (:func:`snap_frames`).
    ``max_pixels`` limits the frame's size, read from its header before anything is decoded:
    ``None`` is :data:`hdrcore.io.MAX_FRAME_PIXELS`, 0 no limit
    (:class:`~hdrcore.errors.FrameTooLargeError`).
    """
    p = input_file(path)
    with reading(p):
        try:
            if p.stat().st_size == 0:
                raise ImageReadError("file is empty", path=p)
            fmt = sniff_format(p)
        except OSError as exc:
            raise InputError(f"cannot read file: {path_problem(p, exc)}", path=p) from exc
        if is_raw_path(p):
            frame = read_raw(p, half_size=raw_half_size, max_pixels=max_pixels)
        elif fmt is None:
            raise ImageReadError(
                "not a recognised image",
                path=p,
                expected="JPEG, PNG, TIFF or a camera RAW file (.dng, .cr2, .nef, ...)",
            )
        else:
            frame = read_ldr(p, fmt, max_pixels=max_pixels)
    return snap_frames([frame])[0]


def snap_frames(frames: Sequence[Frame]) -> list[Frame]:
    """The frames with ``exposure_time_apex`` / ``f_number_apex`` set for one bracket.

    Only EXIF times are snapped (a times file holds exact values, LibRaw's time is already the
    APEX value); the bracket's sequence (:func:`~hdrcore.io.apex.bracket_sequence`) decides the
    values nominal in both sequences, and f-numbers are snapped on that sequence only.
    """
    exif = [f.meta.exposure_time if f.meta.exposure_time_source == "exif" else None for f in frames]
    seq = bracket_sequence(exif)
    out = []
    for f, t in zip(frames, exif, strict=True):
        t_apex = t_seq = n_apex = None
        if t is not None and seq is not None:
            value, which = snap_exposure_time(t, seq)
            if which is not None:
                t_apex, t_seq = value, which
        if f.meta.f_number is not None and seq is not None:
            value, which = snap_f_number(f.meta.f_number, seq)
            if which == seq:
                n_apex = value
        out.append(
            f.with_meta(
                exposure_time_apex=t_apex, exposure_time_sequence=t_seq, f_number_apex=n_apex
            )
        )
    return out


def recorded_exposures(
    metas: Sequence[FrameMetadata], *, snapped: bool = True
) -> tuple[float | None, ...]:
    """Each frame's recorded exposure ``t * (ISO / ISO_0) * (N_0 / N)^2``.

    ``ISO_0`` and ``N_0`` are the first frame's (the values are relative to its settings). The
    ISO term is applied when every frame with a time records its ISO, the aperture term when
    every one records its f-number (a term known for some frames only cannot be compared, so it
    is left out for all). ``snapped`` uses the APEX-snapped time and f-number where the tags are
    nominal (:attr:`FrameMetadata.exposure_time_actual`). ``None`` where the time is unknown.
    """
    timed = [m for m in metas if m.exposure_time is not None]
    use_iso = bool(timed) and all(m.iso for m in timed)
    use_n = bool(timed) and all(m.f_number for m in timed)
    iso0 = timed[0].iso if use_iso else None

    def n_of(m: FrameMetadata) -> float:
        n = m.f_number_actual if snapped else m.f_number
        if n is None:  # use_n: every timed frame records one
            raise ValueError("a frame with an exposure time records no f-number")
        return float(n)

    n0 = n_of(timed[0]) if use_n else None
    out: list[float | None] = []
    for m in metas:
        t = m.exposure_time_actual if snapped else m.exposure_time
        if m.exposure_time is None or t is None:
            out.append(None)
            continue
        e = float(t)
        if iso0 and m.iso:  # use_iso: every timed frame records its ISO
            e *= m.iso / iso0
        if n0 is not None:  # use_n
            e *= (n0 / n_of(m)) ** 2
        out.append(e)
    return tuple(out)


def _seconds(t: Fraction | None) -> str:
    """``1/16 s``, ``1/802.8 s``, ``0.3 s``, ``8 s``."""
    if t is None:
        return "unknown time"
    if t < 1 and t.numerator == 1:
        return f"1/{t.denominator} s"
    if t < Fraction(1, 4):
        return f"1/{1 / float(t):.4g} s"
    return f"{float(t):g} s"


def _brightness_samples(frame: Frame) -> np.ndarray:
    """The frame's levels summed over channels on a regular grid of about 65k pixels."""
    step = max(
        1, int(math.sqrt(frame.levels.shape[0] * frame.levels.shape[1] / _BRIGHTNESS_SAMPLES))
    )
    return frame.levels[::step, ::step].astype(np.int32).sum(axis=-1)


def brightness_order(
    frames: Sequence[Frame], order: Sequence[int]
) -> tuple[list[int], list[tuple[int, int]]]:
    """``order`` (frame indices, darkest first by recorded exposure) corrected by the pixels.

    Two frames are compared pixel by pixel on the same grid: ``score(a, b)`` is the fraction of
    pixels brighter in ``b`` minus the fraction brighter in ``a``. Since every pixel's level
    grows with exposure (clipping included), ``b`` is *clearly* brighter than ``a`` when the
    score exceeds :data:`CLEAR_ORDER_SCORE` and its mean level is higher too. Frames that are
    almost all black or saturated tie at nearly every pixel, so they never contradict anything.
    Returns the order the pixels support (``order`` itself when nothing is contradicted: only
    clear pairs move) and the contradicted pairs ``(a, b)``: ``a`` has the shorter recorded
    exposure but is clearly brighter than ``b``.
    """
    samples: dict[int, np.ndarray] = {}
    means: dict[int, float] = {}

    def sample(k: int) -> np.ndarray:
        if k not in samples:
            samples[k] = _brightness_samples(frames[k])
            means[k] = float(samples[k].mean())
        return samples[k]

    scores: dict[tuple[int, int], float] = {}

    def brighter(a: int, b: int) -> bool:
        """Is ``b`` clearly brighter than ``a``?"""
        if (a, b) not in scores:
            d = np.sign(sample(b) - sample(a))
            scores[(a, b)] = float(d.mean())
            scores[(b, a)] = -scores[(a, b)]
        return scores[(a, b)] > CLEAR_ORDER_SCORE and means[b] > means[a]

    order = list(order)
    contradicted = [
        (order[i], order[j])
        for i in range(len(order))
        for j in range(i + 1, len(order))
        if brighter(order[j], order[i])
    ]
    if not contradicted:
        return order, []
    position = {k: i for i, k in enumerate(order)}

    def compare(a: int, b: int) -> int:
        if brighter(a, b):
            return -1
        if brighter(b, a):
            return 1
        return position[a] - position[b]

    return sorted(order, key=cmp_to_key(compare)), contradicted


def _order_warning(
    frames: Sequence[Frame],
    by_exposure: list[int],
    by_brightness: list[int],
    contradicted: list[tuple[int, int]],
    describe: Callable[[int], str],
) -> BracketWarning:
    """``times-swapped`` when the pixels' order is the recorded one with two frames exchanged,
    else ``out-of-order``. ``by_exposure``, ``by_brightness`` and ``contradicted`` hold indices
    into ``frames``; the warning's ``frames`` are positions in the final (brightness) order."""
    name = [f.name for f in frames]
    final = {k: i for i, k in enumerate(by_brightness)}
    moved = [i for i in range(len(by_exposure)) if by_exposure[i] != by_brightness[i]]
    if len(moved) == 2:
        a, b = by_exposure[moved[0]], by_exposure[moved[1]]  # a: shorter exposure, brighter
        return BracketWarning(
            "times-swapped",
            f"{name[a]} ({describe(a)}) is brighter than {name[b]} ({describe(b)}): the times "
            "look swapped; the frames are ordered by brightness (each keeps the time it was "
            "given, so their exposure ratio from the times comes out below 1)",
            tuple(sorted((final[a], final[b]))),
        )
    pairs = "; ".join(
        f"{name[a]} ({describe(a)}) is brighter than {name[b]} ({describe(b)})"
        for a, b in contradicted[:4]
    )
    more = f" and {len(contradicted) - 4} more" if len(contradicted) > 4 else ""
    involved = sorted({final[k] for pair in contradicted for k in pair})
    return BracketWarning(
        "out-of-order",
        f"brightness contradicts the recorded exposures: {pairs}{more}; the times or the files "
        "are wrong. The frames are ordered by brightness, darkest first: "
        + ", ".join(name[k] for k in by_brightness),
        tuple(involved),
    )


_ORIENTATION_WORDS = {
    1: "as stored",
    2: "mirrored",
    3: "turned 180°",
    4: "flipped upside down",
    5: "transposed",
    6: "turned 90° clockwise",
    7: "transverse",
    8: "turned 90° counter-clockwise",
}


def _orientation_tag(frame: Frame) -> int:
    """The orientation the frame's levels were turned by (no tag, or an unknown value: 1)."""
    o = frame.meta.orientation
    return o if o in _ORIENTATION_WORDS else 1


def _stored_shape(frame: Frame) -> tuple[int, int]:
    """The frame's (height, width) as stored in the file, before its orientation tag."""
    h, w = frame.shape
    return (w, h) if _orientation_tag(frame) in (5, 6, 7, 8) else (h, w)


def _majority(keys: Sequence[K]) -> K:
    """The most common of ``keys``; a tie goes to the one met first."""
    return max(dict.fromkeys(keys), key=list(keys).count)


def _names(frames: Sequence[Frame], limit: int = 3) -> str:
    names = [f.name for f in frames]
    more = f" and {len(names) - limit} more" if len(names) > limit else ""
    return ", ".join(names[:limit]) + more


def _unify_orientation(frames: list[Frame]) -> tuple[list[Frame], BracketWarning | None]:
    """One orientation for every frame whose tag differs, when the stored pixels agree.

    A camera writes its pixels in the sensor's orientation and records how it was held in the
    orientation tag only; when that tag changes within a bracket (the camera tipped, or pointed
    up or down where the sensor cannot tell), the pixels still line up. So when every frame is
    stored with the same size but the tags differ, all frames are turned by one tag, the most
    common one (a tie: the first frame's in file order), and an ``orientation-differs`` warning
    names the others. Frames stored with different sizes that agree once each is turned by its
    own tag (pictures rotated losslessly by software) keep their own tags.
    """
    tags = [_orientation_tag(f) for f in frames]
    if len(set(tags)) <= 1 or len({_stored_shape(f) for f in frames}) != 1:
        return frames, None
    target = _majority(tags)
    out = []
    for f, tag in zip(frames, tags, strict=True):
        if tag == target:
            out.append(f)
            continue
        levels = apply_orientation(undo_orientation(f.levels, tag), target)
        out.append(Frame(levels=levels, meta=replace(f.meta, orientation=target), cfa=f.cfa))
    odd: dict[int, list[str]] = {}
    for f, t in zip(frames, tags, strict=True):
        if t != target:
            odd.setdefault(t, []).append(f.name)
    shown = "; ".join(
        f"{', '.join(names)} {'has' if len(names) == 1 else 'have'} orientation tag {t} "
        f"({_ORIENTATION_WORDS[t]})"
        for t, names in odd.items()
    )
    stored_h, stored_w = _stored_shape(frames[0])
    warning = BracketWarning(
        "orientation-differs",
        f"{shown}, the others {target} ({_ORIENTATION_WORDS[target]}); all are stored alike "
        f"({stored_w}x{stored_h}), so the camera changed its orientation tag, not the picture: "
        f"every frame is shown {_ORIENTATION_WORDS[target]}",
        tuple(k for k, t in enumerate(tags) if t != target),
    )
    return out, warning


def _check_consistent(frames: list[Frame]) -> None:
    """Same kind (RAW or not), same size and same bit depth: the frame that differs from the
    others (from most of them; with a tie, from the first in file order) is the one named."""

    def odd_one(key: Callable[[Frame], object]) -> tuple[Frame, list[Frame]] | None:
        common = _majority([key(f) for f in frames])
        alike = [f for f in frames if key(f) == common]
        odd = next((f for f in frames if key(f) != common), None)
        return None if odd is None else (odd, alike)

    # the kind first: a RAW file among JPEGs differs in size too, and its kind says why
    found = odd_one(lambda f: f.is_linear)
    if found:
        f, alike = found
        raise BracketError(
            "cannot mix RAW and non-linear (JPEG/PNG/TIFF) frames in one bracket",
            path=f.path,
            expected=f"{alike[0].meta.format} like {_names(alike)}",
            found=f.meta.format,
        )
    found = odd_one(lambda f: f.shape)
    if found:
        f, alike = found
        ref = alike[0]
        turned = ""
        if _orientation_tag(f) != _orientation_tag(ref):
            turned = (
                f" once turned by its orientation tag {_orientation_tag(f)} "
                f"({_ORIENTATION_WORDS[_orientation_tag(f)]})"
            )
        if not turned and tuple(f.shape[:2]) == tuple(ref.shape[:2])[::-1]:
            turned = " (the same size turned by 90 degrees: a frame rotated in an editor?)"
        others = "the first frame" if len(frames) == 2 else "the other frames"
        raise BracketError(
            f"frame size differs from {others}{turned}",
            path=f.path,
            expected=f"{ref.shape[1]}x{ref.shape[0]} like {_names(alike)}",
            found=f"{f.shape[1]}x{f.shape[0]}",
        )
    if not frames[0].is_linear:
        found = odd_one(lambda f: f.max_level)
        if found:
            f, alike = found
            raise BracketError(
                "bit depth differs from the other frames",
                path=f.path,
                expected=f"{alike[0].bit_depth} bits like {_names(alike)}",
                found=f"{f.bit_depth} bits",
            )


def _capture_warnings(frames: list[Frame]) -> list[BracketWarning]:
    warns: list[BracketWarning] = []
    n = len(frames)
    names = [f.name for f in frames]
    times = [f.meta.exposure_time for f in frames]
    if all(t is None for t in times):
        warns.append(
            BracketWarning(
                "no-exposure-times",
                "no frame records an exposure time; frames were ordered by brightness and the "
                "ratios "
                "come from the histograms alone",
            )
        )
    elif any(t is None for t in times):
        missing = tuple(k for k, t in enumerate(times) if t is None)
        warns.append(
            BracketWarning(
                "partial-exposure-times",
                "exposure time unknown for " + ", ".join(names[k] for k in missing),
                missing,
            )
        )
    timed = [k for k, t in enumerate(times) if t is not None]

    def changed(attr: str, code: str, label: str, fmt: Callable[[Any], str], term: str) -> None:
        values = [getattr(f.meta, attr) for f in frames]
        known = [(k, v) for k, v in enumerate(values) if v is not None]
        if len({v for _, v in known}) <= 1:
            return
        desc = ", ".join(f"{names[k]} {fmt(v)}" for k, v in known)
        if timed and all(values[k] is not None for k in timed):
            used = (
                f"the exposure used to order and chain the frames is time x {term}, so it "
                f"includes the {label} change"
            )
        else:
            used = (
                f"the {label} is not recorded for every frame, so the exposure used to "
                f"order and chain the frames leaves it out"
            )
        # Frames that share one exposure time differ by this setting alone.
        shared = []
        for t in sorted({t for k in timed if (t := times[k]) is not None}):
            same = [k for k in timed if times[k] == t]
            if len(same) > 1 and len({values[k] for k in same}) > 1:
                shared.append(f"{', '.join(names[k] for k in same)} share {_seconds(t)}")
        also = f" ({'; '.join(shared)}: only their {label} differs)" if shared else ""
        warns.append(
            BracketWarning(
                code,
                f"{label} changed between frames ({desc}){also}; {used}",
                tuple(k for k, _ in known),
            )
        )

    changed("f_number", "aperture-changed", "aperture", lambda v: f"f/{float(v):g}", "(N_0 / N)^2")
    changed("iso", "iso-changed", "ISO", lambda v: f"ISO {v}", "ISO / ISO_0")
    cams = [f.meta.camera for f in frames]
    known_cams = {c for c in cams if c}
    if len(known_cams) > 1:
        warns.append(
            BracketWarning(
                "mixed-cameras",
                "frames come from different cameras: " + ", ".join(sorted(known_cams)),
                tuple(range(n)),
            )
        )
    span = _capture_span(frames)
    if span is not None:
        warns.append(span)
    # Duplicate exposures: the same recorded exposure (time x ISO x aperture, APEX-snapped).
    exposures = recorded_exposures([f.meta for f in frames])
    for k in range(n):
        for j in range(k):
            ej, ek = exposures[j], exposures[k]
            if ej is None or ek is None:
                continue
            if abs(math.log2(ek / ej)) < DUPLICATE_EXPOSURE_STOPS:
                warns.append(
                    BracketWarning(
                        "duplicate-exposure",
                        f"{names[j]} and {names[k]} have the same exposure "
                        f"({_describe(frames[j])}; "
                        f"{_describe(frames[k])}): a valid pair with ratio 1",
                        (j, k),
                    )
                )
                break
    return warns


#: Frames whose recorded capture times span more than this (seconds) are said not to look like
#: one bracket: a camera's bracket takes seconds, a bracket of long exposures minutes (nine
#: 30 s frames: under 5 minutes). The two real CRW files of ``../shared/data``, from two
#: cameras 287 days apart, merged with warnings about their apertures and times only.
CAPTURE_SPAN_S = 3600.0


def _capture_span(frames: list[Frame]) -> BracketWarning | None:
    """``capture-span``: the frames' recorded capture times span more than
    :data:`CAPTURE_SPAN_S` (frames of other shots in the folder)."""
    known = [(k, f.meta.capture_time) for k, f in enumerate(frames) if f.meta.capture_time]
    if len(known) < 2:
        return None
    try:
        first = min(known, key=lambda kv: kv[1])
        last = max(known, key=lambda kv: kv[1])
        seconds = (last[1] - first[1]).total_seconds()
    except TypeError:  # naive and aware times mixed: no comparison
        return None
    if seconds <= CAPTURE_SPAN_S:
        return None
    if seconds >= 2 * 86400:
        gap = f"{seconds / 86400:.0f} days"
    elif seconds >= 7200:
        gap = f"{seconds / 3600:.0f} hours"
    else:
        gap = f"{seconds / 60:.0f} minutes"
    f0, f1 = frames[first[0]], frames[last[0]]
    return BracketWarning(
        "capture-span",
        f"the frames were taken {gap} apart ({f0.name} {first[1]:%Y-%m-%d %H:%M:%S}, "
        f"{f1.name} {last[1]:%Y-%m-%d %H:%M:%S}): a bracket is shot within seconds or "
        "minutes; check that every file belongs to this one",
        tuple(k for k, _ in known),
    )


def _describe(frame: Frame, *, iso: bool = True, aperture: bool = True) -> str:
    """``1/15 s, ISO 800, f/1.7`` (the settings that make up the exposure)."""
    m = frame.meta
    parts = [_seconds(m.exposure_time)]
    if iso and m.iso:
        parts.append(f"ISO {m.iso}")
    if aperture and m.f_number:
        parts.append(f"f/{float(m.f_number):g}")
    return ", ".join(parts)


def _white_balance_warnings(frames: list[Frame]) -> list[BracketWarning]:
    """``no-white-balance``: RAW frames whose file records no usable as-shot white balance."""
    warns = []
    for source, what in (
        ("matrix-neutral", "the colour matrix's D65 neutral"),
        ("unity", "unity (the file has no colour matrix either)"),
    ):
        ks = tuple(k for k, f in enumerate(frames) if f.meta.whitebalance_source == source)
        if not ks:
            continue
        wbs = {
            tuple(round(v, 3) for v in (frames[k].meta.camera_whitebalance or ())[:3]) for k in ks
        }
        used = (
            ", ".join(f"{c} x {v:.3g}" for c, v in zip("RGB", next(iter(wbs)), strict=True))
            if len(wbs) == 1
            else "per frame"
        )
        warns.append(
            BracketWarning(
                "no-white-balance",
                f"{', '.join(frames[k].name for k in ks)} "
                f"{'records' if len(ks) == 1 else 'record'} no as-shot white balance (LibRaw "
                f"reports zero multipliers); {what} is used instead ({used})",
                ks,
            )
        )
    return warns


#: Bit depths cameras and scanners write that a 16-bit file can carry unscaled.
NARROW_DEPTHS = (10, 12, 14)
#: A clipping pile-up: at least this share of the brightest frame's pixels (any channel) at the
#: bracket's top level.
CLIP_PILE = 1e-3


def narrow_container(frames: list[Frame]) -> tuple[list[Frame], BracketWarning | None]:
    """Non-linear 16-bit frames whose levels stop at ``2**b - 1`` (``b`` in
    :data:`NARROW_DEPTHS`) with a clipping pile-up there (:data:`CLIP_PILE` of the brightest
    frame's pixels): ``b``-bit data left unscaled in 16-bit files (a scientific camera, a raw
    converter's document mode). Their levels are read against ``2**b - 1``, so the saturation
    level (a share of the range) finds the clipped pixels; read against 65535 the clipped
    highlights merged as valid data and the response recovered from a quarter of the range
    came out a filmic curve for linear frames. Other frames as they are."""
    if any(f.is_linear or f.max_level != 65535 for f in frames):
        return frames, None
    top = max(int(f.levels.max()) for f in frames)
    depth = next((b for b in NARROW_DEPTHS if top == (1 << b) - 1), None)
    if depth is None:
        return frames, None
    brightest = max(range(len(frames)), key=lambda k: frames[k].mean_level())
    pile = float(np.mean(np.any(frames[brightest].levels == top, axis=-1)))
    if pile < CLIP_PILE:
        return frames, None
    narrowed = [
        f.with_meta(bit_depth=depth, max_level=top, white_level=top, channel_max_levels=(top,) * 3)
        for f in frames
    ]
    return narrowed, BracketWarning(
        "narrow-container",
        f"the frames' levels stop at {top} ({pile:.1%} of {frames[brightest].name}'s pixels "
        f"clip there): {depth}-bit data in 16-bit files, read against {top} instead of 65535",
    )


def load_bracket(
    paths: Iterable[str | os.PathLike],
    *,
    exposure_times: Mapping[str, Fraction | float] | str | os.PathLike | None = None,
    raw_half_size: bool = False,
    max_pixels: int | None = None,
) -> Bracket:
    """Load frames into a :class:`Bracket`, darkest first.

    ``paths`` may include directories (their image files are used). ``exposure_times`` is a
    ``name -> seconds`` mapping or the path of a ``name seconds`` text file; its values replace
    EXIF times (a disagreement with EXIF becomes a warning) and are never APEX-snapped.

    Frames are ordered by their recorded exposure ``t x ISO x 1/N^2`` (APEX-snapped,
    :func:`recorded_exposures`), equal exposures by brightness. When the pixels clearly
    contradict that order (:func:`brightness_order`: a frame brighter than one with a longer
    exposure) the frames are ordered by brightness instead, each keeping the time it was given,
    with a ``times-swapped`` or ``out-of-order`` warning naming the files.

    ``max_pixels`` limits each frame's size, read from its header before anything is decoded
    (``None``: :data:`hdrcore.io.MAX_FRAME_PIXELS`; 0: no limit). Frames whose orientation tags
    differ while their stored pixels agree are all turned by one tag (``orientation-differs``).
    """
    files = expand_paths(paths)
    if len(files) < 2:
        for file in files:  # a path that is missing or unreadable is what is wrong with it
            input_file(file, "file or folder" if not os.path.lexists(file) else "file")
            frame_pixels(file)  # and a file that is no image (its header read, nothing decoded)
        where = files[0] if files else None
        raise BracketError(
            "a bracket needs at least two frames", path=where, found=f"{len(files)} frame(s)"
        )
    seen_paths: dict[str, Path] = {}
    for file in files:
        input_file(file)
        key = str(resolved(file))
        if key in seen_paths:
            raise BracketError("the same file is given twice", path=file)
        seen_paths[key] = file

    times_map: dict[str, Fraction] | None = None
    if exposure_times is not None:
        if isinstance(exposure_times, Mapping):
            times_map = times_from_mapping(exposure_times)
        else:
            times_map = read_exposure_times(exposure_times)

    # Two files decoded at a time (LibRaw and Pillow release the GIL while they decode; the
    # first error in file order is the one raised).
    frames = thread_map(
        lambda p: load_frame(p, raw_half_size=raw_half_size, max_pixels=max_pixels), files
    )
    warns: list[BracketWarning] = []
    if times_map is not None:
        missing = [f.name for f in frames if f.name not in times_map]
        if missing:
            raise InputError(
                "exposure-times list does not name every frame",
                path=None if isinstance(exposure_times, Mapping) else exposure_times,
                found="missing " + ", ".join(missing),
            )
        updated = []
        for f in frames:
            t = times_map[f.name]
            exif_t = f.meta.exposure_time
            if exif_t is not None and f.meta.exposure_time_source == "exif":
                if abs(float(exif_t) / float(t) - 1.0) > 0.02:
                    warns.append(
                        BracketWarning(
                            "exif-times-mismatch",
                            f"{f.name}: EXIF says {float(exif_t):g} s, the times list says "
                            f"{float(t):g} s; using the list",
                        )
                    )
            updated.append(f.with_exposure_time(t, "times-file"))
        frames = updated
    frames = snap_frames(frames)

    frames, orientation = _unify_orientation(frames)
    _check_consistent(frames)
    frames, narrow = narrow_container(frames)
    if narrow is not None:
        warns.append(narrow)

    n = len(frames)
    means = [f.mean_level() for f in frames]
    exposures = recorded_exposures([f.meta for f in frames])
    reorder: BracketWarning | None = None
    if all(e is not None for e in exposures):
        order = sorted(range(n), key=lambda k: (exposures[k], means[k]))
        order_source = "exposure"
        by_brightness, contradicted = brightness_order(frames, order)
        if contradicted:
            iso = len({f.meta.iso for f in frames}) > 1
            aperture = len({f.meta.f_number for f in frames}) > 1
            reorder = _order_warning(
                frames,
                order,
                by_brightness,
                contradicted,
                lambda k: _describe(frames[k], iso=iso, aperture=aperture),
            )
            order, order_source = by_brightness, "brightness"
    else:
        order = sorted(range(n), key=lambda k: means[k])
        order_source = "brightness"
    if order != list(range(n)) and order != list(range(n))[::-1]:
        warns.append(
            BracketWarning(
                "input-unsorted",
                "files were not given in exposure order; they were sorted darkest first",
            )
        )
    if reorder is not None:
        warns.append(reorder)
    position = {k: i for i, k in enumerate(order)}
    if orientation is not None:  # its frames are file positions: to the sorted order
        warns.append(
            BracketWarning(
                orientation.code,
                orientation.message,
                tuple(sorted(position[k] for k in orientation.frames)),
            )
        )
    sorted_frames = [frames[k] for k in order]
    # Indices in warnings refer to the sorted order.
    warns.extend(_capture_warnings(sorted_frames))
    warns.extend(_white_balance_warnings(sorted_frames))
    warns.extend(_colour_space_warnings(sorted_frames))
    for k, f in enumerate(sorted_frames):
        if f.meta.decoder_messages:
            warns.append(
                BracketWarning(
                    "decoder-messages",
                    f"{f.name}: {'; '.join(f.meta.decoder_messages)}; it was decoded anyway, but "
                    "its pixels may be wrong",
                    (k,),
                )
            )
    for k, f in enumerate(sorted_frames):
        step = max(1, int(np.sqrt(f.levels.size / 3 / 262144)))
        sub = f.levels[::step, ::step]
        if float(np.mean(sub >= f.max_level)) > 0.98:
            warns.append(
                BracketWarning(
                    "frame-saturated",
                    f"{f.name} is almost entirely saturated",
                    (k,),
                )
            )
        elif float(np.mean(sub == 0)) > 0.98:
            warns.append(
                BracketWarning(
                    "frame-black",
                    f"{f.name} is almost entirely black",
                    (k,),
                )
            )
    return Bracket(
        frames=tuple(sorted_frames),
        warnings=tuple(warns),
        order_source=order_source,
        input_order=tuple(order),
    )
