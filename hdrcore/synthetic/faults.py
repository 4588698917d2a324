"""Faulty brackets with known truth: the capture mistakes and dark frames of real brackets.

Each ``write_*`` function simulates a bracket with :func:`~hdrcore.synthetic.simulate_bracket`
(the seed's camera model, Cerman & Hlavac 2006, sections 4.2 and 5.3), puts one fault into it,
writes it with :func:`~hdrcore.synthetic.write_bracket` and returns a :class:`FaultyBracket`:
the written paths, the times file to pass with ``--times``, the true exposure times, which
frames are faulty and why, and where each frame and pair has signal. ``truth.json`` in the
directory holds the same facts (key ``"case"`` and those below it).

The faults, as a real camera makes them:

* a **black** frame (lens cap, a flash that did not fire, a far too short time) records no light:
  the read noise around the black level only. 8-bit PNG/JPEG frames are
  ``clip(round(n), 0, 255)`` with ``n ~ N(0, sigma)`` (about half the pixels 0); DNG frames hold
  ``black + n`` raw numbers at 12 or 14 bits (values below black occur, as on sensors).
* an **all-saturated** frame: every pixel at the clipping level, the noise on top clipped
  (``clip(round(max + n))``).
* a **duplicate exposure**: the same time shot twice (independent noise and, hand-held, motion).
* **swapped times**: a times file in which two frames' times are exchanged (the lines keep their
  order; only the mapping of name to time changes, which is what a wrong file does).
* a **tripod bracket whose darkest pairs carry too little signal to register**, a bracket with
  **one usable frame**, and **dark scenes** where the shortest frames are black only because the
  scene is dark (the seed's protocol with a low key).
* the issue's **dark RAW** brackets: a 12-bit DNG bracket 2 stops apart whose darkest frame peaks
  at about 1.5 % of the range, and a 14-bit pair 6 stops apart.

Signal: a sample (pixel and channel) has signal in a frame when its noiseless level is at least
:data:`SIGNAL_SIGMAS` noise sigmas above black and as far below the largest level (levels of the
file's frame: output levels for PNG/JPEG, raw numbers above black for DNG). A pair's common
signal counts samples with signal in both frames at the same pixel index (hand-held frames are
then off by their motion: an estimate).

Reference: J. Cerman, V. Hlavac, "Exposure time estimation for high dynamic range imaging with
hand held camera", Computer Vision Winter Workshop, 2006.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ParameterError
from ..io.atomic import atomic_write, check_output_path
from .camera import SimulatedBracket, apply_response, simulate_bracket
from .dng import as_rational, default_black_level
from .writer import FORMATS, WrittenBracket, write_bracket

__all__ = [
    "DARK_RAW_12BIT",
    "SEED_PROTOCOL",
    "SEED_TIMES",
    "SIGNAL_SIGMAS",
    "WIDE_RAW_14BIT",
    "BracketSpec",
    "Fault",
    "FaultyBracket",
    "write_black_frames",
    "write_dark_raw_bracket",
    "write_dark_scene",
    "write_duplicate_exposure",
    "write_one_usable_frame",
    "write_reference_bracket",
    "write_saturated_frame",
    "write_swapped_times",
    "write_unregistrable_tripod",
    "write_wide_raw_pair",
]

SEED_TIMES: tuple[float, ...] = (1.0, 4.0, 16.0, 64.0, 256.0, 1024.0)
"""The seed's protocol (section 5.3): six frames, 2 stops (x4) apart, times 1..1024."""

SIGNAL_SIGMAS = 5.0
"""A sample has signal when its noiseless level is this many noise sigmas inside the range."""


@dataclass(frozen=True)
class BracketSpec:
    """What to simulate and how to write it; the defaults are the seed's protocol.

    ``exposure_times`` in seconds (any order, written as exact fractions); ``bits`` the frames'
    bit depth (8-bit PNG, deeper frames as scaled 16-bit PNG; ``fmt="dng"`` for RAW with
    ``noise_sigma`` in raw numbers); ``max_shift`` / ``max_rotation_deg`` hand-held motion
    (0: tripod); ``key`` the exposure scale (``None``: the simulator's default, median radiance
    at 0.18 for the geometric-mean time; the dark cases compute their own); ``margins`` masked
    optical-black margins for DNG (see :func:`~hdrcore.synthetic.write_bracket`).
    """

    scene: str = "window"
    shape: tuple[int, int] = (256, 384)
    exposure_times: tuple[float, ...] = SEED_TIMES
    bits: int = 8
    noise_sigma: float = 1.0
    response: str = "linear"
    fmt: str = "png"
    max_shift: float = 0.0
    max_rotation_deg: float = 0.0
    key: float | None = None
    seed: int = 0
    margins: int | tuple[int, int, int, int] | None = None
    masked_areas: bool = True

    def replace(self, **changes: Any) -> BracketSpec:
        return replace(self, **changes)

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["shape"] = list(self.shape)
        d["exposure_times"] = list(self.exposure_times)
        return d


