"""Warping frames onto the reference frame: cubic convolution in separable passes, border masks.

A rigid warp (rotation and shift, what the registration of Cerman & Hlavac 2006, section 6,
estimates) is done as three one-dimensional shears (A. Paeth, "A fast algorithm for general raster
rotation", Graphics Interface 1986; M. Unser et al., "Convolution-based interpolation for fast,
high-quality rotation of images", IEEE TIP 4(10), 1995)::

    R(theta) = X(alpha) Y(beta) X(alpha),   alpha = -tan(theta / 2),   beta = sin(theta)

Each shear moves whole rows (or columns) by one sub-pixel offset, so it is a 1-D resampling with
Keys' cubic convolution (R. Keys, IEEE TASSP 29(6), 1981) whose four weights are constant along a
row: a few vectorised multiply-adds over the image, instead of the 16-tap gather of direct 2-D
cubic interpolation or the full-image prefilter of cubic B-splines. A pure shift needs two
passes. Every other matrix (a similarity's scale, an affine shear, a 3x3 homography's
perspective) is resampled directly with the same Keys kernel, 16 taps per pixel, in a compiled
kernel on two threads (:func:`hdrcore.registration._kernels.warp_rows`; its readable
specification, used only by the tests, is :func:`hdrcore.registration.spec.warp_rows`). The
shear passes are numpy on purpose: not a copy of that kernel but another resampling (exact for
shifts and rotations, whole rows at a time).

The validity mask is analytic: a pixel is valid when its source position lies inside the source
frame (by ``margin`` pixels), so it never depends on the image content. For a homography each
bound is still linear along a row once multiplied by the (positive) perspective denominator, so
the valid pixels of a row remain one interval.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._threads import run_row_spans
from ..errors import ParameterError
from ..geometry import invert
from . import _kernels
from ._sampling import keys_weights

__all__ = ["WarpResult", "warp", "warp_to_reference", "valid_mask"]


@dataclass(frozen=True, eq=False)
class WarpResult:
    """A warped image (float32, ``fill`` outside, or the frame's edge extended) and its validity
    mask (True inside)."""

    image: np.ndarray = field(repr=False)
    mask: np.ndarray = field(repr=False)
    method: str = "shear"


def _row_intervals(
    m: np.ndarray, output_shape: tuple[int, int], source_shape: tuple[int, int], margin: float
) -> tuple[np.ndarray, np.ndarray]:
    """Per output row, the first and last column whose source lies inside (empty: lo > hi).

    ``m`` is 2x3 or 3x3. With ``s(x) = m[2] . (x, y, 1) > 0`` every bound on the source
    coordinate ``u(x) / s(x)`` is a linear constraint on ``x``, so the valid pixels of a row form
    one interval, found from at most five linear constraints.
    """
    h, w = output_shape
    hs, ws = source_shape
    y = np.arange(h, dtype=np.float64)
    lo = np.zeros(h)
    hi = np.full(h, w - 1.0)
    eps = 1e-6
    if m.shape == (3, 3):
        den_a, den_b = m[2, 0], m[2, 1] * y + m[2, 2]
    else:
        den_a, den_b = 0.0, np.ones(h)
    constraints = [(den_a, den_b - 1e-12)] if m.shape == (3, 3) else []
    for row, limit in ((0, ws - 1 - margin), (1, hs - 1 - margin)):
        num_a, num_b = m[row, 0], m[row, 1] * y + m[row, 2]
        constraints.append((num_a - margin * den_a, num_b - margin * den_b + eps * den_b))
        constraints.append((limit * den_a - num_a, limit * den_b - num_b + eps * den_b))
    for a, b in constraints:  # a x + b >= 0
        a = float(a)
        if abs(a) < 1e-12:
            hi = np.where(b >= 0, hi, -1.0)
            continue
        bound = -b / a
        if a > 0:
            lo = np.maximum(lo, bound)
        else:
            hi = np.minimum(hi, bound)
    return np.ceil(lo - eps).astype(np.int64), np.floor(hi + eps).astype(np.int64)


def valid_mask(
    matrix: np.ndarray,
    output_shape: tuple[int, int],
    source_shape: tuple[int, int],
    margin: float = 0.0,
) -> np.ndarray:
    """True where ``matrix`` (2x3 or 3x3, output -> source coordinates) lands inside the source
    frame."""
    lo, hi = _row_intervals(_as_matrix(matrix), output_shape, source_shape, margin)
    x = np.arange(output_shape[1])[None, :]
    return (x >= lo[:, None]) & (x <= hi[:, None])


def _bands(offsets: np.ndarray):
    """Runs of consecutive entries with the same integer part: (start, stop, int_part)."""
    ip = np.floor(offsets).astype(np.int64)
    change = np.flatnonzero(np.diff(ip)) + 1
    starts = np.concatenate([[0], change])
    stops = np.concatenate([change, [ip.size]])
    return ip, [(int(a), int(b), int(ip[a])) for a, b in zip(starts, stops, strict=True)]


def _x_pass(src: np.ndarray, rows: np.ndarray, offsets: np.ndarray, out_w: int) -> np.ndarray:
    """``out[r, u] = src(rows[r], u + offsets[r])`` with cubic convolution along x (edge clamp)."""
    ip, bands = _bands(offsets)
    frac = (offsets - ip).astype(np.float32)
    wts = keys_weights(frac).astype(np.float32).T  # (rows, 4)
    lo = int(ip.min()) - 1
    hi = int(ip.max()) + out_w + 2
    pad_l, pad_r = max(0, -lo), max(0, hi - src.shape[1])
    rows = np.clip(rows, 0, src.shape[0] - 1)
    contiguous = rows.size > 1 and np.all(np.diff(rows) == 1)
    if pad_l or pad_r:
        widths = [(0, 0), (pad_l, pad_r)] + [(0, 0)] * (src.ndim - 2)
        src = np.pad(src, widths, mode="edge")
    out = np.empty((rows.size, out_w) + src.shape[2:], np.float32)
    extra = (None,) * (src.ndim - 1)
    for a, b, i in bands:
        r = slice(rows[a], rows[a] + (b - a)) if contiguous else rows[a:b]
        dst = out[a:b]
        tmp = np.empty_like(dst)
        for j in range(4):
            c0 = pad_l + i + j - 1
            np.multiply(
                src[r, c0 : c0 + out_w],
                wts[a:b, j][(slice(None),) + extra],
                out=dst if j == 0 else tmp,
            )
            if j:
                dst += tmp
    return out


def _y_pass(src: np.ndarray, cols: np.ndarray, offsets: np.ndarray, out_h: int) -> np.ndarray:
    """``out[v, c] = src(v + offsets[c], cols[c])`` with cubic convolution along y (edge clamp)."""
    ip, bands = _bands(offsets)
    frac = (offsets - ip).astype(np.float32)
    wts = keys_weights(frac).astype(np.float32)  # (4, cols)
    lo = int(ip.min()) - 1
    hi = int(ip.max()) + out_h + 2
    pad_t, pad_b = max(0, -lo), max(0, hi - src.shape[0])
    cols = np.clip(cols, 0, src.shape[1] - 1)
    contiguous = cols.size > 1 and np.all(np.diff(cols) == 1)
    if pad_t or pad_b:
        widths = [(pad_t, pad_b), (0, 0)] + [(0, 0)] * (src.ndim - 2)
        src = np.pad(src, widths, mode="edge")
    out = np.empty((out_h, cols.size) + src.shape[2:], np.float32)
    extra = (None,) * (src.ndim - 2)
    for a, b, i in bands:
        c = slice(cols[a], cols[a] + (b - a)) if contiguous else cols[a:b]
        dst = out[:, a:b]
        tmp = np.empty_like(dst)
        for j in range(4):
            r0 = pad_t + i + j - 1
            np.multiply(
                src[r0 : r0 + out_h, c],
                wts[j, a:b][(None, slice(None)) + extra],
                out=dst if j == 0 else tmp,
            )
            if j:
                dst += tmp
    return out


def _as_matrix(matrix: np.ndarray) -> np.ndarray:
    """A finite 2x3 matrix, or a 3x3 one when it has a perspective part."""
    m = np.asarray(matrix, float)
    if m.shape not in ((2, 3), (3, 3)) or not np.all(np.isfinite(m)):
        raise ParameterError(
            "warp matrix must be a finite 2x3 (affine) or 3x3 (homography) matrix",
            found=str(m.shape),
        )
    if m.shape == (3, 3):
        if abs(m[2, 2]) < 1e-300:
            raise ParameterError("warp homography has H[2, 2] = 0", found=str(m.tolist()))
        m = m / m[2, 2]
        if abs(m[2, 0]) < 1e-15 and abs(m[2, 1]) < 1e-15:
            m = m[:2]
    return m


def _resample_direct(src: np.ndarray, m: np.ndarray, h: int, w: int) -> np.ndarray:
    """Keys cubic at ``m @ (x, y, 1)`` per output pixel (compiled, two threads)."""
    h3 = m if m.shape == (3, 3) else np.vstack([m, [0.0, 0.0, 1.0]])
    chans = np.ascontiguousarray(src.reshape(src.shape[0], src.shape[1], -1))
    out = np.empty((h, w, chans.shape[2]), np.float32)
    run_row_spans(h, None, lambda r0, r1: _kernels.warp_rows(chans, h3, r0, r1, out))
    return out[..., 0] if src.ndim == 2 else out


def _is_rotation(m: np.ndarray, tol: float = 1e-9) -> bool:
    lin = m[:, :2]
    return bool(np.allclose(lin.T @ lin, np.eye(2), atol=tol) and np.linalg.det(lin) > 0)


def warp(
    image: np.ndarray,
    matrix: np.ndarray,
    output_shape: tuple[int, int] | None = None,
    *,
    fill: float | None = np.nan,
    margin: float = 0.0,
) -> WarpResult:
    """Resample ``image`` (``(H, W)`` or ``(H, W, C)``) at ``matrix @ (x, y, 1)`` per output pixel.

    ``matrix`` (2x3, or 3x3 with the perspective divide) maps output pixel coordinates to source
    pixel coordinates (a backward map). Shifts and rotations use the separable shear passes
    (``method`` ``"integer"`` / ``"shear"``); every other matrix direct Keys cubic convolution
    (``"cubic"``, compiled: :func:`~hdrcore.registration._kernels.warp_rows`). Pixels whose
    source lies outside the frame (by
    ``margin``) get ``fill`` and ``mask`` False; ``fill=None`` leaves them what the resampling
    gives there, the frame's edge extended (the taps are clamped to the frame: an edge pixel
    repeated outward along the source's rows and columns; NaN only where the perspective
    divide fails).
    """
    img = np.asarray(image)
    if img.ndim not in (2, 3):
        raise ParameterError("warp needs an (H, W) or (H, W, C) image", found=str(img.shape))
    m = _as_matrix(matrix)
    h0, w0 = img.shape[:2]
    h, w = (h0, w0) if output_shape is None else (int(output_shape[0]), int(output_shape[1]))
    src = img.astype(np.float32, copy=False)
    lin, (cx, cy) = m[:2, :2], m[:2, 2]
    method = "shear"
    if m.shape == (3, 3) or not (np.allclose(lin, np.eye(2), atol=1e-12) or _is_rotation(m)):
        method = "cubic"
        out = _resample_direct(src, m, h, w)
    elif np.allclose(lin, np.eye(2), atol=1e-12):
        if abs(cx - round(cx)) < 1e-9 and abs(cy - round(cy)) < 1e-9:
            method = "integer"
        tmp = _y_pass(src, np.arange(w0), np.full(w0, cy), h)  # rows first: y shift
        out = _x_pass(tmp, np.arange(h), np.full(h, cx), w)
    elif _is_rotation(m):
        theta = np.arctan2(lin[1, 0], lin[0, 0])
        alpha = -np.tan(theta / 2.0)
        beta = np.sin(theta)
        ty, tx = cy, cx - alpha * cy
        ys = np.arange(h, dtype=np.float64)
        # I3(x, y) = I2(x + alpha y, y): I2 is needed on columns x2 (its own grid).
        sx = alpha * ys
        x2_0 = int(np.floor(min(sx.min(), 0.0))) - 2
        x2_1 = int(np.ceil(w - 1 + max(sx.max(), 0.0))) + 2
        x2 = np.arange(x2_0, x2_1 + 1, dtype=np.float64)
        # I2(x2, y) = I1(x2, y + beta x2 + ty): I1 is needed on rows y1.
        sy = beta * x2 + ty
        y1_0 = int(np.floor(sy.min())) - 2
        y1_1 = int(np.ceil(h - 1 + sy.max())) + 2
        y1 = np.arange(y1_0, y1_1 + 1)
        # I1(x2, y1) = I0(x2 + alpha y1 + tx, y1): rows of the source frame (clamped).
        i1 = _x_pass(src, y1, x2_0 + alpha * y1 + tx, x2.size)
        i2 = _y_pass(i1, np.arange(x2.size), sy - y1_0, h)
        out = _x_pass(i2, np.arange(h), sx - x2_0, w)
    lo, hi = _row_intervals(m, (h, w), (h0, w0), margin)
    for y in np.flatnonzero((lo > 0) | (hi < w - 1)) if fill is not None else ():
        # fill outside the valid interval
        if lo[y] > hi[y]:
            out[y] = fill
        else:
            out[y, : max(lo[y], 0)] = fill
            out[y, hi[y] + 1 :] = fill
    x = np.arange(w)[None, :]
    mask = (x >= lo[:, None]) & (x <= hi[:, None])
    return WarpResult(out, mask, method)


def warp_to_reference(
    image: np.ndarray, to_reference: np.ndarray, *, fill: float = np.nan, margin: float = 0.0
) -> WarpResult:
    """Warp a frame onto the reference frame given its ``to_reference`` matrix (frame -> ref;
    2x3 or 3x3)."""
    return warp(image, invert(to_reference), fill=fill, margin=margin)
