"""Compiled inner loops of the registration (numba): pyramid building and the eq. 6/7 sums.

The arithmetic of the specifications in :mod:`hdrcore.registration.spec` and
:mod:`hdrcore.registration._sampling` (Cerman & Hlavac 2006, section 6, eqs. 6-7; Keys cubic
convolution, IEEE TASSP 29(6), 1981), in one pass and without temporaries:

* :func:`bin_clip` builds pyramid level 1 of a clipped, exposure-scaled frame straight from the
  raw frame (``clip(scale * v, lo, hi)`` averaged over 2x2 blocks, float32, in the order of
  :func:`~hdrcore.registration._sampling.reduce2`), so a 24-megapixel frame is read once and no
  full-resolution clipped copy is made; :func:`reduce2` halves the coarser levels;
* :func:`score_candidates` picks candidate samples of one pyramid level on the dark frame's
  grid, :func:`support_valid` decides the bright frame's side of their eq. 6 validity once per
  level (see :mod:`hdrcore.registration._problem`);
* :func:`gauss_newton_sums` evaluates, at the sample points mapped by a 3x3 homography, the
  cubic-convolution value and gradient of the bright frame (taps clipped to the shared exposure
  range), the eq. 7 residual and its derivative, and accumulates the weighted eq. 6 sum, the
  sum of the weights and the Gauss-Newton normal equations ``J'J``, ``J'n`` of up to eight
  motion generators.
  Integer frames are read through a linearisation table (``lut``; None means the frame
  already holds linear values).

:func:`warp_rows` resamples a frame through a 3x3 matrix (Keys cubic, 16 taps per pixel) for
the motions the separable shear passes of :mod:`hdrcore.registration.warp` cannot do (scale,
shear, perspective).

Sums run sequentially in float64 (numpy sums pairwise), so results agree with their readable
specifications to rounding: :mod:`hdrcore.registration.spec` (``score_candidates``,
``support_valid``, ``gauss_newton_sums``, ``warp_rows`` with these signatures, and
:func:`~hdrcore.registration._sampling.reduce2` for the pyramid), used only by the tests. The
kernels are compiled with ``nogil`` and ``cache=True``; numba is a dependency, so they are the
only form that runs.
"""

from __future__ import annotations

import math

import numpy as np

# helpers are inlined: a call passing arrays would touch their reference counts per pixel
from .._numba import inline as _inline
from .._numba import njit as _njit
from ..geometry import dkeys4, keys4, keys_row_scratch, keys_row_weights

__all__ = [
    "bin_clip",
    "reduce2",
    "gauss_newton_sums",
    "score_candidates",
    "support_valid",
    "warp_rows",
]


