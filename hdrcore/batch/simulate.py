"""Simulated shooting sessions for testing the grouping and the batch: tiny JPEG files whose
EXIF says what a camera would (exposure time, ISO, f-number, exposure bias, capture time with
or without subseconds, make and model), with the true grouping known.

A session is a timeline of brackets (3/5/7/9 frames, darker-first, brighter-first or
centre-out ``0, -, +``), single shots at the metered exposure and bursts of equal exposures,
separated by pauses drawn from ``gap_range`` (0.2-5 s by default), frames of a bracket a
camera's frame interval apart (0.05-0.25 s after the end of the previous exposure). The
pixels come from :func:`hdrcore.synthetic.simulate_bracket` (the seed's camera model, sRGB
response) of one scene, so a bracket merges; ``same_scene`` keeps one scene for the whole
session (a tripod timelapse: thumbnails cannot tell brackets apart).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from datetime import datetime, timedelta
from fractions import Fraction
from pathlib import Path

import numpy as np

__all__ = [
    "SimShot",
    "bracket_offsets",
    "simulate_session",
    "write_session",
    "true_groups",
    "ORDERS",
]

ORDERS = ("darker", "brighter", "centre-out")
_START = datetime(2026, 6, 1, 18, 0, 0)
#: Metered exposure of the session: 1/64 s at ISO 100, f/8.
BASE_TIME = Fraction(1, 64)


@dataclass(frozen=True)
class SimShot:
    """One simulated file: its exposure, capture time and the group it truly belongs to
    (``group`` is shared by the frames of one bracket; a single shot has its own)."""

    name: str
    stops: float
    time: float
    group: int
    kind: str
    exposure_time: Fraction
    bias: Fraction

    @property
    def datetime(self) -> datetime:
        return _START + timedelta(seconds=self.time)


def bracket_offsets(n: int, order: str, step: int = 1) -> list[int]:
    """Stops from the metered exposure, in capture order: ``darker`` ``[+k .. -k]`` (bright
    first, getting darker), ``brighter`` ``[-k .. +k]``, ``centre-out`` ``[0, -1, +1, ...]``."""
    k = (n - 1) // 2
    up = [step * i for i in range(-k, n - k)]
    if order == "brighter":
        return up
    if order == "darker":
        return up[::-1]
    out = [0]
    for i in range(1, n):
        out.append(-step * ((i + 1) // 2) if i % 2 else step * (i // 2))
    return out


def simulate_session(
    seed: int,
    *,
    n_brackets: int = 12,
    sizes: tuple[int, ...] = (3, 5, 7, 9),
    orders: tuple[str, ...] = ORDERS,
    singles: float = 0.3,
    bursts: float = 0.15,
    gap_range: tuple[float, float] = (0.2, 5.0),
    step: int = 1,
    prefix: str = "IMG_",
) -> list[SimShot]:
    """A timeline of ``n_brackets`` brackets with single shots and bursts between them."""
    rng = np.random.default_rng(seed)
    shots: list[SimShot] = []
    t = 0.0
    group = 0
    number = 1

    def add(stops_list: list[int], kind: str) -> None:
        nonlocal t, group, number
        for i, s in enumerate(stops_list):
            if i:
                t += float(rng.uniform(0.05, 0.25))
            et = BASE_TIME * Fraction(2) ** s
            shots.append(
                SimShot(
                    f"{prefix}{number:04d}.jpg",
                    float(s),
                    t,
                    group if kind == "bracket" else group + i,
                    kind,
                    et,
                    Fraction(s),
                )
            )
            number += 1
            t += float(et)
        group += 1 if kind == "bracket" else len(stops_list)
        t += float(rng.uniform(*gap_range))

    for _ in range(n_brackets):
        r = float(rng.uniform())
        if r < singles:
            add([0], "single")
        elif r < singles + bursts:
            add([0] * int(rng.integers(2, 5)), "burst")
        n = int(rng.choice(sizes))
        add(bracket_offsets(n, str(rng.choice(orders)), step), "bracket")
    return shots


def _exif(shot: SimShot, subsec: bool, camera: tuple[str, str]) -> bytes:
    from PIL import Image
    from PIL.TiffImagePlugin import IFDRational

    exif = Image.Exif()
    exif[0x010F], exif[0x0110] = camera
    when = shot.datetime
    exif[0x0132] = when.strftime("%Y:%m:%d %H:%M:%S")
    ifd = exif.get_ifd(0x8769)
    et = shot.exposure_time
    ifd[0x829A] = IFDRational(et.numerator, et.denominator)
    ifd[0x829D] = IFDRational(8, 1)
    ifd[0x8827] = 100
    ifd[0x9003] = when.strftime("%Y:%m:%d %H:%M:%S")
    ifd[0x9204] = IFDRational(shot.bias.numerator, shot.bias.denominator)
    if subsec:
        ifd[0x9291] = f"{when.microsecond // 1000:03d}"
    return exif.tobytes()


def write_session(
    folder: str | os.PathLike,
    shots: list[SimShot],
    *,
    seed: int = 0,
    shape: tuple[int, int] = (48, 64),
    same_scene: bool = True,
    subsec: bool = True,
    camera: tuple[str, str] = ("SimCam", "S1"),
    scene: str = "window",
) -> list[Path]:
    """Write each shot as a small JPEG with its EXIF; returns the paths (in ``shots`` order)."""
    from PIL import Image

    from ..synthetic import simulate_bracket
    from ..synthetic.scenes import make_scene

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    scenes: dict[int, np.ndarray] = {}
    paths = []
    for s in shots:
        key = 0 if same_scene else s.group
        if key not in scenes:
            scenes[key] = make_scene(scene, shape, seed=seed + key)
        sim = simulate_bracket(
            scenes[key],
            exposure_times=(float(s.exposure_time),),
            response="srgb",
            bits=8,
            noise_sigma=0.5,
            key=0.18 / float(BASE_TIME) / float(np.median(scenes[key])),
            seed=seed + int(1000 * s.time) % 100000,
        )
        img = np.clip(sim.frames[0], 0, 255).astype(np.uint8)
        p = out / s.name
        Image.fromarray(img).save(p, "JPEG", quality=95, exif=_exif(s, subsec, camera))
        paths.append(p)
    return paths


def true_groups(shots: list[SimShot], folder: str | os.PathLike) -> list[frozenset[str]]:
    """The true brackets as sets of absolute paths (single shots and bursts excluded)."""
    by: dict[int, list[str]] = {}
    for s in shots:
        if s.kind == "bracket":
            by.setdefault(s.group, []).append(str((Path(folder) / s.name).absolute()))
    return [frozenset(v) for v in by.values()]
