"""The registration's compiled kernels written as plainly as numpy allows: the specification the
tests hold them to (issue 17).

Used by the tests only: the registration runs the compiled kernels (numba is a dependency), of
:mod:`hdrcore.registration._kernels`, :mod:`hdrcore.registration.residual`,
:mod:`hdrcore.registration.local` and :mod:`hdrcore.registration.warp`. Each function here has
the signature of the runtime function (or kernel) it specifies, so a test can compare the two
directly or put the spec in the kernel's place (``monkeypatch.setattr``) and run a whole
registration through it. Whole arrays, no row blocks, no scratch buffers, no speed.

Where the kernel does the same float operations in the same order the two agree to the bit
(block means, the Keys warp, box fractions, the non-finite fill, the grid reads); elsewhere
(float32 against float64 intermediates, sums in another order) to rounding, as the tests say.
"""

from __future__ import annotations

import numpy as np

from ..geometry import apply, keys_weights
from . import residual
from ._sampling import sample
from .field import DisplacementField, map_points

__all__ = [
    "box_fraction",
    "gauss_newton_sums",
    "nan_to_mean",
    "plane_fit",
    "prepare",
    "reduce",
    "score_candidates",
    "structure",
    "support_valid",
    "tiles",
    "warp",
    "warp_rows",
    "warped",
]


# ------------------------------------------------------------------ residual.py (residual_motion)
def reduce(
    img: np.ndarray,
    f: int,
    lut: np.ndarray | None,
    workers: int | None = None,
    sat: float = np.inf,
) -> np.ndarray:
    """Block means of ``f x f`` (float64 sums, float32 out) of ``img`` or ``lut[img]``, a block
    holding a value at or above ``sat`` set to ``2 * sat``: the spec of ``residual._reduce``
    (kernels ``_reduce_float_rows``, ``_reduce_lut_rows``)."""
    if f == 1 and lut is None:
        return np.asarray(img).astype(np.float32, copy=False)
    a = np.asarray(img)
    hh, ww = a.shape[0] // f, a.shape[1] // f
    a = a[: hh * f, : ww * f]
    a = lut[a] if lut is not None else a
    blocks = a.astype(np.float64).reshape(hh, f, ww, f)
    mean = blocks.mean(axis=(1, 3))
    clipped = (blocks >= sat).any(axis=(1, 3)) & np.isfinite(mean)
    return np.where(clipped, 2.0 * sat, mean).astype(np.float32)


def warp(
    src: np.ndarray, m: np.ndarray, shape: tuple[int, int], workers: int | None = None
) -> np.ndarray:
    """``src`` at ``m @ (x, y, 1)`` (Keys cubic), NaN outside: the spec of ``residual._warp``
    (kernel ``residual._warp_rows``)."""
    h, w = shape
    hs, ws = src.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    zw = m[2, 0] * xx + m[2, 1] * yy + m[2, 2]
    sx = (m[0, 0] * xx + m[0, 1] * yy + m[0, 2]) / zw
    sy = (m[1, 0] * xx + m[1, 1] * yy + m[1, 2]) / zw
    inside = (sx >= 0) & (sx <= ws - 1) & (sy >= 0) & (sy <= hs - 1)
    ix, iy = np.floor(sx), np.floor(sy)
    wx, wy = keys_weights(sx - ix), keys_weights(sy - iy)
    ix, iy = ix.astype(np.int64), iy.astype(np.int64)
    out = np.zeros(shape)
    for j in range(4):
        rows = np.clip(iy - 1 + j, 0, hs - 1)
        for i in range(4):
            out += wy[j] * wx[i] * src[rows, np.clip(ix - 1 + i, 0, ws - 1)]
    out[~inside] = np.nan
    return out.astype(np.float32)


