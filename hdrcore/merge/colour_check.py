"""Colour checked, not assumed: the merge's chromaticity against the frames it came from.

For non-linear input (JPEG, scans) the colour of a merged pixel rests on the response: a curve
whose channels disagree tints the radiance map although every frame shows the right colour
(issue 15: a phone bracket's facade (0.41, 0.33, 0.26) merged as (0.42, 0.43, 0.15)). Three
measurements, all as rg-chromaticity ``(r, g) = (R, G) / (R + G + B)`` distances, medians over
pixels *well exposed* (every channel inside :data:`WELL_EXPOSED` of the level range):

* ``merge_error`` -- the merged radiance against the reference frame linearised with the
  chosen response, over the pixels well exposed in the reference; ``merge_error_srgb`` the
  same against the reference decoded with sRGB (what the frame shows on a screen);
* ``frame_pairs`` -- consecutive frames, both linearised (registered through the merge's
  motion), over pixels well exposed in both: a right response gives a pixel the same colour in
  every frame where it is well exposed (``frame_pairs_srgb``: decoded with sRGB instead);
* ``best_frame_errors`` -- per frame, the same error over the pixels where that frame is the
  best exposed one (nearest mid-grey): the regions whose colour it should give;
* ``frame_pairs_wb`` -- the consecutive frames again with each frame's white balance (below)
  divided out; ``frame_pairs_blocks`` -- again on 4x4-pixel means (:func:`block_consistency`):
  pixel noise averaged down, what is left is the response's error (real brackets, the
  recovered curve: Canon 0.011 per pixel, 0.003 on blocks; sRGB 0.021 and 0.018);
* ``frame_pairs_noise`` -- what the per-pixel figure is made of (:func:`noise_consistency`):
  over the flattest quarter of the pixels, the pair's difference beside the two frames' own
  pixel noise (each pixel against the pixel two to its right in the same frame) and the
  excess over it. A perfect curve leaves the noise: simulated sRGB brackets with 1 level of
  noise decoded with their exact curve differ by 0.0099-0.0110 per pixel (own noise
  0.0094-0.0106, excess 0); real brackets' own noise: the memorial's film grain 0.010-0.039
  per pair, the Canon's darkest pair 0.0136, the phones' denoised JPEGs under 0.003;
* ``white_balance`` -- per frame, the white balance against the reference frame: the chained
  measurement of :mod:`hdrcore.merge.white_balance` when given (``balance``), else the median
  per-channel ratio to the reference frame's linearised values over pixels well exposed in
  both, normalised to green: a phone that re-balances each shot shows up as a frame whose red
  or blue ratio differs from 1;
* ``frame_colours`` -- per frame, the merge against that frame decoded with sRGB over the
  pixels well exposed in it and over those where it is the best exposed
  (:func:`frame_colours`): the colour target on every frame, not only the reference.

A merge whose ``merge_error`` exceeds :data:`MAX_MERGE_ERROR` is flagged ``"drift"``; a frame
whose white balance differs by more than :data:`MAX_WB_DIFFERENCE` is named. The check samples
a grid of at most ``max_samples`` reference pixels (nearest pixel in the other frames).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .._numba import AVAILABLE
from .._numba import njit as _njit
from .._once import Once
from .._threads import run_row_spans, thread_map
from ..errors import ParameterError
from .white_balance import frame_samples

__all__ = [
    "MAX_MERGE_ERROR",
    "MAX_WB_DIFFERENCE",
    "WELL_EXPOSED",
    "ANCHOR_BLUR",
    "ANCHOR_SIGMA",
    "CHECK_SAMPLES",
    "CONSISTENCY_BLOCK",
    "FRAME_BAND",
    "FRAME_SIGMA",
    "block_consistency",
    "REFERENCE_BAND",
    "ColourAnchor",
    "ColourCheck",
    "ColourResult",
    "RadianceSamples",
    "sample_grid",
    "FrameEncoding",
    "frame_encoding",
    "anchor_colour",
    "check_colour",
    "measure_frames",
    "FrameMeasures",
    "FrameColour",
    "FramePairColour",
    "FramePairNoise",
    "frame_colours",
    "noise_consistency",
    "chromaticity",
    "colour_check",
    "srgb_decode_lut",
]

#: Levels (fractions of the range) between which every channel of a pixel must lie for the
#: pixel to count as well exposed.
WELL_EXPOSED = (0.10, 0.90)
#: Median chromaticity error of a merge above which its colours are said to drift.
MAX_MERGE_ERROR = 0.02
#: Relative difference of a frame's red/green or blue/green balance that is reported.
MAX_WB_DIFFERENCE = 0.03
#: Most reference pixels the colour checks sample (:func:`sample_grid`).
CHECK_SAMPLES = 150_000


def _all3(b: np.ndarray) -> np.ndarray:
    """``np.all(b, axis=-1)`` of ``(..., 3)`` booleans, channel by channel (numpy's reductions
    over a last axis of three are several times slower than the three operations)."""
    return b[..., 0] & b[..., 1] & b[..., 2]


def _sum3(x: np.ndarray) -> np.ndarray:
    """``x.sum(axis=-1)`` of ``(..., 3)``, in numpy's order for three values."""
    return x[..., 0] + x[..., 1] + x[..., 2]


def _max3(x: np.ndarray) -> np.ndarray:
    """``np.max(x, axis=-1)`` of ``(..., 3)``."""
    return np.maximum(np.maximum(x[..., 0], x[..., 1]), x[..., 2])


def chromaticity(rgb: np.ndarray) -> np.ndarray:
    """``(..., 2)`` rg-chromaticity of ``(..., 3)`` linear RGB (NaN where the sum is 0)."""
    rgb = np.asarray(rgb, dtype=np.float64)
    s = _sum3(rgb)[..., None]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(s > 0, rgb[..., :2] / s, np.nan)


def srgb_decode_lut(max_level: int) -> np.ndarray:
    """``(max_level + 1,)`` sRGB decoding (IEC 61966-2-1) of every level."""
    v = np.arange(max_level + 1, dtype=np.float64) / max_level
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


@dataclass(frozen=True)
class FrameEncoding:
    """Whether a bracket's frames are sRGB-like or linear-encoded, read from their recovered
    response (its mean over the channels): the encoding it is nearer, and its largest
    distance (in the linear value, 0-1) from each. The colour anchoring decodes the frames
    with sRGB, which is right for frames a camera rendered for a screen (the real JPEG and PNG
    brackets in ``../shared/data``: 0.04-0.23 from sRGB, 0.25-0.44 from linear) and wrong for
    linear-encoded ones (a 16-bit linear TIFF as raw converters write it: simulated, median
    chromaticity error against the truth 0.0002 merged, 0.067 once anchored to its sRGB
    decoding)."""

    linear: bool
    from_linear: float
    from_srgb: float

    def to_json(self) -> dict[str, Any]:
        return {
            "encoding": "linear" if self.linear else "sRGB-like",
            "from_linear": self.from_linear,
            "from_srgb": self.from_srgb,
        }


def frame_encoding(lut: np.ndarray) -> FrameEncoding:
    """:class:`FrameEncoding` of frames whose recovered response is ``lut`` (``(C, L)`` or
    ``(L,)``, every level's linear value, 0 at level 0 and 1 at the top)."""
    g = np.asarray(lut, dtype=np.float64)
    g = g.mean(axis=0) if g.ndim == 2 else g
    top = g.size - 1
    v = np.arange(g.size, dtype=np.float64) / top
    from_linear = float(np.max(np.abs(g - v)))
    from_srgb = float(np.max(np.abs(g - srgb_decode_lut(top))))
    return FrameEncoding(from_linear < from_srgb, from_linear, from_srgb)


@dataclass(frozen=True)
class FramePairColour:
    """Median chromaticity difference of frames ``dark`` and ``bright`` over ``n_pixels``
    pixels well exposed in both (NaN when there are fewer than 50)."""

    dark: int
    bright: int
    median_difference: float
    n_pixels: int

    def to_json(self) -> dict[str, Any]:
        return {
            "dark": self.dark,
            "bright": self.bright,
            "median_difference": _num(self.median_difference),
            "n_pixels": self.n_pixels,
        }


@dataclass(frozen=True)
class FramePairNoise:
    """Frames ``dark`` and ``bright`` over ``n_pixels`` pixels well exposed in both, the
    flattest quarter of them (:func:`noise_consistency`): their median chromaticity
    difference ``flat``, the difference their own pixel noise alone makes (``noise``) and
    ``excess = sqrt(flat^2 - noise^2)`` (0 when the noise explains it all)."""

    dark: int
    bright: int
    flat: float
    noise: float
    excess: float
    n_pixels: int

    def to_json(self) -> dict[str, Any]:
        return {
            "dark": self.dark,
            "bright": self.bright,
            "flat": _num(self.flat),
            "noise": _num(self.noise),
            "excess": _num(self.excess),
            "n_pixels": self.n_pixels,
        }


@dataclass(frozen=True)
class ColourCheck:
    """The colour of a merge checked against its frames (see the module)."""

    reference: int
    merge_error: float
    merge_error_srgb: float
    n_pixels: int
    frame_pairs: tuple[FramePairColour, ...]
    frame_pairs_srgb: tuple[FramePairColour, ...]
    white_balance: tuple[tuple[float, float, float], ...]
    status: str
    message: str
    well_exposed: tuple[float, float] = WELL_EXPOSED
    best_frame_errors: tuple[tuple[float, float, int], ...] = ()
    frame_pairs_wb: tuple[FramePairColour, ...] = ()
    frame_pairs_blocks: tuple[FramePairColour, ...] = ()
    frame_colours: tuple[FrameColour, ...] = ()
    balance_differs: tuple[int, ...] | None = None
    frame_pairs_noise: tuple[FramePairNoise, ...] = ()

    @property
    def frame_noise(self) -> float:
        """Median over the consecutive pairs of the difference their own pixel noise makes
        (the floor of :attr:`frame_consistency` a perfect response still leaves)."""
        v = [p.noise for p in self.frame_pairs_noise if np.isfinite(p.noise)]
        return float(np.median(v)) if v else float("nan")

    @property
    def frame_consistency_excess(self) -> float:
        """Median over the consecutive pairs of their difference beyond their own noise."""
        v = [p.excess for p in self.frame_pairs_noise if np.isfinite(p.excess)]
        return float(np.median(v)) if v else float("nan")

    @property
    def frame_consistency(self) -> float:
        """Median over the consecutive pairs of their chromaticity differences."""
        v = [p.median_difference for p in self.frame_pairs if np.isfinite(p.median_difference)]
        return float(np.median(v)) if v else float("nan")

    @property
    def frame_consistency_wb(self) -> float:
        """:attr:`frame_consistency` with each frame's white balance divided out."""
        v = [p.median_difference for p in self.frame_pairs_wb if np.isfinite(p.median_difference)]
        return float(np.median(v)) if v else float("nan")

    @property
    def frame_consistency_blocks(self) -> float:
        """:attr:`frame_consistency` on block means (:func:`block_consistency`)."""
        v = [
            p.median_difference for p in self.frame_pairs_blocks if np.isfinite(p.median_difference)
        ]
        return float(np.median(v)) if v else float("nan")

    @property
    def frame_consistency_srgb(self) -> float:
        v = [p.median_difference for p in self.frame_pairs_srgb if np.isfinite(p.median_difference)]
        return float(np.median(v)) if v else float("nan")

    @property
    def white_balance_differs(self) -> tuple[int, ...]:
        """Frames whose red/green or blue/green balance differs from the reference's (the
        :class:`~hdrcore.merge.white_balance.FrameBalance` measurement when one was given)."""
        if self.balance_differs is not None:
            return self.balance_differs
        return tuple(
            k
            for k, (r, _, b) in enumerate(self.white_balance)
            if np.isfinite(r)
            and np.isfinite(b)
            and max(abs(r - 1.0), abs(b - 1.0)) > MAX_WB_DIFFERENCE
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "reference": self.reference,
            "merge_error": _num(self.merge_error),
            "merge_error_srgb": _num(self.merge_error_srgb),
            "n_pixels": self.n_pixels,
            "frame_consistency": _num(self.frame_consistency),
            "frame_consistency_srgb": _num(self.frame_consistency_srgb),
            "frame_consistency_wb": _num(self.frame_consistency_wb),
            "frame_consistency_blocks": _num(self.frame_consistency_blocks),
            "frame_noise": _num(self.frame_noise),
            "frame_consistency_excess": _num(self.frame_consistency_excess),
            "frame_pairs_noise": [p.to_json() for p in self.frame_pairs_noise],
            "frame_pairs_blocks": [p.to_json() for p in self.frame_pairs_blocks],
            "frame_pairs": [p.to_json() for p in self.frame_pairs],
            "frame_pairs_srgb": [p.to_json() for p in self.frame_pairs_srgb],
            "frame_pairs_wb": [p.to_json() for p in self.frame_pairs_wb],
            "white_balance": [[_num(v) for v in wb] for wb in self.white_balance],
            "white_balance_differs": list(self.white_balance_differs),
            "well_exposed": list(self.well_exposed),
            "best_frame_errors": [
                {"frame": k, "median_error": _num(e), "median_error_srgb": _num(es), "n_pixels": n}
                for k, (e, es, n) in enumerate(self.best_frame_errors)
            ],
            "frame_colours": [f.to_json() for f in self.frame_colours],
            "status": self.status,
            "message": self.message,
        }


