"""A bracket: frames of one scene at different exposures, darkest first, with capture warnings.

Capture mistakes (aperture or ISO changed between frames, duplicate exposures, frames whose
brightness contradicts their exposure times, mixed cameras, missing EXIF) are reported as
:class:`BracketWarning` objects on the bracket, never as crashes: the estimator can still measure
the real exposure ratios from the histograms. Things that make a bracket impossible (one frame,
different sizes, a mix of RAW and non-linear frames) raise :class:`BracketError`.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from .._threads import thread_map
from ..errors import BracketError, ImageReadError, InputError
from .frame import Frame
from .ldr import read_ldr, sniff_format
from .raw import is_raw_path, read_raw
from .times import read_exposure_times

__all__ = ["BracketWarning", "Bracket", "load_frame", "load_bracket", "expand_paths"]

IMAGE_EXTENSIONS = frozenset({".jpg", ".jpeg", ".png", ".tif", ".tiff"})


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
    """Frames sorted darkest first; ``input_order[k]`` is frame ``k``'s index in the given list."""

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

    def exif_exposures(self) -> tuple[float | None, ...]:
        """Recorded exposure ``t * (ISO / ISO_0) / (N / N_0)^2`` relative to frame 0's settings.

        ISO and aperture terms are applied only when known for both frames; ``None`` where the
        exposure time is unknown.
        """
        first = self.frames[0].meta
        out: list[float | None] = []
        for f in self.frames:
            m = f.meta
            if m.exposure_time is None:
                out.append(None)
                continue
            e = float(m.exposure_time)
            if m.iso and first.iso:
                e *= m.iso / first.iso
            if m.f_number and first.f_number:
                e *= float(first.f_number / m.f_number) ** 2
            out.append(e)
        return tuple(out)

    def exif_ratio(self, dark: int, bright: int) -> float | None:
        """Exposure ratio the metadata implies for frames ``bright`` over ``dark``, or ``None``."""
        e = self.exif_exposures()
        if e[dark] is None or e[bright] is None or e[dark] == 0:
            return None
        return e[bright] / e[dark]

    def warning_codes(self) -> tuple[str, ...]:
        return tuple(w.code for w in self.warnings)


def expand_paths(paths: Iterable[str | os.PathLike]) -> list[Path]:
    """Expand directories into their image files (sorted by name); keep files as given."""
    out: list[Path] = []
    for item in paths:
        p = Path(item)
        if p.is_dir():
            found = sorted(
                c for c in p.iterdir()
                if c.is_file() and (c.suffix.lower() in IMAGE_EXTENSIONS or is_raw_path(c))
            )
            if not found:
                raise InputError("directory holds no JPEG, PNG, TIFF or RAW files", path=p)
            out.extend(found)
        else:
            out.append(p)
    return out


def load_frame(path: str | os.PathLike, *, raw_half_size: bool = False) -> Frame:
    """Read one frame, choosing the reader from the file's content (RAW by extension)."""
    p = Path(path)
    if not p.exists():
        raise InputError("file not found", path=p)
    if not p.is_file():
        raise InputError("not a regular file", path=p)
    try:
        if p.stat().st_size == 0:
            raise ImageReadError("file is empty", path=p)
        fmt = sniff_format(p)
    except OSError as exc:
        raise InputError(f"cannot read file ({exc.strerror})", path=p) from exc
    if is_raw_path(p):
        return read_raw(p, half_size=raw_half_size)
    if fmt is None:
        raise ImageReadError(
            "not a recognised image", path=p,
            expected="JPEG, PNG, TIFF or a camera RAW file (.dng, .cr2, .nef, ...)",
        )
    return read_ldr(p, fmt)


def _check_consistent(frames: list[Frame]) -> None:
    ref = frames[0]
    for f in frames[1:]:
        if f.shape != ref.shape:
            raise BracketError(
                "frame size differs from the first frame", path=f.path,
                expected=f"{ref.shape[1]}x{ref.shape[0]} like {ref.name}",
                found=f"{f.shape[1]}x{f.shape[0]}",
            )
        if f.is_linear != ref.is_linear:
            raise BracketError(
                "cannot mix RAW and non-linear (JPEG/PNG/TIFF) frames in one bracket",
                path=f.path, expected=ref.meta.format, found=f.meta.format,
            )
        if f.max_level != ref.max_level and not f.is_linear:
            raise BracketError(
                "bit depth differs from the first frame", path=f.path,
                expected=f"{ref.bit_depth} bits like {ref.name}", found=f"{f.bit_depth} bits",
            )