def _sobel_magnitude(img: np.ndarray) -> np.ndarray:
    """Gradient magnitude (3x3 Sobel, /8) of ``img``; 0 on the one-pixel border."""
    a = img
    sy = a[:-2] + 2.0 * a[1:-1] + a[2:]  # vertical smoothing, for d/dx
    gx = sy[:, 2:] - sy[:, :-2]
    sx = a[:, :-2] + 2.0 * a[:, 1:-1] + a[:, 2:]  # horizontal smoothing, for d/dy
    gy = sx[2:] - sx[:-2]
    out = np.zeros(a.shape, np.float32)
    out[1:-1, 1:-1] = np.sqrt(gx * gx + gy * gy) * np.float32(0.125)
    return out


def _smoothstep(z: np.ndarray) -> np.ndarray:
    z = np.clip(z, 0.0, 1.0)
    return z * z * (3.0 - 2.0 * z)


def structure(
    img: np.ndarray, lo: float, hi: float, workers: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The structure image and the in-range mask: the spec of ``residual._structure`` (kernels
    ``_log_rows``, ``_gradient_rows``; see its docstring)."""
    with np.errstate(invalid="ignore"):
        log = np.log(np.clip(img, lo, hi))
        g = _sobel_magnitude(log)
        u = log - np.float32(np.log(lo))
        g *= _smoothstep(u / np.log(residual.TAPER_LOW)) * _smoothstep(
            (np.float32(np.log(hi / lo)) - u) / np.log(residual.TAPER_HIGH)
        )
        saturated = img >= hi
    if saturated.any():
        near = saturated.copy()  # 3x3 dilation
        near[1:] |= saturated[:-1]
        near[:-1] |= saturated[1:]
        row = near.copy()
        near[:, 1:] |= row[:, :-1]
        near[:, :-1] |= row[:, 1:]
        g[near] = 0.0
    with np.errstate(invalid="ignore"):
        inside = (img > lo) & (img < hi)
    return g, inside


def plane_fit(
    self: residual._PhasePlane, cross: np.ndarray, d: np.ndarray, iterations: int, workers: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """Whole arrays: the spec of ``_PhasePlane.fit`` (kernel ``residual._plane_rows``); ``self``
    is the phase plane (its band and frequencies)."""
    cb = cross[:, self.band]
    wb = np.abs(cb)
    gx, gy = self.fx, self.fy
    sxx = wb @ (gx * gx)
    sxy = wb @ (gx * gy)
    syy = wb @ (gy * gy)
    det = sxx * syy - sxy * sxy
    det = np.where(det > 0, det, np.inf)
    dx, dy = d[:, 0].copy(), d[:, 1].copy()
    for it in range(iterations + 1):
        rot = np.exp(2j * np.pi * (dx[:, None] * gx[None] + dy[:, None] * gy[None]))
        phase = np.angle(cb * rot)
        if it == iterations:
            break
        bx = -((wb * phase) @ gx) / (2 * np.pi)  # phase ~ -2 pi (fx ddx + fy ddy)
        by = -((wb * phase) @ gy) / (2 * np.pi)
        dx = dx + (syy * bx - sxy * by) / det
        dy = dy + (sxx * by - sxy * bx) / det
    scale = np.sum(wb * phase * phase, axis=1) / (4 * np.pi**2 * self.neff)
    cov = np.empty((len(dx), 2, 2))
    cov[:, 0, 0] = scale * syy / det
    cov[:, 1, 1] = scale * sxx / det
    cov[:, 0, 1] = cov[:, 1, 0] = -scale * sxy / det
    return np.stack([dx, dy], axis=1), cov


def tiles(
    img: np.ndarray, oy: np.ndarray, ox: np.ndarray, d: np.ndarray, win: np.ndarray, workers: int
) -> np.ndarray:
    """Windowed, mean-free tiles at ``(oy, ox) + d`` (``d``: dx, dy), all at once: the spec of
    ``residual._tiles`` (kernel ``residual._extract_tiles``)."""
    dy = np.asarray(d[:, 1], np.float64)
    dx = np.asarray(d[:, 0], np.float64)
    h, w = img.shape
    t = win.shape[0]
    fy0, fx0 = np.floor(dy), np.floor(dx)
    wy, wx = keys_weights(dy - fy0), keys_weights(dx - fx0)
    iy = (oy + fy0.astype(int))[:, None] + np.arange(-1, t + 2)[None]
    ix = (ox + fx0.astype(int))[:, None] + np.arange(-1, t + 2)[None]
    patch = img[np.clip(iy, 0, h - 1)[:, :, None], np.clip(ix, 0, w - 1)[:, None, :]]
    patch = patch.astype(np.float64)
    rows = sum(wy[k][:, None, None] * patch[:, k : k + t, :] for k in range(4))
    tiles = sum(wx[k][:, None, None] * rows[:, :, k : k + t] for k in range(4))
    mean = np.sum(tiles * win, axis=(1, 2)) / np.sum(win)
    return ((tiles - mean[:, None, None]) * win).astype(np.float32)


def nan_to_mean(x: np.ndarray) -> np.ndarray:
    """``x`` with its non-finite values replaced by the mean of its finite ones: the spec of
    ``residual._nan_to_mean`` (kernel ``residual._finite_mean_fill``)."""
    finite = np.isfinite(x)
    mean = np.float32(np.mean(x[finite], dtype=np.float64)) if finite.any() else np.float32(0)
    return np.where(finite, x, mean).astype(x.dtype)


def box_fraction(mask: np.ndarray, oy: np.ndarray, ox: np.ndarray, t: int) -> np.ndarray:
    """The fraction of ``mask`` set in each ``t x t`` box at ``(oy, ox)``, from a summed-area
    table: the spec of ``residual._box_fraction`` (kernel ``residual._box_counts``)."""
    sat = np.zeros((mask.shape[0] + 1, mask.shape[1] + 1), np.int64)
    np.cumsum(mask, axis=0, out=sat[1:, 1:])
    np.cumsum(sat[1:, 1:], axis=1, out=sat[1:, 1:])
    total = sat[oy + t, ox + t] - sat[oy, ox + t] - sat[oy + t, ox] + sat[oy, ox]
    return total / float(t * t)


RESIDUAL_KERNELS = {
    "_reduce": reduce,
    "_warp": warp,
    "_structure": structure,
    "_tiles": tiles,
    "_nan_to_mean": nan_to_mean,
    "_box_fraction": box_fraction,
}
"""The functions of :mod:`hdrcore.registration.residual` that run kernels, and their specs
(with :func:`plane_fit` for ``_PhasePlane.fit``): a test sets these in their place."""


# ------------------------------------------------------------------------------------ warp.py
def warp_rows(src: np.ndarray, m: np.ndarray, r0: int, r1: int, out: np.ndarray) -> None:
    """Rows ``r0:r1`` of ``out[y, x, c] = src(m @ (x, y, 1))`` (Keys cubic, taps clamped to the
    frame; NaN where the perspective divide is not positive or the position is beyond 1e6):
    the spec of :func:`hdrcore.registration._kernels.warp_rows` (same signature)."""
    hs, ws, nc = src.shape
    w = out.shape[1]
    yy, xx = np.mgrid[r0:r1, 0:w].astype(np.float64)
    den = m[2, 0] * xx + m[2, 1] * yy + m[2, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        sx = (m[0, 0] * xx + m[0, 1] * yy + m[0, 2]) / den
        sy = (m[1, 0] * xx + m[1, 1] * yy + m[1, 2]) / den
    ok = (den > 0) & (np.abs(sx) < 1e6) & (np.abs(sy) < 1e6)
    sx, sy = np.where(ok, sx, 0.0), np.where(ok, sy, 0.0)
    ix, iy = np.floor(sx), np.floor(sy)
    wx, wy = keys_weights(sx - ix), keys_weights(sy - iy)
    ix, iy = ix.astype(np.int64), iy.astype(np.int64)
    acc = np.zeros((r1 - r0, w, nc))
    for j in range(4):
        rows = np.clip(iy - 1 + j, 0, hs - 1)
        for i in range(4):
            cols = np.clip(ix - 1 + i, 0, ws - 1)
            acc += (wx[i] * wy[j])[..., None] * src[rows, cols]
    acc[~ok] = np.nan
    out[r0:r1] = acc


# ------------------------------------------------------------------ local.py (refine_bracket)
def prepare(img: np.ndarray, lut: np.ndarray | None, f: int, saturation: float) -> np.ndarray:
    """A frame at the working level: ``f x f`` block means (float32) of the linear values
    (``lut[img]``, or ``img``), +inf where a block holds a value at or above ``saturation``:
    the spec of ``local._prepare`` (kernels ``_prepare_rows``, ``_prepare_rows_lut``)."""
    lin = lut[img] if lut is not None else np.asarray(img, np.float32)
    h, w = lin.shape
    hh, ww = h // f, w // f
    blocks = lin[: hh * f, : ww * f].reshape(hh, f, ww, f)
    out = blocks.mean(axis=(1, 3), dtype=np.float32)
    out[(blocks >= np.float32(saturation)).any(axis=(1, 3))] = np.inf
    return out


def warped(
    fr: np.ndarray,
    grid,
    homography: np.ndarray,
    nodes: np.ndarray | None,
    inside: bool = False,
    cubic: bool = False,
    clipped: float = np.inf,
) -> np.ndarray:
    """A level frame ``fr`` read at ``H(x) + d(x)`` (``inside``: ``H(x + d(x))``) for the level
    pixels of ``grid`` (``local._Grid``; ``d`` the bilinear interpolation of the ``nodes``):
    bilinear, or Keys with ``cubic`` (taps clamped); NaN outside the frame, ``clipped`` where
    the read is not finite (a tap in a clipped block): the spec of ``local._warped`` (kernel
    ``local._warp_rows``)."""
    f = grid.f
    xx, yy = np.meshgrid(grid.xs, grid.ys)
    if nodes is None:
        sx, sy = map_points(homography, None, xx, yy)
    else:
        dx, dy = DisplacementField(grid.tile, nodes).on_grid(grid.xs, grid.ys)
        if inside:
            sx, sy = map_points(homography, None, xx + dx, yy + dy)
        else:
            sx, sy = map_points(homography, None, xx, yy)
            sx, sy = sx + dx, sy + dy
    off = (f - 1) / 2.0
    lx, ly = (sx - off) / f, (sy - off) / f
    h, w = fr.shape
    ok = (lx >= 0) & (lx <= w - 1) & (ly >= 0) & (ly <= h - 1)
    lx, ly = np.where(ok, lx, 0.0), np.where(ok, ly, 0.0)
    src = fr.astype(np.float64)
    with np.errstate(invalid="ignore"):
        if cubic:
            ix, iy = np.floor(lx), np.floor(ly)
            wx, wy = keys_weights(lx - ix), keys_weights(ly - iy)
            ix, iy = ix.astype(np.int64), iy.astype(np.int64)
            out = np.zeros(lx.shape)
            for j in range(4):
                rows = np.clip(iy - 1 + j, 0, h - 1)
                for i in range(4):
                    out += wy[j] * wx[i] * src[rows, np.clip(ix - 1 + i, 0, w - 1)]
        else:
            ix = np.minimum(lx.astype(np.int64), w - 2)
            iy = np.minimum(ly.astype(np.int64), h - 2)
            ax, ay = lx - ix, ly - iy
            # a weight of 0 leaves its tap out (an infinite tap times 0 is not a read)
            t0 = np.where(ax > 0, src[iy, ix] * (1 - ax) + src[iy, ix + 1] * ax, src[iy, ix])
            t1 = np.where(
                ax > 0, src[iy + 1, ix] * (1 - ax) + src[iy + 1, ix + 1] * ax, src[iy + 1, ix]
            )
            out = np.where(ay > 0, t0 * (1 - ay) + t1 * ay, t0)
    out = np.where(np.isfinite(out), out, clipped)
    out[~ok] = np.nan
    return out.astype(np.float32)


# ---------------------------------------------------- _kernels.py (the searches of _problem.py)
def score_candidates(img, lut, n_cand, margin, phase, lo, hi, eps2, gradient, ys, xs, vs, scores):
    """Candidate samples of a level on the dark frame's grid: ``n_cand`` interior pixels (the
    interior cut in raster order into equal runs, one pixel of each at the golden-ratio
    sequence's offset from ``phase``) whose value and whose four neighbours' mean lie strictly
    inside ``(lo, hi)``; written to ``ys, xs, vs`` (and their relative gradient
    ``|grad|^2 / (mean^2 + eps2)`` to ``scores`` with ``gradient``) in raster order. Returns
    how many. The spec of :func:`hdrcore.registration._kernels.score_candidates`."""
    h, w = img.shape
    m = margin
    inner_w = w - 2 * m
    n_inner = (h - 2 * m) * inner_w
    kk = np.arange(n_cand, dtype=np.float64)
    u = kk * 0.6180339887498949 + phase
    u -= np.floor(u)
    idx = np.minimum(((kk + u) * (n_inner / n_cand)).astype(np.int64), n_inner - 1)
    yy = idx // inner_w + m
    xx = idx % inner_w + m

    def at(dy: int, dx: int) -> np.ndarray:
        val = img[yy + dy, xx + dx]
        return (val if lut is None else lut[val]).astype(np.float64)

    right, left, down, up = at(0, 1), at(0, -1), at(1, 0), at(-1, 0)
    mean = 0.25 * (right + left + down + up)
    v = at(0, 0)
    ok = (mean > lo) & (mean < hi) & (v > lo) & (v < hi)
    n = int(ok.sum())
    ys[:n], xs[:n], vs[:n] = yy[ok], xx[ok], v[ok]
    if gradient:
        gx, gy = (right - left)[ok], (down - up)[ok]
        scores[:n] = (gx * gx + gy * gy) / (mean[ok] ** 2 + eps2)
    return n


def support_valid(img, lut, xs, ys, m, check_range, lo, hi, max_contrast, reach, out):
    """``out``: whether the 4x4 Keys support of the bright frame ``img`` at ``m @ (x, y, 1)``
    lies inside the frame, spans at most ``max_contrast`` (if > 0) and, with ``check_range``,
    holds values above ``lo`` and, widened by ``reach`` pixels (cut at the border), below
    ``hi``. The spec of :func:`hdrcore.registration._kernels.support_valid`."""
    h, w = img.shape
    src = img if lut is None else lut[img]
    den = m[2, 0] * xs + m[2, 1] * ys + m[2, 2]
    qx, qy = apply(m, xs, ys)
    qx = np.where(den > 0, qx, -10.0)
    ok = (qx >= 1.0) & (qx < w - 2.0) & (qy >= 1.0) & (qy < h - 2.0)
    ix = np.floor(np.where(ok, qx, 1.0)).astype(np.int64)
    iy = np.floor(np.where(ok, qy, 1.0)).astype(np.int64)
    ok &= (ix <= w - 3) & (iy <= h - 3)
    hi_w = np.full(xs.size, -np.inf)
    lo_s, hi_s = np.full(xs.size, np.inf), np.full(xs.size, -np.inf)
    for dy in range(-1 - reach, 3 + reach):
        yy = np.clip(iy + dy, 0, h - 1)
        for dx in range(-1 - reach, 3 + reach):
            v = src[yy, np.clip(ix + dx, 0, w - 1)].astype(np.float64)
            np.maximum(hi_w, v, out=hi_w)
            if -1 <= dy <= 2 and -1 <= dx <= 2:
                np.minimum(lo_s, v, out=lo_s)
                np.maximum(hi_s, v, out=hi_s)
    if check_range:
        ok &= (lo_s > lo) & (hi_w < hi)
    if max_contrast > 0:
        ok &= hi_s <= max_contrast * np.maximum(lo_s, 1e-30)
    out[:] = ok


def _generators(gx: np.ndarray, gy: np.ndarray, n_par: int) -> list[tuple]:
    """Motion generators ``g(X, Y)`` (x and y parts) at normalised bright-frame positions."""
    one, zero = np.ones_like(gx), np.zeros_like(gx)
    gens = [
        (one, zero),
        (zero, one),
        (-gy, gx),
        (gx, gy),
        (gx, -gy),
        (gy, gx),
        (-gx * gx, -gx * gy),
        (-gx * gy, -gy * gy),
    ]
    return gens[:n_par]


def gauss_newton_sums(
    img, lut, xs, ys, bs, m, frame, n_par, gradient, hess, grad, gain, n_gain, robust, per_sample
):
    """Eq. 6 and its Gauss-Newton normal equations at the samples, whole arrays: the spec of
    :func:`hdrcore.registration._kernels.gauss_newton_sums` (same signature and outputs; see
    its docstring for the model).

    Per sample: ``q = m (x, y, 1)`` in the bright frame, ``a`` its clipped taps' Keys value
    times the gain ``exp(g0 + g1 X + g2 Y)``, ``n = (a - b) / max(a + b, t)``, the weight
    ``min(1, d / ramp)`` with ``d`` the distance of the support from the border (0 outside);
    the Jacobian's columns are ``dn/da`` times the value's gradient along the generators, then
    the gain's ``dn/da a (1, X, Y)``."""
    lo, hi, t, cx, cy, unit, ramp = (float(v) for v in frame)
    lin = img if lut is None else lut[img]
    h, w = lin.shape
    den = m[2, 0] * xs + m[2, 1] * ys + m[2, 2]
    qx, qy = apply(m, xs, ys)
    sm = sample(lin, qx, qy, gradient=gradient, clip=(lo, hi))
    d = np.minimum(np.minimum(qx - 1.0, w - 2.0 - qx), np.minimum(qy - 1.0, h - 2.0 - qy))
    valid = (den > 0) & (d > 0) & sm.inside
    weight = np.where(valid, np.minimum(1.0, np.where(valid, d, 0.0) / ramp), 0.0)
    ux, uy = (qx - cx) / unit, (qy - cy) / unit
    gfac = np.exp(gain[0] + gain[1] * ux + gain[2] * uy)
    a = np.where(valid, sm.value, 0.0) * gfac
    total = a + bs
    above = total > t
    denom = np.where(above, total, t) if t > 0 else total
    denom = np.where(valid & (denom > 0), denom, 1.0)
    n = np.where(valid, (a - bs) / denom, 0.0)
    if per_sample is not None:
        per_sample[:, 0] = n
        per_sample[:, 1] = weight
    wsum = float(weight.sum())
    if robust > 0:
        r2 = (n / robust) ** 2
        ssum = float(np.sum(weight * robust * robust * np.log1p(r2)))
        weight = weight / (1.0 + r2)
    else:
        ssum = float(np.sum(weight * n * n))
    if not gradient:
        return ssum, wsum
    dn_da = np.where(valid, np.where(above, 2.0 * bs / (denom * denom), 1.0 / max(t, 1e-300)), 0.0)
    jx, jy = dn_da * gfac * sm.gx, dn_da * gfac * sm.gy
    cols = [jx * ex + jy * ey for ex, ey in _generators(ux, uy, n_par)]
    ga = dn_da * a
    cols += [ga, ga * ux, ga * uy][:n_gain]
    jac = np.stack(cols, axis=1)
    jac[:, 2:n_par] *= unit
    wj = jac * weight[:, None]
    n_tot = n_par + n_gain
    hess[:n_tot, :n_tot] += wj.T @ jac
    grad[:n_tot] += wj.T @ n
    return ssum, wsum
