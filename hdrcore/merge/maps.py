"""Per-pixel diagnostics of the merge: provenance, clipping and ghost maps.

Provenance
    ``shares[k]`` is frame ``k``'s share of the total weight at a pixel (summed over channels); the
    shares of a pixel sum to 1. Pixels the weighted average could not estimate take one frame's
    value and give that frame a share of 1.
Clipping
    ``clip_count`` counts the frames in which a pixel is clipped (any channel at or above its
    saturation level); ``clipped`` marks pixels clipped in every valid frame (they take the darkest
    frame's value, a lower bound of the true radiance).
Ghosts
    After the exposure times are applied every frame estimates the same radiance ``E``; a moving
    object makes the frames disagree by more than their noise. With normalised weights
    ``p_k = w_k / sum(w)`` the weighted spread ``sum(p_k (E_k - E)**2)`` is compared with the
    weighted noise variance ``sum(p_k var(E_k))`` plus a relative model error ``(m E)**2`` (response
    and exposure-time errors, interpolation of warped frames); the ghost score is the ratio, summed
    over channels, and a pixel is a ghost when it exceeds a threshold. This is the chi-square test
    of consistent exposures used by Granados et al., "Automatic noise modeling for ghost-free HDR
    reconstruction", ACM TOG 32(6), 2013 (doi:10.1145/2508363.2508410), in its simplest,
    single-pass form.

The merge accumulates the moments ``sum(w)``, ``sum(w E_k)``, ``sum(w E_k**2)`` and
``sum(w var(E_k))`` frame by frame; :func:`ghost_score_from_moments` turns them into the score.
"""

from __future__ import annotations

import numpy as np

from .._numba import AVAILABLE
from .._numba import njit as _njit
from .._threads import thread_map

__all__ = [
    "DEFAULT_GHOST_THRESHOLD",
    "DEFAULT_MODEL_ERROR",
    "ghost_score_from_moments",
    "dominant_frame",
    "mean_shares",
    "provenance_summary",
    "to_float16_nonnegative",
]

DEFAULT_GHOST_THRESHOLD = 8.0
"""Ghost when the frames' weighted spread exceeds this many times their expected variance."""

DEFAULT_MODEL_ERROR = 0.02
"""Relative radiance error tolerated between frames on top of their noise (2 %)."""


def ghost_score_from_moments(
    w: np.ndarray,
    we: np.ndarray,
    wee: np.ndarray,
    wv: np.ndarray,
    *,
    model_error: float = DEFAULT_MODEL_ERROR,
) -> np.ndarray:
    """Ghost score per pixel from the per-channel weighted moments, float32 ``(n,)``.

    ``w, we, wee, wv`` are ``(n, C)`` sums over frames of ``w``, ``w E_k``, ``w E_k**2`` and
    ``w var(E_k)``. Pixels with no weight score 0; a single contributing frame scores 0 (no
    disagreement can be seen). The inputs are not modified.
    """
    w = np.asarray(w, np.float32)
    safe = np.where(w > 0, w, np.float32(1.0))
    inv = np.divide(np.float32(1.0), safe, dtype=np.float32)
    inv *= w > 0
    mean = np.multiply(we, inv, dtype=np.float32)  # E
    spread = np.multiply(wee, inv, dtype=np.float32)  # sum(p E_k^2)
    mean_sq = np.square(mean)
    spread -= mean_sq  # sum(p (E_k - E)^2)
    np.maximum(spread, 0.0, out=spread)
    noise = np.multiply(wv, inv, dtype=np.float32)  # sum(p var_k)
    mean_sq *= np.float32(model_error) ** 2
    noise += mean_sq
    num = spread.sum(axis=-1, dtype=np.float32)
    den = noise.sum(axis=-1, dtype=np.float32)
    out = np.zeros_like(num)
    np.divide(num, den, out=out, where=den > 0)
    return out


_HALF_MAX = np.float32(65504.0)


