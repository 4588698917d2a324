"""Geometry: motion matrices (3x3 homographies, 2x3 for affine motion: composition, chaining to a
reference, their parameters) and the sampling kernel that reads a frame through them (Keys' cubic
convolution, a = -1/2), in one module for the registration, the merge and the simulator.

Convention (the project's, see :mod:`hdrcore.synthetic.camera`): a matrix maps pixel coordinates
``(x, y, 1)`` of one frame to pixel coordinates of another; x to the right, y down, origin at the
centre of the top-left pixel. A 2x3 matrix ``A`` is the affine map ``A @ (x, y, 1)``; a 3x3
homography ``H`` maps ``(x, y)`` to ``(u / s, v / s)`` with ``(u, v, s) = H @ (x, y, 1)``. Both
forms are accepted everywhere here: a 2x3 matrix is the homography with last row ``(0, 0, 1)``;
results are 2x3 when every input is 2x3 and 3x3 (scaled to ``H[2, 2] = 1``) otherwise.

A *pair* matrix of the consecutive frames (dark ``i``, bright ``i + 1``) maps coordinates of the
brighter frame to the darker one; a *to-reference* matrix maps coordinates of frame ``k`` to the
reference frame. Cerman & Hlavac (2006), section 6, register only consecutive frames (their
exposures overlap most) and chain the pair transforms to the reference frame; :func:`to_reference`
does the chaining.

:func:`rigid_matrix` is defined here and used by the simulator too, so registration and ground
truth can never disagree on a convention; :func:`similarity_matrix` adds a scale about the same
centre.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ._numba import inline as _inline
from .errors import ParameterError

__all__ = [
    "keys_weights",
    "keys4",
    "dkeys4",
    "keys_at",
    "keys_row_scratch",
    "keys_row_weights",
    "keys_row_at",
    "rigid_matrix",
    "similarity_matrix",
    "compose",
    "invert",
    "identity",
    "homogeneous",
    "affine_part",
    "is_affine",
    "rigid_parameters",
    "similarity_parameters",
    "to_reference",
    "pair_from_reference",
    "apply",
    "corner_error",
    "scale_matrix",
    "nearest_in_frame",
    "common_area",
]

_AFFINE_TOL = 1e-12


def rigid_matrix(dx: float, dy: float, angle_deg: float, shape: tuple[int, int]) -> np.ndarray:
    """2x3 matrix of a rotation by ``angle_deg`` about the image centre followed by a shift.

    ``shape`` is ``(H, W)``; positive angles turn the x axis towards y (clockwise on screen).
    """
    h, w = shape
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    a = np.deg2rad(angle_deg)
    c, s = np.cos(a), np.sin(a)
    rot = np.array([[c, -s], [s, c]])
    centre = np.array([cx, cy])
    t = centre - rot @ centre + np.array([dx, dy])
    return np.hstack([rot, t[:, None]])


def identity() -> np.ndarray:
    """The 2x3 identity."""
    return np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def _check(m: np.ndarray) -> np.ndarray:
    arr = np.asarray(m, float)
    if arr.shape not in ((2, 3), (3, 3)):
        raise ParameterError(
            "a motion matrix must be 2x3 (affine) or 3x3 (homography)", found=f"shape {arr.shape}"
        )
    return arr


def _normalised(h: np.ndarray) -> np.ndarray:
    s = h[2, 2]
    return h / s if abs(s) > 1e-300 else h


def homogeneous(matrix: np.ndarray) -> np.ndarray:
    """The 3x3 homography of a 2x3 or 3x3 matrix (a new array, scaled to ``H[2, 2] = 1``)."""
    m = _check(matrix)
    if m.shape == (2, 3):
        return np.vstack([m, [0.0, 0.0, 1.0]])
    return _normalised(m.copy())


def is_affine(matrix: np.ndarray, tol: float = _AFFINE_TOL) -> bool:
    """Whether ``matrix`` (2x3 or 3x3) is affine: its perspective row is ``(0, 0, 1)``."""
    m = _check(matrix)
    if m.shape == (2, 3):
        return True
    h = _normalised(m)
    return bool(abs(h[2, 0]) <= tol and abs(h[2, 1]) <= tol)


def affine_part(matrix: np.ndarray, tol: float = _AFFINE_TOL) -> np.ndarray:
    """The 2x3 form of an affine matrix (2x3 or 3x3 with last row ``(0, 0, 1)``)."""
    m = _check(matrix)
    if m.shape == (2, 3):
        return m.copy()
    if not is_affine(m, tol):
        raise ParameterError(
            "the homography has a perspective part; it has no 2x3 form",
            found=f"last row {np.round(_normalised(m)[2], 12).tolist()}",
        )
    return _normalised(m)[:2].copy()


def _like(h: np.ndarray, *inputs: np.ndarray) -> np.ndarray:
    h = _normalised(h)
    if all(np.shape(m) == (2, 3) for m in inputs):
        return h[:2].copy()
    return h


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The matrix of ``a`` applied after ``b`` (``a ∘ b``); 2x3 if both are 2x3, else 3x3."""
    return _like(homogeneous(a) @ homogeneous(b), _check(a), _check(b))


