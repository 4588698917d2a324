"""One registration problem (a consecutive pair): preparation, the eq. 6/7 cost, the common driver.

Private: the public entry points are :func:`hdrcore.registration.register_pair` and the method
modules. Every method shares this driver, so the status checks, the eq. 5 start, the reported
costs and the previews are computed the same way whatever the search.

The cost (Cerman & Hlavac 2006, section 6). With ``a`` the bright frame and ``b = k * dark``
the dark frame times the exposure ratio ``k``, both linear, and ``A`` the pair matrix (bright ->
dark coordinates, ``B = A^-1``), the normalised difference of a pixel (eq. 7) and the cost of a
transform (eq. 6) are::

    n(x) = (a(B x) - b(x)) / max(a(B x) + b(x), t)                      (eq. 7)
    C(A) = mean over x in V(A) of n(x)^2                                   (eq. 6)

summed over pixels ``x`` of the dark frame's grid. ``V``: pixels whose ``b`` lies inside the
exposure range both frames share, whose bright-frame interpolation support (4x4 raw taps of the
cubic kernel) is neither saturated nor below the noise floor and has no edge steeper than
``MAX_CONTRAST``, and which land inside the bright frame. ``t`` (the threshold,
given as a fraction of the saturation level) keeps the normalisation from amplifying noise in
the darkest pixels. We take the mean rather than the sum so that costs of different overlaps
compare. This is our reading of eqs. 6-7: the seed normalises the difference by the pair's
brightness so that bright pixels do not dominate and discards badly exposed pixels in both
frames.

A cost that is continuous in the motion. Testing the 16 taps at ``B x`` for every new ``B`` (the
first version) makes ``V`` jump whenever a sample's support crosses a pixel boundary: on a
simulated 8-bit pair (patches scene, ratio 16, noise 3 levels, moved 0.45 px) the cost rose by
3.2e-4 between ``dy = -0.01`` and ``0`` where it otherwise changes by 2e-5 per 0.01 px, and the
search stalled at exactly the eq. 5 start (an identity reported "converged"). So ``V`` is decided
once per pyramid level, on the dark frame's grid, at the level's starting motion
(:func:`select_samples`; a search that moves more than half a pixel from there decides it again,
once, and goes on: samples chosen at a wrong motion pull the minimum towards it, 0.23 px at the
corners for a Nelder-Mead search kept on the samples of its eq. 5 start, 0.007 px when they are
chosen again). While the motion changes
the bright frame's taps are only clipped to their valid range (continuous) and a sample's
weight falls linearly to 0 over the last ``BORDER_RAMP`` pixels before its support leaves the
bright frame, so the cost is a continuous (almost everywhere smooth) function of the motion: on
the same pair its steps are 1.3e-5 per 0.01 px with no jump, and the search finds dy = 0.47.
We chose this over smooth per-tap weights near the noise floor and ``Z``: it keeps the seed's
hard "discard" semantics, costs one pass over the candidates per level, and removes the per-tap
range tests from the inner loop.

Why the dark frame stays on its grid (and the bright frame is interpolated): after the
multiplication by ``k`` the dark frame is the noisier one, and interpolation lowers the variance
of noise by an amount that depends on the sub-pixel phase; interpolating the noisy frame pulls
the minimum of eq. 6 towards half-pixel shifts (measured on simulated 8-bit pairs 384x256, noise
floor 3 levels, t = 0.02: mean corner error 0.116 px with the bright frame on its grid, 0.025 px
with the dark frame on its grid). The searches therefore estimate ``B`` and the driver returns
``A = B^-1``.

Speed: the pyramid's level 1, the sample scoring and the eq. 6 sums with their normal equations
run in compiled kernels (:mod:`hdrcore.registration._kernels`), the only form that runs (numba
is a dependency); their readable specifications, which the tests hold them to, are in
:mod:`hdrcore.registration.spec` (used by the tests only).
Frames may also be integer levels read through a table (``lut``), e.g. the green channel view
of the raw RGB frames, so no linear copy of a 24-megapixel frame is needed.
"""

from __future__ import annotations

import inspect
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import ParameterError, validate_method
from ..geometry import (
    affine_part,
    apply,
    corner_error,
    homogeneous,
    identity,
    invert,
    scale_matrix,
    similarity_parameters,
)
from ..status import RegistrationStatus
from . import _kernels
from ._memo import array_key, table_key
from .fourier import FourierShift, cross_correlation_shift
from .result import PairPreview, PairRegistration

__all__ = [
    "MODELS",
    "AFFINE_MODELS",
    "PairData",
    "prepare",
    "register_with",
    "Samples",
    "RefineResult",
    "cost",
    "normal_equations",
    "motion_update",
]

log = logging.getLogger(__name__)

#: Motion models and their number of parameters. They nest: each adds Jacobian columns (motion
#: generators, see :func:`motion_update`) to the one before: shift (x, y), euclidean (+ rotation),
#: similarity (+ scale), homography (+ stretch, shear and the two perspective terms).
MODELS = {"shift": 2, "euclidean": 3, "similarity": 4, "homography": 8}

#: A pair whose residual cannot be measured (no confident tile) is ``weak`` rather than ``ok``
#: when its motion moves a corner by more than this (px): the memorial film scans without
#: exposure times put three near-black pairs of a tripod bracket 16-146 px apart, unmeasurably.
UNVERIFIED_PX = 1.0

#: The models whose motion is affine (a 2x3 ``matrix`` besides the 3x3 ``homography``).
AFFINE_MODELS = ("shift", "euclidean", "similarity")

#: Width (pixels of the level) over which a sample's weight falls to 0 as its interpolation
#: support reaches the border of the bright frame: the cost stays continuous in the motion.
BORDER_RAMP = 2.0

_SMALL = 1 << 20  # frames up to this many pixels keep their clipped full-resolution copy

#: Samples whose interpolation support in the bright frame spans more than this contrast are left
#: out of eq. 6: across such an edge (a window frame against the sky) the cubic kernel's
#: overshoot, and the difference between interpolating linear and log values, exceed any noise.
MAX_CONTRAST = 4.0


@dataclass
class PairData:
    """A prepared pair: raw frames, the exposure range they share, clipped pyramids.

    With ``lut`` (float32, one entry per possible value of the integer frames) ``dark`` and
    ``bright`` hold integer levels and ``lut[level]`` is the linear value.
    """

    dark: np.ndarray
    bright: np.ndarray
    ratio: float
    saturation: float
    noise_floor: float
    threshold: float  # absolute (linear units)
    lo: float  # common range in bright-frame units: [noise * max(1, k), saturation * min(1, k)]
    hi: float
    # levels[l] = (bright_l, k*dark_l) clipped to [lo, hi]; levels[0] is None for large frames
    levels: list = field(default_factory=list)
    lut: np.ndarray | None = None
    # select_samples' candidates, which do not depend on the motion: a search selects again at
    # each level's start, after moving and for a re-fit (each 1 M candidates at 24 MP)
    candidates: dict = field(default_factory=dict, repr=False, compare=False)

    def linear(self, frame: np.ndarray) -> np.ndarray:
        """A raw frame (``self.dark`` or ``self.bright``) as linear float values."""
        return frame if self.lut is None else self.lut[frame]

    @property
    def shape(self) -> tuple[int, int]:
        return self.bright.shape

    def level_shape(self, level: int) -> tuple[int, int]:
        h, w = self.shape
        for _ in range(level):
            h, w = h // 2, w // 2
        return h, w

    def clipped(self, level: int) -> tuple[np.ndarray, np.ndarray]:
        if self.levels[level] is None:  # full resolution of a large frame: clip on demand
            k = self.ratio
            a = np.clip(self.linear(self.bright), self.lo, self.hi).astype(np.float32)
            b = np.clip(self.linear(self.dark) * np.float32(k), self.lo, self.hi).astype(np.float32)
            return a, b
        return self.levels[level]