def to_float16_nonnegative(
    x: np.ndarray, out: np.ndarray | None = None, scratch: np.ndarray | None = None
) -> np.ndarray:
    """Round non-negative float32 ``x`` to float16, several times faster than ``astype``.

    Numpy's float32 -> float16 cast runs in software (about 5 ns a value here); this does it with
    five integer operations on the bit pattern: values above 65504 saturate to 65504, values below
    the smallest normal half (6.1e-5) flush to zero, the rest round to nearest (ties away from
    zero, so a tie may differ from ``astype`` by one ulp). NaN and negative inputs are not
    supported.
    ``x`` is modified (clamped) in place when it is float32.
    """
    x = np.asarray(x)
    if x.dtype != np.float32:
        x = x.astype(np.float32)
    np.minimum(x, _HALF_MAX, out=x)
    bits = x.view(np.int32)
    if scratch is None:
        scratch = np.empty(x.shape, np.int32)
    np.add(bits, np.int32(0x1000), out=scratch)  # round the 13 dropped mantissa bits
    np.right_shift(scratch, 13, out=scratch)
    scratch -= np.int32(112 << 10)  # exponent bias 127 -> 15
    np.maximum(scratch, 0, out=scratch)
    if out is None:
        out = np.empty(x.shape, np.float16)
    np.copyto(out.view(np.uint16), scratch, casting="unsafe")
    return out


def dominant_frame(shares: np.ndarray) -> np.ndarray:
    """Index of the frame with the largest share at each pixel (the first on a tie, as
    ``argmax``), uint8 ``(H, W)``.

    Frame by frame with element-wise comparisons (cheaper than ``argmax`` over the frame axis
    of float16 maps); non-negative float16 shares compare as their bit patterns.
    """
    s = np.asarray(shares)
    if s.dtype == np.float16:
        s = s.view(np.uint16)  # shares are >= 0: the bits order as the values
    best = s[0].copy()
    idx = np.zeros(s.shape[1:], np.uint8)
    better = np.empty(s.shape[1:], bool)
    for k in range(1, s.shape[0]):
        np.greater(s[k], best, out=better)
        np.copyto(idx, np.uint8(k), where=better)
        np.maximum(best, s[k], out=best)
    return idx


def mean_shares(shares: np.ndarray) -> np.ndarray:
    """Each frame's share of the whole image (float64 ``(N,)``, sums to 1)."""
    s = np.asarray(shares)
    totals = np.array([float(s[k].sum(dtype=np.float64)) for k in range(s.shape[0])])
    total = totals.sum()
    return totals / total if total > 0 else totals


_HALF_VALUES = np.arange(65536, dtype=np.uint16).view(np.float16).astype(np.float64)
"""float64 value of every float16 bit pattern (NaN patterns stay NaN; shares never hold them)."""


@_njit
def _provenance_rows(bits, values, r0, r1):  # pragma: no cover - compiled
    """Per frame: pixels of rows ``r0:r1`` it dominates (largest share, first on a tie) and
    the sum of its shares, from float16 shares given as their bits (non-negative: the bits
    order as the values)."""
    n, _, w = bits.shape
    counts = np.zeros(n, np.int64)
    totals = np.zeros(n, np.float64)
    for y in range(r0, r1):
        for x in range(w):
            best = bits[0, y, x]
            arg = 0
            for k in range(n):
                b = bits[k, y, x]
                totals[k] += values[b]
                if b > best:
                    best = b
                    arg = k
            counts[arg] += 1
    return counts, totals


def provenance_summary(shares: np.ndarray, workers: int | None = None) -> dict:
    """JSON-ready summary: mean share and fraction of pixels each frame dominates.

    float16 shares (as :func:`hdrcore.merge.merge` makes them) are read in one compiled pass
    over row blocks on ``workers`` threads, without full-size temporaries (``argmax`` over
    the frame axis and float64 sums spend most of their time faulting in fresh memory).
    """
    s = np.asarray(shares)
    n = s.shape[0]
    size = max(int(np.prod(s.shape[1:])), 1)
    if AVAILABLE and s.dtype == np.float16 and s.ndim == 3 and s.size:
        bits = np.ascontiguousarray(s).view(np.uint16)
        h = s.shape[1]
        step = max(1, -(-h // 16))
        parts = thread_map(
            lambda r0: _provenance_rows(bits, _HALF_VALUES, r0, min(h, r0 + step)),
            range(0, h, step),
            workers,
        )
        counts = sum(p[0] for p in parts)
        totals = sum(p[1] for p in parts)
    else:
        counts = np.bincount(dominant_frame(s).ravel(), minlength=n)[:n]
        totals = np.array([float(s[k].sum(dtype=np.float64)) for k in range(n)])
    total = float(np.sum(totals))
    return {
        "mean_share": [float(v) for v in (totals / total if total > 0 else totals)],
        "dominant_fraction": [float(c) / size for c in counts],
    }
