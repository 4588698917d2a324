"""Compiled inner loops of the registration (numba): pyramid building and the eq. 6/7 sums.

The same arithmetic as the numpy reference in :mod:`hdrcore.registration._problem` and
:mod:`hdrcore.registration._sampling` (Cerman & Hlavac 2006, section 6, eqs. 6-7; Keys cubic
convolution, IEEE TASSP 29(6), 1981), in one pass and without temporaries:

* :func:`bin_clip` builds pyramid level 1 of a clipped, exposure-scaled frame straight from the
  raw frame (``clip(scale * v, lo, hi)`` averaged over 2x2 blocks, float32, in the order of
  :func:`~hdrcore.registration._sampling.reduce2`), so a 24-megapixel frame is read once and no
  full-resolution clipped copy is made; :func:`reduce2` halves the coarser levels;
* :func:`gauss_newton_sums` evaluates, at the sample points, the cubic-convolution value and
  gradient of the bright frame, the eq. 6 validity (raw taps inside the exposure range, no edge
  steeper than the contrast limit), the eq. 7 residual and its derivative, and accumulates the
  eq. 6 sum, the number of valid samples and the Gauss-Newton normal equations ``J'J``, ``J'n``.
  Integer frames are read through a linearisation table (``lut``; None means the frame
  already holds linear values).

Sums run sequentially in float64 (numpy sums pairwise), so results agree with the reference to
rounding. The kernels are compiled with ``nogil`` and ``cache=True`` (machine code cached next
to this file); without numba the numpy reference runs (``AVAILABLE`` is False).
"""

from __future__ import annotations

import math

import numpy as np

# helpers are inlined: a call passing arrays would touch their reference counts per pixel
from .._numba import AVAILABLE
from .._numba import inline as _inline
from .._numba import njit as _njit

__all__ = ["AVAILABLE", "bin_clip", "reduce2", "gauss_newton_sums", "score_candidates"]



@_njit
def bin_clip(src, lut, scale, lo, hi, out):
    """``out[i, j]`` = mean of ``clip(float32(v) * scale, lo, hi)`` over the 2x2 block at
    ``(2i, 2j)`` of ``src`` (``v = lut[src]`` unless ``lut`` is None); float32 arithmetic in
    the order of the numpy reference (clip, then ``reduce2``)."""
    h2, w2 = out.shape
    s = np.float32(scale)
    lo32 = np.float32(lo)
    hi32 = np.float32(hi)
    q = np.float32(0.25)
    for i in range(h2):
        y0 = 2 * i
        for j in range(w2):
            x0 = 2 * j
            if lut is None:  # resolved at compile time: one machine code per case
                a00 = np.float32(src[y0, x0])
                a10 = np.float32(src[y0 + 1, x0])
                a01 = np.float32(src[y0, x0 + 1])
                a11 = np.float32(src[y0 + 1, x0 + 1])
            else:
                a00 = np.float32(lut[src[y0, x0]])
                a10 = np.float32(lut[src[y0 + 1, x0]])
                a01 = np.float32(lut[src[y0, x0 + 1]])
                a11 = np.float32(lut[src[y0 + 1, x0 + 1]])
            v00 = min(max(a00 * s, lo32), hi32)
            v10 = min(max(a10 * s, lo32), hi32)
            v01 = min(max(a01 * s, lo32), hi32)
            v11 = min(max(a11 * s, lo32), hi32)
            out[i, j] = (((v00 + v10) + v01) + v11) * q


@_inline
def _linear(img, lut, y, x):
    if lut is None:  # resolved at compile time
        return np.float64(img[y, x])
    return np.float64(lut[img[y, x]])


