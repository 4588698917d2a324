"""Cached histograms of a bracket for the exposure stage: whole frames, image regions, and the
common field of view of a registered pair.

Cerman & Hlavac (2006, section 5) estimate ratios from the histograms of whole frames, which
assumes both frames of a pair see the same scene content. Two additions, both still the histogram
method (no pixel value is warped or compared with another):

* Region histograms: every frame is also counted on a grid of ``R`` image regions (they sum to the
  frame histogram), which the region jack-knife of :mod:`.stability` uses to give an honest error
  and to catch pairs that hand-held motion disturbs.
* Overlap-restricted histograms (:func:`pair_histograms_in_overlap`): once the geometric relation
  of a pair is known (the 2x3 pair matrix ``A`` of the registration stage maps pixel coordinates
  of the bright frame to the dark frame), each frame is counted only where the other frame also
  sees the scene: in the bright frame where ``A p`` lies inside the dark frame, in the dark frame
  where ``A^-1 p`` lies inside the bright frame (both by ``margin`` pixels). Content entering or
  leaving at the borders no longer biases the brightness transfer function. Regions of the dark
  frame follow the bright frame's grid through ``A^-1``, so a region holds the same content in
  both frames.

The masks are analytic (they depend on the matrix and the frame size only), the same test as
:func:`hdrcore.registration.valid_mask`, re-implemented here so that the exposure stage does not
import a later stage.

Reference: J. Cerman, V. Hlavac, "Exposure time estimation for high dynamic range imaging with
hand held camera", Computer Vision Winter Workshop 2006, sections 5 and 6.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..btf import BrightnessTransferFunction
from ..errors import BracketError, ParameterError
from ..histogram import _check_max_level, auto_stride, histograms
from ._core import pair_btfs

__all__ = [
    "PairHistograms",
    "BracketHistograms",
    "bracket_histograms",
    "region_histograms",
    "pair_histograms_in_overlap",
    "common_field_masks",
    "chain_pair_matrix",
    "DEFAULT_REGIONS",
    "DEFAULT_TARGET_PIXELS",
]

DEFAULT_REGIONS = (3, 3)
"""Grid of image regions (rows, columns) counted for the region jack-knife."""
DEFAULT_TARGET_PIXELS = 3_000_000
"""Pixels per frame counted by default (every ``stride``-th along both axes beyond that)."""


@dataclass(frozen=True, eq=False)
class PairHistograms:
    """Histograms ``(C, L)`` of the dark and bright frame of one pair, with region histograms
    ``(R, C, L)`` (or ``None``), and the pair matrix when restricted to the common field of view.

    The brightness transfer functions and the jack-knife skeleton depend only on these counts;
    they are computed once and kept in a private cache, so a re-fit with another saturation level
    or noise floor never recomputes them.
    """

    dark: int
    bright: int
    counts_dark: np.ndarray
    counts_bright: np.ndarray
    regions_dark: np.ndarray | None = None
    regions_bright: np.ndarray | None = None
    matrix: np.ndarray | None = None
    common_fraction: float = 1.0
    margin: float = 0.0
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def overlap_restricted(self) -> bool:
        return self.matrix is not None

    @property
    def n_regions(self) -> int:
        return 0 if self.regions_dark is None else int(self.regions_dark.shape[0])

    def btfs(self) -> tuple[BrightnessTransferFunction, ...]:
        """One brightness transfer function per channel (cached)."""
        if "btfs" not in self._cache:
            self._cache["btfs"] = pair_btfs(self.counts_dark, self.counts_bright)
        return self._cache["btfs"]

    def jackknife_skeleton(self, max_groups: int = 256):
        """The histogram-only part of the region jack-knife (cached), or ``None``."""
        dark, bright = self.regions_dark, self.regions_bright
        if dark is None or bright is None or self.n_regions < 3:
            return None
        key = ("jackknife", int(max_groups))
        if key not in self._cache:
            from .stability import jackknife_skeleton

            self._cache[key] = jackknife_skeleton(dark, bright, max_groups=max_groups)
        return self._cache[key]


@dataclass(frozen=True, eq=False)
class BracketHistograms:
    """Per-frame, per-channel histograms ``(N, C, max_level + 1)`` of a bracket, darkest first.

    ``region_counts`` ``(N, R, C, max_level + 1)`` are the same counts split over a grid of
    ``region_grid`` image regions (``None`` when not counted). ``overlap_pairs`` holds, per
    ``(dark, bright)``, histograms restricted to the pair's common field of view
    (:func:`pair_histograms_in_overlap`); pairs not listed use the whole frames.
    """

    counts: np.ndarray
    max_level: int
    stride: int = 1
    region_counts: np.ndarray | None = None
    region_grid: tuple[int, int] = (1, 1)
    overlap_pairs: dict[tuple[int, int], PairHistograms] = field(default_factory=dict)
    _pairs: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def n_frames(self) -> int:
        return int(self.counts.shape[0])

    @property
    def overlap_restricted(self) -> bool:
        return bool(self.overlap_pairs)

    def pair(self, dark: int, bright: int) -> PairHistograms:
        """The histograms of a pair (overlap-restricted when known), with their cache."""
        key = (int(dark), int(bright))
        if key in self.overlap_pairs:
            return self.overlap_pairs[key]
        if key not in self._pairs:
            rc = self.region_counts
            self._pairs[key] = PairHistograms(
                dark=key[0],
                bright=key[1],
                counts_dark=self.counts[key[0]],
                counts_bright=self.counts[key[1]],
                regions_dark=None if rc is None else rc[key[0]],
                regions_bright=None if rc is None else rc[key[1]],
            )
        return self._pairs[key]


def _check_grid(regions: tuple[int, int] | None) -> tuple[int, int]:
    if regions is None:
        return (1, 1)
    try:
        gy, gx = (int(v) for v in regions)
    except (TypeError, ValueError):
        raise ParameterError(
            "regions must be a (rows, columns) grid", found=repr(regions)
        ) from None
    if gy < 1 or gx < 1:
        raise ParameterError(
            "regions must be a (rows, columns) grid of positive sizes", found=repr(regions)
        )
    return gy, gx


def _as_hwc(levels: np.ndarray) -> np.ndarray:
    a = np.asarray(levels)
    return a[..., None] if a.ndim == 2 else a


def region_histograms(
    levels: np.ndarray,
    max_level: int,
    regions: tuple[int, int] = DEFAULT_REGIONS,
    *,
    mask: np.ndarray | None = None,
    stride: int = 1,
) -> np.ndarray:
    """Histograms ``(R, C, max_level + 1)`` of a grid of image regions, row by row.

    They sum to the frame histogram (same ``mask`` and ``stride``).
    """
    gy, gx = _check_grid(regions)
    a = _as_hwc(levels)
    s = max(int(stride), 1)
    a = a[::s, ::s]
    mk = None
    if mask is not None:
        mk = np.asarray(mask, bool)
        if mk.shape != np.asarray(levels).shape[:2]:
            raise ParameterError(
                "mask shape differs from the frame",
                expected=str(np.asarray(levels).shape[:2]),
                found=str(mk.shape),
            )
        mk = mk[::s, ::s]
    h, w = a.shape[:2]
    ys = [(i * h) // gy for i in range(gy + 1)]
    xs = [(j * w) // gx for j in range(gx + 1)]
    out = []
    for i in range(gy):
        for j in range(gx):
            block = a[ys[i] : ys[i + 1], xs[j] : xs[j + 1]]
            bm = None if mk is None else mk[ys[i] : ys[i + 1], xs[j] : xs[j + 1]]
            out.append(histograms(block, max_level, bm))
    return np.stack(out)


def _homogeneous(m: np.ndarray) -> np.ndarray:
    a = np.asarray(m, np.float64)
    if a.shape != (2, 3) or not np.all(np.isfinite(a)):
        raise ParameterError("a pair matrix must be a finite 2x3 affine matrix", found=str(a.shape))
    out = np.vstack([a, [0.0, 0.0, 1.0]])
    if abs(np.linalg.det(out)) < 1e-12:
        raise ParameterError("the pair matrix is singular")
    return out


def chain_pair_matrix(consecutive: Sequence[np.ndarray], dark: int, bright: int) -> np.ndarray:
    """Matrix mapping frame ``bright`` to frame ``dark`` from the consecutive pair matrices
    (``consecutive[i]`` maps frame ``i + 1`` to frame ``i``)."""
    m = np.eye(3)
    for i in range(dark, bright):
        m = m @ _homogeneous(consecutive[i])
    return m[:2]


def common_field_masks(
    matrix: np.ndarray, shape: tuple[int, int], margin: float = 2.0
) -> tuple[np.ndarray, np.ndarray]:
    """``(mask_dark, mask_bright)``: pixels of each frame that the other frame also sees.

    ``matrix`` maps bright-frame pixel coordinates to the dark frame; both frames have ``shape``
    ``(H, W)``. A bright pixel counts when it lies inside its own frame by ``margin`` pixels
    and its position in the dark frame does too (``valid_mask(matrix, shape, shape, margin)`` of
    :mod:`hdrcore.registration`, restricted to its own frame by ``margin``). A dark pixel counts
    when the bright pixel nearest to its position in the bright frame counts, so the two sets
    hold the same scene content (for a translation, pixel for pixel); up to the border rows and
    columns this is ``valid_mask(inverse, shape, shape, margin)``.
    """
    m = _homogeneous(matrix)
    h, w = int(shape[0]), int(shape[1])
    xs = np.arange(w, dtype=np.float64)
    ys = np.arange(h, dtype=np.float64)
    mask_bright = _bright_set(m, xs[None, :], ys[:, None], (h, w), margin)
    mask_dark, _, _ = _dark_set(m, xs, ys, (h, w), margin)
    return mask_dark, mask_bright


def _bright_set(
    a: np.ndarray, x: np.ndarray, y: np.ndarray, shape: tuple[int, int], margin: float
) -> np.ndarray:
    """Bright pixels ``(x, y)`` (integers, broadcastable) inside their own frame and seen by
    the dark frame, both by ``margin``."""
    h, w = shape
    eps = 1e-6
    sx = a[0, 0] * x + a[0, 1] * y + a[0, 2]
    sy = a[1, 0] * x + a[1, 1] * y + a[1, 2]
    return (
        (x >= margin - eps)
        & (x <= w - 1 - margin + eps)
        & (y >= margin - eps)
        & (y <= h - 1 - margin + eps)
        & (sx >= margin - eps)
        & (sx <= w - 1 - margin + eps)
        & (sy >= margin - eps)
        & (sy <= h - 1 - margin + eps)
    )


def _dark_set(
    a: np.ndarray, xs: np.ndarray, ys: np.ndarray, shape: tuple[int, int], margin: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dark pixels of the grid ``xs x ys`` whose owner, the bright pixel nearest to ``A^-1 q``,
    is in the bright set; also the owners' coordinates. For a translation this is exactly the
    image of the bright set, so both frames count the same content even when the shift is not
    a whole number of pixels (independent tests of the two frames would disagree by a row or
    column at the borders)."""
    inv = np.linalg.inv(a)
    ux = np.rint(inv[0, 0] * xs[None, :] + inv[0, 1] * ys[:, None] + inv[0, 2])
    uy = np.rint(inv[1, 0] * xs[None, :] + inv[1, 1] * ys[:, None] + inv[1, 2])
    return _bright_set(a, ux, uy, shape, margin), ux, uy


