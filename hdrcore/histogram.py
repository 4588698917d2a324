"""Histograms and cumulative histograms of integer frames at their native bit depth.

Every histogram-based stage (the brightness transfer functions of :mod:`hdrcore.btf`, the exposure
ratios of Cerman & Hlavac 2006, section 5, and the histogram-based response recovery) starts here.
A histogram has one bin per output level ``0 .. max_level`` (256 bins for 8-bit frames, 4096 or
16384 for RAW), counted with :func:`numpy.bincount`.

Large frames: ``stride`` counts every ``stride``-th pixel along both axes, which keeps the cost of
a 24-megapixel bracket low while leaving millions of samples per channel (see
:func:`auto_stride`).
"""

from __future__ import annotations

import numpy as np

from ._numba import njit as _njit
from .errors import ParameterError

__all__ = ["histogram", "histograms", "cumulative", "auto_stride"]


def _check_max_level(max_level: int) -> int:
    try:
        m = int(max_level)
    except (TypeError, ValueError):
        raise ParameterError("max_level must be an integer", found=repr(max_level)) from None
    if m < 1 or m > 65535:
        raise ParameterError("max_level out of range", expected="1..65535", found=str(m))
    return m


def _check_levels(levels: np.ndarray, ndim: int, what: str) -> np.ndarray:
    a = np.asarray(levels)
    if a.ndim != ndim:
        shape = "(H, W)" if ndim == 2 else "(H, W, C)"
        raise ParameterError(
            f"{what} must be {shape}", expected=f"{ndim} dimensions", found=str(a.shape)
        )
    if not np.issubdtype(a.dtype, np.integer) and a.dtype != np.bool_:
        raise ParameterError(
            f"{what} must hold integer levels", expected="an integer dtype", found=str(a.dtype)
        )
    return a


def auto_stride(n_pixels: int, target: int = 6_000_000) -> int:
    """The smallest stride along each axis that leaves at most about ``target`` pixels."""
    if n_pixels <= target:
        return 1
    return int(np.ceil(np.sqrt(n_pixels / target)))


def _count(values: np.ndarray, max_level: int, what: str) -> np.ndarray:
    if values.size == 0:
        return np.zeros(max_level + 1, np.int64)
    if values.dtype.kind == "i" and values.min() < 0:
        raise ParameterError(f"{what} holds negative levels", found=str(int(values.min())))
    counts = np.bincount(values, minlength=max_level + 1)
    if counts.size > max_level + 1:
        raise ParameterError(
            f"{what} holds levels above max_level",
            expected=f"<= {max_level}",
            found=str(int(np.flatnonzero(counts)[-1])),
        )
    return counts.astype(np.int64, copy=False)


@_njit
def _count_channels(a, mask, use_mask, stride, n):  # pragma: no cover - numba
    """Counts of levels ``0 .. n - 1`` of every channel of the unsigned ``a`` ``(H, W, C)``
    over every ``stride``-th pixel (where ``mask``, with ``use_mask``), read in place (any
    strides), in one pass: a channel's plane read alone loads the others' bytes too (the
    frames are interleaved), and on a 2-core machine the counts are bound by that traffic. And
    the highest level met (``n`` or more: out of range). No branch per pixel: a pixel outside
    the mask or the range lands in a spare bin (a random mask costs no mispredictions); four
    interleaved tables, since neighbouring pixels of a real image share a level and one table
    would make each increment wait for the last."""
    nc = a.shape[2]
    counts = np.zeros((nc, 4, n + 1), np.int64)
    top = 0
    for y in range(0, a.shape[0], stride):
        i = 0
        for x in range(0, a.shape[1], stride):
            keep = np.int64(mask[y, x]) if use_mask else np.int64(1)
            for c in range(nc):
                v = np.int64(a[y, x, c])
                top = max(top, v * keep)
                counts[c, i & 3, min(v, n) if keep else n] += 1
            i += 1
    out = np.zeros((nc, n), np.int64)
    for c in range(nc):
        for q in range(4):
            out[c] += counts[c, q, :n]
    return out, top