SEED_PROTOCOL = BracketSpec()
"""Six frames, times 1..1024 (x4), linear, 8 bits, noise sigma 1 level, 256x384, tripod."""

DARK_RAW_12BIT = BracketSpec(
    scene="patches",
    exposure_times=(1 / 1024, 1 / 256, 1 / 64, 1 / 16, 1 / 4),
    bits=12,
    noise_sigma=2.0,
    fmt="dng",
)
"""Five 12-bit DNG frames 2 stops apart (a camera's 2 EV auto-bracket), read noise 2 DN, of the
``patches`` scene (its brightest patches, not a point light, set the darkest frame's peak)."""

WIDE_RAW_14BIT = BracketSpec(
    scene="patches",
    exposure_times=(1 / 1024, 1 / 16),
    bits=14,
    noise_sigma=2.0,
    fmt="dng",
)
"""Two 14-bit DNG frames 6 stops apart, read noise 2 DN, the simulator's default key."""


@dataclass(frozen=True)
class Fault:
    """What is wrong with frame ``index`` (file order) and whether it still carries signal."""

    index: int
    kind: str  # "black", "saturated", "duplicate", "swapped-time"
    reason: str
    usable: bool

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True, eq=False)
class FaultyBracket:
    """A written faulty bracket and its truth (indices are file order, ``frames[k]``).

    ``exposure_times`` are the true times (what the shutter did; a black or saturated frame
    keeps its nominal time), ``exif_times`` what each file's EXIF says, ``listed_times`` what
    ``times_file`` says (the same unless the case is about the times). ``signal_fraction[k]`` is
    the fraction of frame ``k``'s samples with signal (module docstring). ``sim`` holds the
    radiance truth (``sim.radiance``, in the reference frame's coordinates, in units where a
    frame of time ``t`` records ``radiance * t * sim.key``).
    """

    case: str
    description: str
    directory: Path
    frames: tuple[Path, ...]
    times_file: Path
    truth_file: Path
    exposure_times: tuple[float, ...]
    exif_times: tuple[float, ...]
    listed_times: tuple[float, ...]
    faults: tuple[Fault, ...]
    signal_fraction: tuple[float, ...]
    spec: BracketSpec
    sim: SimulatedBracket = field(repr=False)
    written: WrittenBracket = field(repr=False)
    _signal: tuple[np.ndarray, ...] = field(default=(), repr=False)

    @property
    def usable_frames(self) -> tuple[int, ...]:
        """Frames with no unusable fault and some signal."""
        bad = {f.index for f in self.faults if not f.usable}
        return tuple(
            k for k in range(len(self.frames)) if k not in bad and self.signal_fraction[k] > 0
        )

    @property
    def relative_exposures(self) -> tuple[float, ...]:
        """True exposures relative to the shortest one."""
        t0 = min(self.exposure_times)
        return tuple(t / t0 for t in self.exposure_times)

    def index_of(self, path: str | os.PathLike) -> int:
        """File-order index of a frame given by path or file name."""
        name = Path(path).name
        for k, p in enumerate(self.frames):
            if p.name == name:
                return k
        raise ParameterError("not a frame of this bracket", found=str(path))

    def true_ratio(self, dark: int, bright: int) -> float:
        """True exposure ratio ``t[bright] / t[dark]`` of two frames (file order)."""
        return self.exposure_times[bright] / self.exposure_times[dark]

    def common_signal_fraction(self, i: int, j: int) -> float:
        """Fraction of samples with signal in both frames ``i`` and ``j``."""
        return float(np.mean(self._signal[i] & self._signal[j]))

    def exposure_order(self) -> tuple[int, ...]:
        """File indices sorted by true exposure (stable for equal times)."""
        return tuple(sorted(range(len(self.frames)), key=lambda k: self.exposure_times[k]))

    def pairs_with_signal(self, min_fraction: float = 0.01) -> tuple[tuple[int, int], ...]:
        """Consecutive pairs (by true exposure) with signal in both frames in at least
        ``min_fraction`` of the samples: the pairs a robust pipeline must measure."""
        order = self.exposure_order()
        return tuple(
            (a, b)
            for a, b in zip(order, order[1:], strict=False)
            if self.common_signal_fraction(a, b) >= min_fraction
        )

    def truth(self) -> dict[str, Any]:
        """The ``"case"`` part of ``truth.json``."""
        order = self.exposure_order()
        return {
            "case": self.case,
            "description": self.description,
            "spec": self.spec.to_json(),
            "true_exposure_times": list(self.exposure_times),
            "exif_exposure_times": list(self.exif_times),
            "times_file": self.times_file.name,
            "times_file_exposure_times": list(self.listed_times),
            "faults": [f.to_json() for f in self.faults],
            "usable_frames": list(self.usable_frames),
            "signal": {
                "definition": f"noiseless level >= {SIGNAL_SIGMAS:g} sigma above black and "
                f"<= {SIGNAL_SIGMAS:g} sigma below the largest level",
                "frames": list(self.signal_fraction),
                "pairs": [
                    {
                        "dark": a,
                        "bright": b,
                        "ratio": self.true_ratio(a, b),
                        "common_signal_fraction": self.common_signal_fraction(a, b),
                    }
                    for a, b in zip(order, order[1:], strict=False)
                ],
            },
        }


