"""Cubic-convolution sampling at scattered points, and 2x2 image pyramids, in numpy: the
specifications of the compiled kernels' reads (tests only; :mod:`hdrcore.registration.spec`),
and Keys' weights for the shear passes of :mod:`hdrcore.registration.warp`.

Keys' cubic convolution kernel (a = -1/2; R. Keys, "Cubic convolution interpolation for digital
image processing", IEEE TASSP 29(6), 1981) is interpolating, third-order accurate and has a
closed-form derivative, so the registration cost and its gradient are evaluated only at the
sample points, never on the whole 24-megapixel frame.
"""

from __future__ import annotations

import numpy as np

from ..geometry import keys_weights

__all__ = ["keys_weights", "sample", "reduce2", "Sampled"]

_OFFSETS = np.arange(4)


def _dot4(t: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``sum_k t[k] * w[k]`` over the first axis (length 4), ``w`` of shape ``(4, N)``."""
    return t[0] * w[0] + t[1] * w[1] + t[2] * w[2] + t[3] * w[3]


class Sampled:
    """Values, gradients and tap ranges of an image at scattered points (see :func:`sample`)."""

    __slots__ = ("value", "gx", "gy", "inside", "tap_min", "tap_max")

    def __init__(self, value, gx, gy, inside, tap_min, tap_max) -> None:
        self.value = value
        self.gx = gx
        self.gy = gy
        self.inside = inside
        self.tap_min = tap_min
        self.tap_max = tap_max


def sample(
    image: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    *,
    gradient: bool = True,
    tap_range: bool = False,
    clip: tuple[float, float] | None = None,
) -> Sampled:
    """Cubic-convolution value (and d/dx, d/dy) of a 2-D ``image`` at points ``(x, y)``.

    ``inside`` is False where the 4x4 support leaves the image (value 0 there).
    ``tap_range`` also returns the minimum and maximum of the 16 raw taps (to discard points
    whose support touches a saturated or under-exposed pixel). ``clip``: the taps are clipped
    to ``(lo, hi)`` before the interpolation. Used by the specifications
    (:mod:`hdrcore.registration.spec`) only: the registration reads frames in compiled kernels.
    """
    h, w = image.shape
    ix = np.floor(x).astype(np.int64)
    iy = np.floor(y).astype(np.int64)
    inside = (ix >= 1) & (ix <= w - 3) & (iy >= 1) & (iy <= h - 3)
    fx = np.where(inside, x - ix, 0.0)
    fy = np.where(inside, y - iy, 0.0)
    base = np.where(inside, (iy - 1) * w + (ix - 1), 0)
    flat = image.reshape(-1) if image.flags.c_contiguous else np.ascontiguousarray(image).ravel()
    # taps[j, i, n] = image[iy - 1 + j, ix - 1 + i] of point n: the point axis last, so every
    # sum below runs over long contiguous rows.
    offsets = _OFFSETS[:, None] * w + _OFFSETS[None, :]
    taps = flat.take(base[None, None, :] + offsets[:, :, None]).astype(np.float64)
    if clip is not None:
        np.clip(taps, clip[0], clip[1], out=taps)
    wx = keys_weights(fx)
    wy = keys_weights(fy)
    rows = _dot4(taps.transpose(1, 0, 2), wx)  # (4, N): each row of taps interpolated in x
    value = _dot4(rows, wy)
    gx = gy = None
    if gradient:
        dwx = keys_weights(fx, True)
        dwy = keys_weights(fy, True)
        gx = _dot4(_dot4(taps.transpose(1, 0, 2), dwx), wy)
        gy = _dot4(rows, dwy)
    tmin = tmax = None
    if tap_range:
        flat_taps = taps.reshape(16, -1)
        tmin = flat_taps.min(axis=0)
        tmax = flat_taps.max(axis=0)
    value = np.where(inside, value, 0.0)
    return Sampled(value, gx, gy, inside, tmin, tmax)


def reduce2(image: np.ndarray) -> np.ndarray:
    """Mean of 2x2 blocks (odd last row/column dropped), float32.

    A pixel centre ``x`` of the result sits at ``2 x + 0.5`` in the input. The specification of
    the compiled pyramid kernels (:func:`hdrcore.registration._kernels.reduce2` and
    :func:`~hdrcore.registration._kernels.bin_clip`, equal to the bit), used only by the tests.
    """
    h2, w2 = image.shape[0] // 2, image.shape[1] // 2
    a = image[0 : 2 * h2 : 2, 0 : 2 * w2 : 2].astype(np.float32)
    a += image[1 : 2 * h2 : 2, 0 : 2 * w2 : 2]
    a += image[0 : 2 * h2 : 2, 1 : 2 * w2 : 2]
    a += image[1 : 2 * h2 : 2, 1 : 2 * w2 : 2]
    a *= 0.25
    return a
