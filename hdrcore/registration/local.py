"""Local refinement: a smooth displacement field after the global motion (parallax, lens).

A homography aligns one plane. Objects nearer than it move against it by a few pixels between
hand-held frames; HDR+ (Hasinoff et al. 2016, section 4) therefore aligns tiles of 16-64 px
after a coarse global step. We estimate, after the global registration, one displacement per
node of a grid ``tile`` pixels apart (:class:`~hdrcore.registration.field.DisplacementField`,
interpolated bilinearly: no seams), on the working level (at most ``MAX_LEVEL_PIXELS``):

1. both frames of the pair are resampled onto the reference grid through their motion;
2. per tile of ``tile`` full-resolution pixels, the shift between them by phase correlation of
   their exposure-invariant structure (the measurement of
   :func:`hdrcore.registration.residual.residual_motion`, with its confidence, standard error,
   exposure-range and repetitive-texture tests: only confident tiles count);
3. the node displacements fitted to the tile shifts by weighted least squares (weights
   ``1 / sigma^2``) with a membrane term between 4-neighbour nodes (``SMOOTHNESS`` times the
   median weight: smooth, and nodes without a confident tile filled from their neighbours) and
   a weak pull towards zero (``PULL``: far from any measurement the global motion stands);
4. steps 2-3 again through the field (``ROUNDS``).

Why tiles and not a per-pixel eq. 7 Gauss-Newton field (the first version): on the real phone
brackets the normalised difference of eq. 7 is biased by what the response, white balance and
the phones' local tone mapping leave between two exposures; a free field follows those
brightness differences (25 px of drift on a Pixel 7 pair the homography leaves at 0.47 px, even
with a per-node gain), while the structure tiles' phase correlation ignores them.

Frames are refined outwards from the reference along the chain of consecutive pairs (their
exposures overlap most, as for the global fit): frame ``k`` is compared with its neighbour
``j`` (one step nearer the reference) already resampled through its own refined motion, so the
field of ``k`` is relative to the reference. A field is kept only when it pays: the pair's
residual motion measured independently (:func:`hdrcore.registration.residual.residual_motion`:
phase correlation of gradient tiles on its own tile grid) falls by at least ``min_gain`` of
itself in its median or its 90th percentile (a near object moves a group of tiles) without the
median growing, or a misaligned pair becomes aligned, and as many tiles stay measurable (a field
that scrambles part of the frame makes its tiles unmeasurable, which flatters the rest).
Otherwise the frame keeps its global motion alone (``kept`` False) and the reason is said.

The check reads the working level (see ``CHECK_CUBIC_FACTORS`` for how);
``bench/bench_local.py`` measures the result independently at full resolution, beside OpenCV's
DIS optical flow.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse.linalg import spsolve

from .._numba import njit as _njit
from .._threads import run_row_spans, thread_map
from ..errors import ParameterError
from ..geometry import keys_row_at, keys_row_scratch, keys_row_weights
from ..status import ResidualStatus
from .field import DisplacementField, map_points

__all__ = ["LocalFrame", "LocalRefinement", "refine_bracket", "choose_tile"]

log = logging.getLogger(__name__)

#: Pixels per level the refinement works on at its finest: at most this many (a 24 MP frame is
#: refined at a quarter of its size, an 8 MP one at half, small frames at full size).
MAX_LEVEL_PIXELS = 3.0e6

#: Level factors at which the keep-check reads both frames with Keys cubic, as the merge reads
#: them (elsewhere bilinear). Measured: at half size (8 MP phone brackets) Keys gives the same
#: fields, decisions and full-resolution residuals as a Keys check on the full-resolution frames
#: (which costs far more: ``bench/bench_local.py``); at full size its wider taps drop more tiles
#: next to clipped areas (a rendered near object went unseen); on the 4x4 block means of a
#: 24 MP pair it reads their aliasing: an exactly aligned pair measures 0.35 / 0.99 px (median /
#: 90th percentile) with Keys, 0.24 / 0.52 bilinear, 0.12 / 0.29 px on the full frames.
CHECK_CUBIC_FACTORS = (2,)

#: Rounds of measure-and-fit per frame (the tile shifts are measured again through the field).
ROUNDS = 2

#: Weight of the membrane term relative to the median weight of a tile (see module doc).
SMOOTHNESS = 0.3

#: Pull of every node towards zero (the global motion), relative to the membrane: where no tile
#: is measured the field decays to the global motion within a few nodes instead of carrying a
#: neighbour's parallax across the frame.
PULL = 0.1

#: Tukey's biweight constant, in units of a tile's standard error (at least ``MIN_SPREAD``).
TUKEY = 4.685
MIN_SPREAD = 0.25

#: Passes of the robust fit (1: plain weighted least squares).
PASSES = 1

#: A field is kept when the independent residual (the keep-check's median or 90th percentile)
#: falls by this fraction of itself. Measured on the real phone brackets (every consecutive
#: pair refined; the check's gain against the full-resolution residual, median / p90 px, of
#: ``bench_registration``'s ours homography +- field): the fields with a gain of 0.088-0.13
#: lower both (Xperia 0.178 / 0.359 -> 0.128 / 0.325 and 0.186 / 0.416 -> 0.118 / 0.335,
#: Pixel 7 0.307 / 0.934 -> 0.272 / 0.724) and were left out at 0.15; the two below 0.08 raise
#: one (Xperia, gain 0.067: p90 0.679 -> 0.783; frobisher, a tripod pair, 0.074: median 0.057 ->
#: 0.066). A tripod pair's field is at most 0.08 px median where kept (frobisher, memorial).
MIN_GAIN = 0.08

#: Rounds after the first re-measure a confident tile's neighbour when its confidence reached
#: ``NEAR_CONFIDENCE`` of the threshold and its standard error at most ``NEAR_SIGMA`` times the
#: limit (see :func:`refine_bracket`; on the 24 MP bench pair the standard error is what keeps
#: 790 of 1008 well-correlated tiles out).
NEAR_CONFIDENCE = 0.5
NEAR_SIGMA = 1.5


def _tile_thresholds(tile: int) -> tuple[float, float]:
    """The residual measurement's confidence and standard-error limits for ``tile`` (its own
    pixels)."""
    from .residual import CONFIDENCE_PER_TILE, MAX_SIGMA, MIN_CONFIDENCE

    return max(CONFIDENCE_PER_TILE / tile, MIN_CONFIDENCE), MAX_SIGMA


@dataclass(frozen=True, eq=False)
class LocalFrame:
    """The refinement of one frame against its neighbour ``against`` (one step nearer the
    reference). ``field``: reference pixel -> extra displacement in frame pixels (None when
    not kept); ``before`` / ``after``: the pair's independent residual, median over tiles
    (full-resolution px; NaN when not measured); ``message`` says what happened."""

    frame: int
    against: int
    candidate: DisplacementField | None = field(repr=False)
    kept: bool
    before: float
    after: float
    before_status: ResidualStatus
    after_status: ResidualStatus
    message: str
    seconds: float
    before_p90: float = float("nan")
    after_p90: float = float("nan")

    @property
    def field(self) -> DisplacementField | None:
        """The field in use: the candidate when kept."""
        return self.candidate if self.kept else None

    def to_json(self) -> dict:
        def f(x: float) -> float | None:
            return None if not np.isfinite(x) else round(float(x), 4)

        cand = self.candidate
        return {
            "frame": self.frame,
            "against": self.against,
            "kept": self.kept,
            "residual_before_px": f(self.before),
            "residual_after_px": f(self.after),
            "residual_p90_before_px": f(self.before_p90),
            "residual_p90_after_px": f(self.after_p90),
            "status_before": self.before_status,
            "status_after": self.after_status,
            "field_median_px": None if cand is None else f(cand.median_px),
            "field_max_px": None if cand is None else f(cand.max_px),
            "field": None if self.field is None else self.field.to_json(),
            "message": self.message,
            "seconds": round(self.seconds, 3),
        }


@dataclass(frozen=True, eq=False)
class LocalRefinement:
    """Displacement fields of a bracket: ``fields[k]`` for frame ``k`` (None for the
    reference and frames whose field was not kept), per-frame details in ``frames``."""

    reference: int
    tile: int
    level: int
    fields: tuple[DisplacementField | None, ...]
    frames: tuple[LocalFrame, ...]
    seconds: float

    @property
    def used(self) -> bool:
        return any(f is not None for f in self.fields)

    def summary(self) -> str:
        kept = [f for f in self.frames if f.kept]
        if not self.frames:
            return "local refinement: nothing to refine"
        if not kept:
            return (
                f"local refinement: no field kept ({len(self.frames)} frames tried; the "
                "global motion alone leaves as little)"
            )
        parts = ", ".join(f"frame {f.frame} {f.before:.2f} -> {f.after:.2f} px" for f in kept)
        return f"local refinement ({self.tile} px tiles): {parts}"

    def to_json(self) -> dict:
        return {
            "reference": self.reference,
            "tile": self.tile,
            "level": self.level,
            "seconds": round(self.seconds, 3),
            "summary": self.summary(),
            "frames": [f.to_json() for f in self.frames],
        }


def choose_tile(shape: tuple[int, int]) -> int:
    """Node spacing: about a sixteenth of the short side as a power of two, 32-128 px (128 px
    on phone and camera frames, HDR+'s scale of parallax; 32 px on a 640 x 426 frame)."""
    s = min(shape) / 16.0
    return int(min(128, max(32, 2 ** round(np.log2(max(s, 1.0))))))


def _level_for(shape: tuple[int, int], tile: int) -> int:
    level = 0
    h, w = shape
    while (h >> level) * (w >> level) > MAX_LEVEL_PIXELS and tile >> (level + 1) >= 8:
        level += 1
    return level


# ----------------------------------------------------------------------------- images
@_njit
def _prepare_rows(img, f, saturation, out, r0, r1):  # pragma: no cover
    """Rows ``r0:r1`` of :func:`_prepare` on linear frames (one pass, no full-size
    temporary)."""
    ww = out.shape[1]
    inv = 1.0 / (f * f)
    for y in range(r0, r1):
        for x in range(ww):
            acc = 0.0
            clipped = False
            for r in range(y * f, y * f + f):
                for c in range(x * f, x * f + f):
                    v = img[r, c]
                    if v >= saturation:
                        clipped = True
                    acc += v
            out[y, x] = np.inf if clipped else acc * inv


@_njit
def _prepare_rows_lut(img, lut, f, saturation, out, r0, r1):  # pragma: no cover
    """:func:`_prepare_rows` on integer levels read through ``lut``."""
    ww = out.shape[1]
    inv = 1.0 / (f * f)
    for y in range(r0, r1):
        for x in range(ww):
            acc = 0.0
            clipped = False
            for r in range(y * f, y * f + f):
                for c in range(x * f, x * f + f):
                    v = lut[img[r, c]]
                    if v >= saturation:
                        clipped = True
                    acc += v
            out[y, x] = np.inf if clipped else acc * inv


def _prepare(img: np.ndarray, lut: np.ndarray | None, f: int, saturation: float) -> np.ndarray:
    """A frame at the working level: block means of the linear values, +inf where a block
    holds a sample at or above saturation (an interpolation touching it is not finite).
    Compiled (:func:`_prepare_rows`, :func:`_prepare_rows_lut`); the readable specification is
    :func:`hdrcore.registration.spec.prepare` (tests only)."""
    h, w = img.shape
    out = np.empty((h // f, w // f), np.float32)
    sat = np.float32(saturation)  # the comparison of the float32 specification
    if lut is None:
        src = np.asarray(img, np.float32)
        run_row_spans(out.shape[0], None, lambda r0, r1: _prepare_rows(src, f, sat, out, r0, r1))
    else:
        run_row_spans(
            out.shape[0], None, lambda r0, r1: _prepare_rows_lut(img, lut, f, sat, out, r0, r1)
        )
    return out


class _Grid:
    """The reference grid of one level (``f`` full pixels per level pixel) and the field's
    nodes on it: node ``(i, j)`` at full-resolution pixel ``(j * tile, i * tile)``."""

    def __init__(self, shape: tuple[int, int], f: int, tile: int) -> None:
        self.shape = shape
        self.f = f
        self.tile = tile
        h, w = shape
        self.hl, self.wl = h // f, w // f
        self.gh, self.gw = DisplacementField.grid(shape, tile)
        self.c = tile // f  # level pixels per cell
        # full-resolution coordinates of the level pixels
        off = (f - 1) / 2.0
        self.xs = np.arange(self.wl) * float(f) + off
        self.ys = np.arange(self.hl) * float(f) + off
        # bilinear weights of each level pixel between its cell's nodes (the same in every cell
        # but for the last partial one): u = (x_full - node_x) / tile
        self.cx = np.minimum((self.xs // tile).astype(np.intp), self.gw - 2)
        self.cy = np.minimum((self.ys // tile).astype(np.intp), self.gh - 2)
        self.ux = (self.xs - self.cx * tile) / tile
        self.uy = (self.ys - self.cy * tile) / tile


@_njit
def _warp_rows(src, m, nodes, tile, f, inside, cubic, clipped, out, r0, r1):  # pragma: no cover
    """Rows ``r0:r1`` of the level grid: ``src`` (a level frame) read bilinearly (with
    ``cubic``: Keys) at ``H(x) + d(x)`` (``inside``: ``H(x + d(x))``) of each level pixel's
    full-resolution position ``x = f * p + (f - 1) / 2``, ``d`` the bilinear interpolation of
    ``nodes``
    (node ``(i, j)`` at ``(j * tile, i * tile)``); NaN outside the frame, ``clipped`` where
    a tap is a clipped block (inf). The readable specification:
    :func:`hdrcore.registration.spec.warped` (tests only)."""
    h, w = src.shape
    ww = out.shape[1]
    gh, gw = nodes.shape[0], nodes.shape[1]
    off = (f - 1) / 2.0
    inv_f = 1.0 / f
    cj = np.empty(ww, np.int64)  # per column: its cell of nodes and the weight across it
    cu = np.empty(ww)
    for x in range(ww):
        fx = min(max((x * f + off) / tile, 0.0), gw - 1.0)
        cj[x] = min(int(fx), gw - 2)
        cu[x] = fx - cj[x]
    affine = m[2, 0] == 0.0 and m[2, 1] == 0.0
    # a row's positions, then (Keys) their weights, then the reads, each a loop of its own:
    # keys_at per pixel to the bit, in about half the time
    lxs = np.empty(ww)
    lys = np.empty(ww)
    kx, ky, wx, wy = keys_row_scratch(ww)
    for y in range(r0, r1):
        yf = y * f + off
        fy = min(max(yf / tile, 0.0), gh - 1.0)
        i = min(int(fy), gh - 2)
        v = fy - i
        for x in range(ww):
            xf = x * f + off
            j = cj[x]
            u = cu[x]
            a00, a01, a10, a11 = (1 - u) * (1 - v), u * (1 - v), (1 - u) * v, u * v
            dx = (
                nodes[i, j, 0] * a00
                + nodes[i, j + 1, 0] * a01
                + nodes[i + 1, j, 0] * a10
                + nodes[i + 1, j + 1, 0] * a11
            )
            dy = (
                nodes[i, j, 1] * a00
                + nodes[i, j + 1, 1] * a01
                + nodes[i + 1, j, 1] * a10
                + nodes[i + 1, j + 1, 1] * a11
            )
            px, py = xf, yf
            if inside:
                px += dx
                py += dy
            sx = m[0, 0] * px + m[0, 1] * py + m[0, 2]
            sy = m[1, 0] * px + m[1, 1] * py + m[1, 2]
            if not affine:
                zw = m[2, 0] * px + m[2, 1] * py + m[2, 2]
                sx /= zw
                sy /= zw
            if not inside:
                sx += dx
                sy += dy
            lxs[x] = (sx - off) * inv_f
            lys[x] = (sy - off) * inv_f
        if cubic:
            keys_row_weights(lxs, lys, ww, kx, ky, wx, wy)
        for x in range(ww):
            lx = lxs[x]
            ly = lys[x]
            if not (lx >= 0.0 and lx <= w - 1.0 and ly >= 0.0 and ly <= h - 1.0):
                out[y, x] = np.nan
                continue
            if cubic:
                val = keys_row_at(src, x, kx, ky, wx, wy)  # not finite at a clipped tap (inf)
                out[y, x] = val if np.isfinite(val) else clipped
                continue
            ix = min(int(lx), w - 2)
            iy = min(int(ly), h - 2)
            ax = lx - ix
            ay = ly - iy
            t0 = src[iy, ix] * (1 - ax) + src[iy, ix + 1] * ax if ax > 0 else src[iy, ix]
            t1 = (
                src[iy + 1, ix] * (1 - ax) + src[iy + 1, ix + 1] * ax if ax > 0 else src[iy + 1, ix]
            )
            val = t0 * (1 - ay) + t1 * ay if ay > 0 else t0
            out[y, x] = val if np.isfinite(val) else clipped


def _warped(
    fr: np.ndarray,
    grid: _Grid,
    homography: np.ndarray,
    nodes: np.ndarray | None,
    inside: bool = False,
    cubic: bool = False,
    clipped: float = np.inf,
) -> np.ndarray:
    """A level frame read at ``H(x) + d(x)`` (``inside``: ``H(x + d(x))``) for the level's
    reference pixels: NaN outside the frame, ``clipped`` (default +inf) where the taps touch
    a clipped block (the measurements pass the saturation level: a clipped read counts as
    saturated). ``cubic``: Keys, as the merge reads frames (the checks: bilinear reads shift
    fine structure by an amount that depends on the sub-pixel phase, which the tiles' phase
    correlation sees)."""
    out = np.empty((grid.hl, grid.wl), np.float32)
    nd = (
        np.zeros((grid.gh, grid.gw, 2))
        if nodes is None
        else np.ascontiguousarray(nodes, np.float64)
    )
    m = np.ascontiguousarray(homography, np.float64)
    run_row_spans(
        grid.hl,
        None,
        lambda r0, r1: _warp_rows(
            fr,
            m,
            nd,
            float(grid.tile),
            float(grid.f),
            bool(inside),
            bool(cubic),
            float(clipped),
            out,
            r0,
            r1,
        ),
    )
    return out


def _pair_residual(
    a: np.ndarray,
    b: np.ndarray,
    a_is_dark: bool,
    ratio: float,
    lo: float,
    hi: float,
    pair: tuple[int, int],
    memo: dict | None = None,
    keep_b: bool = False,
    **kw,
):
    """The residual motion between two frames read onto the reference grid (clipped reads
    already at the saturation level ``hi``, see :func:`_warped`; NaN outside the frame stays
    out), or None where the pair cannot be measured (too small to tile). ``memo``: the
    residual's memo of structure images, left holding ``a``'s (the pair's fixed frame,
    measured against every version of the other) and, with ``keep_b``, ``b``'s."""
    from .residual import residual_motion

    dark, bright = (a, b) if a_is_dark else (b, a)
    try:
        return residual_motion(
            dark, bright, ratio, None, saturation=hi, noise_floor=lo, memo=memo, **kw
        )
    except (ParameterError, ValueError) as exc:
        log.debug("residual of frames %d-%d not measured: %s", *pair, exc)
        return None
    finally:
        if memo is not None:
            keep = {id(a)} | ({id(b)} if keep_b else set())
            for key in [key for key, v in memo.items() if id(v[0]) not in keep]:
                del memo[key]


# ------------------------------------------------------------------------ the solver
def _membrane(gh: int, gw: int) -> sparse.csr_matrix:
    """The graph Laplacian of the 4-neighbour node grid."""
    n = gh * gw
    idx = np.arange(n).reshape(gh, gw)
    a = np.concatenate([idx[:, :-1].ravel(), idx[:-1, :].ravel()])
    b = np.concatenate([idx[:, 1:].ravel(), idx[1:, :].ravel()])
    adj = sparse.coo_matrix((np.ones(a.size), (a, b)), shape=(n, n))
    adj = adj + adj.T
    deg = np.asarray(adj.sum(axis=1)).ravel()
    return (sparse.diags(deg) - adj).tocsr()


def _interpolation(points: np.ndarray, gh: int, gw: int, tile: int) -> sparse.csr_matrix:
    """Rows: the bilinear weights of each point ``(x, y)`` (full-resolution px) on the nodes."""
    fx = np.clip(points[:, 0] / tile, 0.0, gw - 1.0)
    fy = np.clip(points[:, 1] / tile, 0.0, gh - 1.0)
    j = np.minimum(fx.astype(np.intp), gw - 2)
    i = np.minimum(fy.astype(np.intp), gh - 2)
    u, v = fx - j, fy - i
    rows = np.repeat(np.arange(len(points)), 4)
    cols = np.stack(
        [i * gw + j, i * gw + j + 1, (i + 1) * gw + j, (i + 1) * gw + j + 1], axis=1
    ).ravel()
    vals = np.stack([(1 - u) * (1 - v), u * (1 - v), (1 - u) * v, u * v], axis=1).ravel()
    return sparse.csr_matrix((vals, (rows, cols)), shape=(len(points), gh * gw))


def _fit_nodes(
    points: np.ndarray,
    targets: np.ndarray,
    sigma: np.ndarray,
    gh: int,
    gw: int,
    tile: int,
    smoothness: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Node displacements ``(gh, gw, 2)`` whose bilinear interpolation meets ``targets``
    ``(N, 2)`` at ``points`` (weights ``1 / sigma^2``), smooth (membrane, ``smoothness`` times
    the median weight) and pulled weakly to zero where no point constrains them. With
    ``PASSES`` > 1, Tukey's biweight leaves out points that disagree with their neighbours (it
    also leaves out a small near object, so the default is one plain pass: the residual's own
    tests already drop ambiguous tiles). Returns the nodes and each point's final weight."""
    n = gh * gw
    interp = _interpolation(points, gh, gw, tile)
    lap = _membrane(gh, gw)
    w0 = 1.0 / np.maximum(sigma, 0.02) ** 2
    scale = float(np.median(w0))
    reg = lap * (smoothness * scale) + sparse.eye(n) * (PULL * smoothness * scale)
    wt = w0.copy()
    nodes = np.zeros((n, 2))
    for _ in range(PASSES):
        m = (interp.T @ sparse.diags(wt) @ interp + reg).tocsc()
        for c in range(2):
            nodes[:, c] = spsolve(m, interp.T @ (wt * targets[:, c]))
        res = np.hypot(*(interp @ nodes - targets).T)
        z = res / (TUKEY * np.maximum(sigma, MIN_SPREAD))
        wt = w0 * np.where(z < 1, (1 - z * z) ** 2, 0.0)
    return nodes.reshape(gh, gw, 2), wt


def _as_source_field(homography: np.ndarray, nodes: np.ndarray, tile: int) -> DisplacementField:
    """Reference displacement ``u`` at the nodes -> frame displacement
    ``H(x + u) - H(x)`` (exact at the nodes)."""
    gh, gw = nodes.shape[:2]
    xx, yy = np.meshgrid(np.arange(gw) * float(tile), np.arange(gh) * float(tile))
    x1, y1 = map_points(homography, None, xx + nodes[..., 0], yy + nodes[..., 1])
    x0, y0 = map_points(homography, None, xx, yy)
    return DisplacementField(tile, np.stack([x1 - x0, y1 - y0], axis=-1))


def refine_bracket(
    images: Sequence[np.ndarray],
    exposures: Sequence[float],
    to_reference_homography: Sequence[np.ndarray],
    reference: int,
    *,
    saturation: float,
    noise_floor: float,
    lut: np.ndarray | None = None,
    threshold: float = 0.02,
    tile: int | None = None,
    smoothness: float = SMOOTHNESS,
    min_gain: float = MIN_GAIN,
    refine: Sequence[bool] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> LocalRefinement:
    """Displacement fields for every frame of a globally registered bracket.

    Parameters
    ----------
    images : single-channel frames ``(H, W)``: linear floats, or integer levels read through
        ``lut`` (``lut[level]`` linear).
    exposures : relative exposure of each frame (e.g. the products of the chain's ratios).
    to_reference_homography : per frame, frame pixel -> reference pixel (3x3 or 2x3), as
        :class:`~hdrcore.registration.result.BracketRegistration` has them.
    reference : the reference frame (no field).
    saturation, noise_floor : linear levels bounding the pixels used (each frame's own).
    threshold : eq. 7's ``t`` as a fraction of the saturation level of the brighter frame.
    tile : node spacing in full-resolution pixels (default :func:`choose_tile`).
    smoothness : weight of the membrane term relative to a node's median data term.
    min_gain : a field is kept when the independent residual falls by this fraction.
    refine : per consecutive pair ``(i, i + 1)``, whether to refine it (default all). A frame
        whose pair is not refined moves with its neighbour's field (the pair is aligned as it
        is), so the frames beyond a refined one stay consistent with it.
    """
    t_start = time.perf_counter()
    n = len(images)
    if n != len(exposures) or n != len(to_reference_homography):
        raise ParameterError(
            "one exposure and one motion per frame",
            expected=str(n),
            found=f"{len(exposures)} exposures, {len(to_reference_homography)} motions",
        )
    if not 0 <= reference < n:
        raise ParameterError(
            "reference frame out of range", expected=f"0..{n - 1}", found=str(reference)
        )
    shape = tuple(np.asarray(images[0]).shape)
    if len(shape) != 2 or any(np.asarray(im).shape != shape for im in images):
        raise ParameterError(
            "local refinement needs single-channel frames of one size",
            found=", ".join(str(np.asarray(im).shape) for im in images),
        )
    lut_arr = None if lut is None else np.ascontiguousarray(lut, np.float32)
    t = int(tile) if tile is not None else choose_tile(shape)
    if t < 16 or t & (t - 1) or t > min(shape) // 2:
        raise ParameterError(
            "local refinement tile out of range",
            expected=f"a power of two, 16..{min(shape) // 2}",
            found=str(t),
        )
    level = _level_for(shape, t)
    f = 1 << level
    mats = []
    for m in to_reference_homography:
        h3 = np.eye(3)
        arr = np.asarray(m, np.float64)
        h3[: arr.shape[0]] = arr
        mats.append(np.linalg.inv(h3))  # reference -> frame
    lo, hi = float(noise_floor), float(saturation)
    frames: dict[int, np.ndarray] = {}

    def level_frame(k: int) -> np.ndarray:
        if k not in frames:
            frames[k] = _prepare(np.asarray(images[k]), lut_arr, f, hi)
        return frames[k]

    if refine is not None and len(refine) != n - 1:
        raise ParameterError(
            "one refine flag per consecutive pair", expected=str(n - 1), found=str(len(refine))
        )
    fields: list[DisplacementField | None] = [None] * n
    moved: dict[int, np.ndarray] = {}  # per frame with a field: its nodes u (reference px)
    order = [(k, k - 1) for k in range(reference + 1, n)] + [
        (k, k + 1) for k in range(reference - 1, -1, -1)
    ]
    details: list[LocalFrame] = []
    grid = _Grid(shape, f, t)
    est_tile = max(16, t // f)  # analysed pixels: one measured tile per cell of nodes
    counted = 0
    lock = threading.Lock()

    def advance() -> None:
        nonlocal counted
        if progress is not None:
            with lock:
                counted += 1
                done = counted
            progress(done, len(order))

    def step(k: int, j: int) -> None:
        t0 = time.perf_counter()
        prev = fields[j]
        if refine is not None and not refine[min(j, k)]:
            if j in moved:  # carried along with its neighbour
                moved[k] = moved[j]
                fields[k] = _as_source_field(mats[k], moved[j], t)
            advance()
            return
        prev_off = None if prev is None else prev.offsets
        dark_first = exposures[j] <= exposures[k]
        ratio = float(exposures[k] / exposures[j] if dark_first else exposures[j] / exposures[k])
        on_level = dict(max_pixels=float("inf"), aligned_px=0.3 / f, local_px=1.0 / f)
        if prev_off is None and np.allclose(mats[j], np.eye(3), rtol=0, atol=1e-12):
            # the reference frame on its own grid: the level itself (a bilinear read at the
            # pixels), clipped blocks at the saturation level
            fr_j = level_frame(j)
            a_lev = np.where(np.isinf(fr_j), np.float32(hi), fr_j)
        else:
            a_lev = _warped(level_frame(j), grid, mats[j], prev_off, clipped=hi)
        b = _warped(level_frame(k), grid, mats[k], None, clipped=hi)
        # How the check reads the level (measured against the full-resolution Keys check of
        # the first version, see CHECK_CUBIC_FACTORS): Keys at half size, bilinear otherwise.
        cubic = f in CHECK_CUBIC_FACTORS
        a_chk = (
            _warped(level_frame(j), grid, mats[j], prev_off, cubic=True, clipped=hi)
            if cubic
            else a_lev
        )
        # frame j's structure is computed once per read, and with a bilinear check frame k's
        # unrefined one is shared by the first check and the first round (the residual's memo)
        memo: dict = {}

        def measure(
            a: np.ndarray,
            bk: np.ndarray,
            memo: dict = memo,
            j: int = j,
            k: int = k,
            dark_first: bool = dark_first,
            ratio: float = ratio,
            b_first: np.ndarray = b,
            on_level: dict = on_level,
            **kw,
        ):
            return _pair_residual(
                a,
                bk,
                dark_first,
                ratio,
                lo,
                hi,
                (j, k),
                memo=memo,
                keep_b=bk is b_first,
                **on_level,
                **kw,
            )

        def check(
            offsets: np.ndarray | None,
            k: int = k,
            b_first: np.ndarray = b,
            a_chk: np.ndarray = a_chk,
            cubic: bool = cubic,
            measure=measure,
        ):
            if offsets is None and not cubic:
                return measure(a_chk, b_first)
            return measure(
                a_chk, _warped(level_frame(k), grid, mats[k], offsets, cubic=cubic, clipped=hi)
            )

        r0 = check(None)
        nodes = np.zeros((grid.gh, grid.gw, 2))
        # the shift of a tile says where the bright frame's content lies in the dark one:
        # frame k moves against it when k is the bright one
        sign = -1.0 if dark_first else 1.0
        confident = None
        for rnd in range(ROUNDS):
            # a round after the first measures again only the tiles the first found
            # confident, and their neighbours that came near (a near object's edge tiles,
            # which mixed two motions): a tile without structure does not gain it from a
            # sub-pixel warp (on the 24 MP bench pair 218 of 1023 tiles are confident)
            rt = measure(a_lev, b, tile=est_tile, only=confident)
            if rt is None or rt.n_valid < 4:
                break
            v = rt.valid
            if confident is None:  # the confident tiles and their neighbours that nearly are
                nx = int(np.unique(rt.centres[:, 0]).size)
                near = ndimage.binary_dilation(
                    v.reshape(-1, nx), structure=np.ones((3, 3), bool)
                ).ravel()
                min_conf, max_sigma = _tile_thresholds(est_tile)
                confident = v | (
                    near
                    & (rt.confidence >= NEAR_CONFIDENCE * min_conf)
                    & (rt.sigma <= NEAR_SIGMA * max_sigma)
                )
            pts = rt.centres[v] * f + (f - 1) / 2.0
            cur = _interpolation(pts, grid.gh, grid.gw, t) @ nodes.reshape(-1, 2)
            nodes, _ = _fit_nodes(
                pts, cur + sign * rt.shifts[v] * f, rt.sigma[v] * f, grid.gh, grid.gw, t, smoothness
            )
            if rnd + 1 < ROUNDS:  # the next round reads frame k through the field
                b = _warped(level_frame(k), grid, mats[k], nodes, inside=True, clipped=hi)
        cand = _as_source_field(mats[k], nodes, t)
        r1 = check(cand.offsets)
        med0, p90_0 = (float("nan"),) * 2 if r0 is None else (r0.median * f, r0.p90 * f)
        med1, p90_1 = (float("nan"),) * 2 if r1 is None else (r1.median * f, r1.p90 * f)
        st0: ResidualStatus = "unmeasured" if r0 is None else r0.status
        st1: ResidualStatus = "unmeasured" if r1 is None else r1.status
        said = (
            f"residual {med0:.2f} -> {med1:.2f} px median, {p90_0:.2f} -> {p90_1:.2f} px "
            f"90th percentile ({st0} -> {st1})"
        )
        if not (np.isfinite(med0) and np.isfinite(med1)):
            keep = False
            why = "the residual cannot be measured on this pair: global motion kept"
        else:
            # a near object moves a group of tiles: it shows in the 90th percentile before
            # the median; the median must not grow meanwhile
            gain = max(1 - med1 / max(med0, 1e-6), 1 - p90_1 / max(p90_0, 1e-6))
            # a field that scrambles part of the frame makes its tiles unmeasurable, which
            # flatters the statistics of the rest: the measured tiles must not drop
            lost = r1.n_valid < 0.95 * r0.n_valid
            keep = not lost and (
                (st1 == "aligned" and st0 != "aligned")
                or (gain >= min_gain and med1 <= 1.1 * med0 + 0.02 * f)
            )
            if lost:
                said += f"; {r0.n_valid} -> {r1.n_valid} tiles measurable"
            why = (
                f"{said}; field {cand.median_px:.2f} px median, {cand.max_px:.2f} px max"
                if keep
                else f"the field does not pay: {said}"
            )
        if keep:
            fields[k] = cand
            moved[k] = nodes
        details.append(
            LocalFrame(
                k, j, cand, keep, med0, med1, st0, st1, why, time.perf_counter() - t0, p90_0, p90_1
            )
        )
        advance()

    # The frames above the reference and those below are two independent chains (each frame is
    # refined against its neighbour towards the reference, through that neighbour's field):
    # refined side by side. Every frame's computation is the one it was in a single loop.
    level_frame(reference)  # both chains start from it

    def chain(steps: list[tuple[int, int]]) -> None:
        for k, j in steps:
            step(k, j)

    sides = [[kj for kj in order if kj[0] > reference], [kj for kj in order if kj[0] < reference]]
    thread_map(chain, [side for side in sides if side])
    details.sort(key=lambda d: d.frame)
    return LocalRefinement(
        reference, t, level, tuple(fields), tuple(details), time.perf_counter() - t_start
    )