# --------------------------------------------------------------------------------------------
# Shared steps


def _simulate(
    spec: BracketSpec,
    *,
    times: Sequence[float] | None = None,
    key: float | None = None,
    noise: bool = True,
) -> SimulatedBracket:
    if spec.fmt not in FORMATS and spec.fmt not in ("jpg", "tif"):
        raise ParameterError(
            f"unknown output format {spec.fmt!r}",
            expected=f"one of {', '.join(FORMATS)}",
            found=repr(spec.fmt),
        )
    return simulate_bracket(
        scene=spec.scene,
        shape=spec.shape,
        exposure_times=tuple(spec.exposure_times if times is None else times),
        bits=spec.bits,
        response=spec.response,
        noise_sigma=spec.noise_sigma if noise else 0.0,
        max_shift=spec.max_shift,
        max_rotation_deg=spec.max_rotation_deg,
        key=spec.key if key is None else key,
        seed=spec.seed,
        keep_linear=True,
    )


def _scene_radiance(spec: BracketSpec) -> np.ndarray:
    """The radiance the bracket of ``spec`` sees (same scene, size and motion margin)."""
    return _simulate(spec, key=1.0, noise=False).radiance


def _level_scale(spec: BracketSpec) -> float:
    """Levels of the file's frame per unit of linear value ``x`` (1.0 = saturation)."""
    if spec.fmt == "dng":
        return float((1 << spec.bits) - 1 - default_black_level(spec.bits))
    return float((1 << spec.bits) - 1)


def _linear_for_level(spec: BracketSpec, level: float) -> float:
    """The linear value ``x`` whose noiseless level in the file is ``level``."""
    y = float(level) / _level_scale(spec)
    if spec.fmt == "dng" or spec.response == "linear":
        return y
    grid = np.linspace(0.0, 1.0, 65537)
    return float(np.interp(y, apply_response(spec.response, grid), grid))


def _signal_masks(sim: SimulatedBracket, spec: BracketSpec) -> tuple[np.ndarray, ...]:
    scale = _level_scale(spec)
    lo = SIGNAL_SIGMAS * spec.noise_sigma
    hi = scale - SIGNAL_SIGMAS * spec.noise_sigma
    out = []
    for x in sim.linear_frames:
        if spec.fmt == "dng":
            level = x.astype(np.float64) * scale
        else:
            level = apply_response(sim.response, x.astype(np.float64)) * scale
        out.append((level >= lo) & (level <= hi) & (x < 1.0))
    return tuple(out)