def _num(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def _triple(v: Sequence[float] | np.ndarray) -> tuple[float, float, float]:
    """The three channels of ``v`` as Python floats."""
    return (float(v[0]), float(v[1]), float(v[2]))


def sample_grid(shape: tuple[int, ...], max_samples: int) -> tuple[np.ndarray, np.ndarray]:
    """``(ys, xs)``: the grid of at most ``max_samples`` reference pixels the colour checks
    read (:func:`colour_check`, :func:`frame_colours`), for frames of ``shape``."""
    h, w = int(shape[0]), int(shape[1])
    step = max(1, int(np.ceil(np.sqrt(h * w / max_samples))))
    ys, xs = (a.ravel() for a in np.mgrid[0:h:step, 0:w:step])
    return ys, xs


@dataclass(frozen=True)
class RadianceSamples:
    """A radiance map ``(H, W, 3)`` as the colour checks read it: its pixels on the grid of
    :func:`sample_grid` (``values`` ``(M, 3)`` float64), taken when it is made and checked
    later (:func:`check_colour` with ``report="later"``: the picture first, its measurements
    after). Stands in for the map in :func:`colour_check` and :func:`frame_colours` with the
    same ``max_samples``."""

    shape: tuple[int, int, int]
    max_samples: int
    values: np.ndarray

    @property
    def ndim(self) -> int:
        return 3

    @classmethod
    def of(cls, radiance: np.ndarray, max_samples: int) -> RadianceSamples:
        ys, xs = sample_grid(radiance.shape, max_samples)
        h, w = radiance.shape[:2]
        return cls((int(h), int(w), 3), int(max_samples), radiance[ys, xs].astype(np.float64))


def _merged_at(
    rad: np.ndarray | RadianceSamples, ys: np.ndarray, xs: np.ndarray, max_samples: int
) -> np.ndarray:
    """The merged pixels on the checks' grid ``(ys, xs)`` (of ``max_samples``), float64."""
    if isinstance(rad, RadianceSamples):
        if rad.max_samples != max_samples:
            raise ParameterError(
                "radiance samples taken on another grid",
                expected=f"max_samples={max_samples}",
                found=f"max_samples={rad.max_samples}",
            )
        return rad.values
    return rad[ys, xs].astype(np.float64)


def _median_distance(a: np.ndarray, b: np.ndarray) -> float:
    d = np.hypot(a[..., 0] - b[..., 0], a[..., 1] - b[..., 1])
    d = d[np.isfinite(d)]
    return float(np.median(d)) if d.size >= 50 else float("nan")


@dataclass(frozen=True)
class FrameColour:
    """The merge against frame ``frame`` decoded with sRGB (what it shows on a screen): the
    median rg-chromaticity distance over the pixels well exposed in it (``well_error``, over
    ``well_pixels``) and over those where it is also the best exposed frame (``best_error``,
    ``best_pixels``); ``*_balanced``: against the frame with its white balance difference to
    the reference divided out (the rendition a white-balanced merge aims at; equal to the
    plain errors when no balance was given)."""

    frame: int
    well_error: float
    well_pixels: int
    best_error: float
    best_pixels: int
    well_error_balanced: float
    best_error_balanced: float

    def to_json(self) -> dict[str, Any]:
        return {
            "frame": self.frame,
            "well_error": _num(self.well_error),
            "well_pixels": self.well_pixels,
            "best_error": _num(self.best_error),
            "best_pixels": self.best_pixels,
            "well_error_balanced": _num(self.well_error_balanced),
            "best_error_balanced": _num(self.best_error_balanced),
        }


def frame_colours(
    frames: Sequence[np.ndarray],
    radiance: np.ndarray | RadianceSamples,
    *,
    max_level: int,
    reference: int,
    to_reference: Sequence[np.ndarray] | None = None,
    masks: Sequence[np.ndarray | None] | None = None,
    gains: np.ndarray | None = None,
    max_samples: int = CHECK_SAMPLES,
    well_exposed: tuple[float, float] = WELL_EXPOSED,
    shared: dict[str, Any] | None = None,
) -> tuple[FrameColour, ...]:
    """Every frame's colour in the merge: per frame ``k`` the median chromaticity distance of
    ``radiance`` to frame ``k`` decoded with sRGB, over the pixels well exposed in ``k`` and
    over those of them where ``k`` is the best exposed frame (every channel nearest mid-grey).
    The issue's colour target, honestly: the regions another frame exposes best must have that
    frame's colour, not only the reference's. ``gains`` ``(N, 3)``: each frame's white balance
    against the reference (:func:`hdrcore.merge.white_balance.measure_white_balance`), for the
    ``*_balanced`` errors. ``shared``: as :func:`colour_check`'s (the same ``gains`` too)."""

    n = len(frames)
    if n < 1 or not 0 <= reference < n:
        raise ParameterError(
            "reference frame out of range", expected=f"0..{n - 1}", found=str(reference)
        )
    rad = radiance if isinstance(radiance, RadianceSamples) else np.asarray(radiance)
    h, w = np.asarray(frames[reference]).shape[:2]
    if rad.shape != (h, w, 3):
        raise ParameterError(
            "radiance must be (H, W, 3) like the frames",
            expected=str((h, w, 3)),
            found=str(rad.shape),
        )
    g = np.ones((n, 3)) if gains is None else np.asarray(gains, dtype=np.float64)
    if g.shape != (n, 3):
        raise ParameterError("gains must be (N, 3)", expected=str((n, 3)), found=str(g.shape))
    g = np.where(np.isfinite(g) & (g > 0), g, 1.0)
    part = None if shared is None else shared.get("colours")
    if part is None:
        ys, xs = sample_grid((h, w), max_samples)
        srgb = srgb_decode_lut(max_level)
        levels, exposed, plain, balanced = [], [], [], []
        for k, (z, ok) in enumerate(
            frame_samples(frames, xs, ys, reference, to_reference, masks, max_level, well_exposed)
        ):
            levels.append(z)
            exposed.append(ok)
            lin = srgb[z]
            plain.append(chromaticity(lin))
            balanced.append(chromaticity(lin / g[k]))
        part = (ys, xs, levels, exposed, plain, balanced)
        if shared is not None:
            shared["colours"] = part
    ys, xs, levels, exposed, plain, balanced = part
    merged = _merged_at(rad, ys, xs, max_samples)
    mok = _all3(np.isfinite(merged)) & (_sum3(merged) > 0)
    cm = chromaticity(merged)
    valid = [ok & mok for ok in exposed]
    score = np.stack(
        [np.where(valid[k], -_max3(np.abs(levels[k] / max_level - 0.5)), -np.inf) for k in range(n)]
    )
    best = np.argmax(score, axis=0)
    out = []
    for k in range(n):
        c_plain, c_bal = plain[k], balanced[k]
        well = valid[k]
        sel = well & (best == k)
        out.append(
            FrameColour(
                frame=k,
                well_error=_median_distance(cm[well], c_plain[well]),
                well_pixels=int(well.sum()),
                best_error=_median_distance(cm[sel], c_plain[sel]),
                best_pixels=int(sel.sum()),
                well_error_balanced=_median_distance(cm[well], c_bal[well]),
                best_error_balanced=_median_distance(cm[sel], c_bal[sel]),
            )
        )
    return tuple(out)


#: Side (pixels) of the blocks whose means :func:`block_consistency` compares.
CONSISTENCY_BLOCK = 4


def block_consistency(
    frames: Sequence[np.ndarray],
    lut: np.ndarray,
    *,
    max_level: int,
    reference: int,
    to_reference: Sequence[np.ndarray] | None = None,
    masks: Sequence[np.ndarray | None] | None = None,
    block: int = CONSISTENCY_BLOCK,
    max_blocks: int = 20_000,
    well_exposed: tuple[float, float] = WELL_EXPOSED,
) -> tuple[FramePairColour, ...]:
    """Consecutive frames' colour agreement on ``block x block`` means of the linearised frames:
    per pair the median rg-chromaticity distance over the blocks whose every pixel is well
    exposed in both. Pixel noise (JPEG, film grain: 0.006-0.012 of chromaticity per pixel on
    the real brackets) is averaged down; the response's own error is kept. Blocks lie on the
    reference's grid, the other frames' pixels are its nearest (``to_reference``, 2x3 or 3x3)."""

    table = np.asarray(lut, dtype=np.float64)
    if table.ndim == 1:
        table = np.tile(table, (3, 1))
    h, w = frames[reference].shape[:2]
    b = max(1, int(block))
    step = max(b, int(np.ceil(np.sqrt(h * w / max_blocks))))
    oy, ox = np.mgrid[0 : h - b + 1 : step, 0 : w - b + 1 : step]
    dy, dx = np.mgrid[0:b, 0:b]
    ys = (oy.ravel()[:, None] + dy.ravel()[None, :]).ravel()
    xs = (ox.ravel()[:, None] + dx.ravel()[None, :]).ravel()
    nb = oy.size
    lins, oks = [], []
    for z, ok in frame_samples(
        frames, xs, ys, reference, to_reference, masks, max_level, well_exposed
    ):
        lin = np.stack([table[c][z[:, c]] for c in range(3)], axis=-1)
        lins.append(lin.reshape(nb, b * b, 3).mean(axis=1))
        oks.append(ok.reshape(nb, b * b).all(axis=1))
    out = []
    for k in range(len(frames) - 1):
        both = oks[k] & oks[k + 1]
        out.append(
            FramePairColour(
                k,
                k + 1,
                _median_distance(chromaticity(lins[k][both]), chromaticity(lins[k + 1][both])),
                int(both.sum()),
            )
        )
    return tuple(out)


#: Offset (pixels, along a row) of the neighbour a frame's own pixel noise is measured
#: against: two, so that the two pixels lie in different chroma blocks of a 4:2:0 JPEG.
NOISE_OFFSET = 2


def noise_consistency(
    frames: Sequence[np.ndarray],
    lut: np.ndarray,
    *,
    max_level: int,
    reference: int,
    to_reference: Sequence[np.ndarray] | None = None,
    masks: Sequence[np.ndarray | None] | None = None,
    gains: np.ndarray | None = None,
    max_samples: int = CHECK_SAMPLES,
    well_exposed: tuple[float, float] = WELL_EXPOSED,
) -> tuple[FramePairNoise, ...]:
    """How much of consecutive frames' per-pixel colour difference their own noise makes.

    On a grid of reference pixels (the other frames' nearest pixel through ``to_reference``),
    over those well exposed in both frames of a pair and in the flattest quarter of them (the
    reference's 3x3 range of linearised green over its mean), the pair's median chromaticity
    difference ``flat``; each frame's own noise there: its pixel against the pixel
    :data:`NOISE_OFFSET` to the right in the same frame (same exposure, curve, balance and
    registration; another 4:2:0 chroma block), median distance over ``sqrt(2)``; the pair's
    noise ``noise = hypot(noise_a, noise_b)`` (what two noisy renditions of one colour differ
    by) and ``excess = sqrt(max(flat^2 - noise^2, 0))``. ``gains`` ``(N, 3)``: each frame's
    white balance divided out (as in ``frame_pairs_wb``). Simulated sRGB brackets, 1 level of
    noise, exact curve: ``flat`` 0.0093-0.0105, ``noise`` 0.0094-0.0106, excess 0; one
    channel 3 % off per stop: excess 0.006-0.007 (``bench/bench_response.py``)."""
    from ..geometry import nearest_in_frame

    table = np.asarray(lut, dtype=np.float64)
    if table.ndim == 1:
        table = np.tile(table, (3, 1))
    n = len(frames)
    g = np.ones((n, 3)) if gains is None else np.asarray(gains, dtype=np.float64)
    h, w = frames[reference].shape[:2]
    if h < 3 or w < 3 + NOISE_OFFSET:
        return ()
    step = max(1, int(np.ceil(np.sqrt(h * w / max_samples))))
    ys, xs = (a.ravel() for a in np.mgrid[1 : h - 1 : step, 1 : w - 1 : step])
    ref = np.asarray(frames[reference])
    green = np.stack(
        [
            table[1][np.clip(ref[ys + dy, xs + dx, 1].astype(np.intp), 0, max_level)]
            for dy in (-1, 0, 1)
            for dx in (-1, 0, 1)
        ]
    )
    contrast = np.ptp(green, axis=0) / np.maximum(green.mean(axis=0), 1e-12)
    del green
    lo_l, hi_l = well_exposed[0] * max_level, well_exposed[1] * max_level
    chroma, valid = [], []
    for k, f in enumerate(frames):
        f = np.asarray(f)
        if k == reference or to_reference is None:
            xk, yk, inside = xs, ys, np.ones(xs.size, bool)
        else:
            xk, yk, inside = nearest_in_frame(to_reference[k], xs, ys, (h, w))
        inside = inside & (xk < w - NOISE_OFFSET)
        xk = np.minimum(xk, w - 1 - NOISE_OFFSET)
        pair = []
        for dx in (0, NOISE_OFFSET):
            z = np.clip(f[yk, xk + dx].astype(np.intp), 0, max_level)
            ok = inside & _all3((z > lo_l) & (z < hi_l))
            if masks is not None and masks[k] is not None:
                ok &= np.asarray(masks[k], bool)[yk, xk + dx]
            lin = np.stack([table[c][z[:, c]] for c in range(3)], axis=-1) / g[k]
            pair.append((chromaticity(lin), ok))
        chroma.append((pair[0][0], pair[1][0]))
        valid.append((pair[0][1], pair[0][1] & pair[1][1]))
    out = []
    for k in range(n - 1):
        both = valid[k][0] & valid[k + 1][0]
        nan = float("nan")
        if both.sum() < 200:
            out.append(FramePairNoise(k, k + 1, nan, nan, nan, int(both.sum())))
            continue
        flat = both & (contrast <= np.quantile(contrast[both], 0.25))
        d_flat = _median_distance(chroma[k][0][flat], chroma[k + 1][0][flat])
        own = flat & valid[k][1] & valid[k + 1][1]
        na = _median_distance(chroma[k][0][own], chroma[k][1][own]) / np.sqrt(2.0)
        nb = _median_distance(chroma[k + 1][0][own], chroma[k + 1][1][own]) / np.sqrt(2.0)
        noise = float(np.hypot(na, nb))
        excess = float(np.sqrt(max(d_flat**2 - noise**2, 0.0))) if np.isfinite(noise) else nan
        out.append(FramePairNoise(k, k + 1, d_flat, noise, excess, int(both.sum())))
    return tuple(out)


@dataclass(frozen=True)
class _CheckFrames:
    """What :func:`colour_check` measures on the frames alone (kept in its ``shared`` dict):
    the sample grid, each frame's linearised samples there (the curve's and sRGB's) and where
    they are well exposed, the best-exposed frame per sample, the consecutive pairs'
    differences (plain, sRGB-decoded, balance divided out) and the white balance."""

    ys: np.ndarray
    xs: np.ndarray
    valid: list[np.ndarray]
    lin: list[np.ndarray]
    lin_srgb: list[np.ndarray]
    best: np.ndarray
    pairs: tuple[FramePairColour, ...]
    pairs_srgb: tuple[FramePairColour, ...]
    pairs_wb: tuple[FramePairColour, ...]
    wb: tuple[tuple[float, float, float], ...]
    colour_gains: np.ndarray
    noise: tuple[FramePairNoise, ...]
    blocks: tuple[FramePairColour, ...]


def _check_frames(
    frames: Sequence[np.ndarray],
    table: np.ndarray,
    *,
    max_level: int,
    reference: int,
    to_reference: Sequence[np.ndarray] | None,
    masks: Sequence[np.ndarray | None] | None,
    max_samples: int,
    well_exposed: tuple[float, float],
    balance: Any,
    frame_pairs_noise: tuple[FramePairNoise, ...] | None,
    frame_pairs_blocks: tuple[FramePairColour, ...] | None,
) -> _CheckFrames:

    kw: dict[str, Any] = dict(
        max_level=max_level,
        reference=reference,
        to_reference=to_reference,
        masks=masks,
        well_exposed=well_exposed,
    )

    def sampled() -> _CheckFrames:
        return _sampled_frames(frames, table, max_samples=max_samples, balance=balance, **kw)

    def noise(gains: Sequence[np.ndarray]) -> tuple[FramePairNoise, ...]:
        if frame_pairs_noise is not None:
            return frame_pairs_noise
        return noise_consistency(
            frames, table, gains=np.asarray(gains, np.float64), max_samples=max_samples, **kw
        )

    def blocks() -> tuple[FramePairColour, ...]:
        if frame_pairs_blocks is not None:
            return frame_pairs_blocks
        return block_consistency(frames, table, **kw)

    if balance is not None:
        # the per-pixel noise and block tests read the frames alone (the gains are the
        # balance's): side by side with the sampling (real Xperia bracket, the check after a
        # registration: 0.67 s of mostly single-threaded numpy in a row)
        given = list(balance.correction())
        parts: list[Any] = thread_map(lambda part: part(), [sampled, lambda: noise(given), blocks])
        return replace(parts[0], noise=parts[1], blocks=parts[2])
    alone = sampled()
    return replace(alone, noise=noise(list(alone.colour_gains)), blocks=blocks())


def _sampled_frames(
    frames,
    table,
    *,
    max_level,
    reference,
    to_reference,
    masks,
    max_samples,
    well_exposed,
    balance,
) -> _CheckFrames:
    """What :func:`_check_frames` measures on sampled pixels (its ``noise`` and ``blocks``
    left empty for the caller)."""
    n = len(frames)
    ys, xs = sample_grid(frames[reference].shape, max_samples)
    srgb = srgb_decode_lut(max_level)
    sampled = frame_samples(frames, xs, ys, reference, to_reference, masks, max_level, well_exposed)
    levels = [z for z, _ in sampled]
    valid = [ok for _, ok in sampled]
    lin = [np.stack([table[c][z[:, c]] for c in range(3)], axis=-1) for z in levels]
    lin_srgb = [srgb[z] for z in levels]
    score = np.stack(
        [np.where(valid[k], -_max3(np.abs(levels[k] / max_level - 0.5)), -np.inf) for k in range(n)]
    )
    best = np.argmax(score, axis=0)

    def pair(a: np.ndarray, b: np.ndarray, both: np.ndarray, k: int) -> FramePairColour:
        return FramePairColour(
            k,
            k + 1,
            _median_distance(chromaticity(a[both]), chromaticity(b[both])),
            int(both.sum()),
        )

    boths = [valid[k] & valid[k + 1] for k in range(n - 1)]
    pairs = tuple(pair(lin[k], lin[k + 1], boths[k], k) for k in range(n - 1))
    pairs_srgb = tuple(pair(lin_srgb[k], lin_srgb[k + 1], boths[k], k) for k in range(n - 1))
    own_gains = None
    wb: list[tuple[float, float, float]]
    if balance is not None:
        wb = [_triple(g) for g in balance.gains]
        gains = list(balance.correction())
        own_gains = balance.correction(every_measured=False)
    else:
        wb = []
        ref_lin = lin[reference]
        for k in range(n):
            both = valid[k] & valid[reference]
            if k == reference:
                wb.append((1.0, 1.0, 1.0))
                continue
            if both.sum() < 50:
                wb.append((float("nan"),) * 3)
                continue
            ratio = lin[k][both] / np.maximum(ref_lin[both], 1e-12)
            med = np.median(ratio, axis=0)
            wb.append(_triple(med / med[1]))
        gains = [np.where(np.isfinite(g), g, 1.0) for g in np.asarray(wb, dtype=np.float64)]
    # the consecutive frames again with each frame's white balance divided out
    pairs_wb = tuple(
        pair(lin[k] / gains[k], lin[k + 1] / gains[k + 1], boths[k], k) for k in range(n - 1)
    )
    return _CheckFrames(
        ys=ys,
        xs=xs,
        valid=valid,
        lin=lin,
        lin_srgb=lin_srgb,
        best=best,
        pairs=pairs,
        pairs_srgb=pairs_srgb,
        pairs_wb=pairs_wb,
        wb=tuple(wb),
        colour_gains=np.asarray(gains) if own_gains is None else own_gains,
        noise=(),
        blocks=(),
    )


def colour_check(
    frames: Sequence[np.ndarray],
    radiance: np.ndarray | RadianceSamples,
    lut: np.ndarray,
    *,
    max_level: int,
    reference: int,
    to_reference: Sequence[np.ndarray] | None = None,
    masks: Sequence[np.ndarray | None] | None = None,
    max_samples: int = CHECK_SAMPLES,
    well_exposed: tuple[float, float] = WELL_EXPOSED,
    frame_pairs_blocks: tuple[FramePairColour, ...] | None = None,
    balance: Any = None,
    frame_pairs_noise: tuple[FramePairNoise, ...] | None = None,
    shared: dict[str, Any] | None = None,
) -> ColourCheck:
    """Check the colour of ``radiance`` (``(H, W, 3)`` linear, in the frames' primaries)
    against the integer ``frames`` linearised by ``lut`` (``(3, max_level + 1)``).

    ``to_reference[k]`` maps frame ``k``'s pixel coordinates to the reference frame (2x3 or
    3x3; ``None``: the frames are aligned); ``masks[k]`` marks frame ``k``'s valid pixels
    (in its own coordinates). ``frame_pairs_blocks`` / ``frame_pairs_noise``: the frames'
    :func:`block_consistency` / :func:`noise_consistency` when already measured (they do not
    depend on ``radiance``). ``balance``: the frames'
    :class:`~hdrcore.merge.white_balance.FrameBalance`; its gains are then the reported white
    balance, its correction is divided out in ``frame_pairs_wb`` (every measured frame's) and
    the ``*_balanced`` errors of ``frame_colours`` (the frames that differ: what the anchoring
    divides out), its ``differs`` the frames named.

    ``shared``: a dict kept between checks of the same frames, ``lut``, ``reference``,
    ``to_reference``, ``masks``, ``balance`` gains and sampling (the check before and after
    the anchoring; a merge's levels moved): what reads only the frames is measured once and
    kept in it.
    """
    n = len(frames)
    if n < 1 or not 0 <= reference < n:
        raise ParameterError(
            "reference frame out of range", expected=f"0..{n - 1}", found=str(reference)
        )
    rad = radiance if isinstance(radiance, RadianceSamples) else np.asarray(radiance)
    h, w = frames[reference].shape[:2]
    if rad.shape[:2] != (h, w) or rad.ndim != 3 or rad.shape[2] != 3:
        raise ParameterError(
            "radiance must be (H, W, 3) like the frames",
            expected=str((h, w, 3)),
            found=str(rad.shape),
        )
    table = np.asarray(lut, dtype=np.float64)
    if table.ndim == 1:
        table = np.tile(table, (3, 1))
    if table.shape != (3, max_level + 1):
        raise ParameterError(
            "lut must be (3, max_level + 1)",
            expected=str((3, max_level + 1)),
            found=str(table.shape),
        )
    fp = None if shared is None else shared.get("check")
    if fp is None:
        fp = _check_frames(
            frames,
            table,
            max_level=max_level,
            reference=reference,
            to_reference=to_reference,
            masks=masks,
            max_samples=max_samples,
            well_exposed=well_exposed,
            balance=balance,
            frame_pairs_noise=frame_pairs_noise,
            frame_pairs_blocks=frame_pairs_blocks,
        )
        if shared is not None:
            shared["check"] = fp
    ys, xs, valid, lin, lin_srgb = fp.ys, fp.xs, fp.valid, fp.lin, fp.lin_srgb

    merged = _merged_at(rad, ys, xs, max_samples)
    mok = _all3(np.isfinite(merged)) & (_sum3(merged) > 0)
    ref_ok = valid[reference] & mok
    cm = chromaticity(merged[ref_ok])
    err = _median_distance(cm, chromaticity(lin[reference][ref_ok]))
    err_srgb = _median_distance(cm, chromaticity(lin_srgb[reference][ref_ok]))

    # every frame against the merge where it is the best exposed (nearest mid-grey) frame
    best_errors = []
    for k in range(n):
        sel = (fp.best == k) & valid[k] & mok
        best_errors.append(
            (
                _median_distance(chromaticity(merged[sel]), chromaticity(lin[k][sel])),
                _median_distance(chromaticity(merged[sel]), chromaticity(lin_srgb[k][sel])),
                int(sel.sum()),
            )
        )
    own = frame_colours(
        frames,
        rad,
        max_level=max_level,
        reference=reference,
        to_reference=to_reference,
        masks=masks,
        gains=fp.colour_gains,
        max_samples=max_samples,
        well_exposed=well_exposed,
        shared=shared,
    )
    pairs, pairs_srgb, pairs_wb, wb = fp.pairs, fp.pairs_srgb, fp.pairs_wb, fp.wb

    status = "ok"
    parts = [
        f"merge vs reference frame {reference}: median chromaticity error {err:.4f} "
        f"(against its sRGB decoding {err_srgb:.4f}) over {int(ref_ok.sum())} pixels"
    ]
    if np.isfinite(err) and err > MAX_MERGE_ERROR:
        status = "drift"
        parts.append(f"the merge's colours drift from the frame's (over {MAX_MERGE_ERROR})")
    check = ColourCheck(
        reference=reference,
        merge_error=err,
        merge_error_srgb=err_srgb,
        n_pixels=int(ref_ok.sum()),
        frame_pairs=tuple(pairs),
        frame_pairs_srgb=tuple(pairs_srgb),
        white_balance=tuple(wb),
        status=status,
        message="",
        well_exposed=(well_exposed[0], well_exposed[1]),
        best_frame_errors=tuple(best_errors),
        frame_pairs_wb=tuple(pairs_wb),
        frame_colours=own,
        balance_differs=None if balance is None else tuple(balance.differs),
        frame_pairs_noise=fp.noise,
        frame_pairs_blocks=fp.blocks,
    )
    cons = check.frame_consistency
    if np.isfinite(cons):
        parts.append(
            f"consecutive frames agree to {cons:.4f} (on {CONSISTENCY_BLOCK}x"
            f"{CONSISTENCY_BLOCK}-pixel means {check.frame_consistency_blocks:.4f}; "
            f"sRGB-decoded: {check.frame_consistency_srgb:.4f}; the frames' own pixel "
            f"noise makes {check.frame_noise:.4f}, beyond it "
            f"{check.frame_consistency_excess:.4f})"
        )
    odd = check.white_balance_differs
    if odd:
        parts.append(
            "white balance differs from the reference in frame(s) "
            + ", ".join(f"{k} (R/G x{wb[k][0]:.3f}, B/G x{wb[k][2]:.3f})" for k in odd)
        )
    return ColourCheck(**{**check.__dict__, "message": "; ".join(parts)})


#: Spread of the well-exposedness weight around mid-grey (Mertens et al. 2007 use 0.2).
ANCHOR_SIGMA = 0.2
#: Blur (in grid cells) of the anchoring weights and colours: transitions between frames.
ANCHOR_BLUR = 2.0
#: The reference frame's weight is multiplied by this. Frames of phones and of some raw
#: converters disagree in colour by 0.01-0.03; favouring the reference gives one rendition
#: where it is well exposed but moves the regions other frames expose best away from their
#: colours. Measured (median chromaticity error against the reference / against each other
#: frame where it is the best exposed; plain sRGB merge: Canon 0.0089 / 0.0081, Xperia
#: 0.0269 / 0.0161): x20 Canon 0.0001 / 0.0091, Xperia 0.0038 / 0.0366; x4 0.0006 / 0.0053,
#: 0.0129 / 0.0236; x1 0.0021 / 0.0044, 0.0217 / 0.0167. The issue asks for every frame's
#: colour where it is well exposed: no preference.
REFERENCE_BOOST = 1.0

#: ``(low, high, ramp)``: where every channel of the reference frame lies inside ``low..high``
#: of the range (the :data:`WELL_EXPOSED` band the colour check measures), the merge takes
#: the reference pixel's own colour; the weight falls linearly to zero over ``ramp`` outside.
#: The merge is on the reference's grid and the reference is the rendition the check (and the
#: user) compares it with; other frames give the colour only where it is not well exposed.
REFERENCE_BAND = (WELL_EXPOSED[0], WELL_EXPOSED[1], 0.05)


def _band_weight(x: np.ndarray, band: tuple[float, float, float] | None) -> np.ndarray:
    """``(...)`` weight of levels ``x`` ``(..., 3)`` (fractions of the range) in ``band``:
    1 when every channel is inside ``low..high``, falling linearly over ``ramp`` outside."""
    if band is None:
        return np.zeros(x.shape[:-1])
    lo, hi, ramp = band
    return np.clip(1.0 - np.maximum(lo - x, x - hi) / ramp, 0.0, 1.0).min(axis=-1)


@dataclass(frozen=True)
class ColourAnchor:
    """What :func:`anchor_colour` did: the grid step (pixels), the largest and median change
    of the chromaticity it applied, the share of the grid each frame's colour came from and
    the per-frame white balance (R, G, B gains against the reference) it divided out."""

    step: int
    max_shift: float
    median_shift: float
    frame_shares: tuple[float, ...]
    decode: str
    white_balance: tuple[tuple[float, float, float], ...] = ()
    own_colour_fraction: float = 0.0

    def to_json(self) -> dict[str, Any]:
        return {
            "step": self.step,
            "max_shift": _num(self.max_shift),
            "median_shift": _num(self.median_shift),
            "frame_shares": [float(v) for v in self.frame_shares],
            "decode": self.decode,
            "white_balance": [list(g) for g in self.white_balance],
            "own_colour_fraction": self.own_colour_fraction,
        }


def _redecode_table(lut: np.ndarray, decode: np.ndarray, size: int = 16384) -> np.ndarray:
    """``(C, size)`` table of ``decode(g^-1(x))`` for ``x`` on ``[0, 1]``: a value linearised
    with the merge's response, turned back into its level and decoded the other way."""
    x = np.linspace(0.0, 1.0, size)
    out = np.empty((lut.shape[0], size))
    levels = np.arange(lut.shape[1], dtype=np.float64)
    for c in range(lut.shape[0]):
        g = lut[c]
        keep = np.concatenate([[True], np.diff(g) > 0])
        z = np.interp(x, g[keep], levels[keep])
        out[c] = np.interp(z, levels, decode[c])
    return out


def _redecode(values: np.ndarray, log_time: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Merged radiance ``(..., C)`` re-decoded through ``table`` at the exposure
    ``exp(log_time)`` (``(...)``) of the frames that made it."""
    t = np.exp(log_time)[..., None]
    x = np.clip(values * t, 0.0, 1.0) * (table.shape[1] - 1)
    i0 = np.minimum(x.astype(np.intp), table.shape[1] - 2)
    f = x - i0
    out = np.empty(values.shape, np.float64)
    for c in range(values.shape[-1]):
        tc = table[c]
        out[..., c] = tc[i0[..., c]] * (1 - f[..., c]) + tc[i0[..., c] + 1] * f[..., c]
    return out / t


_LUMA = (0.2126, 0.7152, 0.0722)


def _apply_numpy(
    rad,
    fields,
    step,
    shares,
    log_t,
    redecode,
    ref_frame,
    table,
    noise_floor,
    saturation,
    max_level,
    rows_per_chunk,
    pixel_log_time,
    band,
) -> None:
    """The full-resolution pass of :func:`anchor_colour` in numpy (the numba kernel's spec)."""
    h, w = rad.shape[:2]
    shape = fields.shape[:2]
    lum = np.array(_LUMA, np.float32)
    cy = (np.arange(h) - step // 2) / step
    cx = np.clip((np.arange(w) - step // 2) / step, 0, shape[1] - 1)
    x0 = np.minimum(np.floor(cx).astype(np.intp), max(shape[1] - 2, 0))
    fx = (cx - x0)[:, None]
    x1 = np.minimum(x0 + 1, shape[1] - 1)
    table32 = table.astype(np.float32)
    for r0 in range(0, h, rows_per_chunk):
        r1 = min(h, r0 + rows_per_chunk)
        yy = np.clip(cy[r0:r1], 0, shape[0] - 1)
        y0 = np.minimum(np.floor(yy).astype(np.intp), max(shape[0] - 2, 0))
        y1 = np.minimum(y0 + 1, shape[0] - 1)
        fy = (yy - y0)[:, None, None]
        row0 = fields[y0][:, x0] * (1 - fx) + fields[y0][:, x1] * fx
        row1 = fields[y1][:, x0] * (1 - fx) + fields[y1][:, x1] * fx
        fl = (row0 * (1 - fy) + row1 * fy).astype(np.float32)
        block = rad[r0:r1]
        y_old = block @ lum
        if redecode is not None:
            col = _redecode(block, pixel_log_time(shares[:, r0:r1]), redecode)
            col = col.astype(np.float32)
        else:
            col = block.copy()
        col *= fl[..., :3]
        if ref_frame is not None:
            z = np.clip(ref_frame[r0:r1], 0, max_level).astype(np.intp)
            a = np.maximum(fl[..., 3], _band_weight(z / float(max_level), band))
            a = a * np.all((z > noise_floor) & (z < saturation), axis=-1)
            lin = np.stack([table32[c][z[..., c]] for c in range(3)], axis=-1)
            s_ref = lin.sum(axis=-1, keepdims=True)
            s_col = col.sum(axis=-1, keepdims=True)
            a = np.where((s_ref[..., 0] > 0) & (s_col[..., 0] > 0), a, 0.0)[..., None]
            col = (1 - a) * col / np.where(s_col > 0, s_col, 1) + a * lin / np.where(
                s_ref > 0, s_ref, 1
            )
        y_new = col @ lum
        usable = np.isfinite(y_new) & (y_new > 0) & np.isfinite(y_old) & (y_old > 0)
        scale = np.where(usable, y_old / np.where(usable, y_new, 1.0), 0.0)
        block[...] = np.where(usable[..., None], col * scale[..., None], block)


@_njit
def _band_row(frame, y, k, tabg, bt, ew, max_level, rs0, rs1, rs2, rws, ra):  # pragma: no cover
    """Step 3's sums of :func:`_anchor_pass` for row ``y`` of frame ``k`` read in place without
    a mask. No branches: a frame outside its band (or of no colour) adds zeros, and ``x + 0.0``
    is ``x``, so the sums are the same to the bit; the selects cost less than the branches
    mispredicted where exposures mix (24 MP sRGB bench bracket, tripod: every frame read
    here; the whole pass on one thread 0.837 -> 0.784 s, the result the same to the bit)."""
    for x in range(frame.shape[1]):
        z0 = min(max(int(frame[y, x, 0]), 0), max_level)
        z1 = min(max(int(frame[y, x, 1]), 0), max_level)
        z2 = min(max(int(frame[y, x, 2]), 0), max_level)
        band = min(bt[z0], min(bt[z1], bt[z2]))
        b0 = tabg[k, 0, z0]
        b1 = tabg[k, 1, z1]
        b2 = tabg[k, 2, z2]
        tot = b0 + b1 + b2
        ok = (band > 0.0) and (tot > 0.0)
        wk = band * (ew[z0] * ew[z1] * ew[z2]) if ok else 0.0
        tt = tot if ok else 1.0
        rs0[x] += np.float32(wk * b0 / tt)
        rs1[x] += np.float32(wk * b1 / tt)
        rs2[x] += np.float32(wk * b2 / tt)
        rws[x] += np.float32(wk)
        ra[x] = max(ra[x], np.float32(band) if ok else np.float32(0.0))


@_njit
def _anchor_pass(
    rad,
    r0,
    r1,
    sh_f,
    sh_off,
    steps12,
    fields,
    step,
    sh_bits,
    half,
    values,
    log_t,
    redecode,
    use_redecode,
    use_ref,
    ref,
    table,
    noise_floor,
    saturation,
    ref_band,
    use_band,
    frames,
    hmats,
    has_h,
    masks,
    has_mask,
    tabg,
    bt,
    ew,
    max_level,
):  # pragma: no cover
    """The per-pixel steps of :func:`anchor_colour` over rows ``r0..r1``, in one pass.

    Steps 1-2 (``steps12``): the colour re-decoded at the exposure of the frames that made the
    pixel (``use_redecode``: its shares' mean of ``log_t``, float16 shares read as their bits
    ``sh_bits`` with ``values`` their float64 values when ``half``, else float32 rows ``sh_f``
    from row ``sh_off``) times the smooth gains ``fields``; with ``use_ref`` the reference's own
    colour where it is well exposed (``ref_band``), else its share (4th field). Step 3
    (``use_band``): every frame's term (:func:`_band_numpy`'s arithmetic, rounded to float32
    and summed in frame order), then the blend (:func:`_blend_numpy`'s, in the same types).
    Per level of one channel (:func:`_band_tables`): ``bt`` the band weight, zero outside the
    noise floor and saturation, ``ew`` the Gaussian factor, ``tabg[k, c]`` frame ``k``'s
    decoded value with its balance divided out (no ``exp``, division or range test per
    channel). Step 3's sums come first, a frame at a time along the row into row buffers (the
    same sums in the same frame order; one frame's reads in a run instead of every frame's at
    each pixel: the 24 MP sRGB bench bracket's pass on one thread 1.01-1.08 -> 0.70-0.89 s, the
    result the same to the bit): where some frame gives the pixel its colour fully (band
    weight 1) steps 1-2 are skipped, their colour replaced (their luminance is the merge's
    own). Luminance (Rec. 709) kept throughout. Returns how many pixels some frame gave their
    colour fully."""
    w = rad.shape[1]
    gh, gw = fields.shape[0], fields.shape[1]
    size = redecode.shape[1]
    n = len(frames)
    l0, l1, l2 = 0.2126, 0.7152, 0.0722
    col = np.empty(3)
    lin = np.empty(3)
    fl = np.empty(4)
    lt_min = 0.0
    if use_redecode:
        lt_min = log_t[0]
        for k in range(log_t.shape[0]):
            lt_min = min(lt_min, log_t[k])
    # each column's cells of the field grid, once for all rows
    cx0 = np.empty(w, np.int64)
    cx1 = np.empty(w, np.int64)
    cfx = np.empty(w)
    for x in range(w):
        gx = (x - step // 2) / step
        gx = min(max(gx, 0.0), gw - 1.0)
        cx0[x] = min(int(gx), max(gw - 2, 0))
        cx1[x] = min(cx0[x] + 1, gw - 1)
        cfx[x] = gx - cx0[x]
    nq = 4 if use_ref else 3  # the reference's share (4th field) is read by use_ref only
    rs0 = np.empty(w, np.float32)
    rs1 = np.empty(w, np.float32)
    rs2 = np.empty(w, np.float32)
    rws = np.empty(w, np.float32)
    ra = np.empty(w, np.float32)
    xib = np.empty(w, np.int64)  # a warped frame's nearest pixels along the row
    yib = np.empty(w, np.int64)
    full = 0  # pixels some frame gave their colour fully (band weight 1)
    for y in range(r0, r1):
        gy = (y - step // 2) / step
        gy = min(max(gy, 0.0), gh - 1.0)
        y0 = min(int(gy), max(gh - 2, 0))
        y1 = min(y0 + 1, gh - 1)
        fy = gy - y0
        # step 3's sums, frame by frame over the row (the same per-pixel order: frames 0..n-1)
        for x in range(w):
            rs0[x] = 0.0
            rs1[x] = 0.0
            rs2[x] = 0.0
            rws[x] = 0.0
            ra[x] = 0.0
        if use_band:
            for k in range(n):
                frame = frames[k]
                fh, fw = frame.shape[0], frame.shape[1]
                hk = has_h[k]
                mk = has_mask[k]
                mask = masks[k]
                hm = hmats[k]
                h01y = hm[0, 1] * y
                h11y = hm[1, 1] * y
                h21y = hm[2, 1] * y
                if not hk and not mk:
                    # read in place, no mask: the same sums as below, in a loop of its own
                    # without branches (:func:`_band_row`)
                    _band_row(frame, y, k, tabg, bt, ew, max_level, rs0, rs1, rs2, rws, ra)
                    continue
                if hk:
                    # the nearest pixels of the row first, in a loop of their own (SIMD:
                    # the divisions were most of a warped frame's cost)
                    for x in range(w):
                        den = hm[2, 0] * x + h21y + hm[2, 2]
                        xib[x] = int(round((hm[0, 0] * x + h01y + hm[0, 2]) / den))
                        yib[x] = int(round((hm[1, 0] * x + h11y + hm[1, 2]) / den))
                for x in range(w):
                    if hk:
                        xi = xib[x]
                        yi = yib[x]
                        if xi < 0 or xi >= fw or yi < 0 or yi >= fh:
                            continue
                    else:
                        xi = x
                        yi = y
                    if mk and not mask[yi, xi]:
                        continue
                    z0 = min(max(int(frame[yi, xi, 0]), 0), max_level)
                    z1 = min(max(int(frame[yi, xi, 1]), 0), max_level)
                    z2 = min(max(int(frame[yi, xi, 2]), 0), max_level)
                    band = min(bt[z0], min(bt[z1], bt[z2]))
                    if band <= 0.0:
                        continue
                    b0 = tabg[k, 0, z0]
                    b1 = tabg[k, 1, z1]
                    b2 = tabg[k, 2, z2]
                    tot = b0 + b1 + b2
                    if not (tot > 0.0):
                        continue
                    wk = band * (ew[z0] * ew[z1] * ew[z2])
                    rs0[x] += np.float32(wk * b0 / tot)
                    rs1[x] += np.float32(wk * b1 / tot)
                    rs2[x] += np.float32(wk * b2 / tot)
                    rws[x] += np.float32(wk)
                    if band > ra[x]:
                        ra[x] = np.float32(band)
        for x in range(w):
            s0 = rs0[x]
            s1 = rs1[x]
            s2 = rs2[x]
            ws = rws[x]
            a = ra[x]
            if a >= 1.0:  # (0 without step 3)
                full += 1
            # steps 1-2, unless a frame's colour replaces theirs
            if steps12 and not (a >= 1.0 and ws > 0.0):
                r_ = rad[y, x, 0]
                g_ = rad[y, x, 1]
                b_ = rad[y, x, 2]
                y_old = l0 * r_ + l1 * g_ + l2 * b_
                if y_old > 0 and np.isfinite(y_old):
                    for q in range(nq):
                        a0 = fields[y0, cx0[x], q] * (1 - cfx[x]) + fields[y0, cx1[x], q] * cfx[x]
                        a1 = fields[y1, cx0[x], q] * (1 - cfx[x]) + fields[y1, cx1[x], q] * cfx[x]
                        fl[q] = a0 * (1 - fy) + a1 * fy
                    if use_redecode:
                        tot = 0.0
                        acc = 0.0
                        for k in range(log_t.shape[0]):
                            if half:
                                sk = values[sh_bits[k, y, x]]
                            else:
                                sk = np.float64(sh_f[k, y - sh_off, x])
                            tot += sk
                            acc += sk * log_t[k]
                        lt = acc / tot if tot > 0 else lt_min
                        t = np.exp(lt)
                        for c in range(3):
                            v = rad[y, x, c] * t
                            v = min(max(v, 0.0), 1.0) * (size - 1)
                            i0 = min(int(v), size - 2)
                            f = v - i0
                            col[c] = (redecode[c, i0] * (1 - f) + redecode[c, i0 + 1] * f) / t
                    else:
                        for c in range(3):
                            col[c] = rad[y, x, c]
                    for c in range(3):
                        col[c] *= fl[c]
                    if use_ref:
                        ok = True
                        for c in range(3):
                            z = ref[y, x, c]
                            if not (z > noise_floor and z < saturation):
                                ok = False
                        # the reference's own colour where it is well exposed, else its share
                        ar = fl[3]
                        if ok and ref_band[0] < ref_band[1]:
                            bw = 1.0
                            for c in range(3):
                                v = ref[y, x, c] / max_level
                                if v < ref_band[0]:
                                    bw = min(bw, max(0.0, 1.0 - (ref_band[0] - v) / ref_band[2]))
                                elif v > ref_band[1]:
                                    bw = min(bw, max(0.0, 1.0 - (v - ref_band[1]) / ref_band[2]))
                            ar = max(ar, bw)
                        if ok and ar > 0:
                            s_ref = 0.0
                            for c in range(3):
                                zc = min(max(int(ref[y, x, c]), 0), max_level)
                                lin[c] = table[c, zc]
                                s_ref += lin[c]
                            s_col = col[0] + col[1] + col[2]
                            if s_ref > 0 and s_col > 0:
                                for c in range(3):
                                    col[c] = (1 - ar) * col[c] / s_col + ar * lin[c] / s_ref
                    y_new = l0 * col[0] + l1 * col[1] + l2 * col[2]
                    if y_new > 0 and np.isfinite(y_new):
                        sc = y_old / y_new
                        for c in range(3):
                            rad[y, x, c] = col[c] * sc
            # step 3's blend
            if not (a > 0.0) or not (ws > 0.0):
                continue
            r_ = np.float64(rad[y, x, 0])
            g_ = np.float64(rad[y, x, 1])
            b_ = np.float64(rad[y, x, 2])
            y_old = l0 * r_ + l1 * g_ + l2 * b_
            sm = r_ + g_ + b_
            if not (y_old > 0.0) or not (sm > 0.0) or not np.isfinite(y_old):
                continue
            q0 = (1 - a) * r_ / sm + a * s0 / ws
            q1 = (1 - a) * g_ / sm + a * s1 / ws
            q2 = (1 - a) * b_ / sm + a * s2 / ws
            y_new = l0 * q0 + l1 * q1 + l2 * q2
            if y_new > 0.0:
                kk = y_old / y_new
                rad[y, x, 0] = np.float32(q0 * kk)
                rad[y, x, 1] = np.float32(q1 * kk)
                rad[y, x, 2] = np.float32(q2 * kk)
    return full


def _pass_rows(
    rad: np.ndarray,
    *,
    max_level: int,
    steps12: dict[str, Any] | None = None,
    band_args: tuple | None = None,
) -> tuple[Callable[[int, int], None], list[int]]:
    """``rows(r0, r1)``: :func:`_anchor_pass` over output rows ``r0..r1`` (the kernel releases
    the GIL: rows run side by side on threads), and the list each call appends its count of
    pixels given a frame's colour fully to. ``steps12``: steps 1-2's arguments (they run: the
    smooth ``fields`` and their grid ``step``; ``shares``, ``log_t``, ``redecode`` for the
    re-decoding; ``ref_frame``, ``table``, ``noise_floor``, ``saturation``, ``band`` for the
    reference's own colour); ``band_args``: :func:`_band_args` (step 3 runs). float16 shares
    are read as their bits (no conversion pass); others as float32 a chunk of rows at a
    time."""

    from .maps import _HALF_VALUES

    st = steps12 or {}
    shares: np.ndarray | None = st.get("shares") if st.get("redecode") is not None else None
    half = shares is not None and shares.dtype == np.float16
    # numba has no float16: float16 shares are read as their bits, others as float32 rows
    float_rows = shares if shares is not None and not half else None
    ref_frame = st.get("ref_frame")
    ref_band = st.get("band")
    fields = st.get("fields")
    fixed = (
        steps12 is not None,
        np.zeros((1, 1, 4), np.float32) if fields is None else fields,
        int(st.get("step", 1)),
        shares.view(np.uint16) if shares is not None and half else np.zeros((1, 1, 1), np.uint16),
        half,
        _HALF_VALUES if half else np.zeros(1),
        np.asarray(st["log_t"], np.float64) if shares is not None else np.zeros(1),
        np.ascontiguousarray(st["redecode"], np.float64)
        if shares is not None
        else np.zeros((3, 2)),
        shares is not None,
        ref_frame is not None,
        np.zeros((1, 1, 3), np.uint8) if ref_frame is None else ref_frame,
        np.ascontiguousarray(st.get("table", np.zeros((3, 1))), np.float64),
        float(st.get("noise_floor", 0.0)),
        float(st.get("saturation", 0.0)),
        np.asarray(ref_band if ref_band is not None else (1.0, 0.0, 1.0), np.float64),
    )
    if band_args is None:
        band = (
            False,
            (np.zeros((1, 1, 3), np.uint8),),
            np.eye(3)[None],
            np.zeros(1, np.bool_),
            (np.zeros((1, 1), np.bool_),),
            np.zeros(1, np.bool_),
            np.zeros((1, 3, 1)),
            np.zeros(1),
            np.zeros(1),
        )
    else:
        band = (True, *band_args)
    none3 = np.zeros((1, 1, 1), np.float32)
    counts: list[int] = []
    lock = threading.Lock()

    def rows(r0: int, r1: int) -> None:
        chunk = r1 - r0 if float_rows is None else ANCHOR_CHUNK_ROWS
        for c0 in range(r0, r1, chunk):
            c1 = min(r1, c0 + chunk)
            part = none3 if float_rows is None else float_rows[:, c0:c1].astype(np.float32)
            c = _anchor_pass(rad, c0, c1, part, c0, *fixed, *band, int(max_level))
            with lock:
                counts.append(int(c))

    return rows, counts


#: ``(low, high, ramp)``: a frame gives a pixel its own colour where every channel of it lies
#: inside ``low..high`` of the range (the :data:`WELL_EXPOSED` band the colour check measures),
#: its weight falling linearly to zero over ``ramp`` outside.
FRAME_BAND = (WELL_EXPOSED[0], WELL_EXPOSED[1], 0.05)
#: Spread (fraction of the range, every channel) of the weight around mid-grey with which the
#: frames' own colours are mixed where several are well exposed: the frame nearest mid-grey
#: gives nearly all of it (one level step of a 1-stop bracket is about 0.13: a weight ratio of
#: 10 or more), the weight still a smooth function of the levels. Real brackets, median
#: chromaticity error against each frame where it is the best exposed (per pixel, measured
#: on the sampled pixels of the Xperia bracket): sigma 0.05 -> at most 0.0045, 0.1 -> 0.0077,
#: 0.2 -> 0.0165 (the sRGB merge: 0.012-0.027); against every pixel a frame exposes well
#: 0.005-0.045 whatever sigma (frames that disagree cannot all be met).
FRAME_SIGMA = 0.1


def _band_tables(
    table: np.ndarray,
    gains: np.ndarray,
    band: tuple[float, float, float],
    inv_2s2: float,
    max_level: int,
    noise_floor: float,
    saturation: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The per-level tables of :func:`_anchor_pass`'s step 3: ``(tabg, bt, ew)``, ``tabg[k, c,
    z] = table[c, z] / gains[k, c]`` (the same division the pixel would make), ``bt`` the band
    weight of :func:`_level_weights` set to zero at levels outside ``(noise_floor,
    saturation)``, ``ew`` its Gaussian factor (24 MP x 3 random frames, one thread: 1.35 ->
    1.08 s, the result the same to the bit)."""
    bt, ew = _level_weights(band, inv_2s2, int(max_level))
    z = np.arange(int(max_level) + 1)
    bt = np.where((z > noise_floor) & (z < saturation), bt, 0.0)
    tab = np.asarray(table, np.float64)[:, : int(max_level) + 1]
    g = np.asarray(gains, np.float64).reshape(-1, 3)
    tabg = np.ascontiguousarray(tab[None, :, :] / g[:, :, None])
    return tabg, bt, ew


def _level_weights(
    band: tuple[float, float, float], inv_2s2: float, max_level: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per level ``z`` of one channel (``v = z / max_level``): the band weight ``clip(1 -
    max(lo - v, v - hi) / ramp, 0, 1)`` and the Gaussian factor ``exp(-(v - 0.5)**2 *
    inv_2s2)``. A pixel's weight in step 3 is the smallest band weight of its channels times
    the product of their factors (the Gaussian of the summed squares, to rounding): tables
    of ``max_level + 1`` entries instead of an ``exp`` per pixel and frame (24 MP, 3 frames:
    the pass 2.35 -> 1.94 CPU s on random levels, the machine shared)."""
    lo, hi, ramp = (float(v) for v in band)
    v = np.arange(int(max_level) + 1, dtype=np.float64) / float(max_level)
    bt = np.clip(1.0 - np.maximum(lo - v, v - hi) / ramp, 0.0, 1.0)
    ew = np.exp(-((v - 0.5) ** 2) * float(inv_2s2))
    return bt, ew


def _band_numpy(
    acc,
    wsum,
    amax,
    frame,
    hmat,
    mask,
    table,
    gains,
    band,
    inv_2s2,
    floor,
    sat,
    max_level,
    rows_per_chunk,
) -> None:
    """One frame's term of step 3 in numpy (the spec of :func:`_anchor_pass`'s step 3, and the
    path without numba)."""
    h, w = acc.shape[:2]
    fh, fw = frame.shape[:2]
    bt, ew = _level_weights(band, inv_2s2, max_level)
    for r0 in range(0, h, rows_per_chunk):
        r1 = min(h, r0 + rows_per_chunk)
        yy, xx = np.mgrid[r0:r1, 0:w]
        if hmat is not None:
            den = hmat[2, 0] * xx + hmat[2, 1] * yy + hmat[2, 2]
            xi = np.rint((hmat[0, 0] * xx + hmat[0, 1] * yy + hmat[0, 2]) / den).astype(np.intp)
            yi = np.rint((hmat[1, 0] * xx + hmat[1, 1] * yy + hmat[1, 2]) / den).astype(np.intp)
            inside = (xi >= 0) & (xi < fw) & (yi >= 0) & (yi < fh)
            xi = np.clip(xi, 0, fw - 1)
            yi = np.clip(yi, 0, fh - 1)
        else:
            xi, yi, inside = xx, yy, np.ones(xx.shape, bool)
        z = np.clip(frame[yi, xi].astype(np.intp), 0, max_level)
        ok = inside & np.all((z > floor) & (z < sat), axis=-1)
        if mask is not None:
            ok &= mask[yi, xi]
        bw = bt[z].min(axis=-1)
        e = ew[z]
        lin = np.stack([table[c][z[..., c]] / gains[c] for c in range(3)], axis=-1)
        tot = lin.sum(axis=-1)
        ok &= (bw > 0) & (tot > 0)
        wk = np.where(ok, bw * (e[..., 0] * e[..., 1] * e[..., 2]), 0.0)
        acc[r0:r1] += (wk[..., None] * lin / np.where(tot > 0, tot, 1.0)[..., None]).astype(
            np.float32
        )
        wsum[r0:r1] += wk.astype(np.float32)
        np.maximum(amax[r0:r1], np.where(ok, bw, 0.0).astype(np.float32), out=amax[r0:r1])


def _blend_numpy(rad, acc, wsum, amax, rows_per_chunk) -> None:
    """The blend of step 3 in numpy (the spec of :func:`_anchor_pass`'s)."""
    lum = np.asarray(_LUMA)
    for r0 in range(0, rad.shape[0], rows_per_chunk):
        r1 = min(rad.shape[0], r0 + rows_per_chunk)
        col = rad[r0:r1].astype(np.float64)
        y_old = col @ lum
        s = col.sum(axis=-1)
        a = amax[r0:r1].astype(np.float64)
        ws = wsum[r0:r1].astype(np.float64)
        use = (a > 0) & (ws > 0) & (y_old > 0) & (s > 0) & np.isfinite(y_old)
        q = (1 - a)[..., None] * col / np.where(s > 0, s, 1.0)[..., None] + a[..., None] * acc[
            r0:r1
        ] / np.where(ws > 0, ws, 1.0)[..., None]
        y_new = q @ lum
        use &= y_new > 0
        k = np.where(use, y_old / np.where(use, y_new, 1.0), 0.0)
        rad[r0:r1] = np.where(use[..., None], q * k[..., None], col).astype(np.float32)


def _frame_band(
    rad,
    frames,
    table,
    gains,
    *,
    max_level,
    noise_floor,
    saturation,
    reference,
    to_reference,
    masks,
    band,
    sigma,
    rows_per_chunk=256,
) -> float:
    """Step 3 of :func:`anchor_colour` with ``frame_band``: every pixel's chromaticity from the
    frames well exposed there (each frame's decoded colour, its white balance divided out),
    mixed with weights that favour the frame nearest mid-grey; luminance kept. Returns the
    fraction of pixels some frame gave their colour fully."""
    h, w = rad.shape[:2]
    if AVAILABLE:
        rows, counts = _frame_band_rows(
            rad,
            frames,
            table,
            gains,
            max_level=max_level,
            noise_floor=noise_floor,
            saturation=saturation,
            reference=reference,
            to_reference=to_reference,
            masks=masks,
            band=band,
            sigma=sigma,
        )
        run_row_spans(h, None, rows)
        return float(sum(counts)) / float(h * w)
    inv_2s2 = 1.0 / (2.0 * float(sigma) ** 2)
    tab = np.ascontiguousarray(table, np.float64)
    # without numba (slow: for debugging the kernel in Python): the per-frame numpy spec
    acc = np.zeros((h, w, 3), np.float32)
    wsum = np.zeros((h, w), np.float32)
    amax = np.zeros((h, w), np.float32)
    reads = _reading_homographies(to_reference, reference, len(frames))
    for k, f in enumerate(frames):
        mask = None if masks is None or masks[k] is None else np.asarray(masks[k], bool)
        _band_numpy(
            acc,
            wsum,
            amax,
            np.asarray(f),
            reads[k],
            mask,
            tab,
            np.asarray(gains[k], np.float64),
            band,
            inv_2s2,
            float(noise_floor),
            float(saturation),
            int(max_level),
            rows_per_chunk,
        )
    _blend_numpy(rad, acc, wsum, amax, rows_per_chunk)
    return float(np.mean(amax >= 1.0))


def _reading_homographies(
    to_reference: Sequence[np.ndarray] | None, reference: int | None, n: int
) -> list[np.ndarray | None]:
    """Per frame the 3x3 matrix reading it at a reference pixel (reference -> frame), or None
    where the frame is read in place (the reference, no motion, the identity)."""
    from ..geometry import homogeneous, invert

    out: list[np.ndarray | None] = [None] * n
    for k in range(n):
        if to_reference is not None and k != reference and to_reference[k] is not None:
            m = homogeneous(invert(np.asarray(to_reference[k], np.float64)))
            if not np.allclose(m, np.eye(3), atol=1e-12):
                out[k] = m
    return out


def _band_args(
    frames,
    table,
    gains,
    *,
    max_level,
    noise_floor,
    saturation,
    reference,
    to_reference,
    masks,
    band,
    sigma,
) -> tuple:
    """Step 3's arguments as :func:`_anchor_pass` reads them: ``(frames, hmats,
    has_h, masks, has_mask, tabg, bt, ew, max_level)``."""
    inv_2s2 = 1.0 / (2.0 * float(sigma) ** 2)
    n = len(frames)
    reads = _reading_homographies(to_reference, reference, n)
    hmats = np.stack([np.eye(3) if m is None else m for m in reads])
    has_h = np.array([m is not None for m in reads], np.bool_)
    has_m = np.zeros(n, np.bool_)
    none_mask = np.zeros((1, 1), np.bool_)
    mks = []
    for k in range(n):
        mk = None if masks is None or masks[k] is None else np.asarray(masks[k], np.bool_)
        has_m[k] = mk is not None
        mks.append(np.ascontiguousarray(mk) if mk is not None else none_mask)
    fr = tuple(np.ascontiguousarray(f) for f in frames)
    tabg, bt, ew = _band_tables(
        table,
        np.asarray(gains, np.float64).reshape(n, 3),
        band,
        inv_2s2,
        int(max_level),
        float(noise_floor),
        float(saturation),
    )
    return fr, hmats, has_h, tuple(mks), has_m, tabg, bt, ew


def _frame_band_rows(
    rad, frames, table, gains, **band_kw: Any
) -> tuple[Callable[[int, int], None], list[int]]:
    """``rows(r0, r1)``: :func:`_frame_band` through :func:`_anchor_pass` (step 3 alone) over
    output rows ``r0..r1`` (every frame read at each pixel: the same result to the bit as the
    per-frame passes), and the list each call appends its count of pixels given a frame's
    colour fully to."""
    return _pass_rows(
        rad, max_level=band_kw["max_level"], band_args=_band_args(frames, table, gains, **band_kw)
    )


def _grid_sums_numpy(
    lins: tuple[np.ndarray, ...], weights: tuple[np.ndarray, ...], gains: np.ndarray, qm: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`anchor_colour` step 2's sums over the frames on the grid: ``num_t`` the weighted
    chromaticities of the frames (each frame's colours ``lins[k]`` divided by its ``gains[k]``),
    ``num_m`` the merge's ``qm`` with the same weights, ``den`` the weights (the spec of
    :func:`_grid_sums`)."""
    m = qm.shape[0]
    num_t = np.zeros((m, 3))
    num_m = np.zeros((m, 3))
    den = np.zeros(m)
    for k in range(len(lins)):
        lin = lins[k] / gains[k]
        wk = weights[k]
        s = _sum3(lin)
        q = lin / np.where(s > 0, s, 1.0)[:, None]
        num_t += wk[:, None] * q
        num_m += wk[:, None] * qm
        den += wk
    return num_t, num_m, den


def _grid_sums(
    lins: tuple[np.ndarray, ...], weights: tuple[np.ndarray, ...], gains: np.ndarray, qm: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_grid_sums_numpy` compiled (:func:`_grid_sums_kernel`); the tuples padded to
    :data:`~hdrcore.merge._fused.TUPLE_SLOTS` as the merge's are, so one compiled kernel
    serves every frame count (a new count compiled for 1.0 s)."""
    from ._fused import TUPLE_SLOTS

    n = len(lins)
    pad = -n % TUPLE_SLOTS
    return _grid_sums_kernel(
        tuple(lins) + (lins[0],) * pad, tuple(weights) + (weights[0],) * pad, n, gains, qm
    )


@_njit
def _grid_sums_kernel(lins, weights, n, gains, qm):  # pragma: no cover - compiled
    """:func:`_grid_sums_numpy` in one pass over the cells (the first ``n`` of the padded
    tuples), the same operations in the same order (the same sums to the bit): 24 MP sRGB
    bench bracket (240,000 cells, 3 frames) 55 -> ~13 ms, on the merge's path to the
    picture."""
    m = qm.shape[0]
    num_t = np.zeros((m, 3))
    num_m = np.zeros((m, 3))
    den = np.zeros(m)
    for k in range(n):
        lin = lins[k]
        wts = weights[k]
        g0, g1, g2 = gains[k, 0], gains[k, 1], gains[k, 2]
        for i in range(m):
            a0 = lin[i, 0] / g0
            a1 = lin[i, 1] / g1
            a2 = lin[i, 2] / g2
            s = a0 + a1 + a2
            d = s if s > 0 else 1.0
            wk = wts[i]
            num_t[i, 0] += wk * (a0 / d)
            num_t[i, 1] += wk * (a1 / d)
            num_t[i, 2] += wk * (a2 / d)
            num_m[i, 0] += wk * qm[i, 0]
            num_m[i, 1] += wk * qm[i, 1]
            num_m[i, 2] += wk * qm[i, 2]
            den[i] += wk
    return num_t, num_m, den


def anchor_colour(
    radiance: np.ndarray,
    frames: Sequence[np.ndarray],
    decode: np.ndarray,
    *,
    max_level: int,
    saturation: float,
    noise_floor: float,
    to_reference: Sequence[np.ndarray] | None = None,
    masks: Sequence[np.ndarray | None] | None = None,
    reference: int | None = None,
    lut: np.ndarray | None = None,
    exposure_times: Sequence[float] | None = None,
    shares: np.ndarray | None = None,
    max_samples: int = 250_000,
    decode_name: str = "srgb",
    white_balance: bool = False,
    rows_per_chunk: int = 256,
    reference_band: tuple[float, float, float] | None = None,
    gains: np.ndarray | None = None,
    frame_band: tuple[float, float, float] | None = FRAME_BAND,
    frame_sigma: float = FRAME_SIGMA,
) -> ColourAnchor:
    """Give the merged ``radiance`` (modified in place) the colour of the frames that expose
    each region best, keeping its luminance.

    1. With the merge's ``lut``, ``exposure_times`` and per-frame ``shares`` (``(N, H, W)``,
       :attr:`MergeResult.shares`) every pixel is first re-decoded: its value at the exposure
       of the frames that made it (the shares' geometric mean of the times) is turned back
       into levels through the ``lut`` and decoded with ``decode`` (``(3, L)`` or ``(L,)``),
       which gives the colour of the frames as ``decode`` renders them, pixel by pixel.
    2. On a grid of at most ``max_samples`` cells every frame's colour (its levels decoded by
       ``decode``) is weighted by how well exposed it is (a Gaussian of :data:`ANCHOR_SIGMA`
       around mid-grey in every channel, zero when clipped or under the noise floor: the frame
       nearest mid-grey counts most; the ``reference`` frame :data:`REFERENCE_BOOST` times
       that), the weights blurred over :data:`ANCHOR_BLUR` cells for smooth transitions. The
       ratio of that colour to the merge's own (same weights, same blur) is a smooth
       per-channel gain: frames that disagree in colour are followed region by region.
    3. With ``frame_band`` (the default, :data:`FRAME_BAND`): every pixel takes the colour of
       the frames well exposed there, each frame read at its nearest pixel (``to_reference``)
       and decoded with ``decode``, mixed with weights ``band * exp(-|x - 0.5|^2 / (2
       frame_sigma^2))`` over the channels' levels ``x`` (:data:`FRAME_SIGMA`: the frame
       nearest mid-grey gives nearly all of it, smoothly in the levels): fully where some frame
       has every channel inside the band, fading over its ramp outside, where none is only
       steps 1-2 apply. So each frame's best-exposed regions have that frame's colour (the
       issue's target on every frame; the Xperia bracket: at most 0.0077 from each frame
       there, the sRGB merge 0.027). ``frame_band=None`` and ``reference_band`` (the previous
       default, :data:`REFERENCE_BAND`): the reference pixel's own colour where every channel
       of it is inside the band, elsewhere the reference's share of the blurred weights; this
       meets the reference exactly and misses the frames around it (Xperia: up to 0.053 from
       a frame where it is the best exposed).

    ``gains`` ``(N, 3)``: each frame's white balance against the reference
    (:func:`hdrcore.merge.white_balance.measure_white_balance`'s correction), divided out of
    its decoded colours in steps 2 and 3: one balance over the whole merge. Without,
    ``white_balance`` measures them here (median channel ratios to the reference, normalised
    to green; off by default).

    The pixel's luminance (Rec. 709 weights) is held fixed throughout. Where no frame is well
    exposed (clipped everywhere) only step 1 applies.
    """
    from scipy import ndimage

    from ..geometry import nearest_in_frame

    rad = radiance
    h, w = rad.shape[:2]
    gains_in = None
    if gains is not None:
        gains_in = np.asarray(gains, dtype=np.float64)
        if (
            gains_in.shape != (len(frames), 3)
            or not np.all(np.isfinite(gains_in))
            or np.any(gains_in <= 0)
        ):
            raise ParameterError(
                "gains must be (N, 3), finite and positive",
                expected=f"({len(frames)}, 3)",
                found=str(gains_in.shape),
            )
    table = np.asarray(decode, dtype=np.float64)
    if table.ndim == 1:
        table = np.tile(table, (3, 1))
    redecode = None
    log_t = None
    if lut is not None and exposure_times is not None and shares is not None:
        lt = np.asarray(lut, dtype=np.float64)
        lt = np.tile(lt, (3, 1)) if lt.ndim == 1 else lt
        redecode = _redecode_table(lt, table)
        log_t = np.log(np.asarray(exposure_times, dtype=np.float64))
    step = max(1, int(np.ceil(np.sqrt(h * w / max_samples))))
    gy = np.arange(step // 2, h, step)
    gx = np.arange(step // 2, w, step)
    ys_grid, xs_grid = np.meshgrid(gy, gx, indexing="ij")
    shape = ys_grid.shape
    ys = ys_grid.ravel()
    xs = xs_grid.ravel()

    def pixel_log_time(sh: np.ndarray) -> np.ndarray:
        if log_t is None:  # only called with the re-decoding, which sets log_t
            raise ParameterError("pixel_log_time needs the exposure times")
        s_ = sh.astype(np.float32)
        tot = s_.sum(axis=0)
        lt_ = np.tensordot(log_t.astype(np.float32), s_, axes=(0, 0))
        return np.where(tot > 0, lt_ / np.where(tot > 0, tot, 1), float(log_t.min()))

    def merge_cells() -> tuple[np.ndarray, np.ndarray]:
        merged = rad[ys, xs].astype(np.float64)
        if redecode is not None and shares is not None:  # redecode is only set with shares
            merged = _redecode(merged, pixel_log_time(shares[:, ys, xs]), redecode)
        msum = _sum3(merged)
        okm = np.isfinite(msum) & (msum > 0)
        return okm, np.where(okm[:, None], merged / np.where(okm, msum, 1.0)[:, None], 0.0)

    lo_w, hi_w = WELL_EXPOSED[0] * max_level, WELL_EXPOSED[1] * max_level

    def frame_cells(k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Frame ``k``'s decoded colour, weight and well-exposed flag on the grid, before the
        merge's own cells are known (``okm`` is applied after)."""
        f = frames[k]
        if to_reference is None or k == reference:
            xk, yk = xs, ys
            inside = np.ones(xs.size, bool)
        else:
            xk, yk, inside = nearest_in_frame(to_reference[k], xs, ys, (h, w))
        z = np.clip(np.asarray(f)[yk, xk].astype(np.intp), 0, max_level)
        x = z / float(max_level)
        # (reductions over the channels written out: numpy's over a last axis of three are
        # slow, 0.07 of this loop's 0.09 s on the 24 MP bench bracket's grid)
        wk = np.exp(-_sum3((x - 0.5) ** 2) / (2.0 * ANCHOR_SIGMA**2))
        ok = inside & _all3((z < saturation) & (z > noise_floor))
        if masks is not None and masks[k] is not None:
            ok &= np.asarray(masks[k], bool)[yk, xk]
        lin = np.stack([table[c][z[:, c]] for c in range(3)], axis=-1)
        wk = np.where(ok & (_sum3(lin) > 0), wk, 0.0)
        return lin, wk, ok & _all3((z > lo_w) & (z < hi_w))

    # the merge's cells and each frame's side by side (numpy's gathers and arithmetic release
    # the GIL); a cell the merge cannot colour is no frame's either
    parts: list[Any] = thread_map(
        lambda k: merge_cells() if k < 0 else frame_cells(k), range(-1, len(frames))
    )
    okm, qm = parts[0]
    lins = [c[0] for c in parts[1:]]
    weights = [np.where(okm, c[1], 0.0) for c in parts[1:]]
    wells = [c[2] & okm for c in parts[1:]]

    # per-frame white balance against the reference (median channel ratios over pixels well
    # exposed in both, normalised to green), divided out: one rendition of the colours
    frame_gains = [np.ones(3) for _ in frames]
    if gains_in is not None:
        frame_gains = [np.asarray(g, np.float64) for g in gains_in]
    elif white_balance and reference is not None:
        for k in range(len(frames)):
            both = wells[k] & wells[reference]
            if k == reference or both.sum() < 500:
                continue
            ratio = lins[k][both] / np.maximum(lins[reference][both], 1e-12)
            med = np.median(ratio, axis=0)
            if np.all(np.isfinite(med)) and np.all(med > 0):
                frame_gains[k] = med / med[1]

    if reference is not None:
        weights[reference] = weights[reference] * REFERENCE_BOOST
    ref_weight = None if reference is None else weights[reference]
    shares_out = [float(wk.sum()) for wk in weights]
    num_t, num_m, den = (_grid_sums if AVAILABLE else _grid_sums_numpy)(
        tuple(lins), tuple(weights), np.asarray(frame_gains, np.float64), qm
    )

    def blur(a: np.ndarray) -> np.ndarray:
        return ndimage.gaussian_filter(a.reshape(shape), ANCHOR_BLUR, mode="nearest").ravel()

    d = blur(den)
    target = np.stack([blur(num_t[:, c]) for c in range(3)], axis=-1)
    own = np.stack([blur(num_m[:, c]) for c in range(3)], axis=-1)
    good = (d > 1e-6 * max(float(d.max()), 1e-300)) & _all3(own > 0) & _all3(target > 0)
    # the same quotients as on the good cells alone (most of the grid): whole-array divisions
    # written where good, no gathered copies
    cells = np.zeros((ys.size, 4))
    cells[:, :3] = 1.0
    gain = cells[:, :3]
    np.divide(target, own, out=gain, where=good[:, None])
    dg = np.where(good, d, 1.0)[:, None]
    shift = np.hypot(*(target[:, :2] / dg - own[:, :2] / dg).T)[good]
    if ref_weight is not None:
        alpha = cells[:, 3]
        np.divide(blur(ref_weight), d, out=alpha, where=good)
        np.clip(alpha, 0.0, 1.0, out=alpha)
    fields = cells.reshape(*shape, 4)

    ref_frame = (
        None if reference is None or frame_band is not None else np.asarray(frames[reference])
    )
    own_fraction = 0.0
    # step 3's arguments, the same for the compiled rows and the numpy path
    band_kw: dict[str, Any] = dict(
        max_level=max_level,
        noise_floor=noise_floor,
        saturation=saturation,
        reference=reference,
        to_reference=to_reference,
        masks=masks,
        band=frame_band,
        sigma=frame_sigma,
    )
    if AVAILABLE:
        # steps 1-2 and 3 in one pass, steps 1-2 only where step 3 leaves some of their colour
        # (24 MP sRGB bench bracket: 84 % of the pixels take a frame's colour fully)
        steps12: dict[str, Any] = dict(
            fields=fields.astype(np.float32),
            step=step,
            shares=shares,
            log_t=log_t,
            redecode=redecode,
        )
        if frame_band is None:
            steps12.update(
                ref_frame=ref_frame,
                table=table,
                noise_floor=noise_floor,
                saturation=saturation,
                band=reference_band,
            )
        rows, counts = _pass_rows(
            rad,
            max_level=max_level,
            steps12=steps12,
            band_args=None
            if frame_band is None
            else _band_args(frames, table, frame_gains, **band_kw),
        )
        run_row_spans(h, None, rows)
        if frame_band is not None:
            own_fraction = float(sum(counts)) / float(h * w)
    else:  # pragma: no cover - exercised only without numba
        _apply_numpy(
            rad,
            fields,
            step,
            shares,
            log_t,
            redecode,
            ref_frame,
            table,
            noise_floor,
            saturation,
            max_level,
            rows_per_chunk,
            pixel_log_time,
            reference_band,
        )
        if frame_band is not None:
            own_fraction = _frame_band(
                rad, frames, table, frame_gains, **band_kw, rows_per_chunk=rows_per_chunk
            )
    return _anchor_result(step, shift, shares_out, decode_name, frame_gains, own_fraction)


#: Rows :func:`anchor_colour`'s per-pixel pass takes at a time when it converts shares that are
#: not float16 to float32 (float16 shares are read as their bits, without a conversion).
ANCHOR_CHUNK_ROWS = 32


def _anchor_result(
    step: int,
    shift: np.ndarray,
    shares_out: list[float],
    decode_name: str,
    frame_gains: Sequence[np.ndarray],
    own_fraction: float,
) -> ColourAnchor:
    total = max(sum(shares_out), 1e-300)
    return ColourAnchor(
        step=step,
        max_shift=float(shift.max()) if shift.size else 0.0,
        median_shift=float(np.median(shift)) if shift.size else 0.0,
        frame_shares=tuple(v / total for v in shares_out),
        decode=decode_name,
        white_balance=tuple(_triple(g) for g in frame_gains),
        own_colour_fraction=own_fraction,
    )


@dataclass(frozen=True)
class ColourResult:
    """The colour stage of a non-linear merge: the check of the merge as made (``before``),
    the local tone-mapping test, the frames' white balance
    (:class:`~hdrcore.merge.white_balance.FrameBalance`, ``applied`` when the merge was
    corrected), the anchoring (``None`` when off, or when the frames are linear-encoded:
    ``encoding``, :func:`frame_encoding`) and the check of the result (``after``);
    ``before`` and ``after`` are ``None`` when the colour was not measured (a draft)."""

    before: ColourCheck | None
    after: ColourCheck | None
    anchor: ColourAnchor | None
    local_tone_mapping: Any
    message: str
    white_balance: Any = None
    encoding: FrameEncoding | None = None
    pending: Callable[[], ColourResult] | None = field(default=None, repr=False, compare=False)

    def measured(self) -> ColourResult:
        """This result with its measurements made (itself when none is pending: see
        :func:`check_colour`'s ``report="later"``); they are made once, whoever asks first."""
        return self if self.pending is None else self.pending()

    def to_json(self) -> dict[str, Any]:
        return {
            "white_balance": None if self.white_balance is None else self.white_balance.to_json(),
            "frame_encoding": None if self.encoding is None else self.encoding.to_json(),
            "before": None if self.before is None else self.before.to_json(),
            "after": None if self.after is None else self.after.to_json(),
            "anchor": None if self.anchor is None else self.anchor.to_json(),
            "local_tone_mapping": None
            if self.local_tone_mapping is None
            else self.local_tone_mapping.to_json(),
            "message": self.message,
        }


@dataclass(frozen=True)
class FrameMeasures:
    """What :func:`check_colour` measures on the frames alone (:func:`measure_frames`): each
    frame's white balance against the reference
    (:class:`~hdrcore.merge.white_balance.FrameBalance`), the local tone mapping test and a
    dict the colour checks of merges of these frames fill with what they measure on the frames
    (:func:`colour_check`'s ``shared``)."""

    balance: Any
    local_tone_mapping: Any
    shared: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)


def measure_frames(
    frames: Sequence[np.ndarray],
    lut: np.ndarray,
    *,
    max_level: int,
    reference: int,
    to_reference: Sequence[np.ndarray] | None = None,
    masks: Sequence[np.ndarray | None] | None = None,
) -> FrameMeasures:
    """What :func:`check_colour` measures on the frames alone: each frame's white balance
    against the reference (:func:`hdrcore.merge.white_balance.measure_white_balance`) and the
    local tone mapping test (:func:`hdrcore.response.local_tonemap.local_tone_mapping`); see
    :class:`FrameMeasures`."""
    from ..response.local_tonemap import local_tone_mapping
    from .white_balance import measure_white_balance

    # two independent measurements of sampled pixels, mostly single-threaded numpy: side by
    # side on the workers (real Xperia bracket: 0.66-0.78 -> 0.49-0.60 s)
    balance, ltm = thread_map(
        lambda measure: measure(),
        [
            lambda: measure_white_balance(
                frames,
                lut,
                max_level=max_level,
                reference=reference,
                to_reference=to_reference,
                masks=masks,
            ),
            lambda: local_tone_mapping(
                frames, lut, max_level=max_level, to_reference=to_reference, reference=reference
            ),
        ],
    )
    return FrameMeasures(balance, ltm)


def check_colour(
    frames: Sequence[np.ndarray],
    radiance: np.ndarray,
    lut: np.ndarray,
    *,
    max_level: int,
    reference: int,
    saturation: float,
    noise_floor: float,
    to_reference: Sequence[np.ndarray] | None = None,
    masks: Sequence[np.ndarray | None] | None = None,
    anchor: bool = True,
    exposure_times: Sequence[float] | None = None,
    shares: np.ndarray | None = None,
    reference_band: tuple[float, float, float] | None = None,
    white_balance: bool = True,
    frame_band: tuple[float, float, float] | None = FRAME_BAND,
    frame_measures: FrameMeasures | None = None,
    report: bool | str = True,
) -> ColourResult:
    """Check a non-linear merge's colour, measure each frame's white balance
    (:func:`hdrcore.merge.white_balance.measure_white_balance`, with the merge's ``lut``) and
    (``white_balance``, with the merge's ``shares``) divide out the balance of the frames
    whose balance differs, test for local tone mapping, and (``anchor``) give the merge the
    frames' own colour (:func:`anchor_colour`, frames decoded with sRGB, as a screen shows
    them, their balance divided out alike), then check it again. ``radiance`` is modified in
    place.

    ``report=False`` (a draft, whose picture is all that is shown): the merge's colour is not
    measured before and after (``before`` and ``after`` are ``None``); the pixels are the same.
    ``report="later"``: the merge's pixels on the checks' grid are taken before and after
    (:class:`RadianceSamples`, a few MB) and measured when :meth:`ColourResult.measured` is
    called (``pending`` until then): the pixels are ready 0.3-0.55 s sooner on the 24 MP
    sRGB bench bracket, the measurements are the same numbers.

    ``frame_measures``: :func:`measure_frames` of the same frames, ``lut``, ``reference``,
    ``to_reference`` and ``masks`` when known already (they read neither the merge nor its
    levels: a saturation step keeps them)."""
    from .white_balance import correct_merge

    if report not in (True, False, "later"):
        raise ParameterError(f"unknown colour report {report!r}", expected="True, False, 'later'")
    later = report == "later"
    measure = report is True
    kw: dict[str, Any] = dict(
        max_level=max_level, reference=reference, to_reference=to_reference, masks=masks
    )
    if frame_measures is None:
        frame_measures = measure_frames(frames, lut, **kw)
    balance, ltm, shared = (
        frame_measures.balance,
        frame_measures.local_tone_mapping,
        frame_measures.shared,
    )
    # what the check before reads: the merge itself, or its pixels on the grid (later)
    as_made: np.ndarray | RadianceSamples = radiance
    if later:
        as_made = RadianceSamples.of(radiance, CHECK_SAMPLES)
    before = (
        colour_check(frames, radiance, lut, **kw, balance=balance, shared=shared)
        if measure
        else None
    )
    correction = balance.correction()
    if white_balance and balance.differs and shares is not None:
        correct_merge(radiance, shares, correction)
        balance = replace(balance, applied=True)
    done = None
    encoding = frame_encoding(lut)
    unanchored = anchor and encoding.linear  # asked for, not applied: why is said below
    if anchor and not unanchored:
        done = anchor_colour(
            radiance,
            frames,
            srgb_decode_lut(max_level),
            max_level=max_level,
            saturation=saturation,
            noise_floor=noise_floor,
            to_reference=to_reference,
            masks=masks,
            reference=reference,
            lut=lut,
            exposure_times=exposure_times,
            shares=shares,
            reference_band=reference_band,
            gains=balance.correction(every_measured=False) if balance.applied else None,
            frame_band=frame_band,
        )
    changed = done is not None or balance.applied
    parts = dict(
        balance=balance,
        ltm=ltm,
        encoding=encoding,
        anchored=done,
        unanchored=unanchored,
        reference=reference,
    )
    if later:
        final: np.ndarray | RadianceSamples = (
            RadianceSamples.of(radiance, CHECK_SAMPLES) if changed else as_made
        )

        def finish() -> ColourResult:
            first = colour_check(frames, as_made, lut, **kw, balance=balance, shared=shared)
            second = (
                colour_check(frames, final, lut, **kw, balance=balance, shared=shared)
                if changed
                else first
            )
            return _colour_result(first, second, **parts)

        return replace(_colour_result(None, None, **parts, pending=True), pending=Once(finish))
    after = before
    if measure and changed:
        after = colour_check(frames, radiance, lut, **kw, balance=balance, shared=shared)
    return _colour_result(before, after, **parts)


def _colour_result(
    before: ColourCheck | None,
    after: ColourCheck | None,
    *,
    balance: Any,
    ltm: Any,
    encoding: FrameEncoding,
    anchored: ColourAnchor | None,
    unanchored: bool,
    reference: int,
    pending: bool = False,
) -> ColourResult:
    """:func:`check_colour`'s result and its message (``pending``: measured later)."""
    parts = []
    if balance.applied:
        parts.append("white balance corrected: " + balance.message)
    else:
        parts.append(balance.message)
    if unanchored:
        parts.append(
            "colour not anchored: the frames are linear-encoded (their response is "
            f"{encoding.from_linear:.3f} from linear, {encoding.from_srgb:.3f} from sRGB), so "
            "the merge holds their colour; anchoring to their sRGB decoding would distort it"
        )
    if before is None or after is None:
        if not unanchored:
            parts.append(
                "colour anchored to the frames" if anchored is not None else "colour not anchored"
            )
        parts.append("being measured" if pending else "not measured (a draft)")
    elif anchored is not None:
        best = [
            f.best_error_balanced for f in after.frame_colours if np.isfinite(f.best_error_balanced)
        ]
        parts.append(
            "colour anchored to the frames (sRGB-decoded: each pixel the colour of the frames "
            "well exposed there, the one nearest mid-grey first): median error against each "
            "frame where it is the best exposed at most "
            + (f"{max(best):.4f}" if best else "n/a")
            + f"; against reference frame {reference} "
            f"{before.merge_error_srgb:.4f} -> {after.merge_error_srgb:.4f}"
        )
    else:
        parts.append(after.message)
    parts.append(ltm.message)
    return ColourResult(
        before=before,
        after=after,
        anchor=anchored,
        local_tone_mapping=ltm,
        message="; ".join(parts),
        white_balance=balance,
        encoding=encoding,
    )