@_njit
def bin_clip(src, lut, scale, lo, hi, out):
    """``out[i, j]`` = mean of ``clip(float32(v) * scale, lo, hi)`` over the 2x2 block at
    ``(2i, 2j)`` of ``src`` (``v = lut[src]`` unless ``lut`` is None); float32 arithmetic in
    the order of its specification (clip, then :func:`~hdrcore.registration._sampling.reduce2`)."""
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
def score_candidates(img, lut, n_cand, margin, phase, lo, hi, eps2, gradient, ys, xs, vs, scores):
    """Stratified candidate pixels of ``img`` (dark frame or a level of ``k * dark``) and their
    relative-gradient scores; returns how many were well exposed.

    The interior (``margin`` pixels from the border) is cut, in raster order, into ``n_cand``
    equal runs and one pixel is taken in each run, at the offset given by the golden-ratio
    sequence (``phase`` shifts it): spread over the whole frame, in raster order, without a
    random generator. Pixels whose own value ``v`` and whose four neighbours' mean ``m`` both
    lie in ``lo < . < hi`` (values ``lut[img]`` unless ``lut`` is None) are written to ``ys, xs,
    vs``; with ``gradient`` also ``scores = |grad v|^2 / (m^2 + eps2)`` (central differences).
    The neighbours' mean, whose noise is not the pixel's, also leaves out pixels that noise
    alone brought into the range beside a black or saturated area (simulated 8-bit homography
    pairs 2 stops apart, half of the bright frame saturated: mean / worst corner error 0.064 /
    0.43 px with the pixel's own test only, 0.042 / 0.22 px with both).
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
        right = _linear(img, lut, y, x + 1)
        left = _linear(img, lut, y, x - 1)
        down = _linear(img, lut, y + 1, x)
        up = _linear(img, lut, y - 1, x)
        mean = 0.25 * (right + left + down + up)
        v = _linear(img, lut, y, x)
        if not (mean > lo and mean < hi and v > lo and v < hi):
            continue
        ys[n] = y
        xs[n] = x
        vs[n] = v
        if gradient:
            gx = right - left
            gy = down - up
            scores[n] = (gx * gx + gy * gy) / (mean * mean + eps2)
        n += 1
    return n


@_njit
def support_valid(img, lut, xs, ys, m, check_range, lo, hi, max_contrast, reach, out):
    """``out[k]``: whether the 4x4 interpolation support of ``img`` (the bright frame) at the
    sample ``(xs[k], ys[k])`` mapped by ``m`` (3x3) lies inside the frame, spans at most
    ``max_contrast`` (when > 0) and (with ``check_range``) holds raw taps above ``lo`` and,
    widened by ``reach`` pixels on every side (cut at the frame's border), below ``hi``: the
    bright frame's side of eq. 6's validity, decided once per pyramid level, such that no motion
    within ``reach`` pixels of ``m`` brings a saturated tap into the interpolation."""
    h, w = img.shape
    for k in range(xs.size):
        x = xs[k]
        y = ys[k]
        out[k] = False
        den = m[2, 0] * x + m[2, 1] * y + m[2, 2]
        if not den > 0:
            continue
        qx = (m[0, 0] * x + m[0, 1] * y + m[0, 2]) / den
        qy = (m[1, 0] * x + m[1, 1] * y + m[1, 2]) / den
        if not (qx >= 1.0 and qx < w - 2.0 and qy >= 1.0 and qy < h - 2.0):
            continue
        ix = int(math.floor(qx))
        iy = int(math.floor(qy))
        if ix > w - 3 or iy > h - 3:
            continue
        tmin = np.inf  # the 4x4 support
        tmax = -np.inf
        for j in range(4):
            for i in range(4):
                v = _linear(img, lut, iy - 1 + j, ix - 1 + i)
                if v < tmin:
                    tmin = v
                if v > tmax:
                    tmax = v
        if max_contrast > 0 and not (tmax <= max_contrast * max(tmin, 1e-30)):
            continue
        if check_range:
            if not tmin > lo:
                continue
            wmax = tmax  # the support widened by reach, against saturation
            if reach > 0:
                for yy in range(max(iy - 1 - reach, 0), min(iy + 3 + reach, h)):
                    for xx in range(max(ix - 1 - reach, 0), min(ix + 3 + reach, w)):
                        v = _linear(img, lut, yy, xx)
                        if v > wmax:
                            wmax = v
            if not wmax < hi:
                continue
        out[k] = True


@_njit
def reduce2(src, out):
    """Mean of 2x2 blocks of a float32 image, as :func:`hdrcore.registration._sampling.reduce2`."""
    h2, w2 = out.shape
    q = np.float32(0.25)
    for i in range(h2):
        y0 = 2 * i
        for j in range(w2):
            x0 = 2 * j
            out[i, j] = (
                ((src[y0, x0] + src[y0 + 1, x0]) + src[y0, x0 + 1]) + src[y0 + 1, x0 + 1]
            ) * q


@_inline
def _keys(f, w):  # pragma: no cover - compiled
    w[0], w[1], w[2], w[3] = keys4(f)


@_inline
def _dkeys(f, w):  # pragma: no cover - compiled
    w[0], w[1], w[2], w[3] = dkeys4(f)


@_njit
def gauss_newton_sums(
    img, lut, xs, ys, bs, m, frame, n_par, gradient, hess, grad, gain, n_gain, robust, per_sample
):
    """Eq. 6 weighted sum of squared eq. 7 residuals and the sum of the weights at the samples;
    with ``gradient`` also the Gauss-Newton normal equations of the first ``n_par`` motion
    generators added into ``hess`` (8x8, upper triangle mirrored) and ``grad`` (8).

    ``m`` (3x3, level coordinates) maps the samples ``(xs, ys)`` of the dark frame's grid into
    ``img`` (the bright frame); ``bs`` is ``k * dark`` there. ``frame`` holds ``(lo, hi, t,
    cx, cy, unit, ramp)``: the bright frame's taps are clipped to ``[lo, hi]`` before the
    cubic interpolation (the pyramid levels are clipped already), ``t`` is eq. 7's threshold,
    ``(cx, cy)`` the bright level's centre and ``unit`` its half-diagonal (the generators act
    on ``X = (q - c) / unit``), and a sample's weight falls linearly from 1 to 0 over the last
    ``ramp`` pixels before its 4x4 support leaves the bright frame. No other test depends on
    the motion (the samples are valid by selection), so the sums are continuous in ``m``.
    Generators (columns of the Jacobian, ``d q / d delta = unit * g(X, Y)``): shift x, shift y,
    rotation ``(-Y, X)``, scale ``(X, Y)``, stretch ``(X, -Y)``, shear ``(Y, X)``, and the two
    perspective terms ``(-X^2, -XY)``, ``(-XY, -Y^2)``. The bright frame is multiplied by the
    smooth gain ``exp(gain[0] + gain[1] X + gain[2] Y)`` (a correction of the exposure ratio
    and of its variation across the frame); with ``n_gain`` (0, 1 or 3) its first coefficients
    are ``n_gain`` more columns after the ``n_par`` of the motion (``d n / d gain_i = dn/da a
    (1, X, Y)_i``), so ``hess`` is at least ``(n_par + n_gain)`` square. With ``robust = c >
    0`` each sample's ``n^2`` becomes Cauchy's ``c^2 log(1 + n^2 / c^2)`` and its normal
    equations are weighted by ``1 / (1 + n^2 / c^2)`` (the Gauss-Newton step of that loss).
    ``per_sample`` (``(N, 2)`` zeros, or None: not wanted) takes each sample's residual ``n``
    and weight ``w`` (both stay 0 where the sample is outside the bright frame).
    Returns ``(sum w n^2, sum w)`` (the robust sum with ``robust``).
    """
    h, w = img.shape
    lo = frame[0]
    hi = frame[1]
    t = frame[2]
    cx = frame[3]
    cy = frame[4]
    unit = frame[5]
    ramp = frame[6]
    inv_unit = 1.0 / unit
    inv_ramp = 1.0 / ramp
    m00, m01, m02 = m[0, 0], m[0, 1], m[0, 2]
    m10, m11, m12 = m[1, 0], m[1, 1], m[1, 2]
    m20, m21, m22 = m[2, 0], m[2, 1], m[2, 2]
    wx = np.empty(4)
    wy = np.empty(4)
    dwx = np.empty(4)
    dwy = np.empty(4)
    rows = np.empty(4)
    n_tot = n_par + n_gain
    cols = np.zeros(n_tot)
    g0 = gain[0]
    g1 = gain[1]
    g2 = gain[2]
    uses_gain = g1 != 0.0 or g2 != 0.0 or n_gain > 1
    ssum = 0.0
    wsum = 0.0
    inv_t = 1.0 / max(t, 1e-300)
    # Two phases per block of samples: first only the loads of the 16 taps (independent of each
    # other, so the processor overlaps their cache misses), then the arithmetic.
    block = 64
    buf = np.empty((block, 4, 4))
    fxs = np.empty(block)
    fys = np.empty(block)
    qxs = np.empty(block)
    qys = np.empty(block)
    wts = np.empty(block)
    ks = np.empty(block, np.int64)
    n_all = xs.size
    for start in range(0, n_all, block):
        nb = 0
        for k in range(start, min(start + block, n_all)):
            x = xs[k]
            y = ys[k]
            den = m20 * x + m21 * y + m22
            if not den > 0:
                continue
            qx = (m00 * x + m01 * y + m02) / den
            qy = (m10 * x + m11 * y + m12) / den
            d = min(min(qx - 1.0, w - 2.0 - qx), min(qy - 1.0, h - 2.0 - qy))
            if not d > 0:
                continue  # the 4x4 support leaves the bright frame
            ix = int(math.floor(qx))
            iy = int(math.floor(qy))
            for j in range(4):
                for i in range(4):
                    if lut is None:
                        v = np.float64(img[iy - 1 + j, ix - 1 + i])
                    else:
                        v = np.float64(lut[img[iy - 1 + j, ix - 1 + i]])
                    buf[nb, j, i] = min(max(v, lo), hi)
            fxs[nb] = qx - ix
            fys[nb] = qy - iy
            qxs[nb] = qx
            qys[nb] = qy
            wts[nb] = min(1.0, d * inv_ramp)
            ks[nb] = k
            nb += 1
        for q in range(nb):
            taps = buf[q]
            k = ks[q]
            fx = fxs[q]
            fy = fys[q]
            wt = wts[q]
            _keys(fx, wx)
            _keys(fy, wy)
            for j in range(4):
                rows[j] = (
                    taps[j, 0] * wx[0]
                    + taps[j, 1] * wx[1]
                    + taps[j, 2] * wx[2]
                    + taps[j, 3] * wx[3]
                )
            gx = (qxs[q] - cx) * inv_unit
            gy = (qys[q] - cy) * inv_unit
            gfac = math.exp(g0 + g1 * gx + g2 * gy) if uses_gain else math.exp(g0)
            a = (rows[0] * wy[0] + rows[1] * wy[1] + rows[2] * wy[2] + rows[3] * wy[3]) * gfac
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
            if per_sample is not None:  # pruned at compile time when None
                per_sample[k, 0] = n
                per_sample[k, 1] = wt
            if robust > 0:
                r2 = (n / robust) ** 2
                ssum += wt * robust * robust * math.log1p(r2)
                wsum += wt
                if not gradient:
                    continue
                wt = wt / (1.0 + r2)
            else:
                ssum += wt * n * n
                wsum += wt
                if not gradient:
                    continue
            _dkeys(fx, dwx)
            _dkeys(fy, dwy)
            sx = 0.0
            for j in range(4):
                sx += (
                    taps[j, 0] * dwx[0]
                    + taps[j, 1] * dwx[1]
                    + taps[j, 2] * dwx[2]
                    + taps[j, 3] * dwx[3]
                ) * wy[j]
            sy = rows[0] * dwy[0] + rows[1] * dwy[1] + rows[2] * dwy[2] + rows[3] * dwy[3]
            dn_da = 2.0 * b / (denom * denom) if above else inv_t
            j0 = dn_da * sx * gfac
            j1 = dn_da * sy * gfac
            cols[0] = j0
            cols[1] = j1
            if n_par > 2:
                cols[2] = (j1 * gx - j0 * gy) * unit
                if n_par > 3:
                    cols[3] = (j0 * gx + j1 * gy) * unit
                if n_par > 4:
                    cols[4] = (j0 * gx - j1 * gy) * unit
                    cols[5] = (j0 * gy + j1 * gx) * unit
                    radial = -(j0 * gx + j1 * gy) * unit
                    cols[6] = radial * gx
                    cols[7] = radial * gy
            if n_gain > 0:
                ga = dn_da * a
                cols[n_par] = ga
                if n_gain > 1:
                    cols[n_par + 1] = ga * gx
                    cols[n_par + 2] = ga * gy
            for i in range(n_tot):
                ci = wt * cols[i]
                grad[i] += ci * n
                for jj in range(i, n_tot):
                    hess[i, jj] += ci * cols[jj]
    if gradient:
        for i in range(n_tot):
            for jj in range(i + 1, n_tot):
                hess[jj, i] = hess[i, jj]
    return ssum, wsum


@_njit
def warp_rows(src, m, r0, r1, out):
    """Rows ``r0:r1`` of ``out[y, x, c] = src(m @ (x, y, 1))`` (``m`` 3x3, perspective divide)
    with Keys cubic convolution, the taps clamped to the frame (the edge repeats, as the
    shear passes of :mod:`hdrcore.registration.warp` do); ``src`` and ``out`` are ``(H, W, C)``
    float32; NaN where the divide fails. A row's positions, their weights
    (:func:`hdrcore.geometry.keys_row_weights`) and the reads in three loops, an RGB pixel's
    sums in registers: 60 -> 30 ns a pixel on a 9 MP phone frame, the same values."""
    hs, ws, nc = src.shape
    w = out.shape[1]
    sx = np.empty(w)
    sy = np.empty(w)
    ok = np.empty(w, np.bool_)
    kx, ky, wxs, wys = keys_row_scratch(w)
    acc = np.empty(nc)
    m00, m01, m02 = m[0, 0], m[0, 1], m[0, 2]
    m10, m11, m12 = m[1, 0], m[1, 1], m[1, 2]
    m20, m21, m22 = m[2, 0], m[2, 1], m[2, 2]
    for y in range(r0, r1):
        for x in range(w):
            den = m20 * x + m21 * y + m22
            a = (m00 * x + m01 * y + m02) / den
            b = (m10 * x + m11 * y + m12) / den
            good = den > 0 and a > -1e6 and a < 1e6 and b > -1e6 and b < 1e6
            ok[x] = good
            sx[x] = a if good else 0.0
            sy[x] = b if good else 0.0
        keys_row_weights(sx, sy, w, kx, ky, wxs, wys)
        for x in range(w):
            if not ok[x]:
                for c in range(nc):
                    out[y, x, c] = np.nan
                continue
            ix = kx[x]
            iy = ky[x]
            inside = ix >= 1 and ix <= ws - 3 and iy >= 1 and iy <= hs - 3
            if nc == 3:
                a0 = 0.0
                a1 = 0.0
                a2 = 0.0
                for j in range(4):
                    yy = iy - 1 + j
                    if not inside:
                        yy = min(max(yy, 0), hs - 1)
                    wyj = wys[x, j]
                    for i in range(4):
                        xx = ix - 1 + i
                        if not inside:
                            xx = min(max(xx, 0), ws - 1)
                        wt = wxs[x, i] * wyj
                        a0 += wt * src[yy, xx, 0]
                        a1 += wt * src[yy, xx, 1]
                        a2 += wt * src[yy, xx, 2]
                out[y, x, 0] = a0
                out[y, x, 1] = a1
                out[y, x, 2] = a2
                continue
            for c in range(nc):
                acc[c] = 0.0
            for j in range(4):
                yy = iy - 1 + j
                if not inside:
                    yy = min(max(yy, 0), hs - 1)
                for i in range(4):
                    xx = ix - 1 + i
                    if not inside:
                        xx = min(max(xx, 0), ws - 1)
                    wt = wxs[x, i] * wys[x, j]
                    for c in range(nc):
                        acc[c] += wt * src[yy, xx, c]
            for c in range(nc):
                out[y, x, c] = acc[c]