def _constant_frame(
    sim: SimulatedBracket, x: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """(levels, linear) of a frame whose every sample records linear value ``x`` (0: no light,
    1: saturated), with the simulator's noise and quantisation."""
    shape = sim.frames[0].shape
    y = float(apply_response(sim.response, np.array([x]))[0]) * sim.max_level
    levels = (
        y + rng.standard_normal(shape) * sim.noise_sigma
        if sim.noise_sigma > 0
        else np.full(shape, y)
    )
    return (
        np.clip(np.rint(levels), 0, sim.max_level).astype(np.uint16),
        np.full(shape, float(x), np.float32),
    )


def _with_frames(sim: SimulatedBracket, replaced: dict[int, float], seed: int) -> SimulatedBracket:
    frames, linear = list(sim.frames), list(sim.linear_frames)
    for k, x in sorted(replaced.items()):
        rng = np.random.default_rng([seed, 15485863, k])
        frames[k], linear[k] = _constant_frame(sim, x, rng)
    return replace(sim, frames=tuple(frames), linear_frames=tuple(linear))


def _positions(positions: int | Sequence[int], n: int, what: str) -> tuple[int, ...]:
    vals: tuple[int, ...] = (
        (positions,) if isinstance(positions, (int, np.integer)) else tuple(positions)
    )
    out = []
    for p in vals:
        k = int(p)
        k = k + n if k < 0 else k
        if not 0 <= k < n:
            raise ParameterError(
                f"{what} out of range",
                expected=f"0..{n - 1} (or negative from the end)",
                found=str(p),
            )
        out.append(k)
    if len(set(out)) != len(out):
        raise ParameterError(f"{what} repeats a frame", found=str(vals))
    return tuple(sorted(out))


def _times_text(names: Sequence[str], times: Sequence[Fraction], note: str) -> str:
    lines = [f"# name seconds ({note})"]
    lines += [f"{name} {t}  # {float(t):.9g}" for name, t in zip(names, times, strict=True)]
    return "\n".join(lines) + "\n"


def _finish(
    outdir: str | os.PathLike,
    spec: BracketSpec,
    sim: SimulatedBracket,
    *,
    case: str,
    description: str,
    faults: Sequence[Fault] = (),
    force: bool = False,
    exif_sim: SimulatedBracket | None = None,
    listed: Sequence[float] | None = None,
    times_name: str | None = None,
) -> FaultyBracket:
    """Write ``sim`` (EXIF times from ``exif_sim`` when given), the times file and the truth."""
    out = Path(outdir)
    extra = out / times_name if times_name else None
    if extra is not None and out.is_dir():
        check_output_path(extra, force=force)
    written = write_bracket(
        out,
        exif_sim if exif_sim is not None else sim,
        spec.fmt,
        force=force,
        margins=spec.margins,
        masked_areas=spec.masked_areas,
    )
    times_file = written.times_file
    listed_times = tuple(float(t) for t in written.exposure_times)
    if extra is not None and listed is not None:
        exact = [as_rational(t, what="exposure time") for t in listed]
        text = _times_text(
            [p.name for p in written.frames],
            exact,
            f"faulty on purpose: case {case}; the truth is in truth.json",
        )
        atomic_write(extra, lambda tmp: tmp.write_text(text, encoding="utf-8"), force=True)
        times_file, listed_times = extra, tuple(float(t) for t in exact)
    if exif_sim is not None:  # exposure_times.txt holds the true times, whatever EXIF says
        true = [as_rational(t, what="exposure time") for t in sim.exposure_times]
        text = _times_text(
            [p.name for p in written.frames],
            true,
            "true times; the EXIF times of this case are wrong on purpose",
        )
        atomic_write(
            written.times_file, lambda tmp: tmp.write_text(text, encoding="utf-8"), force=True
        )
    masks = _signal_masks(sim, spec)
    result = FaultyBracket(
        case=case,
        description=description,
        directory=written.directory,
        frames=written.frames,
        times_file=times_file,
        truth_file=written.truth,
        exposure_times=tuple(float(t) for t in sim.exposure_times),
        exif_times=tuple(float(t) for t in written.exposure_times),
        listed_times=listed_times,
        faults=tuple(faults),
        signal_fraction=tuple(float(m.mean()) for m in masks),
        spec=spec,
        sim=sim,
        written=written,
        _signal=masks,
    )
    truth = json.loads(written.truth.read_text(encoding="utf-8"))
    sim_truth = sim.truth()
    for key in ("exposure_times", "ratios", "pairs", "key"):
        truth[key] = sim_truth[key]
    for k, f in enumerate(truth.get("frames", [])):
        f["true_exposure_time"] = result.exposure_times[k]
    truth["case"] = result.truth()
    text = json.dumps(truth, indent=2) + "\n"
    atomic_write(written.truth, lambda tmp: tmp.write_text(text, encoding="utf-8"), force=True)
    return result


# --------------------------------------------------------------------------------------------
# The cases


def write_reference_bracket(
    outdir: str | os.PathLike,
    spec: BracketSpec = SEED_PROTOCOL,
    *,
    force: bool = False,
) -> FaultyBracket:
    """The bracket of ``spec`` without a fault, with the same truth as the faulty cases (the
    baseline every case is compared with)."""
    sim = _simulate(spec)
    return _finish(outdir, spec, sim, case="reference", force=force, description="no fault")


def write_black_frames(
    outdir: str | os.PathLike,
    positions: int | Sequence[int] = (0,),
    spec: BracketSpec = SEED_PROTOCOL,
    *,
    force: bool = False,
) -> FaultyBracket:
    """The bracket of ``spec`` with the frames at ``positions`` (file order, negative from the
    end) black: no light, only the read noise around the black level (module docstring).

    Their EXIF keeps the nominal time. Works for every format (PNG/JPEG 8-bit: noise around 0;
    DNG 12/14 bits: ``black + N(0, noise_sigma)`` raw numbers).
    """
    sim = _simulate(spec)
    ks = _positions(positions, len(sim.frames), "black frame position")
    sim = _with_frames(sim, {k: 0.0 for k in ks}, spec.seed)
    faults = [
        Fault(
            k,
            "black",
            "no light reached the sensor: read noise around the black level only",
            usable=False,
        )
        for k in ks
    ]
    where = ", ".join(str(k) for k in ks)
    return _finish(
        outdir,
        spec,
        sim,
        case="black-frames",
        faults=faults,
        force=force,
        description=f"frame(s) {where} black (noise around the black level)",
    )


def write_saturated_frame(
    outdir: str | os.PathLike,
    position: int = -1,
    spec: BracketSpec = SEED_PROTOCOL,
    *,
    force: bool = False,
) -> FaultyBracket:
    """The bracket of ``spec`` with frame ``position`` (default the longest) all saturated: every
    sample at the clipping level with the noise on top clipped; EXIF keeps the nominal time."""
    sim = _simulate(spec)
    (k,) = _positions(position, len(sim.frames), "saturated frame position")
    sim = _with_frames(sim, {k: 1.0}, spec.seed)
    fault = Fault(k, "saturated", "every sample at the clipping level", usable=False)
    return _finish(
        outdir,
        spec,
        sim,
        case="saturated-frame",
        faults=[fault],
        force=force,
        description=f"frame {k} all saturated",
    )


def write_duplicate_exposure(
    outdir: str | os.PathLike,
    position: int = 2,
    spec: BracketSpec = SEED_PROTOCOL,
    *,
    force: bool = False,
) -> FaultyBracket:
    """The bracket of ``spec`` with frame ``position`` shot twice: one more frame, right after it,
    with the same exposure time and independent noise (and, hand-held, its own motion).

    Both frames are usable: the pair is a valid pair of ratio 1.
    """
    times = list(spec.exposure_times)
    (k,) = _positions(position, len(times), "duplicated frame position")
    times.insert(k + 1, times[k])
    spec2 = spec.replace(exposure_times=tuple(times))
    sim = _simulate(spec2)
    fault = Fault(k + 1, "duplicate", f"same exposure time as frame {k} (shot twice)", usable=True)
    return _finish(
        outdir,
        spec2,
        sim,
        case="duplicate-exposure",
        faults=[fault],
        force=force,
        description=f"frames {k} and {k + 1} share one exposure time",
    )


def write_swapped_times(
    outdir: str | os.PathLike,
    swap: tuple[int, int] = (1, 2),
    spec: BracketSpec = SEED_PROTOCOL,
    *,
    in_exif: bool = False,
    force: bool = False,
) -> FaultyBracket:
    """The bracket of ``spec`` with a times file ``exposure_times_swapped.txt`` in which frames
    ``swap`` have each other's time (lines in file order; only the name-to-time mapping is
    wrong). ``exposure_times.txt`` keeps the true times. With ``in_exif`` the two files' EXIF
    times are swapped too (a camera or tool that wrote them wrong).
    """
    if len(tuple(swap)) != 2:
        raise ParameterError("swap names two frames", expected="(i, j)", found=str(swap))
    sim = _simulate(spec)
    i, j = _positions(swap, len(sim.frames), "swapped frame")
    listed = list(sim.exposure_times)
    listed[i], listed[j] = listed[j], listed[i]
    exif_sim = replace(sim, exposure_times=tuple(listed)) if in_exif else None
    faults = [
        Fault(i, "swapped-time", f"times file gives frame {j}'s time", usable=True),
        Fault(j, "swapped-time", f"times file gives frame {i}'s time", usable=True),
    ]
    return _finish(
        outdir,
        spec,
        sim,
        case="swapped-times",
        faults=faults,
        force=force,
        exif_sim=exif_sim,
        listed=listed,
        times_name="exposure_times_swapped.txt",
        description=f"times of frames {i} and {j} swapped in the times file"
        + (" and in EXIF" if in_exif else ""),
    )


def write_unregistrable_tripod(
    outdir: str | os.PathLike,
    spec: BracketSpec = SEED_PROTOCOL,
    *,
    darkest_signal: float = 0.002,
    force: bool = False,
) -> FaultyBracket:
    """A tripod bracket (no motion) of ``spec`` whose darkest frame has signal in only
    ``darkest_signal`` of its samples (a few highlights), so its pairs carry too little
    structure to register; the key is set for that. The true motion is the identity everywhere.
    """
    if not 0 < darkest_signal < 1:
        raise ParameterError(
            "darkest_signal is a fraction of the samples",
            expected="0 < f < 1",
            found=str(darkest_signal),
        )
    spec = spec.replace(max_shift=0.0, max_rotation_deg=0.0)
    radiance = _scene_radiance(spec)
    t0 = min(spec.exposure_times)
    e_q = float(np.quantile(radiance, 1.0 - darkest_signal))
    x_lo = _linear_for_level(spec, SIGNAL_SIGMAS * spec.noise_sigma)
    spec = spec.replace(key=x_lo / (e_q * t0))
    sim = _simulate(spec)
    return _finish(
        outdir,
        spec,
        sim,
        case="unregistrable-tripod",
        force=force,
        description=f"tripod; the darkest frame has signal in "
        f"{100 * darkest_signal:g} % of its samples",
    )


def write_one_usable_frame(
    outdir: str | os.PathLike,
    usable: int = 1,
    spec: BracketSpec | None = None,
    *,
    force: bool = False,
) -> FaultyBracket:
    """A bracket (default: the seed's protocol cut to three frames, times 1, 4, 16) with one
    usable frame, ``usable``: every shorter frame is black, every longer one all saturated."""
    spec = SEED_PROTOCOL.replace(exposure_times=SEED_TIMES[:3]) if spec is None else spec
    sim = _simulate(spec)
    n = len(sim.frames)
    (u,) = _positions(usable, n, "usable frame")
    order = sorted(range(n), key=lambda k: sim.exposure_times[k])
    rank = order.index(u)
    repl = {k: (0.0 if order.index(k) < rank else 1.0) for k in range(n) if k != u}
    sim = _with_frames(sim, repl, spec.seed)
    faults = [
        Fault(
            k,
            "black" if x == 0.0 else "saturated",
            "no light reached the sensor" if x == 0.0 else "every sample saturated",
            usable=False,
        )
        for k, x in sorted(repl.items())
    ]
    return _finish(
        outdir,
        spec,
        sim,
        case="one-usable-frame",
        faults=faults,
        force=force,
        description=f"only frame {u} usable",
    )


def write_dark_scene(
    outdir: str | os.PathLike,
    n_black: int = 1,
    spec: BracketSpec = SEED_PROTOCOL,
    *,
    black_peak_sigma: float = 1.0,
    force: bool = False,
) -> FaultyBracket:
    """The bracket of ``spec`` of a scene dark enough that its ``n_black`` shortest frames are
    black: the key puts the brightest sample of the ``n_black``-th shortest frame at
    ``black_peak_sigma`` noise sigmas (noiseless), so those frames record noise only; the next
    frame (x4 in the seed's protocol) peaks at 4x that. Nothing is replaced: the frames are
    black because the scene is dark.
    """
    n = len(spec.exposure_times)
    if not 1 <= int(n_black) < n:
        raise ParameterError(
            "n_black frames must leave at least one", expected=f"1..{n - 1}", found=str(n_black)
        )
    if not 0 < black_peak_sigma < SIGNAL_SIGMAS:
        raise ParameterError(
            "black_peak_sigma must be positive and below the signal threshold",
            expected=f"0 < s < {SIGNAL_SIGMAS:g}",
            found=str(black_peak_sigma),
        )
    radiance = _scene_radiance(spec)
    t_last = sorted(spec.exposure_times)[int(n_black) - 1]
    x_peak = _linear_for_level(spec, black_peak_sigma * spec.noise_sigma)
    spec = spec.replace(key=x_peak / (float(radiance.max()) * t_last))
    sim = _simulate(spec)
    order = sorted(range(n), key=lambda k: sim.exposure_times[k])
    faults = [
        Fault(
            k,
            "black",
            f"the scene is too dark for this time: its brightest sample "
            f"is {black_peak_sigma * sim.exposure_times[k] / t_last:.3g} sigma (noiseless)",
            usable=False,
        )
        for k in order[: int(n_black)]
    ]
    return _finish(
        outdir,
        spec,
        sim,
        case=f"dark-scene-{int(n_black)}",
        faults=faults,
        force=force,
        description=f"dark scene: the {int(n_black)} shortest frame(s) black",
    )


def _raw_bracket(
    outdir: str | os.PathLike, spec: BracketSpec, darkest_peak: float | None, case: str, force: bool
) -> FaultyBracket:
    if spec.fmt != "dng":
        raise ParameterError(
            "a RAW case writes DNG", expected="spec.fmt 'dng'", found=repr(spec.fmt)
        )
    if darkest_peak is not None:
        if not 0 < darkest_peak < 1:
            raise ParameterError(
                "darkest_peak is a fraction of the range",
                expected="0 < p < 1",
                found=str(darkest_peak),
            )
        radiance = _scene_radiance(spec)
        peak_dn = darkest_peak * ((1 << spec.bits) - 1)  # above black, of the full range
        x_peak = _linear_for_level(spec, peak_dn)
        spec = spec.replace(key=x_peak / (float(radiance.max()) * min(spec.exposure_times)))
    sim = _simulate(spec)
    stops = np.log2(np.max(spec.exposure_times) / np.min(spec.exposure_times))
    dark = int(np.argmin(sim.exposure_times))
    peak = float(sim.linear_frames[dark].max()) * _level_scale(spec)
    desc = (
        f"{len(sim.frames)} {spec.bits}-bit DNG frames over {stops:g} stops; the darkest "
        f"peaks at {peak:.0f} of {(1 << spec.bits) - 1} levels above black "
        f"({100 * peak / ((1 << spec.bits) - 1):.2f} %), read noise {spec.noise_sigma:g} DN"
    )
    return _finish(outdir, spec, sim, case=case, force=force, description=desc)


def write_dark_raw_bracket(
    outdir: str | os.PathLike,
    spec: BracketSpec = DARK_RAW_12BIT,
    *,
    darkest_peak: float = 0.015,
    force: bool = False,
) -> FaultyBracket:
    """The issue's dark RAW case: a DNG bracket (default :data:`DARK_RAW_12BIT`, 12 bits, 2 stops
    apart) whose darkest frame peaks (noiseless brightest sample) at ``darkest_peak`` of the
    full range above black (0.015: about 61 of 4095 levels). A normal darkest frame of a RAW
    bracket; none of its samples is faulty."""
    return _raw_bracket(outdir, spec, darkest_peak, "dark-raw", force)


def write_wide_raw_pair(
    outdir: str | os.PathLike,
    spec: BracketSpec = WIDE_RAW_14BIT,
    *,
    darkest_peak: float | None = None,
    force: bool = False,
) -> FaultyBracket:
    """The issue's 14-bit pair 6 stops apart (:data:`WIDE_RAW_14BIT`), at the simulator's default
    key (median radiance at 0.18 for the geometric-mean time: the dark frame's median sits near
    2 % of the range, the bright one mostly saturated) unless ``darkest_peak`` sets the darker
    frame's peak as in :func:`write_dark_raw_bracket`."""
    return _raw_bracket(outdir, spec, darkest_peak, "wide-raw-pair", force)
