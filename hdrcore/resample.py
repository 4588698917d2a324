"""Area downsampling for previews (box filter over whole blocks plus a remainder-aware mean). The
sampling kernel of the registration and the merge (Keys' cubic) is in :mod:`hdrcore.geometry`."""

from __future__ import annotations

import numpy as np

from ._numba import AVAILABLE
from ._numba import njit as _njit
from ._threads import run_row_spans
from .errors import ParameterError

__all__ = ["downsample_factor", "downsample_area", "bin_channel"]


def downsample_factor(shape: tuple[int, int], max_side: int | None) -> int:
    """Smallest integer factor that brings the longer side of ``shape`` to at most ``max_side``."""
    if max_side is None:
        return 1
    if max_side < 1:
        raise ParameterError("max_side must be >= 1", found=str(max_side))
    return max(1, int(np.ceil(max(shape[0], shape[1]) / float(max_side))))


@_njit
def _area_rows(img, f, out, r0, r1):  # pragma: no cover - compiled
    """Output rows ``r0:r1`` of the ``f x f`` block means of ``img (H, W, C)``: float32 sums in
    numpy's order (the block's rows first, then its columns), times ``1 / f**2``; a block with
    NaNs takes the float64 mean of its other values (NaN when none)."""
    c = img.shape[2]
    ww = out.shape[1]
    inv = np.float32(1.0 / (f * f))
    rows = np.empty(f, np.float32)
    for y in range(r0, r1):
        for x in range(ww):
            for ch in range(c):
                nan = False
                for j in range(f):
                    a = np.float32(img[y * f, x * f + j, ch])
                    for i in range(1, f):
                        a += np.float32(img[y * f + i, x * f + j, ch])
                    rows[j] = a
                    nan |= a != a
                t = rows[0]
                for j in range(1, f):
                    t += rows[j]
                if nan:
                    s = 0.0
                    n = 0
                    for i in range(f):
                        for j in range(f):
                            v = np.float64(img[y * f + i, x * f + j, ch])
                            if v == v:
                                s += v
                                n += 1
                    out[y, x, ch] = np.float32(s / n) if n else np.float32(np.nan)
                else:
                    out[y, x, ch] = t * inv


def downsample_area(image: np.ndarray, factor: int, workers: int | None = None) -> np.ndarray:
    """Mean over ``factor x factor`` blocks (float32); the ragged edge is cropped.

    NaNs are ignored within a block (a block of only NaNs stays NaN). With numba one compiled
    pass over output rows on ``workers`` threads, writing only the output (the numpy version
    makes full-size temporaries: at 24 MP their first touch took 0.3 s of a 0.4 s preview).
    """
    img = np.asarray(image)
    f = int(factor)
    if f < 1:
        raise ParameterError("downsampling factor must be >= 1", found=str(factor))
    if f == 1:
        return img.astype(np.float32, copy=False)
    h, w = img.shape[:2]
    hh, ww = h // f, w // f
    if hh == 0 or ww == 0:
        raise ParameterError(
            "image smaller than the downsampling factor", found=f"{h}x{w} for factor {f}"
        )
    if AVAILABLE and img.dtype in (np.float32, np.float64, np.uint8, np.uint16):
        src = img if img.ndim == 3 else img[..., None]
        out = np.empty((hh, ww, src.shape[2]), np.float32)
        run_row_spans(hh, workers, lambda r0, r1: _area_rows(src, f, out, r0, r1))
        return out if img.ndim == 3 else out[..., 0]
    crop = img[: hh * f, : ww * f].astype(np.float32, copy=False)
    if np.isnan(crop).any():
        blocks = crop.reshape(hh, f, ww, f, *img.shape[2:])
        with np.errstate(invalid="ignore"):
            return np.nanmean(blocks, axis=(1, 3)).astype(np.float32)
    # Sum of the f x f strided sub-images: one pass over memory (a reshape + mean over the
    # block axes walks it with a stride and is ~10x slower at 24 MP).
    rows = crop[0::f].copy()
    for i in range(1, f):
        rows += crop[i::f]
    out = rows[:, 0::f].copy()
    for j in range(1, f):
        out += rows[:, j::f]
    out *= np.float32(1.0 / (f * f))
    return out


def bin_channel(image: np.ndarray, channel: int, factor: int) -> np.ndarray:
    """Mean over ``factor x factor`` blocks of one channel of ``(H, W, C)`` data, float32.

    Sums strided views of the channel directly, so no full-resolution float copy is made (the
    ragged edge is cropped).
    """
    img = np.asarray(image)
    f = int(factor)
    if f < 1:
        raise ParameterError("binning factor must be >= 1", found=str(factor))
    plane = img[..., channel] if img.ndim == 3 else img
    h, w = plane.shape
    hh, ww = h // f, w // f
    if hh == 0 or ww == 0:
        raise ParameterError(
            "image smaller than the binning factor", found=f"{h}x{w} for factor {f}"
        )
    plane = plane[: hh * f, : ww * f]
    rows = plane[0::f].astype(np.float32)
    for i in range(1, f):
        rows += plane[i::f]
    out = rows[:, 0::f].copy()
    for j in range(1, f):
        out += rows[:, j::f]
    out *= np.float32(1.0 / (f * f))
    return out
