"""Residual motion between two aligned frames, measured independently of the motion model.

After registration the bright frame, warped onto the dark frame, should match it everywhere.
This module measures what is left, tile by tile, with a method that shares nothing with the
registration (neither its eq. 6/7 cost nor its motion model), so a wrong optimum or a missing
degree of freedom cannot hide:

1. both frames on a common scale (the dark frame times the exposure ratio ``k``), clipped to the
   range they share (above the noise floor, below saturation) and taken in log units, so they
   are the same function of scene radiance (exposure invariant);
2. the structure image: gradient magnitude of the log images (3x3 Sobel), faded out towards
   both clip levels and zero next to saturated pixels (:func:`_structure` says why): edges and
   texture, not brightness;
3. per tile (Hann-windowed), the shift by phase correlation (C. D. Kuglin, D. C. Hines, "The
   phase correlation image alignment method", IEEE Conf. on Cybernetics and Society, 1975):
   the integer peak of the whitened cross-power spectrum, then sub-pixel by a weighted
   least-squares fit of the plane of its phase (H. S. Stone, M. T. Orchard, E.-C. Chang,
   S. A. Martucci, "A fast direct Fourier-based algorithm for subpixel registration of images",
   IEEE TGRS 39(10), 2001; W. S. Hoge, "A subspace identification extension to the phase
   correlation method", IEEE TMI 22(2), 2003); the dark tile is then taken again at the
   estimate and the remainder fitted, twice, which removes the pull of the common window
   towards zero;
4. per tile a confidence: the normalised cross-correlation of the two re-centred tiles
   (1: same structure, near 0: unrelated or noise), the standard error of the phase-plane fit
   and the fraction of the tile both frames expose well; tiles whose shift is the alignment
   itself (structure fixed to the sensor) or that match about as well where the global
   pattern says (a repetitive texture) are left out;
5. the tile field summarised: median and 90th percentile of the shift magnitude over confident
   tiles; a global pattern fitted by robust least squares (shift, zoom, rotation, anisotropic
   scale/shear and the two perspective terms of a homography near the identity, each reported
   as the displacement it makes at the image corners); the local residual left after the
   pattern where neighbouring tiles agree (parallax, a moving object, flare) and where it is
   ("lower left"); a status and a one-line message (:meth:`ResidualMotion.describe`).

Accuracy (tests/registration/test_residual.py, simulated 12-bit pairs 576x384, 64 px tiles):
a known shift, zoom or rotation is recovered to 0.05 px; 8-bit pairs 2-4 stops apart to
about 0.1 px.

Large frames are measured on a 2^L block-mean level (at most ``max_pixels`` pixels, 2.5 MP by
default: a 24 MP pair on level 2, a 9 MP phone frame on level 1); shifts are reported in
full-resolution pixels.

Convention: the shift ``(dx, dy)`` of a tile says that the content of the aligned bright frame
at ``x`` lies at ``x + (dx, dy)`` in the dark frame, i.e. composing the pair matrix (bright ->
dark) after the residual translation would remove it; zero everywhere means aligned.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy import fft as sfft
from scipy.special import fdtri

from .._numba import njit as _njit
from .._threads import run_row_spans, worker_count
from ..errors import ParameterError
from ..geometry import keys4, keys_row_at, keys_row_scratch, keys_row_weights
from ..status import RESIDUAL_STATUSES as _RESIDUAL_STATUSES
from ..status import ResidualStatus
from ._memo import array_key, table_key

__all__ = [
    "ResidualMotion",
    "ResidualPattern",
    "residual_motion",
    "region_name",
    "coherent_tiles",
    "RESIDUAL_STATUSES",
]

#: ``aligned``: nothing above the thresholds; ``misaligned``: a global pattern or a local
#: residual is left (``kind`` says which); ``unmeasured``: too few textured tiles in the range
#: both frames expose.
RESIDUAL_STATUSES = _RESIDUAL_STATUSES  # see hdrcore.status.ResidualStatus

#: A tile counts when the normalised cross-correlation of its two structure tiles, re-centred,
#: is at least this over the tile size (noise alone reaches about 8 / tile: 0.12 for 64 px) and
#: the standard error of its shift at most ``MAX_SIGMA`` analysed pixels. Noise-only tiles and
#: the wrong period of a repetitive texture (a phone's view of a bookshelf: 14-46 px off) have
#: 0.09-0.15; good tiles of real phone pairs mostly under 0.05.
CONFIDENCE_PER_TILE, MAX_SIGMA = 12.0, 0.09
#: ... and at least this whatever the tile size: the fixed-pattern noise of a dark phone frame
#: correlates at 0.1-0.2 (good tiles of the same pairs: 0.45 and more).
MIN_CONFIDENCE = 0.25

#: Components of the global pattern, in the order they are reported.
PATTERN_COMPONENTS = ("shift", "zoom", "rotation", "affine", "perspective")

_HINTS = {
    "shift": "the registration stopped off the optimum",
    "zoom": "the motion model has no scale, or its scale is wrong",
    "rotation": "the rotation is off",
    "affine": "anisotropic scale or shear (rolling shutter, lens), not in the motion model",
    "perspective": "the motion model has no perspective",
}


# ----------------------------------------------------------------------------- result objects
@dataclass(frozen=True)
class ResidualPattern:
    """The global pattern fitted to the tile shifts (full-resolution pixels).

    Model, with ``u, v`` the tile centre relative to the image centre divided by the half
    diagonal ``radius`` (the corners are at distance 1)::

        dx = shift_x + a11 u + a12 v + p u^2 + q u v
        dy = shift_y + a21 u + a22 v + p u v + q v^2

    (an affine map plus the two perspective terms of a homography near the identity).
    ``zoom`` (a fraction: 0.004 is 0.4 %) and ``rotation_deg`` are the similarity part;
    ``*_px`` are the largest displacements each component makes at the four image corners
    (signed for zoom and rotation). ``parameters`` is ``(shift_x, shift_y, a11, a12, a21, a22,
    p, q)`` (terms not kept are 0); ``rms`` the RMS of the tile shifts about the pattern over
    the tiles the robust fit kept; ``terms`` the number of free parameters kept (2, 4, 6, 8).
    """

    shift_x: float
    shift_y: float
    zoom: float
    rotation_deg: float
    shift_px: float
    zoom_px: float
    rotation_px: float
    affine_px: float
    perspective_px: float
    radius: float
    parameters: tuple[float, ...]
    rms: float
    terms: int

    def component_px(self) -> dict[str, float]:
        """Displacement at the corners of each component, in :data:`PATTERN_COMPONENTS` order."""
        return {
            "shift": self.shift_px,
            "zoom": abs(self.zoom_px),
            "rotation": abs(self.rotation_px),
            "affine": self.affine_px,
            "perspective": self.perspective_px,
        }

    def predict(self, x: np.ndarray, y: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """The pattern's shift ``(N, 2)`` at full-resolution points ``(x, y)``."""
        x, y = np.asarray(x, float), np.asarray(y, float)
        return _predict(np.asarray(self.parameters, float), x, y, shape, self.radius)

    def to_json(self) -> dict:
        return {
            "shift_x": self.shift_x,
            "shift_y": self.shift_y,
            "zoom": self.zoom,
            "rotation_deg": self.rotation_deg,
            "shift_px": self.shift_px,
            "zoom_px": self.zoom_px,
            "rotation_px": self.rotation_px,
            "affine_px": self.affine_px,
            "perspective_px": self.perspective_px,
            "radius": self.radius,
            "parameters": list(self.parameters),
            "rms": self.rms,
            "terms": self.terms,
        }