@_njit
def score_candidates(img, lut, n_cand, margin, phase, lo, hi, eps2, gradient, ys, xs, vs,
                     scores):
    """Stratified candidate pixels of ``img`` (dark frame or a level of ``k * dark``) and their
    relative-gradient scores; returns how many were well exposed.

    The interior (``margin`` pixels from the border) is cut, in raster order, into ``n_cand``
    equal runs and one pixel is taken in each run, at the offset given by the golden-ratio
    sequence (``phase`` shifts it): spread over the whole frame, in raster order, without a
    random generator. Pixels with ``lo < v < hi`` (``v = lut[img]`` unless ``lut`` is None) are
    written to ``ys, xs, vs``; with ``gradient`` also ``scores = |grad v|^2 / (v^2 + eps2)``
    (central differences).
    """
    h, w = img.shape
    inner_w = w - 2 * margin
    n_inner = (h - 2 * margin) * inner_w
    step = n_inner / n_cand
    golden = 0.6180339887498949
    n = 0
    for k in range(n_cand):
        u = k * golden + phase
        u -= math.floor(u)
        idx = int((k + u) * step)
        if idx >= n_inner:
            idx = n_inner - 1
        y = idx // inner_w + margin
        x = idx % inner_w + margin
        v = _linear(img, lut, y, x)
        if not (v > lo and v < hi):
            continue
        ys[n] = y
        xs[n] = x
        vs[n] = v
        if gradient:
            gx = _linear(img, lut, y, x + 1) - _linear(img, lut, y, x - 1)
            gy = _linear(img, lut, y + 1, x) - _linear(img, lut, y - 1, x)
            scores[n] = (gx * gx + gy * gy) / (v * v + eps2)
        n += 1
    return n


@_njit
def reduce2(src, out):
    """Mean of 2x2 blocks of a float32 image, as :func:`hdrcore.registration._sampling.reduce2`."""
    h2, w2 = out.shape
    q = np.float32(0.25)
    for i in range(h2):
        y0 = 2 * i
        for j in range(w2):
            x0 = 2 * j
            out[i, j] = (((src[y0, x0] + src[y0 + 1, x0]) + src[y0, x0 + 1])
                         + src[y0 + 1, x0 + 1]) * q


@_inline
def _keys(f, w):
    g = 1.0 - f
    w[0] = -0.5 * f * g * g
    w[1] = (1.5 * f - 2.5) * f * f + 1.0
    w[2] = (1.5 * g - 2.5) * g * g + 1.0
    w[3] = -0.5 * f * f * g


@_inline
def _dkeys(f, w):
    g = 1.0 - f
    w[0] = -0.5 * g * (1.0 - 3.0 * f)
    w[1] = (4.5 * f - 5.0) * f
    w[2] = -(4.5 * g - 5.0) * g
    w[3] = (1.5 * f - 1.0) * f


