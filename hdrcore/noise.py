"""Noise of a bracket's frames, measured from the frames: the noise floor of eq. 4 and eq. 6.

The seed paper leaves the noise floor as a parameter. A fixed fraction of the range (the
project's old default, 2 %: 82 levels at 12 bits, 328 at 14 bits) caps every frame at about
5.6 stops of usable range whatever the sensor, and throws away the highlights a RAW bracket's
darkest frame exists for. Here the floor is ``K_SIGMA`` standard deviations of the frames' own
signal-independent noise, never below a small minimum:

* RAW: the read noise of the masked optical-black pixels when the file has them
  (:attr:`hdrcore.io.FrameMetadata.read_noise`, measured by the RAW reader), otherwise a robust
  estimate from the darkest flat regions of the CFA mosaic (second differences along rows of one
  colour plane, which cancel smooth scene gradients: ``var(d2) = 6 sigma^2``).
* 8-bit / 16-bit non-linear frames (JPEG, PNG, TIFF): the same estimate on the green levels of
  the darkest frame, plus quantisation; compression flattens the shadows of JPEGs, so the estimate
  alone is near zero and the floor never goes below :data:`NONLINEAR_MIN_FLOOR_FRACTION` of the
  range (see its note for the measurements on real brackets behind it).

``K_SIGMA = 3``: a pixel of a truly black frame exceeds the floor with probability 0.13 % (one
sided Gaussian tail), so black-frame noise hardly enters the histogram equations, while a RAW
frame keeps ``log2(white / (3 sigma))`` stops: 10.4 stops for 12 bits at sigma = 1 level instead
of 5.6.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "K_SIGMA",
    "RAW_MIN_FLOOR",
    "NONLINEAR_MIN_FLOOR_FRACTION",
    "FrameNoise",
    "BracketNoise",
    "robust_sigma",
    "frame_noise",
    "bracket_noise",
]

#: Noise floor = K_SIGMA x the measured signal-independent noise (levels).
K_SIGMA = 3.0
#: Smallest floor for RAW frames, levels (two quantisation steps).
RAW_MIN_FLOOR = 2.0
#: Smallest floor for 8-bit non-linear (JPEG/PNG/TIFF) frames as a fraction of the largest
#: level: 2 % (5.1 levels). Deeper non-linear files keep :data:`RAW_MIN_FLOOR` (no real 16-bit
#: bracket in ../shared/data: that rule is checked on simulated 12-bit data in 16-bit PNGs only).
#: The noise measured in JPEG shadows is tiny (sigma 0.19-0.45
#: levels in the darkest frames of the two phone brackets of ../shared/data: compression
#: flattens them), so 3 sigma would put the floor at about one level; measured on the real
#: brackets (``python bench/bench_noise.py``), a low floor hurts: Pixel 7 (dark room, ISO 1599,
#: hand-held), median ratio error against its exact EXIF times 1.33 % with a floor of 3 levels,
#: 1.02 % at 5, 1.66 % at 8; the memorial scans (a film-base pedestal at level 16), median error
#: 2.05 % and ghost pixels 43 % with the floor 2.55 levels above the pedestal, 1.45 % and 5.0 %
#: at 5.1 above it (3.0 % at 8); frobisher (Canon JPEG, tripod): 0.58 % at 3 levels, 0.52 % at
#: 5, 0.54 % at 8.
NONLINEAR_MIN_FLOOR_FRACTION = 0.02
#: Samples (second differences) taken from the darkest part of a frame.
_DARK_FRACTION = 0.10
_MIN_SAMPLES = 2000
_MAX_SAMPLES = 1_000_000


@dataclass(frozen=True)
class FrameNoise:
    """Signal-independent noise of one frame, in the frame's levels.

    ``source``: ``"optical-black"`` (masked pixels of the RAW file), ``"dark-regions"`` (second
    differences in the darkest flat regions), or ``"none"`` (no usable samples: a frame without
    unclipped dark pixels). ``level`` is the mean level of the samples the estimate came from
    (above black for RAW); ``samples`` how many there were.
    """

    sigma: float
    source: str
    samples: int = 0
    level: float = 0.0

    def to_json(self) -> dict[str, Any]:
        return {
            "sigma": None if not math.isfinite(self.sigma) else float(self.sigma),
            "source": self.source,
            "samples": int(self.samples),
            "level": float(self.level),
        }


@dataclass(frozen=True)
class BracketNoise:
    """The bracket's noise and the noise floor derived from it (levels of the frames).

    ``sigma`` is the signal-independent noise used for the floor and the merge's noise model
    (the median of the optical-black values when there are any, else the estimate made at the
    lowest level); ``floor = max(k_sigma * sigma, minimum)``.
    """

    frames: tuple[FrameNoise, ...]
    sigma: float
    k_sigma: float
    minimum: float
    floor: float
    source: str

    def to_json(self) -> dict[str, Any]:
        return {
            "sigma": float(self.sigma),
            "k_sigma": float(self.k_sigma),
            "minimum": float(self.minimum),
            "floor": float(self.floor),
            "source": self.source,
            "frames": [f.to_json() for f in self.frames],
        }


def robust_sigma(values: np.ndarray, *, clip: float = 4.0, iterations: int = 3) -> float:
    """Standard deviation of zero-mean samples with outliers (edges, texture) trimmed.

    Starts from the median absolute deviation (too coarse alone on integer data: the MAD of
    small integers is 0, 1 or 2), then takes the root mean square of the samples within ``clip``
    scales, a few times. The Gaussian variance lost beyond 4 sigma (0.06 %) is ignored.
    """
    v = np.asarray(values, np.float64).ravel()
    if v.size == 0:
        return float("nan")
    med = float(np.median(v))
    d = v - med
    s = 1.4826 * float(np.median(np.abs(d)))
    if s <= 0:
        s = math.sqrt(math.pi / 2) * float(np.mean(np.abs(d)))
    if s <= 0:
        return 0.0
    for _ in range(iterations):
        keep = np.abs(d) <= clip * max(s, 0.5)
        if not np.any(keep):
            break
        s_new = math.sqrt(float(np.mean(d[keep] ** 2)))
        if abs(s_new - s) <= 1e-3 * s:
            s = s_new
            break
        s = s_new
    return float(s)


def _second_differences(
    plane: np.ndarray, low: float, high: float, max_samples: int = _MAX_SAMPLES
) -> tuple[np.ndarray, np.ndarray]:
    """Second differences along rows and the mean of their three taps, where no tap is clipped
    (``<= low`` or ``>= high``); rows are subsampled to at most about ``max_samples`` samples."""
    h, w = plane.shape
    step = max(1, int(math.ceil(h * max(w - 2, 1) / max_samples)))
    a = np.asarray(plane[::step], np.float32)
    left, mid, right = a[:, :-2], a[:, 1:-1], a[:, 2:]
    d2 = left - 2 * mid + right
    mean = (left + mid + right) * np.float32(1 / 3)
    lo = np.minimum(np.minimum(left, mid), right)
    hi = np.maximum(np.maximum(left, mid), right)
    ok = (lo > low) & (hi < high)
    return d2[ok], mean[ok]


def frame_noise(
    plane: np.ndarray, *, black: float = 0.0, white: float, clipped_low: float | None = None
) -> FrameNoise:
    """Noise of one frame from the darkest tenth of its flat regions.

    ``plane`` is one colour plane (a CFA site plane with the black level in it, or the green
    levels of a non-linear frame); ``black`` its black level and ``white`` its largest level.
    Samples with a tap at or below ``clipped_low`` (default: ``black - 1e9``, no clipping for
    raw data that keeps its black offset; non-linear frames clip at 0) or at ``white`` are left
    out: clipping shrinks the noise.
    """
    low = (black - 1e9) if clipped_low is None else clipped_low
    d2_all, mean_all = _second_differences(plane, low, white)
    if d2_all.size < _MIN_SAMPLES // 4:
        return FrameNoise(float("nan"), "none", int(d2_all.size), 0.0)

    def darkest(d2: np.ndarray, mean: np.ndarray) -> tuple[float, np.ndarray]:
        n = max(_MIN_SAMPLES, int(_DARK_FRACTION * d2.size))
        if n < d2.size:
            idx = np.argpartition(mean, n)[:n]
            d2, mean = d2[idx], mean[idx]
        return robust_sigma(d2) / math.sqrt(6.0), mean

    sigma, mean = darkest(d2_all, mean_all)
    if clipped_low is not None:
        # Near the clip even samples whose taps all lie above it are a truncated draw (their
        # noise pushed them up): measure again where the mean is 3 sigma clear of the clip
        # (and 3 quantisation steps: 12-bit data scaled into a 16-bit file moves by 16s).
        q = _level_step(plane)
        clear = mean_all > clipped_low + 3.0 * max(sigma, 0.5, q)
        if np.count_nonzero(clear) < _MIN_SAMPLES // 4:
            return FrameNoise(float("nan"), "none", int(np.count_nonzero(clear)), 0.0)
        sigma, mean = darkest(d2_all[clear], mean_all[clear])
    if not sigma > 0:
        return FrameNoise(float("nan"), "none", int(mean.size), 0.0)
    return FrameNoise(float(sigma), "dark-regions", int(mean.size), float(np.mean(mean) - black))


def _level_step(plane: np.ndarray) -> float:
    """The spacing of the levels a frame uses near black: 1, or about 16 for 12-bit data scaled
    into a 16-bit file (x 65535/4095: steps of 16 and 17)."""
    a = np.asarray(plane)
    if not np.issubdtype(a.dtype, np.integer):
        return 1.0
    step = max(1, int(math.sqrt(a.size / 100_000)))
    used = np.unique(a[::step, ::step])[:65]
    if used.size < 3:
        return 1.0
    return float(max(1.0, np.median(np.diff(used.astype(np.float64)))))


def bracket_noise(
    frames: Sequence[FrameNoise],
    *,
    max_level: int,
    linear: bool,
    k_sigma: float = K_SIGMA,
    minimum: float | None = None,
) -> BracketNoise:
    """The bracket's noise and noise floor from its frames' measurements (module docstring)."""
    if minimum is None:
        # 8-bit files are JPEGs or scans: the measured minimum (see its note). Deeper
        # non-linear files (16-bit TIFF/PNG from a raw converter) carry no JPEG compression:
        # their measured noise rules, as for RAW.
        minimum = (
            NONLINEAR_MIN_FLOOR_FRACTION * max_level
            if not linear and max_level <= 255
            else RAW_MIN_FLOOR
        )
    ob = [f.sigma for f in frames if f.source == "optical-black" and math.isfinite(f.sigma)]
    measured = [f for f in frames if f.source == "dark-regions" and math.isfinite(f.sigma)]
    if ob:
        sigma, source = float(np.median(ob)), "optical-black"
    elif measured:
        # The estimate made closest to black is the least inflated by photon shot noise.
        best = min(measured, key=lambda f: (f.level, -f.samples))
        sigma, source = float(best.sigma), "dark-regions"
    else:
        sigma, source = 0.0, "none"
    floor = max(k_sigma * sigma, float(minimum))
    floor = min(floor, 0.25 * max_level)
    return BracketNoise(
        frames=tuple(frames),
        sigma=sigma,
        k_sigma=float(k_sigma),
        minimum=float(minimum),
        floor=float(floor),
        source=source,
    )
