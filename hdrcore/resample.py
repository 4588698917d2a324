"""Area downsampling for previews (box filter over whole blocks plus a remainder-aware mean)."""

from __future__ import annotations

import numpy as np

from .errors import ParameterError

__all__ = ["downsample_factor", "downsample_area", "bin_channel"]


def downsample_factor(shape: tuple[int, int], max_side: int | None) -> int:
    """Smallest integer factor that brings the longer side of ``shape`` to at most ``max_side``."""
    if max_side is None:
        return 1
    if max_side < 1:
        raise ParameterError("max_side must be >= 1", found=str(max_side))
    return max(1, int(np.ceil(max(shape[0], shape[1]) / float(max_side))))


def downsample_area(image: np.ndarray, factor: int) -> np.ndarray:
    """Mean over ``factor x factor`` blocks (float32); the ragged edge is cropped.

    NaNs are ignored within a block (a block of only NaNs stays NaN).
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
        raise ParameterError("image smaller than the downsampling factor",
                             found=f"{h}x{w} for factor {f}")
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
        raise ParameterError("image smaller than the binning factor",
                             found=f"{h}x{w} for factor {f}")
    plane = plane[: hh * f, : ww * f]
    rows = plane[0::f].astype(np.float32)
    for i in range(1, f):
        rows += plane[i::f]
    out = rows[:, 0::f].copy()
    for j in range(1, f):
        out += rows[:, j::f]
    out *= np.float32(1.0 / (f * f))
    return out