@dataclass(frozen=True, eq=False)
class ResidualMotion:
    """Residual motion of an aligned pair, per tile and summarised (full-resolution pixels).

    ``centres`` ``(N, 2)``: tile centres ``(x, y)``; ``shifts`` ``(N, 2)``: ``(dx, dy)`` per tile
    (see the module's convention); ``confidence``: the normalised cross-correlation of the two
    structure tiles, re-centred on the shift; ``sigma``: the standard error of the tile's shift
    in its least certain direction (px);
    ``in_range``: fraction of the tile both frames expose well; ``valid``: the confident tiles
    (the statistics use only these). ``median`` / ``p90`` / ``max``: of the shift magnitude over
    valid tiles (NaN without any). ``local``: per tile, the magnitude left after the pattern;
    ``worst``: index of the valid tile with the largest local residual (-1 without any);
    ``worst_region``: where the valid tiles off by more than ``local_px`` after the pattern lie
    (their centroid, in thirds of the frame: "lower left"), or the worst tile's place.
    ``status`` is one of :data:`RESIDUAL_STATUSES`, ``kind`` what is left (a
    :data:`PATTERN_COMPONENTS` name, ``"local"``, ``"scattered"``, or ``""``), ``message`` one
    line for people.
    ``tile`` is the tile size and ``level`` the pyramid level (``2**level`` full pixels per
    analysed pixel) the measurement ran on. ``sensor``: confident tiles left out because
    their shift is the alignment itself (structure fixed to the sensor: fixed-pattern noise,
    dust; only when a pair matrix is given); ``ambiguous``: confident tiles left out because
    they match about as well where the pattern says (a repetitive texture).
    """

    shape: tuple[int, int]
    level: int
    tile: int
    centres: np.ndarray = field(repr=False)
    shifts: np.ndarray = field(repr=False)
    confidence: np.ndarray = field(repr=False)
    sigma: np.ndarray = field(repr=False)
    in_range: np.ndarray = field(repr=False)
    valid: np.ndarray = field(repr=False)
    local: np.ndarray = field(repr=False)
    median: float
    p90: float
    max: float
    pattern: ResidualPattern | None
    worst: int
    worst_region: str
    status: ResidualStatus
    kind: str
    message: str
    aligned_px: float
    local_px: float
    sensor: np.ndarray = field(repr=False)
    ambiguous: np.ndarray = field(repr=False)
    seconds: float = 0.0

    @property
    def aligned(self) -> bool:
        return self.status == "aligned"

    @property
    def n_valid(self) -> int:
        return int(np.count_nonzero(self.valid))

    @property
    def magnitudes(self) -> np.ndarray:
        """Shift magnitude per tile (px)."""
        return np.hypot(self.shifts[:, 0], self.shifts[:, 1])

    def describe(self) -> str:
        """One line: what is left and where (``message``)."""
        return self.message

    def to_json(self) -> dict:
        def f(x: float) -> float | None:
            return None if not np.isfinite(x) else float(x)

        return {
            "status": self.status,
            "kind": self.kind,
            "message": self.message,
            "median_px": f(self.median),
            "p90_px": f(self.p90),
            "max_px": f(self.max),
            "valid_tiles": self.n_valid,
            "tiles": int(self.valid.size),
            "worst_tile": self.worst,
            "worst_region": self.worst_region,
            "pattern": None if self.pattern is None else self.pattern.to_json(),
            "aligned_px": self.aligned_px,
            "local_px": self.local_px,
            "shape": list(self.shape),
            "level": self.level,
            "tile_size": self.tile,
            "centres": np.round(self.centres, 2).tolist(),
            "shifts": [[f(a), f(b)] for a, b in np.round(self.shifts, 4)],
            "confidence": [f(c) for c in np.round(self.confidence, 4)],
            "sigma": [f(s) for s in np.round(self.sigma, 4)],
            "in_range": np.round(self.in_range, 3).tolist(),
            "valid": self.valid.astype(bool).tolist(),
            "local": [f(v) for v in np.round(self.local, 4)],
            "sensor": self.sensor.astype(bool).tolist(),
            "ambiguous": self.ambiguous.astype(bool).tolist(),
            "seconds": self.seconds,
        }


# ------------------------------------------------------------------------------ compiled kernels
@_njit
def _reduce_float_rows(img, f, out, top, r0, r1):  # pragma: no cover - compiled
    """Rows ``r0:r1`` of the ``f x f`` block means of a float image (NaN propagates) and of
    each block's largest value (NaN skipped; -inf when every value is NaN): the saturation
    test of :func:`_mark` reads the latter, so a block is summed once for every ``sat``."""
    ww = out.shape[1]
    acc = np.empty(ww, np.float64)
    inv = 1.0 / (f * f)
    for y in range(r0, r1):
        acc[:] = 0.0
        top[y, :] = -np.inf
        for i in range(f):
            row = y * f + i
            for x in range(ww):
                s = 0.0
                m = top[y, x]
                for j in range(f):
                    v = img[row, x * f + j]
                    s += v
                    if v > m:
                        m = v
                acc[x] += s
                top[y, x] = m
        for x in range(ww):
            out[y, x] = acc[x] * inv


@_njit
def _reduce_lut_rows(img, lut, f, out, top, r0, r1):  # pragma: no cover - compiled
    """Rows ``r0:r1`` of the ``f x f`` block means of ``lut[img]`` (integer levels, any strides)
    and of each block's largest ``lut`` value (see :func:`_reduce_float_rows`)."""
    ww = out.shape[1]
    acc = np.empty(ww, np.float64)
    inv = 1.0 / (f * f)
    for y in range(r0, r1):
        acc[:] = 0.0
        top[y, :] = -np.inf
        for i in range(f):
            row = y * f + i
            for x in range(ww):
                s = 0.0
                m = top[y, x]
                for j in range(f):
                    v = lut[img[row, x * f + j]]
                    s += v
                    if v > m:
                        m = v
                acc[x] += s
                top[y, x] = m
        for x in range(ww):
            out[y, x] = acc[x] * inv


@_njit
def _warp_rows(src, m, out, r0, r1):  # pragma: no cover - compiled
    """Rows ``r0:r1`` of ``src`` sampled at ``m @ (x, y, 1)`` (3x3 backward map, Keys cubic);
    NaN where the source position lies outside the frame. A row's positions, then their
    weights (:func:`~hdrcore.geometry.keys_row_weights`), then the reads, each a loop of its
    own: :func:`~hdrcore.geometry.keys_at` per pixel to the bit, 24 -> 14 ns a pixel."""
    h, w = src.shape
    ww = out.shape[1]
    sx = np.empty(ww)
    sy = np.empty(ww)
    ix, iy, wx, wy = keys_row_scratch(ww)
    for y in range(r0, r1):
        for x in range(ww):
            zw = m[2, 0] * x + m[2, 1] * y + m[2, 2]
            sx[x] = (m[0, 0] * x + m[0, 1] * y + m[0, 2]) / zw
            sy[x] = (m[1, 0] * x + m[1, 1] * y + m[1, 2]) / zw
        keys_row_weights(sx, sy, ww, ix, iy, wx, wy)
        for x in range(ww):
            if not (sx[x] >= 0.0 and sx[x] <= w - 1.0 and sy[x] >= 0.0 and sy[x] <= h - 1.0):
                out[y, x] = np.nan
                continue
            out[y, x] = keys_row_at(src, x, ix, iy, wx, wy)


# ------------------------------------------------------------------------------------ helpers
def _homogeneous(matrix: np.ndarray) -> np.ndarray:
    m = np.asarray(matrix, float)
    if m.shape == (2, 3):
        m = np.vstack([m, [0.0, 0.0, 1.0]])
    if m.shape != (3, 3) or not np.all(np.isfinite(m)) or abs(np.linalg.det(m)) < 1e-12:
        raise ParameterError(
            "the pair matrix must be a finite, invertible 2x3 or 3x3 matrix",
            found=str(np.asarray(matrix).shape),
        )
    return m / m[2, 2] if m[2, 2] != 0 else m


def _reduce(
    img: np.ndarray, f: int, lut: np.ndarray | None, workers: int | None, sat: float = np.inf
) -> np.ndarray:
    """``f x f`` block means of ``img`` (or ``lut[img]``). A block holding a pixel at or above
    ``sat`` is saturated as a whole (``2 * sat``; ``sat`` is where the pixel leaves the range
    the pair shares, on the frame's own scale): its mean mixes clipped pixels with others, so
    where a region far above saturation (a window) clips in one frame and not in the other
    the block-mean edge sits off the true one by a fraction of the block, and a tile on that
    edge read a false shift (1.8 px at the centre of the simulated 24 MP window bracket,
    whose registration is exact to 0.004 px: the pair was called misaligned and registered
    again with the homography). ``_mark(_block_stats(...), sat)``: the block sums do not
    depend on ``sat`` (a saturation step takes them from the memo)."""
    a = np.asarray(img)
    if f == 1 and lut is None:
        return a.astype(np.float32, copy=False)
    return _mark(_block_stats(a, f, lut, workers), sat)