def _labelled_histograms(
    a: np.ndarray, labels: np.ndarray, n_regions: int, max_level: int
) -> np.ndarray:
    """``(R, C, L)`` counts of ``a`` ``(h, w, C)`` by region label (``-1``: not counted)."""
    n = max_level + 1
    keep = labels >= 0
    lab = labels[keep].astype(np.int64) * n
    out = []
    for c in range(a.shape[2]):
        v = a[..., c][keep]
        if v.size and v.max() > max_level:
            raise ParameterError(
                "levels above max_level", expected=f"<= {max_level}", found=str(int(v.max()))
            )
        out.append(np.bincount(lab + v, minlength=n_regions * n).reshape(n_regions, n))
    return np.stack(out, axis=1).astype(np.int64, copy=False)


def _grid_label(
    sx: np.ndarray, sy: np.ndarray, shape: tuple[int, int], grid: tuple[int, int]
) -> np.ndarray:
    h, w = shape
    gy, gx = grid
    r = np.clip(np.floor((sy + 0.5) * gy / h), 0, gy - 1).astype(np.int64)
    c = np.clip(np.floor((sx + 0.5) * gx / w), 0, gx - 1).astype(np.int64)
    return r * gx + c


def pair_histograms_in_overlap(
    levels_dark: np.ndarray,
    levels_bright: np.ndarray,
    max_level: int,
    matrix: np.ndarray,
    *,
    margin: float = 2.0,
    stride: int = 1,
    regions: tuple[int, int] | None = DEFAULT_REGIONS,
    mask: np.ndarray | None = None,
    dark: int = 0,
    bright: int = 1,
) -> PairHistograms:
    """Histograms of a pair counted only over their common field of view.

    ``matrix`` (2x3) maps pixel coordinates of the bright frame to the dark frame (the project's
    pair convention, e.g. ``register_pair(...).matrix``). A bright pixel counts when its position
    in the dark frame lies inside that frame by ``margin`` pixels (and inside its own frame by
    ``margin``), a dark pixel when the bright pixel nearest to its position in the bright frame
    counts: both counted sets hold the same content (:func:`common_field_masks`). ``mask``
    (``(H, W)``, True = use) further excludes pixels in each frame's own coordinates.
    ``regions`` also counts a grid of regions laid on the bright frame (followed into the dark
    frame through the matrix) for the jack-knife.
    """
    m = _check_max_level(max_level)
    d = _as_hwc(levels_dark)
    b = _as_hwc(levels_bright)
    if d.shape != b.shape or d.ndim != 3:
        raise ParameterError(
            "frames of a pair must have the same (H, W, C) shape", found=f"{d.shape} and {b.shape}"
        )
    if not (np.issubdtype(d.dtype, np.integer) and np.issubdtype(b.dtype, np.integer)):
        raise ParameterError("frames must hold integer levels", found=f"{d.dtype}, {b.dtype}")
    a = _homogeneous(matrix)
    grid = _check_grid(regions)
    n_regions = grid[0] * grid[1]
    h, w = d.shape[:2]
    s = max(int(stride), 1)
    xs = np.arange(0, w, s, dtype=np.float64)
    ys = np.arange(0, h, s, dtype=np.float64)
    gx_full, gy_full = np.meshgrid(xs, ys)
    in_dark = _bright_set(a, gx_full, gy_full, (h, w), margin)  # bright pixels seen by dark
    in_bright, ux, uy = _dark_set(a, xs, ys, (h, w), margin)  # dark pixels seen by bright
    if mask is not None:
        mk = np.asarray(mask, bool)
        if mk.shape != (h, w):
            raise ParameterError(
                "mask shape differs from the frames", expected=str((h, w)), found=str(mk.shape)
            )
        in_dark = in_dark & mk[::s, ::s]
        in_bright = in_bright & mk[::s, ::s]
    lab_b = np.where(in_dark, _grid_label(gx_full, gy_full, (h, w), grid), -1)
    lab_d = np.where(in_bright, _grid_label(ux, uy, (h, w), grid), -1)
    reg_d = _labelled_histograms(d[::s, ::s], lab_d, n_regions, m)
    reg_b = _labelled_histograms(b[::s, ::s], lab_b, n_regions, m)
    for r in (reg_d, reg_b):
        r.setflags(write=False)
    hd, hb = reg_d.sum(axis=0), reg_b.sum(axis=0)
    keep_regions = regions is not None and n_regions >= 3
    return PairHistograms(
        dark=int(dark),
        bright=int(bright),
        counts_dark=hd,
        counts_bright=hb,
        regions_dark=reg_d if keep_regions else None,
        regions_bright=reg_b if keep_regions else None,
        matrix=np.asarray(matrix, np.float64).copy(),
        common_fraction=float(np.count_nonzero(in_dark) / in_dark.size),
        margin=float(margin),
    )


