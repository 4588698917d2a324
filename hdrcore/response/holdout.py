"""Held-back correspondences: how well a curve explains data it was not fitted to.

A non-parametric curve always fits its own correspondences better than sRGB does; the fair
comparison (issue 15: "pick the method on evidence") is on correspondences of the same bracket
held back from the fit. The frame is cut into a grid of regions coloured like a chess board;
a curve fitted on one colour is scored on the other, and the other way round. Regions rather
than single pixels are held back, so a curve is also tested on image content it has not seen
(a phone's local tone mapping makes the transfer between frames differ across the image).

The score of a curve on level pairs ``(z, T(z))`` of consecutive frames ``k, k+1`` is the
weighted RMS of

    r = ln g_c(T(z)) - ln g_c(z) - rho_k

in natural-log units (0.01 = 1 % of exposure), with the weights of the fit
(:func:`.samples.pair_weight`: pixel count, the hat weight of both levels, less weight near
black where the log of a level is noise). ``rho_k`` is the exposure ratio of the pair: by
default one free value per pair shared by the channels (its weighted mean over the held-back
pairs), so wrong metadata does not favour a curve bent to it, while channels that disagree
(a colour cast) still cost.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from .samples import Correspondences, pair_weight

__all__ = [
    "COLOUR_LEVELS",
    "FOLD_GRID",
    "colour_consistency",
    "colour_pairs",
    "fold_masks",
    "heldout_residual",
    "pair_residuals",
    "sample_levels",
]

#: Regions per side of the chess board of the two folds.
FOLD_GRID = 8


def fold_masks(
    n_folds: int = 2, grid: int = FOLD_GRID
) -> list[Callable[[tuple[int, int]], np.ndarray]]:
    """``n_folds`` functions ``shape -> (H, W) bool``: region ``(i, j)`` of a ``grid x grid``
    cut belongs to fold ``(i + j) % n_folds``."""

    def make(k: int) -> Callable[[tuple[int, int]], np.ndarray]:
        def mask(shape: tuple[int, int]) -> np.ndarray:
            h, w = int(shape[0]), int(shape[1])
            iy = np.minimum(np.arange(h) * grid // max(h, 1), grid - 1)
            ix = np.minimum(np.arange(w) * grid // max(w, 1), grid - 1)
            # one row per row of regions, then each image row its region row's (a copy
            # of rows, not an integer sum and remainder per pixel: 0.28 -> 0.002 s at 9 MP)
            rows = ((np.arange(grid)[:, None] + ix[None, :]) % n_folds) == k
            return rows[iy]

        return mask

    return [make(k) for k in range(n_folds)]


def pair_residuals(
    g: np.ndarray,
    pairs: Sequence[Correspondences],
    lo: float,
    hi: float,
    log_ratios: np.ndarray | None = None,
) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """Per channel the residuals and weights of the pairs inside ``(lo, hi)``, and the log
    ratios used (given, or fitted per pair over all channels)."""
    g = np.atleast_2d(np.asarray(g, dtype=np.float64))
    x = np.arange(g.shape[1], dtype=np.float64)
    diffs, weights, which = [], [], []
    for c, corr in enumerate(pairs):
        gc = g[min(c, g.shape[0] - 1)]
        w = pair_weight(corr, lo, hi, g.shape[1] - 1)
        lg = np.log(np.maximum(gc, 1e-12))
        d = np.interp(corr.bright, x, lg) - np.interp(corr.dark, x, lg)
        # a curve flat at zero (a degenerate toe) gives -27 here: such pairs count fully
        diffs.append(d)
        weights.append(w)
        which.append(corr.pair)
    n_pairs = 1 + max((int(p.max()) for p in which if p.size), default=0)
    if log_ratios is None:
        num = np.zeros(n_pairs)
        den = np.zeros(n_pairs)
        for d, w, p in zip(diffs, weights, which, strict=True):
            np.add.at(num, p, w**2 * d)
            np.add.at(den, p, w**2)
        rho = np.where(den > 0, num / np.maximum(den, 1e-300), 0.0)
    else:
        rho = np.asarray(log_ratios, dtype=np.float64)
    res = [d - rho[p] for d, p in zip(diffs, which, strict=True)]
    return res, weights, rho


def heldout_residual(
    g: np.ndarray,
    pairs: Sequence[Correspondences],
    lo: float,
    hi: float,
    log_ratios: np.ndarray | None = None,
) -> tuple[float, float]:
    """Weighted RMS residual (ln units) of curve ``g`` on ``pairs`` and the total squared
    weight behind it (to pool folds). ``log_ratios=None`` fits one ratio per pair."""
    res, weights, _ = pair_residuals(g, pairs, lo, hi, log_ratios)
    num = sum(float(np.sum(w**2 * r**2)) for r, w in zip(res, weights, strict=True))
    den = sum(float(np.sum(w**2)) for w in weights)
    if den <= 0:
        return float("inf"), 0.0
    return float(np.sqrt(num / den)), den


#: Levels (fractions of the range) inside which every channel of a pixel must lie for its
#: colour to be compared between frames.
COLOUR_LEVELS = (0.10, 0.90)


def sample_levels(
    frames: Sequence[np.ndarray], mask: np.ndarray | None = None, max_samples: int = 200_000
) -> list[np.ndarray]:
    """The frames' levels ``(P, C)`` on a regular grid of at most ``max_samples`` pixels
    (those of ``mask`` only), for :func:`colour_consistency`."""
    h, w = frames[0].shape[:2]
    step = max(1, int(np.ceil(np.sqrt(h * w / max_samples))))
    sel = (slice(None, None, step), slice(None, None, step))
    keep = None if mask is None else np.asarray(mask, bool)[sel].ravel()
    out = []
    for f in frames:
        a = np.asarray(f)
        a = a if a.ndim == 3 else a[..., None]
        s = a[sel].reshape(-1, a.shape[-1])
        out.append(s if keep is None else s[keep])
    return out


def colour_pairs(
    levels: Sequence[np.ndarray], max_level: int, well: tuple[float, float] = COLOUR_LEVELS
) -> list[tuple[np.ndarray, np.ndarray]]:
    """The consecutive frames' levels (clipped to ``0..max_level``) at the pixels whose
    channels are all inside ``well`` of the range in both, per pair with at least 50 of them:
    what :func:`colour_consistency` reads for every curve it scores (made once for them all:
    the real Pixel 7's response selection scores seven curves)."""
    m = int(max_level)
    lo, hi = well[0] * m, well[1] * m
    out = []
    for a, b in zip(levels[:-1], levels[1:], strict=True):
        ok = np.all((a > lo) & (a < hi) & (b > lo) & (b < hi), axis=-1)
        if ok.sum() < 50:
            continue
        out.append((np.clip(a[ok], 0, m), np.clip(b[ok], 0, m)))
    return out


def colour_consistency(
    g: np.ndarray,
    levels: Sequence[np.ndarray],
    well: tuple[float, float] = COLOUR_LEVELS,
    pairs: list[tuple[np.ndarray, np.ndarray]] | None = None,
) -> float:
    """How well curve ``g`` gives a pixel one colour in consecutive frames: the median over
    the pairs of the median rg-chromaticity distance between the two linearised frames, over
    pixels whose channels are all inside ``well`` of the range in both (NaN: too few, or not
    three channels). A right response leaves only noise; a wrong shape or channels that
    disagree tint a pixel differently at different exposures. ``pairs``: :func:`colour_pairs`
    of the same ``levels``, ``well`` and ``g``'s range, when made already."""
    g = np.atleast_2d(np.asarray(g, dtype=np.float64))
    if g.shape[0] != 3 or len(levels) < 2 or levels[0].shape[-1] != 3:
        return float("nan")
    if pairs is None:
        pairs = colour_pairs(levels, g.shape[1] - 1, well)
    meds = []
    for za, zb in pairs:
        la = np.stack([g[c][za[:, c]] for c in range(3)], axis=-1)
        lb = np.stack([g[c][zb[:, c]] for c in range(3)], axis=-1)
        sa = la.sum(axis=-1, keepdims=True)
        sb = lb.sum(axis=-1, keepdims=True)
        good = (sa[:, 0] > 0) & (sb[:, 0] > 0)
        d = np.hypot(*(la[good, :2] / sa[good] - lb[good, :2] / sb[good]).T)
        meds.append(float(np.median(d)))
    return float(np.median(meds)) if meds else float("nan")