def _as_image(x: np.ndarray, name: str, lut: np.ndarray | None = None) -> np.ndarray:
    arr = np.asarray(x)
    if arr.ndim != 2:
        raise ParameterError(
            f"the {name} frame must be a single-channel 2-D image",
            expected="(H, W) linear values" if lut is None else "(H, W) integer levels",
            found=f"shape {arr.shape}",
        )
    if lut is not None:
        if arr.dtype not in (np.uint8, np.uint16):
            raise ParameterError(
                f"with a linearisation table the {name} frame must hold integer levels",
                expected="uint8 or uint16",
                found=str(arr.dtype),
            )
        return arr
    if arr.dtype not in (np.float32, np.float64):
        arr = arr.astype(np.float32)
    return arr


def _as_lut(lut: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """The table as float32, extended to every value of ``dtype`` (levels past its end read
    its last entry), so no level can index outside it."""
    table = np.asarray(lut, np.float32)
    if table.ndim != 1 or table.size < 2 or not np.all(np.isfinite(table)):
        raise ParameterError(
            "the linearisation table must be a 1-D array of finite linear values",
            found=f"shape {table.shape}",
        )
    n = int(np.iinfo(dtype).max) + 1
    if table.size < n:
        table = np.concatenate([table, np.full(n - table.size, table[-1], np.float32)])
    return np.ascontiguousarray(table[:n])


def prepare(
    dark: np.ndarray,
    bright: np.ndarray,
    ratio: float,
    *,
    saturation: float,
    noise_floor: float,
    threshold: float,
    min_level_size: int = 12,
    lut: np.ndarray | None = None,
    memo: Any = None,
) -> PairData:
    """Validate a pair and build the clipped, exposure-equalised pyramids.

    ``lut``: the frames hold integer levels (uint8 or uint16, e.g. a channel view of the raw
    RGB frames, any strides) and ``lut[level]`` is the linear value; no linear copy of the
    frames is made. ``memo`` (a :class:`~hdrcore.registration._memo.RunMemo`): pyramids of
    the same frames, table, ratio and range made before are taken from it (they do not depend
    on the threshold).
    """
    dark = _as_image(dark, "dark", lut)
    bright = _as_image(bright, "bright", lut)
    if lut is not None:
        if dark.dtype != bright.dtype:
            raise ParameterError(
                "dark and bright levels differ in type",
                expected=str(bright.dtype),
                found=str(dark.dtype),
            )
        lut = _as_lut(lut, dark.dtype)
    if dark.shape != bright.shape:
        raise ParameterError(
            "dark and bright frames differ in size",
            expected=str(bright.shape),
            found=str(dark.shape),
        )
    if min(dark.shape) < 16:
        raise ParameterError(
            "frames too small to register", expected=">= 16x16", found=str(dark.shape)
        )
    k = float(ratio)
    if not np.isfinite(k) or k <= 0:
        raise ParameterError("exposure ratio must be finite and positive", found=str(ratio))
    sat = float(saturation)
    nf = float(noise_floor)
    if not (np.isfinite(sat) and sat > 0):
        raise ParameterError("saturation level must be positive", found=str(saturation))
    if not (np.isfinite(nf) and 0 <= nf < sat):
        raise ParameterError(
            "noise floor must be >= 0 and below the saturation level",
            expected=f"0 <= noise_floor < {sat}",
            found=str(noise_floor),
        )
    if not (np.isfinite(threshold) and threshold >= 0):
        raise ParameterError("normalisation threshold t must be >= 0", found=str(threshold))
    lo = max(nf * max(1.0, k), float(np.finfo(np.float32).tiny))
    hi = sat * min(1.0, k)
    data = PairData(dark, bright, k, sat, nf, float(threshold) * sat, lo, hi, lut=lut)
    if lo >= hi:
        data.levels = [None]
        return data
    key: tuple | None = None
    if memo is not None:
        key = (
            "pyramid",
            array_key(dark),
            array_key(bright),
            k,
            lo,
            hi,
            table_key(lut),
            min_level_size,
        )
        hit = memo.get(key)
        if hit is not None:
            data.levels = hit[2]
            return data
    levels: list = [None]  # full resolution: a clipped copy for small frames only
    if dark.size <= _SMALL:
        a0 = np.clip(data.linear(bright), lo, hi).astype(np.float32, copy=False)
        b0 = np.multiply(data.linear(dark), np.float32(k), dtype=np.float32)
        np.clip(b0, lo, hi, out=b0)
        levels[0] = (a0, b0)
    h, w = dark.shape
    if min(h, w) // 2 < min_level_size:
        data.levels = levels
        return data
    # level 1 straight from the raw frames: one read, no full-size copy
    a = np.empty((h // 2, w // 2), np.float32)
    b = np.empty_like(a)
    _kernels.bin_clip(bright, lut, 1.0, lo, hi, a)
    _kernels.bin_clip(dark, lut, k, lo, hi, b)
    levels.append((a, b))
    while min(a.shape) // 2 >= min_level_size:
        a, b = _reduce2(a), _reduce2(b)
        levels.append((a, b))
    data.levels = levels
    if memo is not None:
        memo[key] = (dark, bright, levels)  # the frames kept alive: their keys are addresses
    return data


def _reduce2(image: np.ndarray) -> np.ndarray:
    out = np.empty((image.shape[0] // 2, image.shape[1] // 2), np.float32)
    _kernels.reduce2(image, out)
    return out


@dataclass
class Samples:
    """Sample points on the dark frame's grid of one pyramid level, with ``b = k * dark`` there."""

    x: np.ndarray
    y: np.ndarray
    b: np.ndarray
    well_exposed: float = 1.0  # fraction of the candidate pixels that were well exposed


def select_samples(
    data: PairData,
    level: int,
    max_samples: int,
    *,
    motion: np.ndarray | None = None,
    by_gradient: bool = True,
    seed: int = 0,
    max_contrast: float = MAX_CONTRAST,
    check_bright: bool = True,
    reach: int = 0,
    exclude: np.ndarray | None = None,
) -> Samples:
    """Up to ``max_samples`` valid eq. 6 samples on the dark frame's grid of ``level``, in raster
    order, their validity decided once for the level at ``motion``.

    A pixel of the dark frame is a sample when ``k * dark``, there and averaged over its four
    neighbours (see ``_kernels.score_candidates``), lies strictly inside the exposure range
    both frames share and, at ``motion`` (3x3 or 2x3, level coordinates, dark -> bright;
    default the identity), the 4x4 interpolation support of the bright frame lies inside it,
    spans at most ``max_contrast`` and (full resolution; the coarser levels are clipped
    already) holds raw taps above the noise floor and, widened by ``reach`` pixels, below
    saturation: no motion within ``reach`` pixels of ``motion`` brings a saturated tap into the
    sample's interpolation (a clipped highlight biases eq. 6 far more than a tap under the
    noise floor, which is only noisy). The searches call this once per pyramid level with
    their estimate at the start of the level and keep the samples while the motion changes:
    nothing in the cost then switches on or off but a border weight that goes smoothly to 0,
    so the cost is continuous in the motion (module docstring).

    The dark frame stays on its pixel grid and the bright frame is interpolated: after the
    multiplication by ``k`` the dark frame is the noisier one, and interpolating noise lowers its
    variance by an amount that depends on the sub-pixel phase, which would pull the eq. 6 minimum
    towards half-pixel shifts. Candidates are all interior pixels or, on large levels,
    ``4 * max_samples`` of them spread over the frame: the interior is cut in raster order into
    equal runs and one pixel of each run is taken at an offset from the golden-ratio sequence
    (``seed`` shifts it). With ``by_gradient`` the valid candidates with the largest relative
    gradient are kept (the informative ones); otherwise about ``max_samples`` valid candidates
    are drawn the same way (more candidates on a mostly badly exposed frame) and a seeded random
    subset of ``max_samples`` is kept. ``well_exposed`` is the fraction of candidates that are
    valid. ``check_bright=False`` leaves the bright frame out (the dark frame's side only).
    ``exclude``: rectangles ``(K, 4)`` of ``x0, y0, x1, y1`` in full-resolution dark-frame
    pixels whose pixels are never samples (a near object found by the residual check, see
    :func:`register_with`). The candidates and the bright frame's side are compiled
    (``_kernels.score_candidates``, ``_kernels.support_valid``; their readable specifications,
    used only by the tests, are in :mod:`hdrcore.registration.spec`).
    """
    if level == 0:
        img, lut, k = data.dark, data.lut, data.ratio
        lo, hi = data.lo / k, data.hi / k  # the shared range in dark-frame units
        bright = data.bright
    else:
        img, lut, lo, hi, k = data.levels[level][1], None, data.lo, data.hi, 1.0
        bright = data.levels[level][0]
    m_motion = np.eye(3) if motion is None else homogeneous(motion)
    rects = None
    if exclude is not None and len(exclude):
        rects = np.asarray(exclude, np.float64).reshape(-1, 4)
    h, w = img.shape
    m = 2
    inner_w = w - 2 * m
    n_inner = (h - 2 * m) * inner_w
    n_cand = min(n_inner, 4 * max_samples if by_gradient else max_samples)
    phase = (seed * 0.7548776662466927) % 1.0
    eps2 = (data.threshold / k) ** 2
    contrast = float(max_contrast or 0.0)

    def bright_ok(xx: np.ndarray, yy: np.ndarray) -> np.ndarray:
        out = np.empty(xx.size, np.bool_)
        _kernels.support_valid(
            bright,
            lut,
            xx.astype(np.float64),
            yy.astype(np.float64),
            m_motion,
            level == 0,
            data.noise_floor,
            data.saturation,
            contrast,
            int(reach),
            out,
        )
        return out

    def scored(n_cand: int):
        """The well-exposed candidates of the dark frame's side, in raster order (cached)."""
        key = (level, n_cand, phase, by_gradient, None if rects is None else rects.tobytes())
        hit = data.candidates.get(key)
        if hit is not None:
            return hit
        yy = np.empty(n_cand, np.int64)
        xx = np.empty(n_cand, np.int64)
        v = np.empty(n_cand)
        score = np.empty(n_cand if by_gradient else 0)
        n = _kernels.score_candidates(
            img, lut, n_cand, m, phase, lo, hi, eps2, by_gradient, yy, xx, v, score
        )
        yy, xx, v, score = yy[:n], xx[:n], v[:n], score[:n]
        if rects is not None and yy.size:
            fx = (xx + 0.5) * (1 << level) - 0.5  # level -> full-resolution coordinates
            fy = (yy + 0.5) * (1 << level) - 0.5
            out = np.zeros(yy.size, bool)
            for x0, y0, x1, y1 in rects:
                out |= (fx >= x0) & (fx < x1) & (fy >= y0) & (fy < y1)
            keep_c = ~out
            yy, xx, v = yy[keep_c], xx[keep_c], v[keep_c]
            if score.size:
                score = score[keep_c]
        data.candidates[key] = hit = (yy, xx, v, score)
        return hit

    def candidates(n_cand: int):
        yy, xx, v, score = scored(n_cand)
        if not check_bright:
            return yy, xx, v, score
        n_top = int(1.3 * max_samples)
        if by_gradient and v.size > n_top:
            # the bright frame's side only for the best-scoring candidates (it is the slower
            # test): the top 1.3 max_samples, then the others if too few of those pass
            top = _raster(np.argpartition(score, -n_top)[-n_top:], v.size)
            ok = bright_ok(xx[top], yy[top])
            if np.count_nonzero(ok) < max_samples:
                rest = np.ones(v.size, bool)
                rest[top] = False
                others = np.flatnonzero(rest)
                passed = others[bright_ok(xx[others], yy[others])]
                top = _raster(np.concatenate([top[ok], passed]), v.size)
            else:
                top = top[ok]
            return yy[top], xx[top], v[top], score[top]
        ok = bright_ok(xx, yy)
        return yy[ok], xx[ok], v[ok], score[ok] if by_gradient else score

    yy, xx, v, score = candidates(n_cand)
    if not by_gradient and 0 < v.size < max_samples and n_cand < n_inner:
        # a random subset is meant to hold max_samples valid pixels: on a mostly dark
        # or saturated frame, draw proportionally more candidates (once)
        n_cand = min(n_inner, int(n_cand * 1.05 * max_samples / v.size) + 1)
        yy, xx, v, score = candidates(n_cand)
    well_exposed = v.size / n_cand if n_cand else 0.0
    keep = None
    if by_gradient and v.size > max_samples:
        keep = np.argpartition(score, -max_samples)[-max_samples:]
    elif v.size > max_samples:
        keep = np.random.default_rng(seed).choice(v.size, max_samples, replace=False)
    if keep is not None:
        keep = _raster(keep, v.size)  # the searches' reads stay local in memory
        yy, xx, v = yy[keep], xx[keep], v[keep]
    return Samples(xx.astype(np.float64), yy.astype(np.float64), k * v, well_exposed)


def _raster(idx: np.ndarray, n: int) -> np.ndarray:
    """Distinct indices into ``n`` candidates, in increasing (raster) order: a mask read back,
    cheaper than sorting a large fraction of ``n``."""
    mask = np.zeros(n, bool)
    mask[idx] = True
    return np.flatnonzero(mask)


def _frame(data: PairData, level: int, ramp: float = BORDER_RAMP) -> np.ndarray:
    """``(lo, hi, t, cx, cy, unit, ramp)`` of a level (see ``_kernels.gauss_newton_sums``).

    ``lo, hi``: the range the bright frame's taps are clipped to: its own valid range at full
    resolution, the shared range (the pyramid's) on coarser levels.
    """
    h, w = data.level_shape(level)
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    unit = max(float(np.hypot(cx, cy)), 1.0)
    lo, hi = (data.noise_floor, data.saturation) if level == 0 else (data.lo, data.hi)
    return np.array([lo, hi, data.threshold, cx, cy, unit, ramp])


def sample_residuals(
    data: PairData,
    level: int,
    inverse: np.ndarray,
    s: Samples,
    *,
    ramp: float = BORDER_RAMP,
    gain: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Each sample's eq. 7 residual ``n`` and border weight (both 0 where its support is
    outside the bright frame) under ``inverse`` (dark -> bright, level coordinates) and
    ``gain``, from the kernel of :func:`normal_equations` (``per_sample``)."""
    m = homogeneous(inverse)
    g = np.zeros(3) if gain is None else np.asarray(gain, np.float64)
    per = np.zeros((s.x.size, 2))
    _kernels.gauss_newton_sums(
        data.bright if level == 0 else data.levels[level][0],
        data.lut if level == 0 else None,
        s.x,
        s.y,
        s.b,
        m,
        _frame(data, level, ramp),
        2,
        False,
        np.zeros((2, 2)),
        np.zeros(2),
        g,
        0,
        0.0,
        per,
    )
    return per[:, 0], per[:, 1]


def normal_equations(
    data: PairData,
    level: int,
    inverse: np.ndarray,
    s: Samples,
    *,
    n_par: int = 3,
    gradient: bool = True,
    ramp: float = BORDER_RAMP,
    gain: np.ndarray | None = None,
    n_gain: int = 0,
    robust: float = 0.0,
) -> tuple[float, float, np.ndarray, np.ndarray]:
    """Eq. 6 sum over the samples and its Gauss-Newton normal equations in one pass.

    ``inverse`` (2x3 or 3x3, level coordinates, dark -> bright) is the current motion; the
    Jacobian columns are the derivatives of the eq. 7 residuals along the first ``n_par``
    generators of :func:`motion_update` applied on the bright side (translations in pixels,
    the others in units of the level's half-diagonal). Returns ``(sum w n^2, sum w, J'WJ
    (n_par x n_par), J'Wn (n_par))`` with ``w`` the border weights; with ``gradient=False`` the
    matrices are zeros. Compiled (``_kernels.gauss_newton_sums``; its readable specification,
    used only by the tests: :func:`hdrcore.registration.spec.gauss_newton_sums`).

    ``gain`` ``(g0, g1, g2)`` (default 0): the bright frame is compared multiplied by
    ``exp(g0 + g1 X + g2 Y)`` (``X, Y`` as the generators'): a correction of the exposure
    ratio and a linear change of it across the frame (a phone's local tone mapping or
    vignetting correction). With ``n_gain`` (1: ``g0``; 3: all) these are ``n_gain`` more
    unknowns after the motion's: the matrices are ``n_par + n_gain`` square. ``robust`` (``c``
    > 0): Cauchy's loss ``c^2 log(1 + n^2 / c^2)`` instead of ``n^2`` (samples far off the
    fit, a second plane or a moving object, weigh less); the first value is then its sum.
    """
    if n_gain not in (0, 1, 3):
        raise ParameterError("the gain has 0, 1 or 3 free coefficients", found=str(n_gain))
    m = homogeneous(inverse)
    frame = _frame(data, level, ramp)
    g = np.zeros(3) if gain is None else np.asarray(gain, np.float64)
    n_tot = n_par + n_gain
    hess = np.zeros((n_tot, n_tot))
    grad = np.zeros(n_tot)
    img = data.bright if level == 0 else data.levels[level][0]
    ssum, wsum = _kernels.gauss_newton_sums(
        img,
        data.lut if level == 0 else None,
        s.x,
        s.y,
        s.b,
        m,
        frame,
        n_par,
        gradient,
        hess,
        grad,
        g,
        n_gain,
        float(robust),
        None,  # no per-sample output
    )
    return float(ssum), float(wsum), hess, grad


def motion_update(delta: np.ndarray, shape_l: tuple[int, int]) -> np.ndarray:
    """The 3x3 motion (level pixels, bright frame -> bright frame) of a Gauss-Newton step.

    ``delta`` holds 2, 3, 4 or 8 coefficients of the generators of
    ``_kernels.gauss_newton_sums``: shift x, y (pixels), rotation (radians), log scale, stretch,
    shear and the two perspective terms (in units of the level's half-diagonal ``unit``, about
    its centre ``c``). Up to 4 coefficients the update is the exact similarity
    ``c + delta_xy + e^sigma R(theta) (q - c)`` (so shift, euclidean and similarity searches stay
    in their model); 8 give the homography ``I + sum delta_i E_i`` in normalised coordinates.
    The estimate is updated on the bright side: ``B <- G(delta) B``.
    """
    d = np.zeros(8)
    d[: len(delta)] = delta
    h, w = shape_l
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    unit = max(float(np.hypot(cx, cy)), 1.0)
    if len(delta) <= 4:
        sc = np.exp(d[3])
        c, s = sc * np.cos(d[2]), sc * np.sin(d[2])
        return np.array(
            [
                [c, -s, cx - (c * cx - s * cy) + d[0]],
                [s, c, cy - (s * cx + c * cy) + d[1]],
                [0.0, 0.0, 1.0],
            ]
        )
    g = np.array(
        [
            [1.0 + d[3] + d[4], -d[2] + d[5], d[0] / unit],
            [d[2] + d[5], 1.0 + d[3] - d[4], d[1] / unit],
            [d[6], d[7], 1.0],
        ]
    )
    norm = np.array([[1 / unit, 0.0, -cx / unit], [0.0, 1 / unit, -cy / unit], [0.0, 0.0, 1.0]])
    back = np.array([[unit, 0.0, cx], [0.0, unit, cy], [0.0, 0.0, 1.0]])
    out = back @ g @ norm
    return out / out[2, 2]


def corner_move(a: np.ndarray, b: np.ndarray, shape_l: tuple[int, int]) -> float:
    """The largest distance (pixels) between the four corners mapped by ``a`` and ``b``."""
    return float(corner_error(a, b, shape_l).max())


def cost(
    data: PairData, level: int, inverse: np.ndarray, s: Samples, gain: np.ndarray | None = None
) -> tuple[float, float]:
    """Eq. 6 cost (weighted mean squared eq. 7 difference) and the sum of the sample weights
    (the number of samples that the motion keeps inside the bright frame).

    ``inverse`` maps dark-frame coordinates to the bright frame (see :func:`residuals`).
    """
    ssum, count, _, _ = normal_equations(data, level, inverse, s, gradient=False, gain=gain)
    if count <= 0:
        return float("inf"), 0.0
    return ssum / count, count


def overlap_fraction(matrix: np.ndarray, shape: tuple[int, int], grid: int = 64) -> float:
    """Fraction of the bright frame mapped inside the dark frame by ``matrix``."""
    h, w = shape
    yy, xx = np.meshgrid(np.linspace(0, h - 1, grid), np.linspace(0, w - 1, grid), indexing="ij")
    qx, qy = apply(matrix, xx, yy)
    return float(np.mean((qx >= 0) & (qx <= w - 1) & (qy >= 0) & (qy <= h - 1)))


def level_matrix(matrix: np.ndarray, level: int) -> np.ndarray:
    """Full-resolution matrix expressed on pyramid ``level`` (and back with negative levels)."""
    return scale_matrix(matrix, 2.0 ** (-level)) if level else np.asarray(matrix, float)


@dataclass
class RefineResult:
    matrix: np.ndarray
    iterations: int
    cost_history: list[float]
    level_history: list[int]
    message: str = ""
    gain: tuple[float, ...] = ()  # (g0, g1, g2) of the gain refined with the motion, if any


Refiner = Callable[..., RefineResult]


def _tone(v: np.ndarray, lo: float, hi: float) -> np.ndarray:
    t = (np.log(np.clip(v, lo, hi)) - np.log(lo)) / max(np.log(hi) - np.log(lo), 1e-12)
    return np.clip(t, 0.0, 1.0)


def make_preview(data: PairData, matrix: np.ndarray, size: int = 320) -> PairPreview | None:
    """Red/cyan overlays and eq. 7 difference maps before/after, at <= ``size`` pixels."""
    if data.levels[0] is None and len(data.levels) == 1:
        return None
    level = 0
    while level + 1 < len(data.levels) and max(data.level_shape(level)) > size:
        level += 1
    a, b = data.clipped(level)
    h, w = a.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    t = data.threshold
    src = np.ascontiguousarray(b, np.float32)[..., None]
    out = []
    for m in (identity(), matrix):
        ml = homogeneous(level_matrix(m, level))
        # b read (Keys, compiled) where its 4x4 support lies inside the frame
        qx, qy = apply(ml, xx, yy)
        with np.errstate(invalid="ignore"):
            ix, iy = np.floor(qx), np.floor(qy)
            inside = (ix >= 1) & (ix <= w - 3) & (iy >= 1) & (iy <= h - 3)
        read = np.empty((h, w, 1), np.float32)
        _kernels.warp_rows(src, ml, 0, h, read)  # a preview: <= size pixels a side
        bw = np.where(inside, read[..., 0], data.lo)
        valid = inside & (a > data.lo) & (a < data.hi) & (bw > data.lo) & (bw < data.hi)
        diff = np.where(valid, (a - bw) / np.maximum(a + bw, max(t, 1e-30)), np.nan)
        ta, tb = _tone(a, data.lo, data.hi), _tone(bw, data.lo, data.hi)
        tb = np.where(inside, tb, 0.0)
        rgb = np.stack([ta, tb, tb], axis=-1)
        out.append(((rgb * 255 + 0.5).astype(np.uint8), diff.astype(np.float32)))
    scale = 2.0 ** (-level)
    return PairPreview(scale, out[0][0], out[1][0], out[0][1], out[1][1])


def _fft_level(data: PairData, fft_size: int) -> int:
    level = 0
    while level + 1 < len(data.levels) and max(data.level_shape(level)) > fft_size:
        level += 1
    return level


def _failed(
    data: PairData,
    status: RegistrationStatus,
    message: str,
    *,
    method: str,
    model: str,
    dark_index: int,
    bright_index: int,
    t0: float,
    shift: FourierShift | None = None,
    cost_before: float = np.nan,
    valid_fraction: float = 0.0,
    previews: bool = False,
    overlap: float = float("nan"),
) -> PairRegistration:
    log.info("pair %d-%d: %s: %s", dark_index, bright_index, status, message)
    preview = make_preview(data, identity()) if previews and data.lo < data.hi else None
    return PairRegistration(
        dark=dark_index,
        bright=bright_index,
        matrix=identity() if model in AFFINE_MODELS else None,
        homography=np.eye(3),
        dx=0.0,
        dy=0.0,
        angle_deg=0.0,
        ratio=data.ratio,
        model=model,
        method=method,
        cost_before=cost_before,
        cost_after=cost_before,
        overlap=overlap,
        valid_fraction=valid_fraction,
        iterations=0,
        cost_history=(),
        level_history=(),
        initial_shift=(float(shift.dx), float(shift.dy)) if shift else (0.0, 0.0),
        peak_ncc=shift.ncc if shift else float("nan"),
        peak_psr=shift.psr if shift else float("nan"),
        status=status,
        message=message,
        shape=data.shape,
        seconds=time.perf_counter() - t0,
        preview=preview,
    )


def register_with(
    refine: Refiner,
    method: str,
    dark: np.ndarray,
    bright: np.ndarray,
    ratio: float,
    *,
    saturation: float = 1.0,
    noise_floor: float = 0.0,
    threshold: float = 0.1,
    model: str = "similarity",
    models: tuple[str, ...] | None = None,
    initial: np.ndarray | None = None,
    fft_size: int = 512,
    min_ncc: float = 0.2,
    min_valid_fraction: float = 0.005,
    min_overlap: float = 0.2,
    evaluation_samples: int = 30_000,
    previews: bool = True,
    lut: np.ndarray | None = None,
    dark_index: int = 0,
    bright_index: int = 1,
    check_residual: bool = False,
    refit_local: bool = True,
    memo: Any = None,
    **refine_options,
) -> PairRegistration:
    """The common driver: checks, eq. 5 integer shift, ``refine``, costs, status, previews.

    ``models``: the motion models ``refine`` supports (default: all of :data:`MODELS`).
    ``check_residual``: a registered pair is then also measured by
    :func:`hdrcore.registration.residual.residual_motion` (shares nothing with the search) and
    is ``ok`` only if that finds it aligned; otherwise ``weak`` with what is left and where
    (its motion is still usable), the measurement in ``residual`` (its cost:
    ``bench/bench_registration.py``'s speed section).
    ``refit_local`` (with ``check_residual``): when the check finds a group of neighbouring
    tiles moving on their own (a nearer object: parallax, or a moving one), the search runs
    again from its estimate with those tiles' area left out of the samples (see
    :func:`_refit_without_local`), so the global motion is the dominant plane's; the re-fit
    is kept when the tiles outside that area are left no worse.
    ``memo`` (:class:`~hdrcore.registration._memo.RunMemo`): what a registration of the same
    frames made before and this one would make the same (the pyramids, the residual check's
    block means and fixed structure image) is taken from it: the same result, sooner.
    """
    t0 = time.perf_counter()
    accepted = [
        n
        for n, prm in inspect.signature(refine).parameters.items()
        if prm.kind is inspect.Parameter.KEYWORD_ONLY
    ]
    unknown = sorted(set(refine_options) - set(accepted))
    if unknown:
        raise ParameterError(
            f"unknown option(s) {', '.join(unknown)} for registration method {method!r}",
            expected=f"some of {', '.join(accepted)} or the common options",
        )
    model = validate_method(model, MODELS, "motion model")
    if models is not None and model not in models:
        raise ParameterError(
            f"registration method {method!r} does not support the {model!r} motion model",
            expected=", ".join(models),
            found=model,
        )
    data = prepare(
        dark,
        bright,
        ratio,
        saturation=saturation,
        noise_floor=noise_floor,
        threshold=threshold,
        lut=lut,
        memo=memo,
    )
    common: dict[str, Any] = dict(
        method=method, model=model, dark_index=dark_index, bright_index=bright_index, t0=t0
    )
    if data.lo >= data.hi:
        return _failed(
            data,
            "saturated",
            f"no exposure range shared by the frames: noise floor x ratio {data.lo:.4g} >= "
            f"saturation {data.hi:.4g}",
            **common,
        )
    # Well-exposed pixels in both frames (eq. 6's V): enough to register?
    shared = select_samples(
        data, 0, evaluation_samples, by_gradient=False, seed=1, check_bright=False
    )
    rng = np.random.default_rng(2)
    h, w = data.shape
    ys, xs = rng.integers(0, h, 20_000), rng.integers(0, w, 20_000)
    probe = data.linear(data.bright[ys, xs])
    bright_ok = float(np.mean((probe > data.noise_floor) & (probe < data.saturation)))
    probe = data.linear(data.dark[ys, xs])
    dark_ok = float(np.mean((probe > data.noise_floor) & (probe < data.saturation)))
    if shared.b.size < 64 or dark_ok * bright_ok < min_valid_fraction:
        return _failed(
            data,
            "saturated",
            f"too few well-exposed pixels: {100 * bright_ok:.2f}% of the bright frame and "
            f"{100 * dark_ok:.2f}% of the dark frame lie between the noise floor and "
            f"saturation, {100 * shared.well_exposed:.2f}% of the dark frame (times the ratio) "
            f"in the range both frames expose",
            valid_fraction=dark_ok * bright_ok,
            **common,
        )
    ev = select_samples(data, 0, evaluation_samples, by_gradient=False, seed=1)
    cost_before, n_before = cost(data, 0, identity(), ev)

    shift = None
    if initial is None:
        lf = _fft_level(data, fft_size)
        a, b = data.clipped(lf)
        shift = cross_correlation_shift(np.log(a), np.log(b))  # eq. 5
        rel_contrast = shift.contrast  # log units: relative contrast of the bright frame
        if shift.ncc < min_ncc:
            if rel_contrast < 0.02:
                return _failed(
                    data,
                    "flat",
                    f"no texture: relative contrast {rel_contrast:.4f} at 1/{2**lf} resolution "
                    f"(flat or featureless frame)",
                    shift=shift,
                    cost_before=cost_before,
                    previews=previews,
                    **common,
                )
            return _failed(
                data,
                "weak-peak",
                f"eq. 5 correlation peak too weak: NCC {shift.ncc:.3f} < {min_ncc} "
                f"(PSR {shift.psr:.1f}); frames unrelated, repetitive or too noisy",
                shift=shift,
                cost_before=cost_before,
                previews=previews,
                **common,
            )
        scale = 2.0**lf
        init = identity()
        init[0, 2], init[1, 2] = shift.dx * scale, shift.dy * scale
    else:
        init = np.asarray(initial, float)
        if init.shape not in ((2, 3), (3, 3)) or not np.all(np.isfinite(init)):
            raise ParameterError(
                "initial matrix must be a finite 2x3 or 3x3 matrix", found=str(init.shape)
            )
        init = homogeneous(init)
        if model in AFFINE_MODELS and not (abs(init[2, 0]) < 1e-12 and abs(init[2, 1]) < 1e-12):
            raise ParameterError(
                f"the {model!r} model needs an affine initial matrix",
                found=f"perspective row {init[2].tolist()}",
            )
    overlap0 = overlap_fraction(init, data.shape)
    if overlap0 < min_overlap:
        return _failed(
            data,
            "no-overlap",
            f"the initial shift leaves {overlap0:.0%} overlap (< {min_overlap:.0%})",
            shift=shift,
            cost_before=cost_before,
            previews=previews,
            overlap=overlap0,
            **common,
        )

    # The searches work on the inverse (dark -> bright) matrix: see select_samples.
    res = refine(data, homogeneous(invert(init)), model, **refine_options)
    inverse, homography = _search_motion(res.matrix, model)

    def evaluated(inverse: np.ndarray, homography: np.ndarray):
        ev = select_samples(data, 0, evaluation_samples, motion=inverse, by_gradient=False, seed=1)
        c, n = cost(data, 0, inverse, ev)
        return (
            ev,
            c,
            n,
            overlap_fraction(homography, data.shape),
            similarity_parameters(homography, data.shape),
        )

    ev_after, cost_after, n_after, overlap, (dx, dy, angle, scale) = evaluated(inverse, homography)
    status: RegistrationStatus = "ok"
    message = res.message or "converged"
    if not np.all(np.isfinite(homography)) or not np.isfinite(cost_after):
        status, message = "diverged", "the search left the frames (no valid pixels)"
    elif overlap < min_overlap:
        status, message = "no-overlap", f"only {overlap:.0%} of the frames overlap after the search"
    elif cost_after > 1.05 * cost_before + 1e-12:
        status, message = (
            "diverged",
            f"the search ended with a higher eq. 6 cost than the identity "
            f"({cost_after:.4g} > {cost_before:.4g})",
        )
    if status != "ok":
        return _failed(
            data,
            status,
            message,
            shift=shift,
            cost_before=cost_before,
            previews=previews,
            overlap=overlap,
            **common,
        )
    residual = None
    if check_residual:
        status, message, residual = _checked(data, homography, model, message, memo)
        again = None
        if (
            refit_local
            and "exclude" in accepted
            and residual is not None
            and (residual.kind == "local")
        ):
            again = _refit_without_local(
                refine, data, inverse, model, residual, refine_options, min_overlap, memo
            )
            if again is not None:
                res, inverse, homography, status, message, residual = again
        elif (
            refit_local
            and "exclude" in accepted
            and (residual is None or residual.status == "unmeasured")
        ):
            # nothing measured the pair independently: the search's own residuals per
            # block find a nearer plane (see _refit_by_blocks)
            again = _refit_by_blocks(
                refine,
                data,
                inverse,
                model,
                res,
                refine_options,
                min_overlap,
                start=homogeneous(invert(init)),
            )
            if again is not None:
                res, inverse, homography, message = again
                if residual is not None:
                    status, message = judge_residual(
                        residual, homography, model, message, data.shape
                    )
        if again is not None:  # what the pair reports is the re-fitted motion's
            ev_after, cost_after, n_after, overlap, (dx, dy, angle, scale) = evaluated(
                inverse, homography
            )
    return PairRegistration(
        dark=dark_index,
        bright=bright_index,
        matrix=affine_part(homography) if model in AFFINE_MODELS else None,
        homography=homography,
        dx=dx,
        dy=dy,
        angle_deg=angle,
        scale=scale,
        ratio=data.ratio,
        model=model,
        method=method,
        cost_before=cost_before,
        cost_after=cost_after,
        overlap=overlap,
        valid_fraction=n_after / max(1, ev_after.b.size) * ev_after.well_exposed,
        iterations=res.iterations,
        cost_history=tuple(res.cost_history),
        level_history=tuple(res.level_history),
        initial_shift=(float(init[0, 2]), float(init[1, 2])),
        peak_ncc=shift.ncc if shift else float("nan"),
        peak_psr=shift.psr if shift else float("nan"),
        status=status,
        message=message,
        shape=data.shape,
        seconds=time.perf_counter() - t0,
        preview=make_preview(data, homography) if previews else None,
        residual=residual,
        gain=tuple(float(g) for g in getattr(res, "gain", ())),
    )


def _search_motion(matrix: np.ndarray, model: str) -> tuple[np.ndarray, np.ndarray]:
    """``(inverse, homography)`` of a search's result (``matrix``: dark -> bright): for the
    affine models the rounding in the homography's last row is cleared (the searches keep the
    model) and the inverse taken again from it."""
    inverse = homogeneous(matrix)
    homography = homogeneous(invert(inverse))
    if model in AFFINE_MODELS:
        homography[2] = (0.0, 0.0, 1.0)
        inverse = homogeneous(invert(homography))
    return inverse, homography


#: Tiles found moving on their own are left out of a re-fit with this margin around them, in
#: tiles (the near object reaches past the tiles that measured it, whose neighbours mixed both
#: motions and were not confident).
LOCAL_MARGIN = 0.5


def local_regions(res, margin: float = LOCAL_MARGIN) -> np.ndarray:
    """Full-resolution rectangles ``(K, 4)`` (``x0, y0, x1, y1``) around the confident tiles of a
    residual measurement that are off its global pattern by more than ``local_px`` and agree
    with a neighbour (what :func:`~.residual.residual_motion` calls local motion), widened by
    ``margin`` tiles on every side."""
    from .residual import coherent_tiles

    off = coherent_tiles(res)
    side = res.tile * (1 << res.level)
    half = (0.5 + margin) * side
    c = res.centres[off]
    return (
        np.stack([c[:, 0] - half, c[:, 1] - half, c[:, 0] + half, c[:, 1] + half], axis=1)
        if c.size
        else np.zeros((0, 4))
    )


def _outside_median(res, rects: np.ndarray) -> tuple[float, int]:
    """Median shift magnitude and count of a measurement's valid tiles outside ``rects``."""
    c = res.centres
    inside = np.zeros(c.shape[0], bool)
    for x0, y0, x1, y1 in rects:
        inside |= (c[:, 0] >= x0) & (c[:, 0] < x1) & (c[:, 1] >= y0) & (c[:, 1] < y1)
    keep = res.valid & ~inside
    if not keep.any():
        return float("nan"), 0
    return float(np.median(np.hypot(*res.shifts[keep].T))), int(keep.sum())


def _refit_without_local(
    refine,
    data: PairData,
    inverse: np.ndarray,
    model: str,
    residual,
    refine_options: dict,
    min_overlap: float,
    memo: Any = None,
):
    """The search again from ``inverse`` with the residual's local-motion area left out, or
    None when that does not leave the rest of the frame at least as well aligned (median of
    the tiles outside the area within 0.01 px plus 2 %, and at most one of them or 5 % no
    longer measurable). Returns ``(refine result, inverse, homography, status, message,
    residual)``."""
    rects = local_regions(residual)
    if not rects.size:
        return None
    try:
        res = refine(data, inverse, model, exclude=rects, **refine_options)
    except ParameterError:
        return None
    if not np.all(np.isfinite(res.matrix)):
        return None
    inv2, hom2 = _search_motion(res.matrix, model)
    if overlap_fraction(hom2, data.shape) < min_overlap:
        return None
    msg2 = f"{res.message or 'converged'}; re-fitted without the local motion"
    status2, msg2, res2 = _checked(data, hom2, model, msg2, memo)
    if res2 is None:
        return None
    before, n_before = _outside_median(residual, rects)
    after, n_after = _outside_median(res2, rects)
    if not (np.isfinite(before) and np.isfinite(after)) or n_after < min(
        0.95 * n_before, n_before - 1
    ):
        return None
    if after > 1.02 * before + 0.01:
        return None
    return res, inv2, hom2, status2, msg2, res2


#: :func:`_refit_by_blocks`: blocks of a twelfth of the short side; a block is off when its RMS
#: eq. 7 residual is ``BLOCK_OFF`` times the median block's; the re-fit is kept when it lowers
#: the cost of the other samples by at least ``BLOCK_GAIN`` and leaves out at most
#: ``BLOCK_MAX_SHARE`` of them. Measured on the simulated 8-bit two-plane pairs whose residual
#: cannot be measured (bench_registration), worst corner px of the harder one, similarity /
#: homography: blocks of an eighth and 1.6x 0.332 / 1.333, a twelfth and 1.4x 0.152 / 0.467;
#: on 8 single-plane 8-bit low-texture pairs (6 unmeasured) no re-fit is made.
BLOCK_OFF = 1.4
BLOCK_GAIN = 0.03
BLOCK_MAX_SHARE = 0.35
BLOCK_ROUNDS = 3

#: A homography re-fitted by blocks (its residual unmeasurable) keeps its perspective only
#: where that lowers the eq. 7 cost of held-out samples (random, not the search's high-gradient
#: ones; the left-out blocks excluded) by this fraction against the similarity fitted on the
#: same samples; otherwise the similarity is its result. Measured (bench_registration's
#: simulated pairs, 384x576, ratio 4): a true perspective of 0.5-2.5 px at the corners lowers
#: that cost by 15-96 % (8- and 12-bit); on the two 8-bit two-plane landscapes whose dominant
#: plane has none the fitted perspective lowers it by 0.08 % and 0.45 % while moving the
#: corners 0.13 / 0.23 and 0.26 / 0.47 px (mean / worst) off the truth.
PERSPECTIVE_GAIN = 0.01


def _off_blocks(data: PairData, probe: np.ndarray, gain: np.ndarray, side: int):
    """``(off, weight per block, samples, their block rows, columns)``: the blocks of ``side``
    px whose RMS eq. 7 residual under ``probe`` is ``BLOCK_OFF`` times the median block's and
    that have an off neighbour; None with too few samples or blocks."""
    h, w = data.shape
    s = select_samples(data, 0, 60_000, motion=probe)
    if s.b.size < 1000:
        return None
    n, wt = sample_residuals(data, 0, probe, s, gain=gain)
    gy, gx = (s.y // side).astype(np.int64), (s.x // side).astype(np.int64)
    ny, nx = h // side + 1, w // side + 1
    sq = np.zeros((ny, nx))
    cnt = np.zeros((ny, nx))
    np.add.at(sq, (gy, gx), n * n * wt)
    np.add.at(cnt, (gy, gx), wt)
    enough = cnt >= max(20.0, 0.1 * s.b.size / (ny * nx))
    if enough.sum() < 8:
        return None
    rms = np.sqrt(sq / np.maximum(cnt, 1e-12))
    off = enough & (rms > BLOCK_OFF * np.median(rms[enough]))
    pad = np.pad(off, 1)
    neighbours = sum(
        pad[1 + dy : 1 + dy + ny, 1 + dx : 1 + dx + nx]
        for dy in (-1, 0, 1)
        for dx in (-1, 0, 1)
        if dy or dx
    )
    return off & (neighbours > 0), cnt, s, gy, gx


def _finite_gain(r) -> np.ndarray:
    return np.asarray(getattr(r, "gain", ()) or (0.0, 0.0, 0.0), float)


def _refit_by_blocks(
    refine,
    data: PairData,
    inverse: np.ndarray,
    model: str,
    res,
    refine_options: dict,
    min_overlap: float,
    start: np.ndarray | None = None,
):
    """Where the independent check measured nothing (too little structure in the range both
    frames share), a nearer plane can still pull the global fit: the search's own eq. 7
    residuals, as RMS per block of about a twelfth of the short side, show it as a group of
    neighbouring blocks ``BLOCK_OFF`` times the median block (under the similarity: a
    homography bends towards a textured nearer plane and spreads its residual). The search
    runs again without them; the blocks are looked for again under the new fit (the object
    stands out more once the fit leaves it), at most ``BLOCK_ROUNDS`` times. The re-fit is kept
    when the cost of the samples outside every left-out block falls by ``BLOCK_GAIN`` (a single
    plane re-fitted on a subset barely moves). ``start``: the search's starting point (dark ->
    bright), where the similarity probe starts too. Returns ``(refine result, inverse,
    homography, message)`` or None."""
    h, w = data.shape
    side = max(16, min(h, w) // 12)
    gain = _finite_gain(res)

    def similarity_probe(exclude):
        if model in AFFINE_MODELS:
            return None
        affine = homogeneous(inverse if start is None else start).copy()
        affine /= affine[2, 2]
        affine[2] = (0.0, 0.0, 1.0)
        sim = refine(data, affine, "similarity", exclude=exclude, **refine_options)
        m = homogeneous(sim.matrix)
        return (m, _finite_gain(sim), sim) if np.all(np.isfinite(m)) else None

    try:
        probe = similarity_probe(None) or (inverse, gain, None)
    except ParameterError:
        return None
    first = _off_blocks(data, probe[0], probe[1], side)
    if first is None:
        return None
    off, cnt, s0, gy0, gx0 = first
    total = np.zeros_like(off)
    best = None
    for _ in range(BLOCK_ROUNDS):
        grown = total | off
        if not grown.any() or np.array_equal(grown, total):
            break
        if cnt[grown].sum() > BLOCK_MAX_SHARE * cnt.sum():
            log.debug("block re-fit: %d blocks hold too many samples", int(grown.sum()))
            break
        total = grown
        by, bx = np.nonzero(total)
        rects = np.stack([bx * side, by * side, (bx + 1) * side, (by + 1) * side], axis=1).astype(
            np.float64
        )
        try:
            again = refine(data, inverse, model, exclude=rects, **refine_options)
            probe = similarity_probe(rects) or (
                homogeneous(again.matrix),
                _finite_gain(again),
                None,
            )
        except ParameterError:
            break
        inv2 = homogeneous(again.matrix)
        if not np.all(np.isfinite(inv2)):
            break
        best = (again, inv2, total.copy(), rects, probe[2])
        found = _off_blocks(data, probe[0], probe[1], side)
        if found is None:
            break
        off = found[0]
    if best is None:
        log.debug("block re-fit: no group of blocks off")
        return None
    again, inv2, total, rects, similar = best
    inv2, hom2 = _search_motion(inv2, model)
    if overlap_fraction(hom2, data.shape) < min_overlap:
        return None
    left_out = total[gy0, gx0]
    kept = Samples(s0.x[~left_out], s0.y[~left_out], s0.b[~left_out])
    before, _ = cost(data, 0, inverse, kept, gain)
    after, _ = cost(data, 0, inv2, kept, _finite_gain(again))
    if not after <= (1.0 - BLOCK_GAIN) * before:
        log.debug(
            "block re-fit without %d blocks does not pay: %.4g -> %.4g",
            int(total.sum()),
            before,
            after,
        )
        return None
    share = cnt[total].sum() / cnt.sum()
    note = ""
    if similar is not None:
        # nothing independent verifies this pair: keep the perspective only where the frames
        # support it, i.e. where it lowers eq. 6 on samples the searches did not use
        ev = select_samples(data, 0, 30_000, motion=inv2, by_gradient=False, seed=1, exclude=rects)
        c_h, _ = cost(data, 0, inv2, ev, _finite_gain(again))
        inv_s, _ = _search_motion(similar.matrix, "similarity")
        c_s, _ = cost(data, 0, inv_s, ev, _finite_gain(similar))
        if not c_h < (1.0 - PERSPECTIVE_GAIN) * c_s:
            again, note = (
                similar,
                (
                    f"; its perspective is not supported by the frames (eq. 7 cost on held-out "
                    f"samples {c_h:.4g} against the similarity's {c_s:.4g}): similarity kept"
                ),
            )
            inv2, hom2 = inv_s, homogeneous(invert(inv_s))
            hom2[2] = (0.0, 0.0, 1.0)
            if overlap_fraction(hom2, data.shape) < min_overlap:
                return None
    return (
        again,
        inv2,
        hom2,
        (
            f"{again.message or 'converged'}; re-fitted without "
            f"{int(total.sum())} blocks ({share:.0%} of the samples) that "
            f"moved on their own (eq. 7 cost of the rest "
            f"{before:.4g} -> {after:.4g}){note}"
        ),
    )


def _checked(
    data: PairData, homography: np.ndarray, model: str, message: str, memo: Any = None
) -> tuple[RegistrationStatus, str, Any]:
    """``(status, message, residual)`` of a registered pair after the independent residual
    check (see :func:`register_with`); the words are the pipeline's."""
    from .residual import residual_motion

    try:
        res = residual_motion(
            data.dark,
            data.bright,
            data.ratio,
            homography,
            saturation=data.saturation,
            noise_floor=data.noise_floor,
            lut=data.lut,
            memo=memo,
        )
    except ParameterError as exc:  # too small a frame to tile
        return "ok", f"{message}; residual not measured: {exc}", None
    status, message = judge_residual(res, homography, model, message, data.shape)
    return status, message, res


def judge_residual(
    res, homography: np.ndarray, model: str, message: str, shape: tuple[int, int]
) -> tuple[RegistrationStatus, str]:
    """``(status, message)`` of a registered pair from its residual motion (the words of the
    registration and the pipeline): ``weak`` when misaligned, or when nothing can verify a
    motion of more than ``UNVERIFIED_PX``; otherwise ``ok``, the message saying what was found
    (``message`` is the search's own)."""
    if res.status == "misaligned":
        what = res.describe()
        if model == "homography":  # the words of the residual assume a simpler model
            what = what.replace(
                "the motion model has no perspective",
                "the homography did not remove it (parallax or a poor optimum)",
            )
        return "weak", f"{what} (the search itself: {message})"
    if res.status == "unmeasured":
        # Nothing verifies the motion: a sub-pixel one is harmless either way; a larger one
        # found on frames without measurable structure (near black, flat) is not called ok.
        moved = float(corner_error(homography, np.eye(3), shape).max())
        if moved > UNVERIFIED_PX:
            return "weak", (
                f"its motion ({moved:.1f} px at the corners) cannot be verified: "
                f"{res.describe()} (the search itself: {message})"
            )
        return "ok", f"{message}; {res.describe()}"
    return "ok", message


def to_level(matrix: np.ndarray, level: int) -> np.ndarray:
    """A full-resolution matrix as a 3x3 homography on pyramid ``level``."""
    return homogeneous(level_matrix(homogeneous(matrix), level))


def to_full(matrix: np.ndarray, level: int) -> np.ndarray:
    """A 3x3 matrix of pyramid ``level`` at full resolution."""
    return homogeneous(level_matrix(matrix, -level)) if level else homogeneous(matrix)