_NO_MASK = np.zeros((1, 1), np.bool_)


def _compiled_counts(
    a: np.ndarray, mask: np.ndarray | None, stride: int, max_level: int
) -> np.ndarray:
    """``(C, max_level + 1)`` counts of the uint8/uint16 ``(H, W, C)`` ``a`` by
    :func:`_count_channels`; ``mask`` ``(H, W)`` (made C-contiguous like the no-mask
    placeholder: one compiled signature per kind of frame)."""
    mk = _NO_MASK if mask is None else np.ascontiguousarray(mask, bool)
    counts, top = _count_channels(a, mk, mask is not None, max(int(stride), 1), max_level + 1)
    if top > max_level:
        raise ParameterError(
            "levels holds levels above max_level", expected=f"<= {max_level}", found=str(int(top))
        )
    return counts


def histogram(
    levels_2d: np.ndarray, max_level: int, mask: np.ndarray | None = None, *, stride: int = 1
) -> np.ndarray:
    """Counts of each level ``0 .. max_level`` in one channel, int64 of shape ``(max_level+1,)``.

    ``mask`` (boolean, same shape) selects the pixels to count; ``stride`` counts every
    ``stride``-th pixel along both axes.
    """
    m = _check_max_level(max_level)
    a = _check_levels(levels_2d, 2, "levels")
    s = max(int(stride), 1)
    if mask is not None and np.shape(mask) != a.shape:
        raise ParameterError(
            "mask shape differs from the frame",
            expected=str(levels_2d.shape),
            found=str(np.shape(mask)),
        )
    if a.dtype in (np.uint8, np.uint16):
        # one pass in place: no masked or strided copy, no separate range check (the response
        # recovery counts hundreds of 9 MP planes)
        return _compiled_counts(a[:, :, None], mask, s, m)[0]
    if s > 1:
        a = a[::s, ::s]
    if mask is not None:
        mk = np.asarray(mask, bool)
        if s > 1:
            mk = mk[::s, ::s]
        values = a[mk]
    else:
        values = a.ravel()
    return _count(values, m, "levels")


def histograms(
    levels_hwc: np.ndarray, max_level: int, mask: np.ndarray | None = None, *, stride: int = 1
) -> np.ndarray:
    """Per-channel histograms of an ``(H, W, C)`` frame, int64 of shape ``(C, max_level+1)``.

    ``mask`` is ``(H, W)`` (the same pixels in every channel) or ``(H, W, C)``.
    """
    a = _check_levels(levels_hwc, 3, "levels")
    if a.dtype in (np.uint8, np.uint16) and (mask is None or np.shape(mask) == a.shape[:2]):
        return _compiled_counts(a, mask, stride, _check_max_level(max_level))
    if mask is not None:
        mk = np.asarray(mask, bool)
        if mk.shape == a.shape[:2]:
            mk = np.broadcast_to(mk[..., None], a.shape)
        elif mk.shape != a.shape:
            raise ParameterError(
                "mask shape differs from the frame",
                expected=f"{a.shape[:2]} or {a.shape}",
                found=str(mk.shape),
            )
        return np.stack(
            [histogram(a[..., c], max_level, mk[..., c], stride=stride) for c in range(a.shape[2])]
        )
    return np.stack([histogram(a[..., c], max_level, stride=stride) for c in range(a.shape[2])])


def cumulative(hist: np.ndarray, *, normalise: bool = True) -> np.ndarray:
    """Cumulative histogram along the last axis: entry ``m`` counts pixels with level ``<= m``.

    With ``normalise`` the result is a fraction in ``[0, 1]`` (float64); an empty histogram gives
    zeros.
    """
    h = np.asarray(hist)
    c = np.cumsum(h, axis=-1, dtype=np.float64 if normalise else np.int64)
    if not normalise:
        return c
    total = c[..., -1:]
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(total > 0, c / np.where(total > 0, total, 1.0), 0.0)
    return out