@_njit
def gauss_newton_sums(
    img, lut, xs, ys, bs, m, check_range, noise_floor, saturation, max_contrast, t,
    angle, cx, cy, n_par, gradient, hess, grad,
):
    """Eq. 6 sum of squared eq. 7 residuals and valid count at the samples; with ``gradient``
    also the normal equations of the rigid parameters (shift, and the angle when ``n_par`` is
    3) added into ``hess`` (3x3) and ``grad`` (3).

    ``m`` (2x3, level coordinates) maps the samples ``(xs, ys)`` of the dark frame's grid into
    ``img`` (the bright frame); ``bs`` is ``k * dark`` there. ``check_range``: the 16 raw taps
    must lie strictly between ``noise_floor`` and ``saturation`` (full resolution).
    ``max_contrast`` > 0: the taps' max must not exceed it times their min. ``angle``, ``cx``,
    ``cy``: the rotation of ``m`` and the level's centre (for d/d angle). Returns
    ``(sum n^2, count)``.
    """
    h, w = img.shape
    m00, m01, m02 = m[0, 0], m[0, 1], m[0, 2]
    m10, m11, m12 = m[1, 0], m[1, 1], m[1, 2]
    cs, sn = math.cos(angle), math.sin(angle)
    wx = np.empty(4)
    wy = np.empty(4)
    dwx = np.empty(4)
    dwy = np.empty(4)
    rows = np.empty(4)
    ssum = 0.0
    count = 0
    inv_t = 1.0 / max(t, 1e-300)
    # Two phases per block of samples: first only the loads of the 16 taps (independent of each
    # other, so the processor overlaps their cache misses), then the arithmetic.
    block = 64
    buf = np.empty((block, 4, 4))
    fxs = np.empty(block)
    fys = np.empty(block)
    ks = np.empty(block, np.int64)
    n_all = xs.size
    for start in range(0, n_all, block):
        nb = 0
        for k in range(start, min(start + block, n_all)):
            x = xs[k]
            y = ys[k]
            qx = m00 * x + m01 * y + m02
            qy = m10 * x + m11 * y + m12
            if not (qx >= 1.0 and qx < w - 2.0 and qy >= 1.0 and qy < h - 2.0):
                continue  # the 4x4 support leaves the bright frame
            ix = int(math.floor(qx))
            iy = int(math.floor(qy))
            if ix > w - 3 or iy > h - 3:
                continue
            for j in range(4):
                for i in range(4):
                    if lut is None:
                        buf[nb, j, i] = np.float64(img[iy - 1 + j, ix - 1 + i])
                    else:
                        buf[nb, j, i] = np.float64(lut[img[iy - 1 + j, ix - 1 + i]])
            fxs[nb] = qx - ix
            fys[nb] = qy - iy
            ks[nb] = k
            nb += 1
        for q in range(nb):
            taps = buf[q]
            tmin = np.inf
            tmax = -np.inf
            for j in range(4):
                for i in range(4):
                    v = taps[j, i]
                    if v < tmin:
                        tmin = v
                    if v > tmax:
                        tmax = v
            if check_range and not (tmin > noise_floor and tmax < saturation):
                continue
            if max_contrast > 0 and not (tmax <= max_contrast * max(tmin, 1e-30)):
                continue
            k = ks[q]
            fx = fxs[q]
            fy = fys[q]
            _keys(fx, wx)
            _keys(fy, wy)
            for j in range(4):
                rows[j] = taps[j, 0] * wx[0] + taps[j, 1] * wx[1] + taps[j, 2] * wx[2] \
                    + taps[j, 3] * wx[3]
            a = rows[0] * wy[0] + rows[1] * wy[1] + rows[2] * wy[2] + rows[3] * wy[3]
            b = bs[k]
            total = a + b
            above = total > t
            if t > 0:
                denom = total if above else t
            else:
                denom = total
            if not denom > 0:
                denom = 1.0
            n = (a - b) / denom
            ssum += n * n
            count += 1
            if not gradient:
                continue
            _dkeys(fx, dwx)
            _dkeys(fy, dwy)
            sx = 0.0
            for j in range(4):
                sx += (taps[j, 0] * dwx[0] + taps[j, 1] * dwx[1] + taps[j, 2] * dwx[2]
                       + taps[j, 3] * dwx[3]) * wy[j]
            sy = rows[0] * dwy[0] + rows[1] * dwy[1] + rows[2] * dwy[2] + rows[3] * dwy[3]
            dn_da = 2.0 * b / (denom * denom) if above else inv_t
            j0 = dn_da * sx
            j1 = dn_da * sy
            hess[0, 0] += j0 * j0
            hess[0, 1] += j0 * j1
            hess[1, 1] += j1 * j1
            grad[0] += j0 * n
            grad[1] += j1 * n
            if n_par == 3:
                xc = xs[k] - cx
                yc = ys[k] - cy
                j2 = j0 * (-sn * xc - cs * yc) + j1 * (cs * xc - sn * yc)
                hess[0, 2] += j0 * j2
                hess[1, 2] += j1 * j2
                hess[2, 2] += j2 * j2
                grad[2] += j2 * n
    if gradient:
        hess[1, 0] = hess[0, 1]
        hess[2, 0] = hess[0, 2]
        hess[2, 1] = hess[1, 2]
    return ssum, count