def _block_stats(
    img: np.ndarray, f: int, lut: np.ndarray | None, workers: int | None
) -> tuple[np.ndarray, np.ndarray]:
    """``f x f`` block means of ``img`` (or ``lut[img]``; float32) and each block's largest
    value (float64, NaN skipped)."""
    a = np.asarray(img)
    shape = (a.shape[0] // f, a.shape[1] // f)
    out = np.empty(shape, np.float32)
    top = np.empty(shape, np.float64)
    if lut is not None:
        run_row_spans(
            out.shape[0], workers, lambda r0, r1: _reduce_lut_rows(a, lut, f, out, top, r0, r1)
        )
    else:
        src = a if a.dtype in (np.float32, np.float64) else a.astype(np.float32)
        run_row_spans(
            out.shape[0], workers, lambda r0, r1: _reduce_float_rows(src, f, out, top, r0, r1)
        )
    return out, top


def _mark(stats: tuple[np.ndarray, np.ndarray], sat: float) -> np.ndarray:
    """:func:`_block_stats`' means with every block whose largest value is at or above ``sat``
    set to ``2 * sat`` (a block whose mean is NaN stays NaN)."""
    mean, top = stats
    clipped = (top >= np.float64(sat)) & (mean == mean)
    return np.where(clipped, np.float32(2.0 * float(sat)), mean)


def _warp(
    src: np.ndarray, m: np.ndarray, shape: tuple[int, int], workers: int | None
) -> np.ndarray:
    out = np.empty(shape, np.float32)
    m = np.ascontiguousarray(m, np.float64)
    run_row_spans(shape[0], workers, lambda r0, r1: _warp_rows(src, m, out, r0, r1))
    return out


#: Widths (as brightness factors) over which the structure fades out towards the noise floor
#: and towards saturation.
TAPER_LOW, TAPER_HIGH = 4.0, 2.0


@_njit
def _log_rows(img, lo, hi, out, r0, r1):  # pragma: no cover - compiled
    """Rows ``r0:r1``: ``log(clip(img, lo, hi))`` (NaN stays NaN)."""
    for y in range(r0, r1):
        for x in range(img.shape[1]):
            v = img[y, x]
            out[y, x] = np.log(min(max(v, lo), hi)) if v == v else np.nan


@_njit
def _gradient_rows(log, llo, lhi, tl, th, out, r0, r1):  # pragma: no cover - compiled
    """Rows ``r0:r1``: Sobel gradient magnitude / 8 of ``log``, faded by the smoothsteps of
    ``(log - llo) / tl`` and ``(lhi - log) / th``, zero where a 3x3 neighbour is at ``lhi``
    (saturated) and on the one-pixel border. Per row, the columns with a saturated pixel in
    the three rows first, then every pixel's value in a loop without branches (it
    vectorises: 7.1 -> 2.3 ns a pixel, the same values)."""
    h, w = log.shape
    sat = np.empty(w, np.bool_)
    for y in range(r0, r1):
        if y == 0 or y == h - 1:
            for x in range(w):
                out[y, x] = 0.0
            continue
        for x in range(w):
            sat[x] = (log[y - 1, x] >= lhi) | (log[y, x] >= lhi) | (log[y + 1, x] >= lhi)
        out[y, 0] = 0.0
        out[y, w - 1] = 0.0
        for x in range(1, w - 1):
            gx = (
                log[y - 1, x + 1]
                + 2.0 * log[y, x + 1]
                + log[y + 1, x + 1]
                - log[y - 1, x - 1]
                - 2.0 * log[y, x - 1]
                - log[y + 1, x - 1]
            )
            gy = (
                log[y + 1, x - 1]
                + 2.0 * log[y + 1, x]
                + log[y + 1, x + 1]
                - log[y - 1, x - 1]
                - 2.0 * log[y - 1, x]
                - log[y - 1, x + 1]
            )
            a = min(max((log[y, x] - llo) / tl, 0.0), 1.0)
            b = min(max((lhi - log[y, x]) / th, 0.0), 1.0)
            fade = a * a * (3.0 - 2.0 * a) * b * b * (3.0 - 2.0 * b)
            v = np.sqrt(gx * gx + gy * gy) * 0.125 * fade
            out[y, x] = 0.0 if (sat[x - 1] | sat[x] | sat[x + 1]) else v


def _structure(
    img: np.ndarray, lo: float, hi: float, workers: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Exposure-invariant structure image of a frame on the common scale, and its in-range mask.

    The gradient magnitude (3x3 Sobel) of the log of the frame clipped to ``[lo, hi]``, faded
    out smoothly over the last two stops above the noise floor's end of the range and the last
    stop below saturation (``TAPER_LOW``, ``TAPER_HIGH``): a hard cut at a clip level would turn
    the contour where a noisy frame crosses it (far from the scene's edges on a soft gradient)
    into an edge. Zero next to saturated pixels: a pixel that straddles the edge of a region
    far above saturation (a window, a lamp) saturates for any coverage, so that edge snaps to
    whole pixels, differently in each frame, and would pull the tile's shift towards an integer.
    NaN (outside a warped frame) stays NaN.
    """
    with np.errstate(invalid="ignore"):
        inside = (img > lo) & (img < hi)
    src = np.ascontiguousarray(img, np.float32)
    log = np.empty(src.shape, np.float32)
    g = np.empty(src.shape, np.float32)
    h = src.shape[0]
    run_row_spans(
        h, workers, lambda r0, r1: _log_rows(src, np.float32(lo), np.float32(hi), log, r0, r1)
    )
    llo, lhi = float(np.log(np.float32(lo))), float(np.log(np.float32(hi)))
    tl, th = float(np.log(TAPER_LOW)), float(np.log(TAPER_HIGH))
    run_row_spans(h, workers, lambda r0, r1: _gradient_rows(log, llo, lhi, tl, th, g, r0, r1))
    return g, inside


def _hann(n: int) -> np.ndarray:
    return 0.5 - 0.5 * np.cos(2.0 * np.pi * (np.arange(n) + 0.5) / n)


def region_name(x: float, y: float, shape: tuple[int, int]) -> str:
    """Where ``(x, y)`` lies in a frame of ``shape``, in thirds: "upper left", "top", "centre"..."""
    h, w = shape
    col = min(2, max(0, int(3 * (x + 0.5) / w)))
    row = min(2, max(0, int(3 * (y + 0.5) / h)))
    names = (
        ("upper left", "top", "upper right"),
        ("left", "centre", "right"),
        ("lower left", "bottom", "lower right"),
    )
    return names[row][col]


def _radius(shape: tuple[int, int]) -> float:
    h, w = shape
    return 0.5 * float(np.hypot(w - 1, h - 1))


def _design(x: np.ndarray, y: np.ndarray, shape: tuple[int, int], radius: float) -> np.ndarray:
    """Design matrix ``(2N, 8)`` of the pattern (rows: all dx, then all dy)."""
    h, w = shape
    u = (x - (w - 1) / 2.0) / radius
    v = (y - (h - 1) / 2.0) / radius
    z, o = np.zeros_like(u), np.ones_like(u)
    top = np.stack([o, z, u, v, z, z, u * u, u * v], axis=1)
    bottom = np.stack([z, o, z, z, u, v, u * v, v * v], axis=1)
    return np.vstack([top, bottom])


def _predict(
    params: np.ndarray, x: np.ndarray, y: np.ndarray, shape: tuple[int, int], radius: float
) -> np.ndarray:
    d = _design(np.atleast_1d(x), np.atleast_1d(y), shape, radius) @ params
    n = d.size // 2
    return np.stack([d[:n], d[n:]], axis=1)


_PATTERN_TERMS = (2, 4, 6, 8)  # shift; + zoom, rotation; + anisotropic scale, shear; + perspective


def _expansion(terms: int) -> np.ndarray:
    """``(8, p)``: the full parameters from the ``p`` free ones of a nested pattern."""
    if terms == 4:  # similarity: a11 = a22 = zoom, a21 = -a12 = rotation
        e = np.zeros((8, 4))
        e[0, 0] = e[1, 1] = 1.0
        e[2, 2] = e[5, 2] = 1.0
        e[4, 3], e[3, 3] = 1.0, -1.0
        return e
    return np.eye(8)[:, :terms]


def _tukey(res: np.ndarray) -> np.ndarray:
    """Tukey biweights of residual norms (scale: their MAD, at least 1 whitened unit)."""
    c = 4.685 * max(1.4826 * float(np.median(res)), 1.0)
    return np.where(res < c, (1.0 - (res / c) ** 2) ** 2, 0.0)


def _robust_lstsq(aw: np.ndarray, bw: np.ndarray, wt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """IRLS with Tukey biweights on the per-tile whitened residual norm from the weights
    ``wt``; ``(coef, weights)``. Redescending: tiles of a second plane or a moving object
    (up to nearly half of them) end with weight 0 instead of bending the pattern."""
    n = aw.shape[0]
    coef = np.zeros(aw.shape[2])
    for _ in range(10):
        sw = np.sqrt(wt)[:, None, None]
        coef = np.linalg.lstsq((aw * sw).reshape(2 * n, -1), (bw * sw[..., 0]).ravel(), rcond=None)[
            0
        ]
        new = _tukey(np.linalg.norm(bw - aw @ coef, axis=1))
        if np.allclose(new, wt, atol=1e-6):
            break
        wt = new
    return coef, wt


def _fit_pattern(
    centres: np.ndarray,
    shifts: np.ndarray,
    shape: tuple[int, int],
    cov: np.ndarray | None = None,
    floor: float = 0.02,
) -> ResidualPattern:
    """Robust least-squares fit of the pattern to the valid tiles' shifts.

    Each tile's two equations are weighted by the inverse of its covariance (plus ``floor``
    squared, px): a tile with structure in one direction only constrains that direction. Tukey
    biweights on the whitened residuals (IRLS, started about the median shift) keep the tiles
    of a second plane or a moving object from bending the pattern. The terms are nested
    (shift; + zoom and rotation; + anisotropic scale and shear; + the two perspective terms)
    and each step is kept only when it lowers the weighted residual significantly (F test at
    0.1 %, the robust weights of the larger model for both); a model needs 1.5 tiles per free
    parameter, so the higher terms of a small tile count are held at 0.
    """
    n = len(centres)
    radius = _radius(shape)
    full = _design(centres[:, 0], centres[:, 1], shape, radius)
    a3 = np.stack([full[:n], full[n:]], axis=1)  # (n, 2, 8)
    c = np.eye(2)[None] * floor**2 if cov is None else cov + np.eye(2)[None] * floor**2
    whiten = np.linalg.cholesky(np.linalg.inv(c)).transpose(0, 2, 1)  # L^T, info = L L^T
    bw = np.einsum("nij,nj->ni", whiten, shifts)
    # Start: Tukey weights about the median shift (the dominant motion covers most tiles).
    start = np.einsum("nij,j->ni", whiten, np.median(shifts, axis=0))
    wt = _tukey(np.linalg.norm(bw - start, axis=1))
    fits = {}
    for terms in _PATTERN_TERMS:
        if 2 * n < 3 * terms and terms > 2:
            break
        e = _expansion(terms)
        aw = np.einsum("nij,njk->nik", whiten, a3 @ e)
        coef, wt = _robust_lstsq(aw, bw, wt)
        fits[terms] = (e @ coef, aw, coef, wt)
    chosen = 2
    for terms in _PATTERN_TERMS[1:]:
        if terms not in fits:
            break
        _, aw, coef, wt = fits[terms]
        _, aw0, coef0, _ = fits[chosen]
        rss = float(np.sum(wt[:, None] * (bw - aw @ coef) ** 2))
        rss0 = float(np.sum(wt[:, None] * (bw - aw0 @ coef0) ** 2))
        dof = 2 * int(np.count_nonzero(wt > 0)) - terms
        if dof <= 0 or rss <= 0:
            chosen = terms
            continue
        f_stat = ((rss0 - rss) / (terms - chosen)) / (rss / dof)
        if f_stat > fdtri(terms - chosen, dof, 0.999):
            chosen = terms
    params, _, _, wt = fits[chosen]
    r = shifts - a3 @ params
    inl = wt > 0
    rms = float(np.sqrt(np.mean(np.sum(r[inl] ** 2, axis=1)))) if inl.any() else float("nan")
    tx, ty, a11, a12, a21, a22, p, q = (float(v) for v in params)
    zoom_px = 0.5 * (a11 + a22)
    rot_px = 0.5 * (a21 - a12)
    # the perspective terms move a corner (u, v) by (u, v) (p u + q v): at most this
    uc, vc = (shape[1] - 1) / 2.0 / radius, (shape[0] - 1) / 2.0 / radius
    return ResidualPattern(
        shift_x=tx,
        shift_y=ty,
        zoom=zoom_px / radius,
        rotation_deg=float(np.degrees(rot_px / radius)),
        shift_px=float(np.hypot(tx, ty)),
        zoom_px=zoom_px,
        rotation_px=rot_px,
        affine_px=float(np.hypot(0.5 * (a11 - a22), 0.5 * (a12 + a21))),
        perspective_px=abs(p) * uc + abs(q) * vc,
        radius=radius,
        parameters=tuple(float(v) for v in params),
        rms=rms,
        terms=chosen,
    )


# ------------------------------------------------------------------------------- tile shifts
@dataclass(frozen=True)
class _TileShifts:
    shifts: np.ndarray  # (N, 2) analysis pixels
    ncc: np.ndarray  # normalised cross-correlation of the re-centred tiles
    cov: np.ndarray  # (N, 2, 2) analysis pixels^2


class _PhasePlane:
    """Weighted least-squares fit of the phase plane of cross-power spectra (Stone et al. 2001).

    For ``dark(x + d) = bright(x)`` the cross-power spectrum ``F_dark conj(F_bright)`` is
    ``|F|^2 exp(-2 pi i f.d)``: its phase is a plane of slope ``-2 pi d``. Frequencies
    ``0 < |f| <= f_max`` (cycles/pixel; aliasing and interpolation errors grow above) are
    fitted, weighted by the cross-power magnitude.
    """

    def __init__(self, t: int, f_max: float = 0.3) -> None:
        fy = sfft.fftfreq(t)[:, None] * np.ones((1, t // 2 + 1))
        fx = sfft.rfftfreq(t)[None, :] * np.ones((t, 1))
        self.band = (fx * fx + fy * fy <= f_max * f_max) & ((fx != 0) | (fy != 0))
        self.fx, self.fy = fx[self.band], fy[self.band]
        self.index = np.flatnonzero(self.band.ravel())  # flat positions of the band
        # Independent frequencies: the Hann window correlates neighbours (about 1 in 4 free).
        self.neff = max(self.band.sum() / 4.0, 1.0)

    def fit(
        self, cross: np.ndarray, d: np.ndarray, iterations: int, workers: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        """Shifts ``(N, 2)`` refined from ``d`` and their covariances ``(N, 2, 2)``.

        ``iterations`` Gauss-Newton steps on the phase plane (the phase wrapped to
        ``(-pi, pi]`` about the current shift), then the residual phase's weighted mean square
        for the covariance. The compiled kernel (:func:`_plane_rows`) reads the band straight
        from ``cross`` (no complex temporaries of ``N x band``); its readable specification is
        :func:`hdrcore.registration.spec.plane_fit` (tests only).
        """
        n = cross.shape[0]
        flat = cross.reshape(n, -1)
        d0 = np.ascontiguousarray(d, np.float64)
        out = np.empty((n, 2))
        cov = np.empty((n, 2, 2))
        run_row_spans(
            n,
            workers,
            lambda i0, i1: _plane_rows(
                flat,
                self.index,
                self.fx,
                self.fy,
                d0,
                int(iterations),
                self.neff,
                out,
                cov,
                i0,
                i1,
            ),
        )
        return out, cov


@_njit
def _plane_rows(cross, index, fx, fy, d0, iterations, neff, out, cov, i0, i1):  # pragma: no cover
    """Tiles ``i0:i1`` of :meth:`_PhasePlane.fit`: ``cross`` ``(N, t * (t // 2 + 1))``, the band
    at flat ``index`` with frequencies ``fx, fy``; shifts into ``out``, covariances ``cov``.
    Each band frequency's phase ``arg(c)`` is taken once a tile; an iteration's phase about
    the shift ``d`` is then ``arg(c) + 2 pi (dx fx + dy fy)`` wrapped to ``[-pi, pi)``, the
    argument of ``c exp(2 pi i f.d)`` without an ``atan2`` an iteration (the same shifts to
    1e-15 px on a real phone pair's tiles, half the time)."""
    nb = index.size
    wb = np.empty(nb)
    phi = np.empty(nb)
    two_pi = 2.0 * np.pi
    inv_two_pi = 1.0 / two_pi
    for i in range(i0, i1):
        sxx = 0.0
        sxy = 0.0
        syy = 0.0
        for j in range(nb):
            c = cross[i, index[j]]
            a = math.hypot(c.real, c.imag)
            wb[j] = a
            phi[j] = math.atan2(c.imag, c.real)
            sxx += a * fx[j] * fx[j]
            sxy += a * fx[j] * fy[j]
            syy += a * fy[j] * fy[j]
        det = sxx * syy - sxy * sxy
        if not det > 0:
            det = np.inf
        dx = d0[i, 0]
        dy = d0[i, 1]
        ss = 0.0
        for it in range(iterations + 1):
            bx = 0.0
            by = 0.0
            ss = 0.0
            ax = two_pi * dx
            ay = two_pi * dy
            for j in range(nb):
                p = phi[j] + (ax * fx[j] + ay * fy[j])
                p -= two_pi * np.floor((p + np.pi) * inv_two_pi)
                wp = wb[j] * p
                bx += wp * fx[j]
                by += wp * fy[j]
                ss += wp * p
            if it == iterations:
                break
            bx = -bx / two_pi
            by = -by / two_pi
            ndx = dx + (syy * bx - sxy * by) / det
            ndy = dy + (sxx * by - sxy * bx) / det
            dx = ndx
            dy = ndy
        scale = ss / (4.0 * np.pi * np.pi * neff)
        out[i, 0] = dx
        out[i, 1] = dy
        cov[i, 0, 0] = scale * syy / det
        cov[i, 1, 1] = scale * sxx / det
        cov[i, 0, 1] = -scale * sxy / det
        cov[i, 1, 0] = -scale * sxy / det


def _peak_shifts(cross: np.ndarray, t: int, workers: int) -> np.ndarray:
    """Integer peak of the phase-correlation surface (whitened cross power), parabolic
    sub-pixel, ``(N, 2)`` as ``(dx, dy)``."""
    n = cross.shape[0]
    mag = np.abs(cross)
    tiny = 1e-20 + 1e-12 * mag.reshape(n, -1).max(axis=1)[:, None, None]
    surface = sfft.irfft2(cross / (mag + tiny), s=(t, t), axes=(1, 2), workers=workers)
    idx = np.argmax(surface.reshape(n, -1), axis=1)
    iy, ix = np.divmod(idx, t)
    rows = np.arange(n)

    def at(dy: int, dx: int) -> np.ndarray:
        return surface[rows, (iy + dy) % t, (ix + dx) % t]

    c, left, right, up, down = at(0, 0), at(0, -1), at(0, 1), at(-1, 0), at(1, 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        cx, cy = left - 2 * c + right, up - 2 * c + down
        ox = np.where(np.abs(cx) > 1e-12, 0.5 * (left - right) / cx, 0.0)
        oy = np.where(np.abs(cy) > 1e-12, 0.5 * (up - down) / cy, 0.0)
    ix = np.where(ix > t // 2, ix - t, ix)
    iy = np.where(iy > t // 2, iy - t, iy)
    return np.stack([ix + np.clip(ox, -0.5, 0.5), iy + np.clip(oy, -0.5, 0.5)], axis=1)


@_njit
def _extract_tiles(img, oy, ox, dy, dx, win, out, i0, i1):  # pragma: no cover - compiled
    """Tiles ``i0:i1``: ``img`` at ``(oy + dy + r, ox + dx + c)`` (Keys cubic, clamped at the
    edges), minus their window-weighted mean, times the window ``win``. ``img`` is finite
    (the callers fill a structure image's NaNs first): a tile at whole-pixel offsets is then
    its pixels as they are, read without the taps whose weights are 0 (Keys' weights at the
    fraction 0 are -0, 1, 0, -0, so the sums are these pixels to the bit)."""
    h, w = img.shape
    t = win.shape[0]
    wsum = 0.0
    for r in range(t):
        for c in range(t):
            wsum += win[r, c]
    tmp = np.empty((t, t + 3), np.float64)
    for i in range(i0, i1):
        fy0 = np.floor(dy[i])
        fx0 = np.floor(dx[i])
        fy = dy[i] - fy0
        fx = dx[i] - fx0
        y0 = oy[i] + int(fy0) - 1
        x0 = ox[i] + int(fx0) - 1
        mean = 0.0
        if fy == 0.0 and fx == 0.0:
            for r in range(t):
                yb = min(max(y0 + r + 1, 0), h - 1)
                for c in range(t):
                    v = np.float64(img[yb, min(max(x0 + c + 1, 0), w - 1)])
                    out[i, r, c] = v
                    mean += v * win[r, c]
        else:
            wy0, wy1, wy2, wy3 = keys4(fy)
            wx0, wx1, wx2, wx3 = keys4(fx)
            for r in range(t):
                ya = min(max(y0 + r, 0), h - 1)
                yb = min(max(y0 + r + 1, 0), h - 1)
                yc = min(max(y0 + r + 2, 0), h - 1)
                yd = min(max(y0 + r + 3, 0), h - 1)
                for c in range(t + 3):
                    xx = min(max(x0 + c, 0), w - 1)
                    tmp[r, c] = (
                        wy0 * img[ya, xx]
                        + wy1 * img[yb, xx]
                        + wy2 * img[yc, xx]
                        + wy3 * img[yd, xx]
                    )
            for r in range(t):
                for c in range(t):
                    v = (
                        wx0 * tmp[r, c]
                        + wx1 * tmp[r, c + 1]
                        + wx2 * tmp[r, c + 2]
                        + wx3 * tmp[r, c + 3]
                    )
                    out[i, r, c] = v
                    mean += v * win[r, c]
        mean /= wsum
        for r in range(t):
            for c in range(t):
                out[i, r, c] = (out[i, r, c] - mean) * win[r, c]


def _tiles(
    img: np.ndarray, oy: np.ndarray, ox: np.ndarray, d: np.ndarray, win: np.ndarray, workers: int
) -> np.ndarray:
    """Windowed, mean-free tiles ``(N, t, t)`` of ``img`` at ``(oy, ox) + d`` (``d``: dx, dy)."""
    dy = np.ascontiguousarray(d[:, 1], np.float64)
    dx = np.ascontiguousarray(d[:, 0], np.float64)
    n, t = oy.size, win.shape[0]
    out = np.empty((n, t, t), np.float32)
    oy64, ox64 = oy.astype(np.int64), ox.astype(np.int64)
    win64 = win.astype(np.float64)
    run_row_spans(
        n, workers, lambda i0, i1: _extract_tiles(img, oy64, ox64, dy, dx, win64, out, i0, i1)
    )
    return out


def _ncc_at(
    ga: np.ndarray,
    gb: np.ndarray,
    oy: np.ndarray,
    ox: np.ndarray,
    d: np.ndarray,
    t: int,
    workers: int,
) -> np.ndarray:
    """Normalised cross-correlation of the bright tiles with the dark tiles taken at ``d``."""
    win = np.outer(_hann(t), _hann(t)).astype(np.float32)
    ta = _tiles(ga, oy, ox, d, win, workers)
    tb = _tiles(gb, oy, ox, np.zeros_like(d), win, workers)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.einsum("nij,nij->n", ta, tb, dtype=np.float64) / np.sqrt(
            np.einsum("nij,nij->n", ta, ta, dtype=np.float64)
            * np.einsum("nij,nij->n", tb, tb, dtype=np.float64)
        )


#: A tile is re-centred again only while its last re-centring moved it by more than this
#: (analysed pixels): the window's pull is a fraction of the step, so below it the next pass
#: changes the shift by a few thousandths of a pixel (see :func:`_tile_shifts`).
RECENTRE_TOL = 0.01


def _tile_shifts(
    ga: np.ndarray,
    gb: np.ndarray,
    oy: np.ndarray,
    ox: np.ndarray,
    t: int,
    workers: int,
    *,
    recentre: int = 2,
) -> _TileShifts:
    """Shift per tile between the structure images ``ga`` (dark) and ``gb`` (bright).

    Phase correlation (integer peak, parabolic start, phase-plane fit); then the dark tile is
    taken again at the estimated shift (Keys cubic) and the remaining shift fitted, up to
    ``recentre`` times: a window common to both tiles pulls the estimate towards zero by a
    fraction of the shift, which vanishes once the dark tile is re-centred on the same content.
    Only tiles whose shift is plausible (under a quarter tile) are re-centred, and a tile whose
    last re-centring moved it by at most ``RECENTRE_TOL`` is not re-centred again (on an
    aligned real pair most tiles: the second pass is then skipped for them).
    """
    win = np.outer(_hann(t), _hann(t)).astype(np.float32)
    zero = np.zeros((oy.size, 2))
    tb = _tiles(gb, oy, ox, zero, win, workers)
    fb_conj = np.conj(sfft.rfft2(tb, axes=(1, 2), workers=workers))
    ta = _tiles(ga, oy, ox, zero, win, workers)
    cross = sfft.rfft2(ta, axes=(1, 2), workers=workers) * fb_conj
    plane = _PhasePlane(t)
    d, cov = plane.fit(cross, _peak_shifts(cross, t, workers), 2, workers)
    active = np.flatnonzero(np.all(np.isfinite(d), axis=1) & (np.abs(d).max(axis=1) < t / 4))
    for _ in range(recentre):
        if active.size == 0:
            break
        base = d[active]
        sub = _tiles(ga, oy[active], ox[active], base, win, workers)
        cross = sfft.rfft2(sub, axes=(1, 2), workers=workers) * fb_conj[active]
        step, c = plane.fit(cross, np.zeros_like(base), 1, workers)
        d[active], cov[active], ta[active] = base + step, c, sub
        moved = np.all(np.isfinite(step), axis=1) & (np.abs(step).max(axis=1) > RECENTRE_TOL)
        active = active[moved & (np.abs(d[active]).max(axis=1) < t / 4)]
    na = np.sqrt(np.einsum("nij,nij->n", ta, ta, dtype=np.float64))
    nb = np.sqrt(np.einsum("nij,nij->n", tb, tb, dtype=np.float64))
    with np.errstate(invalid="ignore", divide="ignore"):
        ncc = np.einsum("nij,nij->n", ta, tb, dtype=np.float64) / (na * nb)
    return _TileShifts(d, ncc, cov)


# ------------------------------------------------------------------------------- entry point
@_njit
def _box_counts(mask, oy, ox, t, out):  # pragma: no cover - compiled
    """The number of set samples of ``mask`` in each ``t x t`` box at ``(oy, ox)``."""
    for i in range(oy.size):
        n = 0
        for r in range(oy[i], oy[i] + t):
            for c in range(ox[i], ox[i] + t):
                if mask[r, c]:
                    n += 1
        out[i] = n


@_njit
def _finite_mean_fill(x, out):  # pragma: no cover - compiled
    """``out``: ``x`` with its NaNs and infinities replaced by the mean of its finite values
    (``v - v == 0`` holds for finite ``v`` only; no fast-math)."""
    h, w = x.shape
    total = 0.0
    n = 0
    for r in range(h):
        for c in range(w):
            v = x[r, c]
            if v - v == 0.0:
                total += v
                n += 1
    mean = total / n if n else 0.0
    for r in range(h):
        for c in range(w):
            v = x[r, c]
            out[r, c] = v if v - v == 0.0 else mean


def _nan_to_mean(x: np.ndarray) -> np.ndarray:
    """A copy of ``x`` whose non-finite values are the mean of its finite ones (a structure
    image outside a warped frame: flat, so it adds no phase-correlation peak)."""
    out = np.empty_like(x)
    _finite_mean_fill(x, out)
    return out


def _box_fraction(mask: np.ndarray, oy: np.ndarray, ox: np.ndarray, t: int) -> np.ndarray:
    """The fraction of ``mask`` set in each ``t x t`` box at ``(oy, ox)`` (exact: counted per
    box)."""
    counts = np.empty(oy.size, np.int64)
    _box_counts(mask, oy.astype(np.int64), ox.astype(np.int64), int(t), counts)
    return counts / float(t * t)


def _choose_level(shape: tuple[int, int], max_pixels: float) -> int:
    h, w = shape
    level = 0
    while h * w / 4.0**level > max_pixels and min(h, w) >> (level + 1) >= 64:
        level += 1
    return level


def _choose_tile(shape: tuple[int, int]) -> int:
    side = min(shape)
    for t in (128, 64, 32):
        if side >= 6 * t:
            return t
    return 32


def residual_motion(
    dark: np.ndarray,
    bright: np.ndarray,
    ratio: float = 1.0,
    matrix: np.ndarray | None = None,
    *,
    saturation: float = 1.0,
    noise_floor: float = 0.0,
    lut: np.ndarray | None = None,
    tile: int | None = None,
    max_pixels: float = 2.5e6,
    aligned_px: float = 0.3,
    local_px: float = 1.0,
    min_confidence: float | None = None,
    min_tiles: int = 4,
    min_in_range: float = 0.5,
    workers: int | None = None,
    memo: dict | None = None,
    only: np.ndarray | None = None,
) -> ResidualMotion:
    """Measure the residual motion of an aligned pair, tile by tile (see the module docstring).

    Parameters
    ----------
    dark, bright : single-channel linear frames ``(H, W)`` of the same size (float, NaN allowed
        outside the valid area), or integer levels read through ``lut`` (``lut[level]`` is the
        linear value; any strides, e.g. a channel view of the RGB frame).
    ratio : exposure ratio ``k = t_bright / t_dark``; the dark frame is compared times ``k``.
    matrix : the pair matrix (2x3 or 3x3) mapping bright-frame pixel coordinates to the dark
        frame, as returned by the registration; the bright frame is warped onto the dark frame
        with it (Keys cubic, on the analysis level). ``None``: the frames are already aligned.
    saturation, noise_floor : linear levels bounding the range both frames must expose (the
        dark frame's floor is multiplied by ``k``; at least 0.1 % of ``saturation``).
    tile : tile size in analysed pixels (default: 128, 64 or 32, at least six tiles across the
        short side); ``max_pixels``: the analysis level is the first 2x2 block-mean level with
        at most this many pixels.
    aligned_px : the pair is ``aligned`` when the median shift is at most this, no pattern
        component moves the corners by more than twice this, and no group of neighbouring
        tiles is off by more than ``local_px`` after the pattern (full-resolution pixels).
    min_confidence : a tile counts when the normalised cross-correlation of its two structure
        tiles (re-centred) is at least this (default the larger of ``CONFIDENCE_PER_TILE /
        tile`` and ``MIN_CONFIDENCE``), the
        standard error of its shift at most ``MAX_SIGMA`` analysed pixels and at least
        ``min_in_range`` of it is exposed well in both frames; ``min_tiles``: fewer confident
        tiles are ``unmeasured``. ``workers``: threads of the compiled passes (default two).
    memo : a dict (or a :class:`~hdrcore.registration._memo.RunMemo`) kept by a caller that
        measures one frame against several others (local refinement) or the same frames again
        (a registration run again, :func:`hdrcore.registration._problem.register_with`): each
        frame's block means and structure image are computed once and looked up by where the
        frame's pixels lie (the memo keeps the frame alive) and the values they depend on; the
        frames must not be changed while it is used. Frames warped by ``matrix`` are not
        memoised (their block means before the warp are).
    only : a flag per tile of the grid (raster order, as ``centres``): only these are measured
        (the others are not valid). Local refinement measures again, through its field, only
        the tiles a first measurement of the same grid found confident.

    Returns a :class:`ResidualMotion`; its ``describe()`` is one line such as "0.12 px median
    over 80 tiles: aligned", "a zoom of +0.40 % is left (1.4 px at the corners): the motion
    model has no scale, or its scale is wrong" or "3.1 px of residual motion at the lower left
    (4 tiles): parallax, a moving object or flare".
    """
    t0 = time.perf_counter()
    a = np.asarray(dark)
    b = np.asarray(bright)
    if a.ndim != 2 or a.shape != b.shape:
        raise ParameterError(
            "residual motion needs two single-channel frames of the same size",
            expected="two (H, W) arrays",
            found=f"{a.shape} and {b.shape}",
        )
    if not (np.isfinite(ratio) and ratio > 0):
        raise ParameterError("the exposure ratio must be positive and finite", found=str(ratio))
    if not (saturation > 0 and 0 <= noise_floor < saturation):
        raise ParameterError(
            "need 0 <= noise_floor < saturation",
            found=f"noise_floor {noise_floor}, saturation {saturation}",
        )
    if lut is not None:
        lut = np.ascontiguousarray(lut, np.float32)
        if a.dtype.kind not in "ui" or b.dtype.kind not in "ui":
            raise ParameterError(
                "frames read through a lut must be integer levels", found=f"{a.dtype} and {b.dtype}"
            )
        top = max(int(a.max(initial=0)), int(b.max(initial=0)))
        if top >= lut.size:
            raise ParameterError(
                "a level is beyond the end of the lut",
                expected=f"levels < {lut.size}",
                found=str(top),
            )
    h, w = a.shape
    if min(h, w) < 64:
        raise ParameterError(
            "frames too small to measure residual motion",
            expected="at least 64 x 64 pixels",
            found=f"{h}x{w}",
        )
    nw = worker_count(workers)
    level = _choose_level((h, w), max_pixels)
    f = 1 << level

    # each frame's blocks saturated where a pixel leaves the range both frames share: the dark
    # frame is compared times k, so its pixels at saturation / k already do (the same blocks
    # in both frames, up to noise)
    lut_k = table_key(lut) if memo is not None else None

    def reduced(src: np.ndarray, sat: float) -> np.ndarray:
        if f == 1 and lut is None:
            return _reduce(src, f, lut, nw, sat)
        # the block sums and maxima do not depend on sat: a saturation step, and a frame that
        # is the dark one of a pair and the bright one of the next, sum its blocks once
        key = ("blocks", array_key(src), f, lut_k)
        hit = None if memo is None else memo.get(key)
        if hit is not None:
            return _mark(hit[1], sat)
        stats = _block_stats(src, f, lut, nw)
        if memo is not None:
            memo[key] = (src, stats)
        return _mark(stats, sat)

    al = reduced(a, float(saturation) / max(float(ratio), 1.0))
    bl = reduced(b, float(saturation))
    hl, wl = al.shape
    if matrix is not None:
        hm = _homogeneous(matrix)
        s = np.array([[f, 0.0, (f - 1) / 2.0], [0.0, f, (f - 1) / 2.0], [0.0, 0.0, 1.0]])
        back = np.linalg.inv(s) @ np.linalg.inv(hm) @ s  # dark level -> bright level
        bl = _warp(bl, back, (hl, wl), nw)

    k = float(ratio)
    lo = max(float(noise_floor), 1e-3 * float(saturation))
    hi = float(saturation)

    def structure(
        src: np.ndarray, level: np.ndarray, scale: float | None, warped: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        key = ("structure", array_key(src), scale, k * lo, hi, f, lut_k)
        hit = None if memo is None or warped else memo.get(key)
        if hit is not None:
            return hit[1]
        out = _structure(level if scale is None else level * np.float32(scale), k * lo, hi, nw)
        if memo is not None and not warped:
            memo[key] = (src, out, lut)  # the frame and lut kept alive: ids stay unique
        return out

    ga, in_a = structure(a, al, k, False)
    gb, in_b = structure(b, bl, None, matrix is not None)
    nan_a, nan_b = ~np.isfinite(ga), ~np.isfinite(gb)

    t = int(tile) if tile is not None else _choose_tile((hl, wl))
    if t < 16 or t > min(hl, wl) - 2:
        raise ParameterError(
            "tile size out of range", expected=f"16..{min(hl, wl) - 2}", found=str(t)
        )
    ny, nx = max(1, (hl - 2) // t), max(1, (wl - 2) // t)
    ys = np.rint(np.linspace(1, hl - 1 - t, ny)).astype(int)
    xs = np.rint(np.linspace(1, wl - 1 - t, nx)).astype(int)
    oy, ox = (a.ravel() for a in np.meshgrid(ys, xs, indexing="ij"))
    n = oy.size
    both_in = in_a & in_b
    bad = nan_a | nan_b
    frac_in = _box_fraction(both_in, oy, ox, t)
    frac_nan = _box_fraction(bad, oy, ox, t)
    # outside the warped frame: the tile's mean gradient (drops tiles > 10 %)
    if nan_a.any():
        ga = _nan_to_mean(ga)
    if nan_b.any():
        gb = _nan_to_mean(gb)
    # Only tiles that can count are measured (a tile mostly outside the range both frames
    # expose, or outside the warped frame, is never valid): NaN shifts, confidence 0 for others.
    can = (frac_in >= min_in_range) & (frac_nan <= 0.1)
    if only is not None:
        only = np.asarray(only, bool)
        if only.shape != can.shape:
            raise ParameterError(
                "one flag per tile of the grid", expected=str(can.size), found=str(only.size)
            )
        can &= only
    measurable = np.flatnonzero(can)
    ts = _TileShifts(np.full((n, 2), np.nan), np.zeros(n), np.full((n, 2, 2), np.nan))
    if measurable.size:
        part = _tile_shifts(ga, gb, oy[measurable], ox[measurable], t, nw)
        ts.shifts[measurable], ts.ncc[measurable], ts.cov[measurable] = (
            part.shifts,
            part.ncc,
            part.cov,
        )
    min_conf = (
        max(CONFIDENCE_PER_TILE / t, MIN_CONFIDENCE)
        if min_confidence is None
        else float(min_confidence)
    )
    conf = np.nan_to_num(ts.ncc, nan=0.0)
    with np.errstate(invalid="ignore"):  # worst-direction standard error, analysed pixels
        tr = ts.cov[:, 0, 0] + ts.cov[:, 1, 1]
        dt = ts.cov[:, 0, 0] * ts.cov[:, 1, 1] - ts.cov[:, 0, 1] ** 2
        sig_l = np.sqrt(np.maximum(0.5 * tr + np.sqrt(np.maximum(0.25 * tr * tr - dt, 0)), 0))
    sig_l = np.where(np.isfinite(sig_l), sig_l, np.inf)
    valid = (
        (conf >= min_conf)
        & (sig_l <= MAX_SIGMA)
        & (frac_in >= min_in_range)
        & (frac_nan <= 0.1)
        & np.all(np.isfinite(ts.shifts), axis=1)
        & (np.abs(ts.shifts).max(axis=1) < t / 4)
    )
    centres = np.stack(
        [(ox + (t - 1) / 2.0) * f + (f - 1) / 2.0, (oy + (t - 1) / 2.0) * f + (f - 1) / 2.0], axis=1
    )
    shifts = ts.shifts * f
    sigma = sig_l * f
    cov = ts.cov * (f * f)
    mags = np.hypot(shifts[:, 0], shifts[:, 1])
    local = np.full(n, np.nan)
    sensor = np.zeros(n, bool)
    ambiguous = np.zeros(n, bool)
    pattern, pred = None, None
    if valid.sum() >= min_tiles:
        pattern = _fit_pattern(centres[valid], shifts[valid], (h, w), cov[valid], 0.05 * f)
        pred = pattern.predict(centres[:, 0], centres[:, 1], (h, w))
        local = np.hypot(*(shifts - pred).T)
        if matrix is not None:
            # Structure fixed to the sensor (fixed-pattern noise, hot pixels, dust, JPEG
            # blocks) does not move with the scene: after the warp it shows the alignment
            # itself, H^-1 c - c, and says nothing about the scene's alignment.
            fixed = _field(np.linalg.inv(hm), centres)
            apart = np.hypot(*(fixed - pred).T)
            sensor = (
                valid
                & (apart > 3.0 * f)
                & (np.hypot(*(shifts - fixed).T) <= np.maximum(1.0 * f, 0.1 * apart))
            )
        # A tile far off the pattern that matches about as well where the pattern says is
        # ambiguous (the wrong period of a repetitive texture), not a local motion.
        far = np.flatnonzero(valid & ~sensor & (local > 3.0 * f))
        if far.size:
            at = _ncc_at(ga, gb, oy[far], ox[far], pred[far] / f, t, nw)
            ambiguous[far[at >= 0.8 * conf[far]]] = True
        if (valid & ~sensor & ~ambiguous).sum() >= min_tiles:
            valid &= ~sensor & ~ambiguous
        else:  # too few left: keep them rather than say nothing
            sensor[:] = ambiguous[:] = False
    nv = int(valid.sum())
    worst, region = -1, ""
    if pattern is not None:
        off = valid & (local > local_px)
        coherent = _coherent(off, shifts - pred, ny, nx, 0.5 * local_px)
        lv = np.where(coherent if coherent.any() else valid, local, -np.inf)
        worst = int(np.argmax(lv))
        where = centres[coherent].mean(axis=0) if coherent.any() else centres[worst]
        region = region_name(where[0], where[1], (h, w))
        med = float(np.median(mags[valid]))
        p90 = float(np.percentile(mags[valid], 90))
        mx = float(mags[valid].max())
        status, kind, message = _verdict(
            pattern, med, p90, mags, local, valid, coherent, off, region, aligned_px, local_px
        )
        if sensor.any():
            k = int(sensor.sum())
            message += (
                f"; {k} tile{'s follow' if k > 1 else ' follows'} the sensor, not the "
                f"scene (fixed-pattern noise or dust), left out"
            )
    else:
        med = p90 = mx = float("nan")
        status, kind = "unmeasured", ""
        why = (
            "no tile is textured"
            if not np.any(frac_in >= min_in_range) or not np.any(conf > 0)
            else "no tile matches"
        )
        message = (
            f"{nv} of {n} tiles confident ({why} in the exposure range both frames "
            f"share): the residual motion cannot be measured"
        )
    return ResidualMotion(
        shape=(h, w),
        level=level,
        tile=t,
        centres=centres,
        shifts=shifts,
        confidence=conf,
        sigma=sigma,
        in_range=frac_in,
        valid=valid,
        local=local,
        median=med,
        p90=p90,
        max=mx,
        pattern=pattern,
        worst=worst,
        worst_region=region,
        status=status,
        kind=kind,
        message=message,
        aligned_px=float(aligned_px),
        local_px=float(local_px),
        sensor=sensor,
        ambiguous=ambiguous,
        seconds=time.perf_counter() - t0,
    )


def _field(m: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Displacement ``m(p) - p`` (3x3) at ``points`` ``(N, 2)``."""
    x, y = points[:, 0], points[:, 1]
    zw = m[2, 0] * x + m[2, 1] * y + m[2, 2]
    return np.stack(
        [
            (m[0, 0] * x + m[0, 1] * y + m[0, 2]) / zw - x,
            (m[1, 0] * x + m[1, 1] * y + m[1, 2]) / zw - y,
        ],
        axis=1,
    )


def coherent_tiles(res: ResidualMotion) -> np.ndarray:
    """The tiles of a measurement that move on their own: valid, off the global pattern by
    more than ``local_px``, with a neighbour that agrees (see :func:`_coherent`); a boolean
    per tile (none without a pattern)."""
    if res.pattern is None:
        return np.zeros(res.valid.shape, bool)
    nx = int(np.unique(res.centres[:, 0]).size)
    ny = res.centres.shape[0] // max(nx, 1)
    pred = res.pattern.predict(res.centres[:, 0], res.centres[:, 1], res.shape)
    off = res.valid & (res.local > res.local_px)
    return _coherent(off, res.shifts - pred, ny, nx, 0.5 * res.local_px)


def _coherent(off: np.ndarray, resid: np.ndarray, ny: int, nx: int, tol: float) -> np.ndarray:
    """Tiles of ``off`` with a neighbour (8-connected on the tile grid) also in ``off`` whose
    residual after the pattern agrees within ``tol`` px or 30 %: parallax and moving objects
    span neighbouring tiles the same way, false matches (noise, the wrong period of a
    repetitive texture) do not."""
    out = np.zeros_like(off)
    for i in np.flatnonzero(off):
        r, c = divmod(int(i), nx)
        for rr in range(max(r - 1, 0), min(r + 2, ny)):
            for cc in range(max(c - 1, 0), min(c + 2, nx)):
                j = rr * nx + cc
                if (
                    j != i
                    and off[j]
                    and np.hypot(*(resid[i] - resid[j]))
                    <= max(tol, 0.3 * float(max(np.hypot(*resid[i]), np.hypot(*resid[j]))))
                ):
                    out[i] = True
    return out


def _verdict(
    pattern: ResidualPattern,
    med: float,
    p90: float,
    mags: np.ndarray,
    local: np.ndarray,
    valid: np.ndarray,
    coherent: np.ndarray,
    off: np.ndarray,
    region: str,
    aligned_px: float,
    local_px: float,
) -> tuple[ResidualStatus, str, str]:
    """``(status, kind, message)`` from the summarised field (see :func:`residual_motion`).

    A local residual needs neighbouring tiles that agree (:func:`_coherent`); tiles off on their
    own are counted in the message but do not decide the status.
    """
    comps = pattern.component_px()
    name = max(comps, key=lambda c: comps[c])
    big = comps[name]
    n_local = int(np.count_nonzero(coherent))
    local_worst = float(local[coherent].max()) if n_local else 0.0
    n_alone = int(np.count_nonzero(off & ~coherent))
    alone = (
        f" ({n_alone} isolated tile{'s' if n_alone > 1 else ''} off by up to "
        f"{float(mags[off & ~coherent].max()):.1f} px)"
        if n_alone
        else ""
    )
    if med <= aligned_px and big <= 2 * aligned_px and local_worst <= local_px:
        return ("aligned", "", f"{med:.2f} px median over {int(valid.sum())} tiles: aligned{alone}")
    if big > 2 * aligned_px and big >= local_worst:
        if name == "zoom":
            what = f"a zoom of {100 * pattern.zoom:+.2f} % is left ({big:.1f} px at the corners)"
        elif name == "rotation":
            what = (
                f"a rotation of {pattern.rotation_deg:+.3f} deg is left ({big:.1f} px at "
                f"the corners)"
            )
        elif name == "shift":
            what = (
                f"a shift of {big:.1f} px is left (dx {pattern.shift_x:+.2f}, "
                f"dy {pattern.shift_y:+.2f})"
            )
        elif name == "perspective":
            what = f"a perspective tilt of {big:.1f} px at the corners is left"
        else:
            what = f"an anisotropic scale or shear of {big:.1f} px at the corners is left"
        return "misaligned", name, f"{what}: {_HINTS[name]}"
    if local_worst > local_px:
        size = float(np.median(mags[coherent]))
        return (
            "misaligned",
            "local",
            f"{size:.1f} px of residual motion at the {region} ({n_local} tiles): "
            f"parallax, a moving object or flare",
        )
    return (
        "misaligned",
        "scattered",
        f"{med:.2f} px median residual motion (90 % under {p90:.2f} px), no global pattern: "
        f"noise, blur or a poor match{alone}",
    )