def bracket_histograms(
    frames: Sequence[np.ndarray],
    max_level: int,
    *,
    mask: np.ndarray | None = None,
    stride: int | None = None,
    regions: tuple[int, int] | None = DEFAULT_REGIONS,
    pair_matrices: Sequence[np.ndarray] | None = None,
    margin: float = 2.0,
    max_span: int = 3,
) -> BracketHistograms:
    """Histograms of every frame (``(H, W, C)`` integer levels), darkest first.

    ``stride=None`` picks one that keeps about three million pixels per frame
    (:func:`hdrcore.histogram.auto_stride`). ``regions`` also counts a grid of image regions for
    the region jack-knife (``None``: whole frames only). ``pair_matrices`` (one 2x3 matrix per
    consecutive pair, mapping frame ``i + 1`` to frame ``i``, e.g.
    ``[p.matrix for p in register_bracket(...).pairs]``) adds overlap-restricted histograms of
    every pair up to ``max_span`` frames apart (:func:`pair_histograms_in_overlap`).
    """
    if len(frames) < 2:
        raise BracketError("a bracket needs at least two frames", found=f"{len(frames)} frame(s)")
    shapes = {np.asarray(f).shape for f in frames}
    if len(shapes) != 1:
        raise BracketError("frames of a bracket must have the same shape", found=str(shapes))
    frames = [_as_hwc(f) for f in frames]
    f0 = frames[0]
    if stride is None:
        s = auto_stride(f0.shape[0] * f0.shape[1], DEFAULT_TARGET_PIXELS)
    else:
        s = max(int(stride), 1)
    grid = _check_grid(regions)
    if grid[0] * grid[1] >= 3:
        region_counts = np.stack(
            [region_histograms(f, max_level, grid, mask=mask, stride=s) for f in frames]
        )
        region_counts.setflags(write=False)
        counts = region_counts.sum(axis=1)
    else:
        region_counts = None
        counts = np.stack([histograms(f, max_level, mask, stride=s) for f in frames])
    counts.setflags(write=False)
    overlap: dict[tuple[int, int], PairHistograms] = {}
    if pair_matrices is not None:
        n = len(frames)
        if len(pair_matrices) != n - 1:
            raise ParameterError(
                "one pair matrix per consecutive pair",
                expected=str(n - 1),
                found=str(len(pair_matrices)),
            )
        for span in range(1, max(1, min(max_span, n - 1)) + 1):
            for i in range(n - span):
                mat = chain_pair_matrix(pair_matrices, i, i + span)
                overlap[(i, i + span)] = pair_histograms_in_overlap(
                    frames[i],
                    frames[i + span],
                    max_level,
                    mat,
                    margin=margin,
                    stride=s,
                    regions=regions,
                    mask=mask,
                    dark=i,
                    bright=i + span,
                )
    return BracketHistograms(
        counts=counts,
        max_level=int(max_level),
        stride=s,
        region_counts=region_counts,
        region_grid=grid,
        overlap_pairs=overlap,
    )
