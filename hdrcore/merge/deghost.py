"""Ghost removal: each region where the frames disagree is filled from one frame.

The weighted average of frames that saw different things (a person who walked, a branch in the
wind, a scratch on one scan) is a semi-transparent mix: the ghost. :func:`hdrcore.merge.merge`
flags such pixels (``ghost``: the frames' spread beyond their noise). With ``deghost=True`` each
connected region of flagged pixels (grown by a few pixels, so its rim joins it) takes the values
of a single frame, the one with the largest total share of the weight over the region (the best
exposed there), wherever that frame is usable (weighted, not clipped, not below the noise
floor); elsewhere the region keeps the weighted average. One frame per region keeps a moving
object whole and sharp instead of doubled, at the noise of one exposure.

This is the region-wise "reference" selection common to exposure fusion and HDR de-ghosting
(e.g. Gallo et al., "Artifact-free high dynamic range imaging", ICCP 2009, choose one exposure
per inconsistent patch); the consistency test is the merge's own noise-normalised spread.
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
) -> np.ndarray:
    """Fill every ghost region from one frame, in place; returns the bool ``(H, W)`` map of the
    pixels replaced.

    ``single(k, y0, y1)`` gives frame ``k`` merged alone over output rows ``y0:y1`` (a
    :class:`~hdrcore.merge.MergeResult` of those rows). ``radiance``, ``weight_sum`` and
    ``shares`` (float16, ``(N, H, W)``) are updated where a pixel is replaced: the frame's value,
    its weight, and all of the share to it.
    """
    from scipy import ndimage

    h, w = ghost.shape
    replaced = np.zeros((h, w), bool)
    if not ghost.any():
        return replaced
    grown = ndimage.binary_dilation(ghost, iterations=int(grow)) if grow > 0 else ghost
    labels, count = ndimage.label(grown, structure=np.ones((3, 3), bool))
    boxes = ndimage.find_objects(labels)
    n = shares.shape[0]
    # the frame with the largest share over each region
    chosen: dict[int, list[int]] = {}
    for r, box in enumerate(boxes, start=1):
        if box is None:
            continue
        inside = labels[box] == r
        totals = [float(shares[k][box][inside].sum(dtype=np.float64)) for k in range(n)]
        chosen.setdefault(int(np.argmax(totals)), []).append(r)
    bits = shares.view(np.uint16)
    for k, regions in chosen.items():
        y0 = min(boxes[r - 1][0].start for r in regions)
        y1 = max(boxes[r - 1][0].stop for r in regions)
        alone = single(k, y0, y1)
        rows = slice(y0, y1)
        usable = (alone.weight_sum > 0) & ~alone.clipped & ~alone.underexposed
        take = np.isin(labels[rows], regions) & usable
        if not take.any():
            continue
        radiance[rows][take] = alone.radiance[take]
        weight_sum[rows][take] = alone.weight_sum[take]
        for j in range(n):
            bits[j, rows][take] = _ONE_F16_BITS if j == k else np.uint16(0)
        replaced[rows] |= take
    return replaced