def _capture_warnings(frames: list[Frame], order_source: str) -> list[BracketWarning]:
    warns: list[BracketWarning] = []
    n = len(frames)
    names = [f.name for f in frames]
    times = [f.meta.exposure_time for f in frames]
    if all(t is None for t in times):
        warns.append(BracketWarning(
            "no-exposure-times",
            "no frame records an exposure time; frames were ordered by brightness and the ratios "
            "come from the histograms alone",
        ))
    elif any(t is None for t in times):
        missing = tuple(k for k, t in enumerate(times) if t is None)
        warns.append(BracketWarning(
            "partial-exposure-times",
            "exposure time unknown for " + ", ".join(names[k] for k in missing),
            missing,
        ))

    def changed(attr: str, code: str, label: str, fmt: Callable[[object], str]) -> None:
        values = [getattr(f.meta, attr) for f in frames]
        known = [(k, v) for k, v in enumerate(values) if v is not None]
        if len({v for _, v in known}) > 1:
            desc = ", ".join(f"{names[k]} {fmt(v)}" for k, v in known)
            warns.append(BracketWarning(
                code, f"{label} changed between frames ({desc}); brackets should vary only the "
                "exposure time", tuple(k for k, _ in known),
            ))

    changed("f_number", "aperture-changed", "aperture", lambda v: f"f/{float(v):g}")
    changed("iso", "iso-changed", "ISO", lambda v: f"ISO {v}")
    cams = [f.meta.camera for f in frames]
    known_cams = {c for c in cams if c}
    if len(known_cams) > 1:
        warns.append(BracketWarning(
            "mixed-cameras", "frames come from different cameras: " + ", ".join(sorted(known_cams)),
            tuple(range(n)),
        ))
    # Duplicate exposures: same time (and same aperture and ISO when known).
    seen: dict[tuple, int] = {}
    for k, f in enumerate(frames):
        m = f.meta
        if m.exposure_time is None:
            continue
        key = (m.exposure_time, m.f_number, m.iso)
        if key in seen:
            j = seen[key]
            warns.append(BracketWarning(
                "duplicate-exposure",
                f"{names[j]} and {names[k]} have the same exposure ({float(m.exposure_time):g} s)",
                (j, k),
            ))
        else:
            seen[key] = k
    # Brightness must grow with exposure time; a frame that is darker than a shorter exposure
    # points to wrong EXIF or a mislabelled file.
    if order_source == "exposure_time":
        means = [f.mean_level() for f in frames]
        for k in range(n - 1):
            if times[k] == times[k + 1]:
                continue
            if means[k + 1] < means[k] - 0.01 and means[k] < 0.95:
                warns.append(BracketWarning(
                    "out-of-order",
                    f"{names[k + 1]} ({float(times[k + 1]):g} s) is darker than {names[k]} "
                    f"({float(times[k]):g} s): its exposure time or its file is wrong",
                    (k, k + 1),
                ))
    return warns


def load_bracket(
    paths: Iterable[str | os.PathLike],
    *,
    exposure_times: Mapping[str, Fraction | float] | str | os.PathLike | None = None,
    raw_half_size: bool = False,
) -> Bracket:
    """Load frames into a :class:`Bracket`, darkest first.

    ``paths`` may include directories (their image files are used). ``exposure_times`` is a
    ``name -> seconds`` mapping or the path of a ``name seconds`` text file; its values replace
    EXIF times (a disagreement with EXIF becomes a warning).
    """
    files = expand_paths(paths)
    if len(files) < 2:
        where = files[0] if files else None
        raise BracketError(
            "a bracket needs at least two frames", path=where, found=f"{len(files)} frame(s)"
        )
    seen_paths: dict[str, Path] = {}
    for f in files:
        key = str(f.resolve())
        if key in seen_paths:
            raise BracketError("the same file is given twice", path=f)
        seen_paths[key] = f

    times_map: dict[str, Fraction] | None = None
    if exposure_times is not None:
        if isinstance(exposure_times, Mapping):
            times_map = {
                Path(k).name: (v if isinstance(v, Fraction) else Fraction(str(v)))
                for k, v in exposure_times.items()
            }
        else:
            times_map = read_exposure_times(exposure_times)

    # Two files decoded at a time (LibRaw and Pillow release the GIL while they decode; the
    # first error in file order is the one raised).
    frames = thread_map(lambda p: load_frame(p, raw_half_size=raw_half_size), files)
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
                    warns.append(BracketWarning(
                        "exif-times-mismatch",
                        f"{f.name}: EXIF says {float(exif_t):g} s, the times list says "
                        f"{float(t):g} s; using the list",
                    ))
            updated.append(f.with_exposure_time(t, "times-file"))
        frames = updated

    _check_consistent(frames)

    n = len(frames)
    means = [f.mean_level() for f in frames]
    if all(f.meta.exposure_time is not None for f in frames):
        order = sorted(range(n), key=lambda k: (float(frames[k].meta.exposure_time), means[k]))
        order_source = "exposure_time"
    else:
        order = sorted(range(n), key=lambda k: means[k])
        order_source = "brightness"
    if order != list(range(n)) and order != list(range(n))[::-1]:
        warns.append(BracketWarning(
            "input-unsorted",
            "files were not given in exposure order; they were sorted darkest first",
        ))
    sorted_frames = [frames[k] for k in order]
    # Indices in warnings refer to the sorted order; remap the exif-times warnings (none carry
    # indices) and compute the capture warnings on the sorted frames.
    warns.extend(_capture_warnings(sorted_frames, order_source))
    for k, f in enumerate(sorted_frames):
        step = max(1, int(np.sqrt(f.levels.size / 3 / 262144)))
        sub = f.levels[::step, ::step]
        if float(np.mean(sub >= f.max_level)) > 0.98:
            warns.append(BracketWarning(
                "frame-saturated", f"{f.name} is almost entirely saturated",
                (k,),
            ))
        elif float(np.mean(sub == 0)) > 0.98:
            warns.append(BracketWarning(
                "frame-black", f"{f.name} is almost entirely black",
                (k,),
            ))
    return Bracket(
        frames=tuple(sorted_frames),
        warnings=tuple(warns),
        order_source=order_source,
        input_order=tuple(order),
    )