def invert(a: np.ndarray) -> np.ndarray:
    """Inverse of a 2x3 or 3x3 matrix, in the same form."""
    return _like(np.linalg.inv(homogeneous(a)), _check(a))


def apply(matrix: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map point coordinates ``(x, y)`` through ``matrix`` (2x3, or 3x3 with the division)."""
    m = _check(matrix)
    u = m[0, 0] * x + m[0, 1] * y + m[0, 2]
    v = m[1, 0] * x + m[1, 1] * y + m[1, 2]
    if m.shape == (2, 3) or (m[2, 0] == 0 and m[2, 1] == 0 and m[2, 2] == 1):
        return u, v
    s = m[2, 0] * x + m[2, 1] * y + m[2, 2]
    return u / s, v / s


def similarity_matrix(
    dx: float, dy: float, angle_deg: float, scale: float, shape: tuple[int, int]
) -> np.ndarray:
    """2x3 matrix of a rotation by ``angle_deg`` and a scaling by ``scale`` about the image centre,
    then a shift by ``(dx, dy)`` (``scale = 1``: :func:`rigid_matrix`)."""
    m = rigid_matrix(dx, dy, angle_deg, shape)
    h, w = shape
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    m[:, :2] *= float(scale)
    m[:, 2] = centre - m[:, :2] @ centre + np.array([dx, dy])
    return m


def _local(matrix: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The displacement of the image centre and the Jacobian (2x2) of the map there."""
    m = _check(matrix)
    h, w = shape
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    if m.shape == (2, 3):
        jac = m[:, :2]
        d = jac @ np.array([cx, cy]) + m[:, 2] - np.array([cx, cy])
        return d, jac
    hm = _normalised(m)
    u, v, s = hm @ np.array([cx, cy, 1.0])
    px, py = u / s, v / s
    jac = (hm[:2, :2] - np.outer([px, py], hm[2, :2])) / s
    return np.array([px - cx, py - cy]), jac


def rigid_parameters(matrix: np.ndarray, shape: tuple[int, int]) -> tuple[float, float, float]:
    """``(dx, dy, angle_deg)`` such that ``rigid_matrix(dx, dy, angle_deg, shape)`` is ``matrix``.

    The inverse of :func:`rigid_matrix` (rotation about the image centre, then shift). For a
    matrix that is not exactly rigid, ``(dx, dy)`` is the displacement of the image centre and
    the angle that of the rotation nearest to the map's Jacobian there.
    """
    d, jac = _local(matrix, shape)
    angle = float(np.degrees(np.arctan2(jac[1, 0] - jac[0, 1], jac[0, 0] + jac[1, 1])))
    return float(d[0]), float(d[1]), angle


def similarity_parameters(
    matrix: np.ndarray, shape: tuple[int, int]
) -> tuple[float, float, float, float]:
    """``(dx, dy, angle_deg, scale)``: the inverse of :func:`similarity_matrix`.

    For any other matrix: the displacement of the image centre, and the angle and scale of the
    similarity nearest to the map's Jacobian there (``scale = |J[:, 0]|`` of its conformal part).
    """
    d, jac = _local(matrix, shape)
    a = 0.5 * (jac[0, 0] + jac[1, 1])
    b = 0.5 * (jac[1, 0] - jac[0, 1])
    angle = float(np.degrees(np.arctan2(b, a)))
    return float(d[0]), float(d[1]), angle, float(np.hypot(a, b))


def scale_matrix(matrix: np.ndarray, factor: float) -> np.ndarray:
    """The same motion expressed on an image resampled by ``factor`` (2x2 block means: 0.5).

    A pixel centre ``x`` of the resampled image sits at ``(x + 0.5) / factor - 0.5`` in the
    original, so the matrix is conjugated by that affine change of coordinates. 2x3 in, 2x3 out;
    3x3 in, 3x3 out.
    """
    f = float(factor)
    s = np.array([[1 / f, 0, 0.5 / f - 0.5], [0, 1 / f, 0.5 / f - 0.5]])  # resampled -> original
    return compose(invert(s), compose(matrix, s))


def to_reference(pairs: Sequence[np.ndarray], reference: int) -> tuple[np.ndarray, ...]:
    """Chain consecutive pair matrices into per-frame matrices to the ``reference`` frame.

    ``pairs[i]`` maps coordinates of frame ``i + 1`` to frame ``i``. Returns ``n = len(pairs) + 1``
    matrices; entry ``k`` maps coordinates of frame ``k`` to the reference frame (identity for the
    reference itself). All 2x3 when every pair is 2x3, all 3x3 otherwise.
    """
    n = len(pairs) + 1
    if not 0 <= int(reference) < n:
        raise ParameterError(
            "reference frame out of range", expected=f"0..{n - 1}", found=str(reference)
        )
    ref = int(reference)
    affine = all(np.shape(p) == (2, 3) for p in pairs)
    out: list[np.ndarray] = [identity() if affine else np.eye(3)] * n  # the reference's
    for k in range(ref + 1, n):  # brighter frames: k -> k-1 -> ... -> ref
        out[k] = compose(out[k - 1], pairs[k - 1])
    for k in range(ref - 1, -1, -1):  # darker frames: k -> k+1 -> ... -> ref
        out[k] = compose(out[k + 1], invert(pairs[k]))
    return tuple(np.asarray(m) if affine else homogeneous(m) for m in out)


def pair_from_reference(to_ref: Sequence[np.ndarray], dark: int, bright: int) -> np.ndarray:
    """Matrix mapping coordinates of frame ``bright`` to frame ``dark``."""
    return compose(invert(to_ref[dark]), to_ref[bright])


def corner_error(estimate: np.ndarray, truth: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Distances (pixels) between the four image corners mapped by ``estimate`` and ``truth``
    (each 2x3 or 3x3)."""
    h, w = shape
    x = np.array([0.0, w - 1.0, 0.0, w - 1.0])
    y = np.array([0.0, 0.0, h - 1.0, h - 1.0])
    ex, ey = apply(estimate, x, y)
    tx, ty = apply(truth, x, y)
    return np.hypot(ex - tx, ey - ty)


def nearest_in_frame(
    to_reference: np.ndarray, xs: np.ndarray, ys: np.ndarray, shape: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The nearest pixel of a frame to reference-grid points ``(xs, ys)``.

    ``to_reference`` (2x3 or 3x3) maps the frame's pixel coordinates to the reference frame's.
    Returns integer ``(xk, yk)`` clipped into the frame of ``shape`` ``(h, w)`` (so they always
    index it) and ``inside``, whether the point falls in the frame at all.
    """
    h, w = int(shape[0]), int(shape[1])
    fx, fy = apply(
        invert(np.asarray(to_reference, np.float64)),
        np.asarray(xs, np.float64),
        np.asarray(ys, np.float64),
    )
    xk = np.rint(fx).astype(np.intp)
    yk = np.rint(fy).astype(np.intp)
    inside = (xk >= 0) & (xk < w) & (yk >= 0) & (yk < h)
    np.clip(xk, 0, w - 1, out=xk)
    np.clip(yk, 0, h - 1, out=yk)
    return xk, yk, inside


# ---------------------------------------------------------------------- the sampling kernel
def keys_weights(f: np.ndarray, derivative: bool = False) -> np.ndarray:
    """Keys' cubic convolution (a = -1/2) weights ``(4, N)`` of taps at offsets -1, 0, 1, 2 for
    fractional positions ``f`` in [0, 1).

    With ``derivative`` the weights of d/df (the kernel's derivative).
    """
    g = 1.0 - f
    if not derivative:
        return np.stack(
            [
                -0.5 * f * g * g,
                (1.5 * f - 2.5) * f * f + 1.0,
                (1.5 * g - 2.5) * g * g + 1.0,
                -0.5 * f * f * g,
            ]
        )
    return np.stack(
        [
            -0.5 * g * (1.0 - 3.0 * f),
            (4.5 * f - 5.0) * f,
            -(4.5 * g - 5.0) * g,
            (1.5 * f - 1.0) * f,
        ]
    )


@_inline
def keys4(f):  # pragma: no cover - compiled
    """Keys weights of the taps -1, 0, 1, 2 at the fraction ``f`` in [0, 1) (float64): the
    compiled form of :func:`keys_weights`."""
    g = 1.0 - f
    return (
        -0.5 * f * g * g,
        (1.5 * f - 2.5) * f * f + 1.0,
        (1.5 * g - 2.5) * g * g + 1.0,
        -0.5 * f * f * g,
    )


@_inline
def dkeys4(f):  # pragma: no cover - compiled
    """The weights of the kernel's derivative d/df at ``f``: the compiled form of
    ``keys_weights(f, derivative=True)``."""
    g = 1.0 - f
    return (
        -0.5 * g * (1.0 - 3.0 * f),
        (4.5 * f - 5.0) * f,
        -(4.5 * g - 5.0) * g,
        (1.5 * f - 1.0) * f,
    )


@_inline
def keys_at(src, sx, sy):  # pragma: no cover - compiled
    """Keys cubic of the 2-D ``src`` at ``(sx, sy)``, the 4 x 4 taps clamped to the frame (a tap
    that is not finite makes the value not finite)."""
    h, w = src.shape
    ix = int(np.floor(sx))
    iy = int(np.floor(sy))
    wx0, wx1, wx2, wx3 = keys4(sx - ix)
    wy0, wy1, wy2, wy3 = keys4(sy - iy)
    return _keys_taps(src, ix, iy, wx0, wx1, wx2, wx3, wy0, wy1, wy2, wy3)


@_inline
def keys_row_scratch(n):  # pragma: no cover - compiled
    """The arrays :func:`keys_row_weights` fills for a row of ``n`` positions: ``(ix, iy, wx,
    wy)``."""
    return (
        np.empty(n, np.int64),
        np.empty(n, np.int64),
        np.empty((n, 4)),
        np.empty((n, 4)),
    )


@_inline
def keys_row_weights(sx, sy, n, ix, iy, wx, wy):  # pragma: no cover - compiled
    """For the positions ``sx[:n], sy[:n]``: ``ix, iy`` their floors and ``wx, wy`` ``(>= n,
    4)`` their Keys weights, as :func:`keys_at` takes them (a position that is not finite or
    beyond 1e15 gets those of 0: such a position is outside any frame, never read). A straight
    loop of its own (it vectorises), for a row of reads by :func:`keys_row_at`: the same values
    as ``keys_at`` to the bit, in about half its time a pixel when each read makes its own."""
    for k in range(n):
        px = sx[k]
        py = sy[k]
        px = px if abs(px) < 1e15 else 0.0  # NaN fails the test too: no int() of NaN
        py = py if abs(py) < 1e15 else 0.0
        fx = np.floor(px)
        fy = np.floor(py)
        ix[k] = int(fx)
        iy[k] = int(fy)
        a0, a1, a2, a3 = keys4(px - fx)
        b0, b1, b2, b3 = keys4(py - fy)
        wx[k, 0] = a0
        wx[k, 1] = a1
        wx[k, 2] = a2
        wx[k, 3] = a3
        wy[k, 0] = b0
        wy[k, 1] = b1
        wy[k, 2] = b2
        wy[k, 3] = b3


@_inline
def keys_row_at(src, k, ix, iy, wx, wy):  # pragma: no cover - compiled
    """:func:`keys_at` of the ``k``-th position of a row set up by :func:`keys_row_weights`."""
    return _keys_taps(
        src,
        ix[k],
        iy[k],
        wx[k, 0],
        wx[k, 1],
        wx[k, 2],
        wx[k, 3],
        wy[k, 0],
        wy[k, 1],
        wy[k, 2],
        wy[k, 3],
    )


@_inline
def _keys_taps(src, ix, iy, wx0, wx1, wx2, wx3, wy0, wy1, wy2, wy3):  # pragma: no cover
    h, w = src.shape
    x0 = min(max(ix - 1, 0), w - 1)
    x1 = min(max(ix, 0), w - 1)
    x2 = min(max(ix + 1, 0), w - 1)
    x3 = min(max(ix + 2, 0), w - 1)
    acc = 0.0
    for dy in range(4):
        yy = min(max(iy - 1 + dy, 0), h - 1)
        wy = wy0 if dy == 0 else (wy1 if dy == 1 else (wy2 if dy == 2 else wy3))
        acc += wy * (wx0 * src[yy, x0] + wx1 * src[yy, x1] + wx2 * src[yy, x2] + wx3 * src[yy, x3])
    return acc


def _largest_rectangle(ok: np.ndarray) -> tuple[int, int, int, int]:
    """The largest axis-aligned all-True rectangle of a boolean grid, ``(r0, c0, r1, c1)``
    half-open (the column histograms and a stack per row; ``(0, 0, 0, 0)`` when none)."""
    rows, cols = ok.shape
    height = np.zeros(cols + 1, np.int64)  # a sentinel column of height 0 closes every run
    best, rect = 0, (0, 0, 0, 0)
    for r in range(rows):
        height[:cols] = np.where(ok[r], height[:cols] + 1, 0)
        stack: list[int] = []
        for c in range(cols + 1):
            start = c
            while stack and height[stack[-1]] >= height[c]:
                top = stack.pop()
                h = int(height[top])
                left = stack[-1] + 1 if stack else 0
                area = h * (c - left)
                if area > best:
                    best, rect = area, (r - h + 1, left, r + 1, c)
                start = left
            del start
            stack.append(c)
    return rect


def common_area(
    to_reference: Sequence[np.ndarray | None],
    shape: tuple[int, int],
    *,
    margin: float = 2.0,
    step: int = 8,
) -> tuple[int, int, int, int]:
    """The largest axis-aligned rectangle of the reference grid ``shape`` (h, w) that every
    frame covers, ``(x0, y0, x1, y1)`` in pixels, half-open: the crop that leaves out the edges
    only some frames reach (a hand-held bracket's border strips, where a merge has fewer
    exposures and, with locally tone-mapped frames, a different rendition).

    ``to_reference[k]``: frame ``k``'s 2x3 / 3x3 matrix to the reference (``None`` or the
    identity: the reference grid itself). A frame covers a reference pixel when the pixel maps
    into it at least ``margin`` px inside its edges (a resampling support, plus any local
    displacement the caller adds). Found on a grid of ``step`` px, then each side moved out
    pixel by pixel while its whole new edge is covered."""
    h, w = int(shape[0]), int(shape[1])
    step = max(1, int(step))
    inverse = []
    for m in to_reference:
        if m is None:
            continue
        hm = homogeneous(np.asarray(m, np.float64))
        if not np.allclose(hm, np.eye(3), atol=1e-12):
            inverse.append(invert(hm))

    def covered(xx: np.ndarray, yy: np.ndarray) -> np.ndarray:
        ok = np.ones(np.shape(xx), bool)
        for mi in inverse:
            sx, sy = apply(mi, xx, yy)
            ok &= (sx >= margin) & (sx <= w - 1 - margin) & (sy >= margin)
            ok &= sy <= h - 1 - margin
        return ok

    ys = np.arange(0, h + step - 1, step, dtype=np.float64).clip(max=h - 1)
    xs = np.arange(0, w + step - 1, step, dtype=np.float64).clip(max=w - 1)
    r0, c0, r1, c1 = _largest_rectangle(covered(*np.meshgrid(xs, ys)))
    if r1 <= r0 or c1 <= c0:
        return (0, 0, 0, 0)
    # grid node i is pixel ys[i]; the covered nodes r0..r1-1 span pixels ys[r0]..ys[r1-1]
    # (coverage is convex for these motions: the pixels between covered nodes are covered)
    x0, x1 = int(xs[c0]), int(xs[c1 - 1]) + 1
    y0, y1 = int(ys[r0]), int(ys[r1 - 1]) + 1

    def edge_ok(x_a: int, x_b: int, y_a: int, y_b: int) -> bool:
        """Every pixel of the (one pixel wide) edge ``x_a:x_b`` x ``y_a:y_b`` covered."""
        yy, xx = np.mgrid[y_a:y_b, x_a:x_b].astype(np.float64)
        return bool(covered(xx, yy).all())

    # then outwards pixel by pixel while a whole new edge is covered (at most step - 1 each)
    for _ in range(step - 1):
        if x0 > 0 and edge_ok(x0 - 1, x0, y0, y1):
            x0 -= 1
        if x1 < w and edge_ok(x1, x1 + 1, y0, y1):
            x1 += 1
        if y0 > 0 and edge_ok(x0, x1, y0 - 1, y0):
            y0 -= 1
        if y1 < h and edge_ok(x0, x1, y1, y1 + 1):
            y1 += 1
    return (x0, y0, x1, y1)
