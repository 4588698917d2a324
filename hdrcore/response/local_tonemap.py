"""Is the bracket locally tone-mapped? The spread of the brightness transfer across the image.

A camera with one global response maps a level ``z`` of a darker frame to one level ``T(z)`` of
the next frame, wherever in the image the pixel is: the brightness transfer function (Grossberg
& Nayar 2002) does not depend on the position. Phones tone-map locally (shadows lifted and
highlights held differently across the frame), so at one dark-frame level the bright-frame level
varies across the image (issue 15: by 1.6x on a phone JPEG bracket): no global curve fits, the
exposure ratios come out "unstable" in the region jack-knife of :mod:`hdrcore.exposure`, and a
radiance map made from such frames is a compromise.

:func:`local_tone_mapping` measures that spread directly on the registered pixels: for each
consecutive pair, the pixels well exposed in both frames are binned by their dark-frame level
(green channel) and by image region (a ``grid`` of the reference frame); in each bin the median
bright-frame level of each region is linearised (the bracket's response) and the spread is the
ratio of the largest to the smallest region median (the 90th and 10th percentiles when there
are more than five regions). The bracket's spread is the median over the level bins and the
pairs. It needs no response to be right: at one dark level a global response gives one bright
level, whatever the curve.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import ParameterError

__all__ = ["LTM_SPREAD", "LocalToneMapping", "local_tone_mapping"]

#: A spread of the transferred level across the image regions above this (a ratio of linear
#: exposures) says the frames were tone-mapped locally.
LTM_SPREAD = 1.15


@dataclass(frozen=True)
class LocalToneMapping:
    """The regional spread of each consecutive pair's transfer and the verdict.

    ``pair_spreads[k]`` is the median over dark levels of the regions' spread for pair
    ``k, k + 1`` (NaN: too few pixels); ``spread`` their median; ``detected`` whether it
    exceeds :data:`LTM_SPREAD`.
    """

    detected: bool
    spread: float
    pair_spreads: tuple[float, ...]
    grid: tuple[int, int]
    n_bins: int
    message: str

    def to_json(self) -> dict[str, Any]:
        return {
            "detected": bool(self.detected),
            "spread": None if not np.isfinite(self.spread) else float(self.spread),
            "pair_spreads": [None if not np.isfinite(v) else float(v) for v in self.pair_spreads],
            "grid": list(self.grid),
            "n_bins": int(self.n_bins),
            "threshold": LTM_SPREAD,
            "message": self.message,
        }


def local_tone_mapping(
    frames: Sequence[np.ndarray],
    lut: np.ndarray,
    *,
    max_level: int,
    to_reference: Sequence[np.ndarray] | None = None,
    reference: int | None = None,
    grid: tuple[int, int] = (4, 4),
    max_samples: int = 200_000,
    well_exposed: tuple[float, float] = (0.1, 0.9),
    bin_width: int | None = None,
    min_pixels: int = 40,
    threshold: float = LTM_SPREAD,
) -> LocalToneMapping:
    """Measure how much the transfer between consecutive frames varies across the image.

    ``frames`` are integer ``(H, W, C)`` levels, darkest first; ``lut`` ``(C, L)`` (or
    ``(L,)``) linearises them; ``to_reference[k]`` maps frame ``k``'s pixels to the reference
    frame (``None``: aligned).
    """
    from ..geometry import nearest_in_frame

    n = len(frames)
    if n < 2:
        raise ParameterError("local tone mapping needs at least two frames", found=str(n))
    first = np.asarray(frames[0])
    h, w = first.shape[:2]
    ch = 1 if first.ndim == 3 and first.shape[2] >= 2 else 0  # green (or the only channel)
    table = np.asarray(lut, dtype=np.float64)
    table = table[min(ch, table.shape[0] - 1)] if table.ndim == 2 else table
    step = max(1, int(np.ceil(np.sqrt(h * w / max_samples))))
    ys, xs = np.mgrid[0:h:step, 0:w:step]
    ys = ys.ravel()
    xs = xs.ravel()
    gr, gc = int(grid[0]), int(grid[1])
    region = np.minimum(ys * gr // h, gr - 1) * gc + np.minimum(xs * gc // w, gc - 1)
    lo, hi = well_exposed[0] * max_level, well_exposed[1] * max_level
    width = max(1, int(round(max_level / 32))) if bin_width is None else int(bin_width)

    sampled = []
    for k, f in enumerate(frames):
        a = np.asarray(f)
        a = a if a.ndim == 3 else a[..., None]
        if to_reference is None or (reference is not None and k == reference):
            xk, yk, inside = xs, ys, np.ones(xs.size, bool)
        else:
            xk, yk, inside = nearest_in_frame(to_reference[k], xs, ys, (h, w))
        z = a[yk, xk, min(ch, a.shape[2] - 1)].astype(np.intp)
        sampled.append(np.where(inside, z, -1))

    spreads, total_bins = [], 0
    for k in range(n - 1):
        zd, zb = sampled[k], sampled[k + 1]
        ok = (zd > lo) & (zd < hi) & (zb > lo) & (zb < hi)
        if ok.sum() < min_pixels * 4:
            spreads.append(float("nan"))
            continue
        b = zd[ok] // width
        r = region[ok]
        v = table[np.clip(zb[ok], 0, max_level)]
        per_bin = []
        for bb in np.unique(b):
            sel = b == bb
            meds = []
            for rr in np.unique(r[sel]):
                vals = v[sel & (r == rr)]
                if vals.size >= min_pixels:
                    meds.append(float(np.median(vals)))
            if len(meds) < 3:
                continue
            med = np.asarray(meds)
            lo_v, hi_v = (
                (np.percentile(med, 10), np.percentile(med, 90))
                if med.size > 5
                else (med.min(), med.max())
            )
            if lo_v > 0:
                per_bin.append(hi_v / lo_v)
        total_bins += len(per_bin)
        spreads.append(float(np.median(per_bin)) if per_bin else float("nan"))
    finite = [s for s in spreads if np.isfinite(s)]
    spread = float(np.median(finite)) if finite else float("nan")
    detected = bool(np.isfinite(spread) and spread > threshold)
    if not finite:
        message = "too few pixels well exposed in consecutive frames to test for local tone mapping"
    elif detected:
        message = (
            f"the frames look locally tone-mapped: at one dark-frame level the "
            f"next frame's exposure varies by {spread:.2f}x across the image (a global "
            f"response gives 1x; over {threshold:.2f}x is not one curve)"
        )
    else:
        message = (
            f"one global response fits: at one dark-frame level the next frame's "
            f"exposure varies by {spread:.2f}x across the image"
        )
    return LocalToneMapping(
        detected=detected,
        spread=spread,
        pair_spreads=tuple(spreads),
        grid=(gr, gc),
        n_bins=total_bins,
        message=message,
    )
