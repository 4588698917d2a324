"""Demosaicing of a Bayer colour filter array: our own compiled kernels, scale-equivariant.

Method ``"hamilton-adams"``: J. F. Hamilton, J. E. Adams, "Adaptive color plane
interpolation in single sensor color electronic camera", US patent 5,629,734 (1997). Green at
an R or B site is interpolated along the direction of the smaller gradient, ``|G_w - G_e| +
|2 C - C_ww - C_ee|`` against the same vertically, as ``(G_w + G_e) / 2 + (2 C - C_ww - C_ee) / 4``
(both directions averaged on a tie); red and blue are the green plane plus the bilinear mean of
the neighbouring colour differences ``C - G`` (row or column neighbours at a G site, the four
diagonals at a B or R site). Its choices compare gradients, so scaling the mosaic by ``k``
scales the result by ``k``.

Method ``"malvar2004"`` (the default): H. S. Malvar, L.-W. He, R. Cutler, "High-quality linear
interpolation for demosaicing of Bayer-patterned color images", IEEE ICASSP 2004, vol. 3, pp.
485-488,
doi:10.1109/ICASSP.2004.1326587. Each missing colour is the bilinear estimate plus a gain times
the Laplacian of the colour the site samples (the paper's figure 2 filters, 5x5, sums of 8):

* G at an R or B site: ``(4 v + 2 (N + S + E + W) - (NN + SS + EE + WW)) / 8``;
* R (B) at a G site whose row neighbours are R (B): ``(5 v + 4 (E + W) - (EE + WW) - (NE + NW +
  SE + SW) + (NN + SS) / 2) / 8``, and transposed when its column neighbours are;
* B at an R site (and R at B): ``(6 v + 2 (NE + NW + SE + SW) - 3/2 (NN + SS + EE + WW)) / 8``.

It is linear (a fixed combination of the input) but zips along sharp horizontal and vertical
lines of the real Canon CRW files, where Hamilton-Adams does not; it is the default for the
merge's accuracy next to clipped regions (see :mod:`hdrcore.io.raw`). Both keep the R/B ratios of a
bracket, which LibRaw's AHD (a choice between interpolation directions by a homogeneity test in
CIELab, a non-linear space) does not. Borders are mirrored without repeating the edge (index
``-1`` reads ``1``), which keeps the CFA phase.

:func:`demosaic` runs the compiled kernels (numba, GIL released, rows on two threads);
:func:`demosaic_reference` is the same as whole-image NumPy code, used only by the tests.
``DEMOSAIC_METHODS`` lists the methods (:func:`validate_method` names them in its error).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ._numba import njit
from ._threads import run_row_spans
from .errors import ParameterError

__all__ = [
    "DEMOSAIC_METHODS",
    "bayer_channels",
    "demosaic",
    "demosaic_reference",
    "validate_method",
]

#: Demosaic methods of :func:`demosaic` (the file readers add LibRaw's, see
#: :mod:`hdrcore.io.raw`).
DEMOSAIC_METHODS: dict[str, str] = {
    "malvar2004": "Malvar, He & Cutler 2004: bilinear + gradient correction, 5x5, linear",
    "bilinear": "bilinear interpolation of each colour plane, 3x3, linear",
    "malvar2004-clamped": "malvar2004, each interpolated value held within the range of the "
                          "nearest samples of its colour (no overshoot at high-contrast edges; "
                          "scale-equivariant)",
    "hamilton-adams": "Hamilton & Adams 1997: green along the direction of the smaller "
                      "gradient + Laplacian, red and blue by colour differences; its choices "
                      "compare gradients, so it is scale-equivariant",
}

_LETTERS = {"R": 0, "G": 1, "B": 2}


def validate_method(method: str) -> str:
    """``method`` if it is a key of :data:`DEMOSAIC_METHODS`, else a ParameterError naming them."""
    if method not in DEMOSAIC_METHODS:
        raise ParameterError(f"unknown demosaic method {method!r}",
                             expected=", ".join(DEMOSAIC_METHODS), found=repr(method))
    return method


def bayer_channels(pattern: np.ndarray | Sequence[Sequence[int]], colors: str) -> np.ndarray:
    """The 2x2 channel map (0 R, 1 G, 2 B) of a Bayer CFA from rawpy's ``raw_pattern`` and
    ``color_desc`` (``"RGBG"``: index 3 is the second green); a ParameterError for anything that
    is not a Bayer cell (one R, one B, two G on a diagonal)."""
    pat = np.asarray(pattern, dtype=np.int64)
    if pat.shape != (2, 2):
        raise ParameterError("demosaic needs a 2x2 colour filter array", expected="(2, 2)",
                             found=str(pat.shape))
    try:
        ch = np.array([[_LETTERS[colors[int(i)]] for i in row] for row in pat], np.int64)
    except (KeyError, IndexError):
        raise ParameterError("colour filter array site is not R, G or B",
                             found=f"pattern {pat.tolist()}, colours {colors!r}") from None
    if not (ch[0, 0] == ch[1, 1] == 1 or ch[0, 1] == ch[1, 0] == 1) or sorted(
            ch.ravel().tolist()) != [0, 1, 1, 2]:
        raise ParameterError("demosaic needs a Bayer pattern (one R, one B, two G on a diagonal)",
                             found=str(ch.tolist()))
    return ch


@njit
def _reflect_index(n, pad):  # pragma: no cover - numba
    """Indices ``-pad .. n + pad - 1`` mirrored into ``0 .. n - 1`` without repeating the edge."""
    out = np.empty(n + 2 * pad, np.int64)
    for i in range(n + 2 * pad):
        j = i - pad
        while j < 0 or j >= n:
            if j < 0:
                j = -j
            if j >= n:
                j = 2 * (n - 1) - j
        out[i] = j
    return out


@njit
def _malvar_rows(cfa, offset, chan, method, lo, hi, rounding, out, r0, r1,
                 ceiling, capped):  # pragma: no cover
    h, w = cfa.shape
    ry = _reflect_index(h, 2)
    rx = _reflect_index(w, 2)
    half = np.float32(0.5)
    quarter = np.float32(0.25)
    for y in range(r0, r1):
        ym2, ym1, yp1, yp2 = ry[y], ry[y + 1], ry[y + 3], ry[y + 4]
        p = y & 1
        q = 1 - p
        for x in range(w):
            xm2, xm1, xp1, xp2 = rx[x], rx[x + 1], rx[x + 3], rx[x + 4]
            i = x & 1
            j = 1 - i
            # Mirroring keeps the CFA phase: a tap's site is (row parity, column parity).
            # ``capped``: every tap is held at the centre's ceiling (see demosaic()).
            cap = ceiling[y, x] if capped else np.float32(np.inf)
            cen = min(np.float32(cfa[y, x]) - offset[p, i], cap)
            n = min(np.float32(cfa[ym1, x]) - offset[q, i], cap)
            s = min(np.float32(cfa[yp1, x]) - offset[q, i], cap)
            e = min(np.float32(cfa[y, xp1]) - offset[p, j], cap)
            wv = min(np.float32(cfa[y, xm1]) - offset[p, j], cap)
            od = offset[q, j]
            d1 = min(np.float32(cfa[ym1, xm1]) - od, cap)
            d2 = min(np.float32(cfa[ym1, xp1]) - od, cap)
            d3 = min(np.float32(cfa[yp1, xm1]) - od, cap)
            d4 = min(np.float32(cfa[yp1, xp1]) - od, cap)
            diag = d1 + d2 + d3 + d4
            c = chan[p, i]
            clamp = method == 2
            if method != 1:
                op = offset[p, i]
                far_v = (min(np.float32(cfa[ym2, x]) - op, cap)
                         + min(np.float32(cfa[yp2, x]) - op, cap))
                far_h = (min(np.float32(cfa[y, xm2]) - op, cap)
                         + min(np.float32(cfa[y, xp2]) - op, cap))
            else:
                far_v = np.float32(0.0)
                far_h = np.float32(0.0)
            if c == 1:
                row = e + wv
                col = n + s
                if method != 1:
                    a_h = (5 * cen + 4 * row - far_h - diag + half * far_v) / 8
                    a_v = (5 * cen + 4 * col - far_v - diag + half * far_h) / 8
                    if clamp:
                        a_h = min(max(a_h, min(e, wv)), max(e, wv))
                        a_v = min(max(a_v, min(n, s)), max(n, s))
                else:
                    a_h = half * row
                    a_v = half * col
                g = cen
                if chan[p, j] == 0:  # red row neighbours
                    r = a_h
                    b = a_v
                else:
                    r = a_v
                    b = a_h
            else:
                cross = n + s + e + wv
                if method != 1:
                    far = far_v + far_h
                    g = (4 * cen + 2 * cross - far) / 8
                    oo = (6 * cen + 2 * diag - np.float32(1.5) * far) / 8
                    if clamp:
                        g = min(max(g, min(min(n, s), min(e, wv))), max(max(n, s), max(e, wv)))
                        oo = min(max(oo, min(min(d1, d2), min(d3, d4))),
                                 max(max(d1, d2), max(d3, d4)))
                else:
                    g = quarter * cross
                    oo = quarter * diag
                if c == 0:
                    r = cen
                    b = oo
                else:
                    r = oo
                    b = cen
            r = min(max(r, lo), hi)
            g = min(max(g, lo), hi)
            b = min(max(b, lo), hi)
            if rounding:
                r = np.floor(r + half)
                g = np.floor(g + half)
                b = np.floor(b + half)
            out[y, x, 0] = r
            out[y, x, 1] = g
            out[y, x, 2] = b


@njit
def _ha_green_rows(cfa, offset, chan, green, r0, r1, ceiling, capped):  # pragma: no cover
    """Hamilton-Adams pass 1: the green plane (``green``, float32 ``(H, W)``)."""
    h, w = cfa.shape
    ry = _reflect_index(h, 2)
    rx = _reflect_index(w, 2)
    half = np.float32(0.5)
    quarter = np.float32(0.25)
    for y in range(r0, r1):
        ym2, ym1, yp1, yp2 = ry[y], ry[y + 1], ry[y + 3], ry[y + 4]
        p = y & 1
        q = 1 - p
        for x in range(w):
            i = x & 1
            j = 1 - i
            cap = ceiling[y, x] if capped else np.float32(np.inf)
            cen = min(np.float32(cfa[y, x]) - offset[p, i], cap)
            if chan[p, i] == 1:
                green[y, x] = cen
                continue
            xm2, xm1, xp1, xp2 = rx[x], rx[x + 1], rx[x + 3], rx[x + 4]
            op = offset[p, i]
            e = min(np.float32(cfa[y, xp1]) - offset[p, j], cap)
            wv = min(np.float32(cfa[y, xm1]) - offset[p, j], cap)
            n = min(np.float32(cfa[ym1, x]) - offset[q, i], cap)
            s = min(np.float32(cfa[yp1, x]) - offset[q, i], cap)
            lap_h = 2 * cen - min(np.float32(cfa[y, xm2]) - op, cap) \
                - min(np.float32(cfa[y, xp2]) - op, cap)
            lap_v = 2 * cen - min(np.float32(cfa[ym2, x]) - op, cap) \
                - min(np.float32(cfa[yp2, x]) - op, cap)
            grad_h = abs(e - wv) + abs(lap_h)
            grad_v = abs(n - s) + abs(lap_v)
            g_h = half * (e + wv) + quarter * lap_h
            g_v = half * (n + s) + quarter * lap_v
            if grad_h < grad_v:
                green[y, x] = g_h
            elif grad_v < grad_h:
                green[y, x] = g_v
            else:
                green[y, x] = half * (g_h + g_v)


@njit
def _ha_colour_rows(cfa, offset, chan, green, lo, hi, rounding, out, r0, r1, ceiling,
                    capped):  # pragma: no cover
    """Hamilton-Adams pass 2: red and blue by bilinear colour differences over ``green``."""
    h, w = cfa.shape
    ry = _reflect_index(h, 2)
    rx = _reflect_index(w, 2)
    half = np.float32(0.5)
    quarter = np.float32(0.25)
    for y in range(r0, r1):
        ym1, yp1 = ry[y + 1], ry[y + 3]
        p = y & 1
        q = 1 - p
        for x in range(w):
            xm1, xp1 = rx[x + 1], rx[x + 3]
            i = x & 1
            j = 1 - i
            cap = ceiling[y, x] if capped else np.float32(np.inf)
            c = chan[p, i]
            g = green[y, x]
            cen = min(np.float32(cfa[y, x]) - offset[p, i], cap)
            if c == 1:
                # Row neighbours' colour and column neighbours' colour, as differences to G.
                d_h = half * ((min(np.float32(cfa[y, xm1]) - offset[p, j], cap)
                               - min(green[y, xm1], cap))
                              + (min(np.float32(cfa[y, xp1]) - offset[p, j], cap)
                                 - min(green[y, xp1], cap)))
                d_v = half * ((min(np.float32(cfa[ym1, x]) - offset[q, i], cap)
                               - min(green[ym1, x], cap))
                              + (min(np.float32(cfa[yp1, x]) - offset[q, i], cap)
                                 - min(green[yp1, x], cap)))
                if chan[p, j] == 0:
                    r = g + d_h
                    b = g + d_v
                else:
                    r = g + d_v
                    b = g + d_h
            else:
                od = offset[q, j]
                d = quarter * (
                    (min(np.float32(cfa[ym1, xm1]) - od, cap) - min(green[ym1, xm1], cap))
                    + (min(np.float32(cfa[ym1, xp1]) - od, cap) - min(green[ym1, xp1], cap))
                    + (min(np.float32(cfa[yp1, xm1]) - od, cap) - min(green[yp1, xm1], cap))
                    + (min(np.float32(cfa[yp1, xp1]) - od, cap) - min(green[yp1, xp1], cap)))
                if c == 0:
                    r = cen
                    b = g + d
                else:
                    r = g + d
                    b = cen
            r = min(max(r, lo), hi)
            g = min(max(g, lo), hi)
            b = min(max(b, lo), hi)
            if rounding:
                r = np.floor(r + half)
                g = np.floor(g + half)
                b = np.floor(b + half)
            out[y, x, 0] = r
            out[y, x, 1] = g
            out[y, x, 2] = b


def _prepare(mosaic: np.ndarray, pattern, colors: str, black_level):
    cfa = np.asarray(mosaic)
    if cfa.ndim != 2 or cfa.shape[0] < 3 or cfa.shape[1] < 3:
        raise ParameterError("demosaic needs a 2-D mosaic of at least 3x3", found=str(cfa.shape))
    chan = bayer_channels(pattern, colors)
    pat = np.asarray(pattern, dtype=np.int64)
    blacks = np.atleast_1d(np.asarray(black_level, dtype=np.float64))
    if blacks.size == 1:
        offset = np.full((2, 2), float(blacks[0]), np.float32)
    else:
        offset = np.array([[blacks[int(i)] for i in row] for row in pat], np.float32)
    return cfa, chan, offset


def demosaic(
    mosaic: np.ndarray,
    pattern: np.ndarray | Sequence[Sequence[int]],
    colors: str = "RGBG",
    *,
    method: str = "malvar2004",
    black_level: float | Sequence[float] = 0.0,
    max_level: float | None = None,
    dtype: type = np.float32,
    out: np.ndarray | None = None,
    workers: int | None = None,
    ceiling: np.ndarray | None = None,
) -> np.ndarray:
    """Demosaic a Bayer mosaic ``(H, W)`` into ``(H, W, 3)`` R, G, B.

    ``ceiling`` (float32 ``(H, W)``, same units as the black-subtracted mosaic): for an HDR
    mosaic (:mod:`hdrcore.merge.mosaic`), every value read for the output pixel ``(y, x)`` is
    held at ``ceiling[y, x]``, the clipping level of the longest frame in which that site is
    unclipped. A pixel next to something far brighter then sees it as the frame that measured
    the pixel saw it (clipped), as in the per-frame path, instead of the full merged contrast
    leaking into it through the filter's taps. Scaling the mosaic and the ceiling by ``k``
    scales the result by ``k``.

    ``pattern`` / ``colors``: rawpy's ``raw_pattern`` and ``color_desc``; ``black_level`` one
    value or one per colour index (rawpy's ``black_level_per_channel``), subtracted first.
    The result is held in ``[0, max_level]`` (``max_level`` None: only below at 0) and, for an
    integer ``dtype`` (``np.uint16``: the frame's levels), rounded to the nearest level.
    ``out`` is written when given (its dtype wins).
    """
    method = validate_method(method)
    cfa, chan, offset = _prepare(mosaic, pattern, colors, black_level)
    h, w = cfa.shape
    if out is None:
        out = np.empty((h, w, 3), dtype=dtype)
    elif out.shape != (h, w, 3):
        raise ParameterError("demosaic output has the wrong shape", expected=str((h, w, 3)),
                             found=str(out.shape))
    integer = np.issubdtype(out.dtype, np.integer)
    hi = float(np.iinfo(out.dtype).max) if integer else float(np.inf)
    if max_level is not None:
        hi = min(hi, float(max_level))
    cfa = np.ascontiguousarray(cfa)
    if ceiling is None:
        cap = np.full((1, 1), np.inf, np.float32)
    else:
        cap = np.ascontiguousarray(ceiling, dtype=np.float32)
        if cap.shape != (h, w):
            raise ParameterError("demosaic ceiling has the wrong shape", expected=str((h, w)),
                                 found=str(cap.shape))
    capped = ceiling is not None
    lo32, hi32 = np.float32(0.0), np.float32(hi)
    if method == "hamilton-adams":
        green = np.empty((h, w), np.float32)
        run_row_spans(h, workers, lambda r0, r1: _ha_green_rows(
            cfa, offset, chan, green, r0, r1, cap, capped))
        run_row_spans(h, workers, lambda r0, r1: _ha_colour_rows(
            cfa, offset, chan, green, lo32, hi32, integer, out, r0, r1, cap, capped))
        return out
    code = {"malvar2004": 0, "bilinear": 1, "malvar2004-clamped": 2}[method]
    run_row_spans(h, workers, lambda r0, r1: _malvar_rows(
        cfa, offset, chan, code, lo32, hi32, integer, out, r0, r1, cap, capped))
    return out


#: The paper's filters (figure 2), sums of 8, as (name, 5x5) for the NumPy reference.
_K_G_AT_RB = np.array([[0, 0, -1, 0, 0], [0, 0, 2, 0, 0], [-1, 2, 4, 2, -1], [0, 0, 2, 0, 0],
                       [0, 0, -1, 0, 0]], np.float64) / 8
_K_ROW = np.array([[0, 0, 0.5, 0, 0], [0, -1, 0, -1, 0], [-1, 4, 5, 4, -1], [0, -1, 0, -1, 0],
                   [0, 0, 0.5, 0, 0]], np.float64) / 8
_K_COL = _K_ROW.T
_K_DIAG = np.array([[0, 0, -1.5, 0, 0], [0, 2, 0, 2, 0], [-1.5, 0, 6, 0, -1.5], [0, 2, 0, 2, 0],
                    [0, 0, -1.5, 0, 0]], np.float64) / 8
_B_CROSS = np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]], np.float64) / 4
_B_DIAG = np.array([[1, 0, 1], [0, 0, 0], [1, 0, 1]], np.float64) / 4
_B_ROW = np.array([[0, 0, 0], [1, 0, 1], [0, 0, 0]], np.float64) / 2


def demosaic_reference(
    mosaic: np.ndarray,
    pattern: np.ndarray | Sequence[Sequence[int]],
    colors: str = "RGBG",
    *,
    method: str = "malvar2004",
    black_level: float | Sequence[float] = 0.0,
    ceiling: np.ndarray | None = None,
) -> np.ndarray:
    """:func:`demosaic` as whole-image filters (float64, no clipping): the tests' spec."""
    method = validate_method(method)
    cfa, chan, offset = _prepare(mosaic, pattern, colors, black_level)
    h, w = cfa.shape
    site = (np.arange(h)[:, None] % 2, np.arange(w)[None, :] % 2)
    x = cfa.astype(np.float64) - offset.astype(np.float64)[site]
    if method == "hamilton-adams":
        return _hamilton_adams_reference(x, chan, site, ceiling)
    if method.startswith("malvar2004"):
        k = {"cross": _K_G_AT_RB, "row": _K_ROW, "col": _K_COL, "diag": _K_DIAG}
    else:
        k = {"cross": _B_CROSS, "row": _B_ROW, "col": _B_ROW.T, "diag": _B_DIAG}
    padded = np.pad(x, 2, mode="reflect")  # mirrored without repeating the edge
    cap = np.inf if ceiling is None else np.asarray(ceiling, np.float64)

    def at(dy: int, dx: int) -> np.ndarray:
        return np.minimum(padded[2 + dy:2 + dy + h, 2 + dx:2 + dx + w], cap)

    def filt(kern: np.ndarray) -> np.ndarray:
        r = kern.shape[0] // 2  # symmetric kernels: correlation = convolution
        return sum(kern[dy + r, dx + r] * at(dy, dx) for dy in range(-r, r + 1)
                   for dx in range(-r, r + 1) if kern[dy + r, dx + r] != 0)

    f = {name: filt(kern) for name, kern in k.items()}
    x = at(0, 0)
    if method == "malvar2004-clamped":

        sets = {"row": (at(0, -1), at(0, 1)), "col": (at(-1, 0), at(1, 0)),
                "cross": (at(-1, 0), at(1, 0), at(0, -1), at(0, 1)),
                "diag": (at(-1, -1), at(-1, 1), at(1, -1), at(1, 1))}
        f = {name: np.clip(v, np.minimum.reduce(sets[name]), np.maximum.reduce(sets[name]))
             for name, v in f.items()}
    out = np.zeros((h, w, 3))
    c = chan[site]
    c_h = chan[site[0], (site[1] + 1) % 2]  # the colour of a site's row neighbours
    for ch in range(3):
        out[..., ch] = np.where(
            c == ch, x,
            np.where(c == 1, np.where(c_h == ch, f["row"], f["col"]),
                     f["cross"] if ch == 1 else f["diag"]))
    return out


def _hamilton_adams_reference(x: np.ndarray, chan: np.ndarray, site, ceiling) -> np.ndarray:
    """Hamilton-Adams as whole-image shifts (float64), the ceiling held per output pixel."""
    h, w = x.shape
    cap = np.inf if ceiling is None else np.asarray(ceiling, np.float64)
    px = np.pad(x, 2, mode="reflect")

    def at(dy: int, dx: int, src: np.ndarray = px) -> np.ndarray:
        return np.minimum(src[2 + dy:2 + dy + h, 2 + dx:2 + dx + w], cap)

    c = chan[site]
    c_h = chan[site[0], (site[1] + 1) % 2]
    cen = at(0, 0)
    lap_h = 2 * cen - at(0, -2) - at(0, 2)
    lap_v = 2 * cen - at(-2, 0) - at(2, 0)
    grad_h = np.abs(at(0, 1) - at(0, -1)) + np.abs(lap_h)
    grad_v = np.abs(at(1, 0) - at(-1, 0)) + np.abs(lap_v)
    g_h = (at(0, 1) + at(0, -1)) / 2 + lap_h / 4
    g_v = (at(1, 0) + at(-1, 0)) / 2 + lap_v / 4
    green = np.where(grad_h < grad_v, g_h, np.where(grad_v < grad_h, g_v, (g_h + g_v) / 2))
    green = np.where(c == 1, cen, green)
    # The green plane is read back uncapped in the compiled kernel's second pass except by
    # the centre's cap: the same here.
    pg = np.pad(green, 2, mode="reflect")

    def diff(dy: int, dx: int) -> np.ndarray:
        return at(dy, dx) - at(dy, dx, pg)

    d_h = (diff(0, -1) + diff(0, 1)) / 2
    d_v = (diff(-1, 0) + diff(1, 0)) / 2
    d_diag = (diff(-1, -1) + diff(-1, 1) + diff(1, -1) + diff(1, 1)) / 4
    out = np.zeros((h, w, 3))
    out[..., 1] = green
    for ch in (0, 2):
        at_g = np.where(c_h == ch, d_h, d_v)
        out[..., ch] = np.where(c == ch, cen, green + np.where(c == 1, at_g, d_diag))
    return out
