"""Ghost removal: each region where the frames disagree is filled from one frame.

The weighted average of frames that saw different things (a person who walked, a branch in the
wind, a scratch on one scan) is a semi-transparent mix: the ghost. :func:`hdrcore.merge.merge`
flags such pixels (``ghost``: by default the consistency regions of
:mod:`hdrcore.merge.consistency`, where blocks of the frames disagree beyond their noise,
misregistration and the brightness transfer error of each pair). With ``deghost=True`` each
connected region of flagged pixels (grown by a few pixels, so its rim joins it) takes the
values of a single frame, the one with the largest total share of the weight over the region
(the best exposed there; a frame not resampled when its share is at least half of that, since
its values carry no interpolation error), wherever that frame is usable (weighted, not clipped,
not below the noise floor); elsewhere the region keeps the weighted average. One frame per
region keeps a moving object whole and sharp instead of doubled, at the noise of one exposure.

This is the region-wise "reference" selection common to exposure fusion and HDR de-ghosting
(e.g. Gallo et al., "Artifact-free high dynamic range imaging", ICCP 2009, choose one exposure
per inconsistent patch).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["fill_ghost_regions"]

_ONE_F16_BITS = np.uint16(0x3C00)


def fill_ghost_regions(
    radiance: np.ndarray,
    weight_sum: np.ndarray,
    shares: np.ndarray,
    ghost: np.ndarray,
    single: Callable[[int, int, int], Any],
    grow: int = 2,
    min_area: int = 64,
    row_gap: int = 64,
    prefer: np.ndarray | None = None,
    prefer_share: float = 0.5,
) -> np.ndarray:
    """Fill every ghost region from one frame, in place; returns the bool ``(H, W)`` map of the
    pixels replaced.

    ``single(k, y0, y1)`` gives frame ``k`` merged alone over output rows ``y0:y1`` (a
    :class:`~hdrcore.merge.MergeResult` of those rows). ``radiance``, ``weight_sum`` and
    ``shares`` (float16, ``(N, H, W)``) are updated where a pixel is replaced: the frame's value,
    its weight, and all of the share to it. Regions smaller than ``min_area`` pixels (after
    growing) keep the average: an isolated disagreement is noise or an aliased edge, not an
    object. A frame is merged alone over bands of the rows its regions cover (bands closer than
    ``row_gap`` rows joined). ``prefer`` (bool ``(N,)``): frames to take when their share of a
    region is at least ``prefer_share`` of the largest, e.g. the frames not resampled, whose
    values carry no interpolation error (measured on a hand-held bracket: filling from a
    resampled frame left 1.2 % median error over the region, from the reference 0.1 %).
    """
    from scipy import ndimage

    h, w = ghost.shape
    replaced = np.zeros((h, w), bool)
    if not ghost.any():
        return replaced
    grown = ndimage.binary_dilation(ghost, iterations=int(grow)) if grow > 0 else ghost
    labels, count = ndimage.label(grown, structure=np.ones((3, 3), bool))
    flat = labels.ravel()
    idx = np.flatnonzero(flat)
    lab = flat[idx]
    area = np.bincount(lab, minlength=count + 1)
    n = shares.shape[0]
    # the frame with the largest total share over each region (one pass per frame)
    totals = np.stack(
        [
            np.bincount(lab, weights=shares[k].ravel()[idx].astype(np.float64), minlength=count + 1)
            for k in range(n)
        ]
    )
    best = np.argmax(totals, axis=0)
    if prefer is not None and np.any(prefer) and not np.all(prefer):
        pref = np.where(np.asarray(prefer, bool)[:, None], totals, -1.0)
        alt = np.argmax(pref, axis=0)
        good = pref[alt, np.arange(pref.shape[1])] >= prefer_share * totals.max(axis=0)
        best = np.where(good, alt, best)
    best[area < int(min_area)] = -1  # too small: keep the average
    frame_of = best[lab]
    bits = shares.view(np.uint16)
    for k in range(n):
        pix = idx[frame_of == k]
        if pix.size == 0:
            continue
        rows = np.unique(pix // w)
        cuts = np.flatnonzero(np.diff(rows) > int(row_gap)) + 1
        for band in np.split(rows, cuts):
            y0, y1 = int(band[0]), int(band[-1]) + 1
            alone = single(k, y0, y1)
            sl = slice(y0, y1)
            take = (best[labels[sl]] == k) & (labels[sl] > 0)
            take &= (alone.weight_sum > 0) & ~alone.clipped & ~alone.underexposed
            if not take.any():
                continue
            radiance[sl][take] = alone.radiance[take]
            weight_sum[sl][take] = alone.weight_sum[take]
            for j in range(n):
                bits[j, sl][take] = _ONE_F16_BITS if j == k else np.uint16(0)
            replaced[sl] |= take
    return replaced
