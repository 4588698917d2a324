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
    "rcd": "Sanz Rodriguez's ratio corrected demosaicing (RCD 2.3): directions from "
    "high-pass statistics, green by low-pass ratios, red and blue by colour differences "
    "blended by inverse gradients; ratios and ratios of gradients, so scale-equivariant "
    "(up to its 1e-5 guards)",
}

_LETTERS = {"R": 0, "G": 1, "B": 2}


def validate_method(method: str) -> str:
    """``method`` if it is a key of :data:`DEMOSAIC_METHODS`, else a ParameterError naming them."""
    if method not in DEMOSAIC_METHODS:
        raise ParameterError(
            f"unknown demosaic method {method!r}",
            expected=", ".join(DEMOSAIC_METHODS),
            found=repr(method),
        )
    return method


def bayer_channels(pattern: np.ndarray | Sequence[Sequence[int]], colors: str) -> np.ndarray:
    """The 2x2 channel map (0 R, 1 G, 2 B) of a Bayer CFA from rawpy's ``raw_pattern`` and
    ``color_desc`` (``"RGBG"``: index 3 is the second green); a ParameterError for anything that
    is not a Bayer cell (one R, one B, two G on a diagonal)."""
    pat = np.asarray(pattern, dtype=np.int64)
    if pat.shape != (2, 2):
        raise ParameterError(
            "demosaic needs a 2x2 colour filter array", expected="(2, 2)", found=str(pat.shape)
        )
    try:
        ch = np.array([[_LETTERS[colors[int(i)]] for i in row] for row in pat], np.int64)
    except (KeyError, IndexError):
        raise ParameterError(
            "colour filter array site is not R, G or B",
            found=f"pattern {pat.tolist()}, colours {colors!r}",
        ) from None
    if not (ch[0, 0] == ch[1, 1] == 1 or ch[0, 1] == ch[1, 0] == 1) or sorted(
        ch.ravel().tolist()
    ) != [0, 1, 1, 2]:
        raise ParameterError(
            "demosaic needs a Bayer pattern (one R, one B, two G on a diagonal)",
            found=str(ch.tolist()),
        )
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
def _malvar_rows(
    cfa, offset, chan, method, lo, hi, rounding, out, r0, r1, ceiling, capped
):  # pragma: no cover
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
                far_v = min(np.float32(cfa[ym2, x]) - op, cap) + min(
                    np.float32(cfa[yp2, x]) - op, cap
                )
                far_h = min(np.float32(cfa[y, xm2]) - op, cap) + min(
                    np.float32(cfa[y, xp2]) - op, cap
                )
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
                        oo = min(
                            max(oo, min(min(d1, d2), min(d3, d4))), max(max(d1, d2), max(d3, d4))
                        )
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
            lap_h = (
                2 * cen
                - min(np.float32(cfa[y, xm2]) - op, cap)
                - min(np.float32(cfa[y, xp2]) - op, cap)
            )
            lap_v = (
                2 * cen
                - min(np.float32(cfa[ym2, x]) - op, cap)
                - min(np.float32(cfa[yp2, x]) - op, cap)
            )
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
def _ha_colour_rows(
    cfa, offset, chan, green, lo, hi, rounding, out, r0, r1, ceiling, capped
):  # pragma: no cover
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
                d_h = half * (
                    (min(np.float32(cfa[y, xm1]) - offset[p, j], cap) - min(green[y, xm1], cap))
                    + (min(np.float32(cfa[y, xp1]) - offset[p, j], cap) - min(green[y, xp1], cap))
                )
                d_v = half * (
                    (min(np.float32(cfa[ym1, x]) - offset[q, i], cap) - min(green[ym1, x], cap))
                    + (min(np.float32(cfa[yp1, x]) - offset[q, i], cap) - min(green[yp1, x], cap))
                )
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
                    + (min(np.float32(cfa[yp1, xp1]) - od, cap) - min(green[yp1, xp1], cap))
                )
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


# ---------------------------------------------------------------------------------------- RCD
#: RCD's guards against dividing by zero, in units of the white level (its own values).
_RCD_EPS = np.float32(1e-5)
_RCD_EPSSQ = np.float32(1e-10)


@njit
def _rcd_hpf(x, r, c, dr, dc):  # pragma: no cover - numba
    """RCD's high-pass filter along ``(dr, dc)`` at ``(r, c)``."""
    return (
        (
            x[r - 3 * dr, c - 3 * dc]
            - x[r - dr, c - dc]
            - x[r + dr, c + dc]
            + x[r + 3 * dr, c + 3 * dc]
        )
        - 3.0 * (x[r - 2 * dr, c - 2 * dc] + x[r + 2 * dr, c + 2 * dc])
        + 6.0 * x[r, c]
    )


@njit
def _rcd_directions(x, chan, vh, pq, lpf, r0, r1):  # pragma: no cover - numba
    """Pass 1 over rows ``r0..r1``: the V/H (every site) and P/Q (R and B sites) statistics
    ``V / (V + H)`` from RCD's high-pass filters summed in squares over three lines, and the
    low-pass filter at R and B sites."""
    h, w = x.shape
    eps2 = _RCD_EPSSQ
    for r in range(max(r0, 2), min(r1, h - 2)):
        for c in range(2, w - 2):
            if chan[r & 1, c & 1] != 1:  # held at 0: the ratios below stay within [0, 2]
                lpf[r, c] = max(
                    0.0,
                    x[r, c]
                    + 0.5 * (x[r - 1, c] + x[r + 1, c] + x[r, c - 1] + x[r, c + 1])
                    + 0.25
                    * (x[r - 1, c - 1] + x[r - 1, c + 1] + x[r + 1, c - 1] + x[r + 1, c + 1]),
                )
    for r in range(max(r0, 4), min(r1, h - 4)):
        for c in range(4, w - 4):
            v = 0.0
            hh = 0.0
            for k in (-1, 0, 1):
                a = _rcd_hpf(x, r + k, c, 1, 0)
                b = _rcd_hpf(x, r, c + k, 0, 1)
                v += a * a
                hh += b * b
            v = max(v, eps2)
            hh = max(hh, eps2)
            vh[r, c] = v / (v + hh)
            if chan[r & 1, c & 1] != 1:
                p = 0.0
                q = 0.0
                for k in (-1, 0, 1):
                    a = _rcd_hpf(x, r + k, c + k, 1, 1)
                    b = _rcd_hpf(x, r + k, c - k, 1, -1)
                    p += a * a
                    q += b * b
                p = max(p, eps2)
                q = max(q, eps2)
                pq[r, c] = p / (p + q)


@njit
def _rcd_refined(d, r, c):  # pragma: no cover - numba
    """RCD's refined discrimination: the diagonal neighbours' mean where it is more decided
    (further from 0.5) than the site's own value."""
    centre = d[r, c]
    near = 0.25 * (d[r - 1, c - 1] + d[r - 1, c + 1] + d[r + 1, c - 1] + d[r + 1, c + 1])
    return near if abs(0.5 - centre) < abs(0.5 - near) else centre


@njit
def _rcd_green(x, chan, vh, lpf, g, r0, r1):  # pragma: no cover - numba
    """Pass 2: green at R and B sites, the four cardinal neighbours each corrected by the ratio
    of the low-pass filter between the site and the next same-colour site, blended by inverse
    gradients and the refined V/H discrimination; green sites keep their sample."""
    h, w = x.shape
    eps = _RCD_EPS
    for r in range(max(r0, 4), min(r1, h - 4)):
        for c in range(4, w - 4):
            if chan[r & 1, c & 1] == 1:
                g[r, c] = x[r, c]
                continue
            gn = (
                eps
                + abs(x[r - 1, c] - x[r + 1, c])
                + abs(x[r, c] - x[r - 2, c])
                + abs(x[r - 1, c] - x[r - 3, c])
                + abs(x[r - 2, c] - x[r - 4, c])
            )
            gs = (
                eps
                + abs(x[r + 1, c] - x[r - 1, c])
                + abs(x[r, c] - x[r + 2, c])
                + abs(x[r + 1, c] - x[r + 3, c])
                + abs(x[r + 2, c] - x[r + 4, c])
            )
            gw = (
                eps
                + abs(x[r, c - 1] - x[r, c + 1])
                + abs(x[r, c] - x[r, c - 2])
                + abs(x[r, c - 1] - x[r, c - 3])
                + abs(x[r, c - 2] - x[r, c - 4])
            )
            ge = (
                eps
                + abs(x[r, c + 1] - x[r, c - 1])
                + abs(x[r, c] - x[r, c + 2])
                + abs(x[r, c + 1] - x[r, c + 3])
                + abs(x[r, c + 2] - x[r, c + 4])
            )
            l0 = lpf[r, c]
            en = x[r - 1, c] * 2.0 * l0 / (eps + l0 + lpf[r - 2, c])
            es = x[r + 1, c] * 2.0 * l0 / (eps + l0 + lpf[r + 2, c])
            ew = x[r, c - 1] * 2.0 * l0 / (eps + l0 + lpf[r, c - 2])
            ee = x[r, c + 1] * 2.0 * l0 / (eps + l0 + lpf[r, c + 2])
            v = (gs * en + gn * es) / (gn + gs)
            hz = (gw * ee + ge * ew) / (ge + gw)
            d = _rcd_refined(vh, r, c)
            g[r, c] = min(d * hz + (1.0 - d) * v, 1.0)


@njit
def _rcd_diagonal(x, chan, pq, g, rb, r0, r1):  # pragma: no cover - numba
    """Pass 3: at an R site blue, at a B site red, from the four diagonal colour differences,
    blended by inverse gradients and the refined P/Q discrimination; the sites' own colour
    copied into ``rb`` (plane 0 red, 1 blue)."""
    h, w = x.shape
    eps = _RCD_EPS
    for r in range(max(r0, 4), min(r1, h - 4)):
        for c in range(4, w - 4):
            s = chan[r & 1, c & 1]
            if s == 1:
                continue
            own = 0 if s == 0 else 1
            o = 1 - own
            rb[r, c, own] = x[r, c]
            # the other colour sits on the diagonals (samples of the mosaic)
            gnw = (
                eps
                + abs(x[r - 1, c - 1] - x[r + 1, c + 1])
                + abs(x[r - 1, c - 1] - x[r - 3, c - 3])
                + abs(g[r, c] - g[r - 2, c - 2])
            )
            gne = (
                eps
                + abs(x[r - 1, c + 1] - x[r + 1, c - 1])
                + abs(x[r - 1, c + 1] - x[r - 3, c + 3])
                + abs(g[r, c] - g[r - 2, c + 2])
            )
            gsw = (
                eps
                + abs(x[r + 1, c - 1] - x[r - 1, c + 1])
                + abs(x[r + 1, c - 1] - x[r + 3, c - 3])
                + abs(g[r, c] - g[r + 2, c - 2])
            )
            gse = (
                eps
                + abs(x[r + 1, c + 1] - x[r - 1, c - 1])
                + abs(x[r + 1, c + 1] - x[r + 3, c + 3])
                + abs(g[r, c] - g[r + 2, c + 2])
            )
            enw = x[r - 1, c - 1] - g[r - 1, c - 1]
            ene = x[r - 1, c + 1] - g[r - 1, c + 1]
            esw = x[r + 1, c - 1] - g[r + 1, c - 1]
            ese = x[r + 1, c + 1] - g[r + 1, c + 1]
            p = (gnw * ese + gse * enw) / (gnw + gse)
            q = (gne * esw + gsw * ene) / (gne + gsw)
            d = _rcd_refined(pq, r, c)
            rb[r, c, o] = min(g[r, c] + (1.0 - d) * p + d * q, 1.0)


@njit
def _rcd_cardinal(chan, vh, g, rb, r0, r1):  # pragma: no cover - numba
    """Pass 4: red and blue at G sites from the four cardinal colour differences (samples one
    way, pass 3's values the other), blended by inverse gradients and the refined V/H
    discrimination."""
    h, w = g.shape
    eps = _RCD_EPS
    for r in range(max(r0, 4), min(r1, h - 4)):
        for c in range(4, w - 4):
            if chan[r & 1, c & 1] != 1:
                continue
            d = _rcd_refined(vh, r, c)
            for k in range(2):
                gn = (
                    eps
                    + abs(g[r, c] - g[r - 2, c])
                    + abs(rb[r - 1, c, k] - rb[r + 1, c, k])
                    + abs(rb[r - 1, c, k] - rb[r - 3, c, k])
                )
                gs = (
                    eps
                    + abs(g[r, c] - g[r + 2, c])
                    + abs(rb[r + 1, c, k] - rb[r - 1, c, k])
                    + abs(rb[r + 1, c, k] - rb[r + 3, c, k])
                )
                gw = (
                    eps
                    + abs(g[r, c] - g[r, c - 2])
                    + abs(rb[r, c - 1, k] - rb[r, c + 1, k])
                    + abs(rb[r, c - 1, k] - rb[r, c - 3, k])
                )
                ge = (
                    eps
                    + abs(g[r, c] - g[r, c + 2])
                    + abs(rb[r, c + 1, k] - rb[r, c - 1, k])
                    + abs(rb[r, c + 1, k] - rb[r, c + 3, k])
                )
                en = rb[r - 1, c, k] - g[r - 1, c]
                es = rb[r + 1, c, k] - g[r + 1, c]
                ew = rb[r, c - 1, k] - g[r, c - 1]
                ee = rb[r, c + 1, k] - g[r, c + 1]
                v = (gn * es + gs * en) / (gn + gs)
                hz = (ge * ew + gw * ee) / (ge + gw)
                rb[r, c, k] = min(g[r, c] + (1.0 - d) * v + d * hz, 1.0)


@njit
def _rcd_store(g, rb, scale, lo, hi, rounding, out, r0, r1):  # pragma: no cover - numba
    """The interior (4 px from every border) into ``out``: scaled back to levels, held in
    ``[lo, hi]`` and rounded for an integer output; the border keeps what ``out`` holds."""
    h, w = g.shape
    for r in range(max(r0, 4), min(r1, h - 4)):
        for c in range(4, w - 4):
            for k, v in ((0, rb[r, c, 0]), (1, g[r, c]), (2, rb[r, c, 1])):
                v = min(max(v * scale, lo), hi)
                if rounding:
                    v = np.floor(v + 0.5)
                out[r, c, k] = v


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
        raise ParameterError(
            "demosaic output has the wrong shape", expected=str((h, w, 3)), found=str(out.shape)
        )
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
            raise ParameterError(
                "demosaic ceiling has the wrong shape", expected=str((h, w)), found=str(cap.shape)
            )
    capped = ceiling is not None
    lo32, hi32 = np.float32(0.0), np.float32(hi)
    if method == "hamilton-adams":
        green = np.empty((h, w), np.float32)
        run_row_spans(
            h, workers, lambda r0, r1: _ha_green_rows(cfa, offset, chan, green, r0, r1, cap, capped)
        )
        run_row_spans(
            h,
            workers,
            lambda r0, r1: _ha_colour_rows(
                cfa, offset, chan, green, lo32, hi32, integer, out, r0, r1, cap, capped
            ),
        )
        return out
    if method == "rcd":
        if capped:
            raise ParameterError(
                "the rcd demosaic takes no ceiling (an HDR mosaic)",
                expected="malvar2004 or hamilton-adams with a ceiling",
            )
        return _rcd(cfa, offset, chan, lo32, hi32, integer, out, workers)
    code = {"malvar2004": 0, "bilinear": 1, "malvar2004-clamped": 2}[method]
    run_row_spans(
        h,
        workers,
        lambda r0, r1: _malvar_rows(
            cfa, offset, chan, code, lo32, hi32, integer, out, r0, r1, cap, capped
        ),
    )
    return out


def _rcd(cfa, offset, chan, lo32, hi32, integer, out, workers):
    """RCD (see :data:`DEMOSAIC_METHODS`): Malvar-He-Cutler first (the 4-pixel border keeps it,
    and it is where the passes start), then RCD's four passes on the mosaic in units of its
    largest sample (RCD's unit, the white level, for a frame that clips; its guards then scale
    with the frame, so the result is exactly scale-equivariant; no interpolated value exceeds
    that sample), the interior written back."""
    h, w = cfa.shape
    no_cap = np.full((1, 1), np.inf, np.float32)
    run_row_spans(
        h,
        workers,
        lambda r0, r1: _malvar_rows(
            cfa, offset, chan, 0, lo32, hi32, integer, out, r0, r1, no_cap, False
        ),
    )
    if h < 9 or w < 9:
        return out
    site = offset[np.arange(h)[:, None] % 2, np.arange(w)[None, :] % 2]
    x = cfa.astype(np.float32) - site
    del site
    scale = max(float(x.max()), 1e-30)  # the frame's own: exactly scale-equivariant
    x *= np.float32(1.0 / scale)
    g = out[..., 1].astype(np.float32) * np.float32(1.0 / scale)
    rb = np.empty((h, w, 2), np.float32)
    rb[..., 0] = out[..., 0] * np.float32(1.0 / scale)
    rb[..., 1] = out[..., 2] * np.float32(1.0 / scale)
    vh = np.full((h, w), 0.5, np.float32)
    pq = np.full((h, w), 0.5, np.float32)
    lpf = np.zeros((h, w), np.float32)
    run_row_spans(h, workers, lambda r0, r1: _rcd_directions(x, chan, vh, pq, lpf, r0, r1))
    run_row_spans(h, workers, lambda r0, r1: _rcd_green(x, chan, vh, lpf, g, r0, r1))
    run_row_spans(h, workers, lambda r0, r1: _rcd_diagonal(x, chan, pq, g, rb, r0, r1))
    run_row_spans(h, workers, lambda r0, r1: _rcd_cardinal(chan, vh, g, rb, r0, r1))
    run_row_spans(
        h,
        workers,
        lambda r0, r1: _rcd_store(g, rb, np.float32(scale), lo32, hi32, integer, out, r0, r1),
    )
    return out


#: The paper's filters (figure 2), sums of 8, as (name, 5x5) for the NumPy reference.
_K_G_AT_RB = (
    np.array(
        [[0, 0, -1, 0, 0], [0, 0, 2, 0, 0], [-1, 2, 4, 2, -1], [0, 0, 2, 0, 0], [0, 0, -1, 0, 0]],
        np.float64,
    )
    / 8
)
_K_ROW = (
    np.array(
        [
            [0, 0, 0.5, 0, 0],
            [0, -1, 0, -1, 0],
            [-1, 4, 5, 4, -1],
            [0, -1, 0, -1, 0],
            [0, 0, 0.5, 0, 0],
        ],
        np.float64,
    )
    / 8
)
_K_COL = _K_ROW.T
_K_DIAG = (
    np.array(
        [
            [0, 0, -1.5, 0, 0],
            [0, 2, 0, 2, 0],
            [-1.5, 0, 6, 0, -1.5],
            [0, 2, 0, 2, 0],
            [0, 0, -1.5, 0, 0],
        ],
        np.float64,
    )
    / 8
)
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
    if method == "rcd":
        if ceiling is not None:
            raise ParameterError("the rcd demosaic takes no ceiling (an HDR mosaic)")
        base = demosaic_reference(
            mosaic, pattern, colors, method="malvar2004", black_level=black_level
        )
        return _rcd_reference(x, chan[site], np.maximum(base, 0.0))
    if method.startswith("malvar2004"):
        k = {"cross": _K_G_AT_RB, "row": _K_ROW, "col": _K_COL, "diag": _K_DIAG}
    else:
        k = {"cross": _B_CROSS, "row": _B_ROW, "col": _B_ROW.T, "diag": _B_DIAG}
    padded = np.pad(x, 2, mode="reflect")  # mirrored without repeating the edge
    cap = np.inf if ceiling is None else np.asarray(ceiling, np.float64)

    def at(dy: int, dx: int) -> np.ndarray:
        return np.minimum(padded[2 + dy : 2 + dy + h, 2 + dx : 2 + dx + w], cap)

    def filt(kern: np.ndarray) -> np.ndarray:
        r = kern.shape[0] // 2  # symmetric kernels: correlation = convolution
        return sum(
            kern[dy + r, dx + r] * at(dy, dx)
            for dy in range(-r, r + 1)
            for dx in range(-r, r + 1)
            if kern[dy + r, dx + r] != 0
        )

    f = {name: filt(kern) for name, kern in k.items()}
    x = at(0, 0)
    if method == "malvar2004-clamped":
        sets = {
            "row": (at(0, -1), at(0, 1)),
            "col": (at(-1, 0), at(1, 0)),
            "cross": (at(-1, 0), at(1, 0), at(0, -1), at(0, 1)),
            "diag": (at(-1, -1), at(-1, 1), at(1, -1), at(1, 1)),
        }
        f = {
            name: np.clip(v, np.minimum.reduce(sets[name]), np.maximum.reduce(sets[name]))
            for name, v in f.items()
        }
    out = np.zeros((h, w, 3))
    c = chan[site]
    c_h = chan[site[0], (site[1] + 1) % 2]  # the colour of a site's row neighbours
    for ch in range(3):
        out[..., ch] = np.where(
            c == ch,
            x,
            np.where(
                c == 1,
                np.where(c_h == ch, f["row"], f["col"]),
                f["cross"] if ch == 1 else f["diag"],
            ),
        )
    return out


def _hamilton_adams_reference(x: np.ndarray, chan: np.ndarray, site, ceiling) -> np.ndarray:
    """Hamilton-Adams as whole-image shifts (float64), the ceiling held per output pixel."""
    h, w = x.shape
    cap = np.inf if ceiling is None else np.asarray(ceiling, np.float64)
    px = np.pad(x, 2, mode="reflect")

    def at(dy: int, dx: int, src: np.ndarray = px) -> np.ndarray:
        return np.minimum(src[2 + dy : 2 + dy + h, 2 + dx : 2 + dx + w], cap)

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


def _rcd_reference(x: np.ndarray, c: np.ndarray, base: np.ndarray) -> np.ndarray:
    """RCD as whole-image array code (float64): ``x`` the black-subtracted mosaic, ``c`` each
    site's colour, ``base`` Malvar's result (held at 0 below), which the 4-pixel border keeps."""
    h, w = x.shape
    out = base.copy()
    if h < 9 or w < 9:
        return out
    scale = max(float(x.max()), 1e-30)
    x = x / scale
    eps, eps2 = 1e-5, 1e-10
    rb_site = c != 1

    def at(a: np.ndarray, dy: int, dx: int, m: int) -> np.ndarray:
        """``a`` at the offset (dy, dx) over the rows and columns [m, n - m)."""
        return a[m + dy : h - m + dy, m + dx : w - m + dx]

    def hpf(dy: int, dx: int) -> np.ndarray:  # over [3, n - 3), along (dy, dx)
        outer = (
            at(x, -3 * dy, -3 * dx, 3)
            - at(x, -dy, -dx, 3)
            - at(x, dy, dx, 3)
            + at(x, 3 * dy, 3 * dx, 3)
        )
        return (
            outer - 3 * (at(x, -2 * dy, -2 * dx, 3) + at(x, 2 * dy, 2 * dx, 3)) + 6 * at(x, 0, 0, 3)
        )

    def stat(f: np.ndarray, dy: int, dx: int) -> np.ndarray:  # over [4, n - 4)
        q = f * f
        k = h - 6, w - 6
        s3 = sum(
            q[1 + j * dy : k[0] - 1 + j * dy, 1 + j * dx : k[1] - 1 + j * dx] for j in (-1, 0, 1)
        )
        return np.maximum(s3, eps2)

    v, hz = stat(hpf(1, 0), 1, 0), stat(hpf(0, 1), 0, 1)
    p, q = stat(hpf(1, 1), 1, 1), stat(hpf(1, -1), 1, -1)
    vh = np.full((h, w), 0.5)
    pq = np.full((h, w), 0.5)
    inner = (slice(4, h - 4), slice(4, w - 4))
    vh[inner] = v / (v + hz)
    pq[inner] = np.where(rb_site[inner], p / (p + q), 0.5)
    lpf = np.zeros((h, w))
    lp = (
        at(x, 0, 0, 2)
        + 0.5 * (at(x, -1, 0, 2) + at(x, 1, 0, 2) + at(x, 0, -1, 2) + at(x, 0, 1, 2))
        + 0.25 * (at(x, -1, -1, 2) + at(x, -1, 1, 2) + at(x, 1, -1, 2) + at(x, 1, 1, 2))
    )
    lpf[2 : h - 2, 2 : w - 2] = np.where(rb_site[2 : h - 2, 2 : w - 2], np.maximum(lp, 0.0), 0.0)

    def refined(d: np.ndarray) -> np.ndarray:
        centre = at(d, 0, 0, 4)
        near = 0.25 * (at(d, -1, -1, 4) + at(d, -1, 1, 4) + at(d, 1, -1, 4) + at(d, 1, 1, 4))
        return np.where(np.abs(0.5 - centre) < np.abs(0.5 - near), near, centre)

    # green at R and B sites
    g = base[..., 1] / scale
    xs = {
        (dy, dx): at(x, dy, dx, 4)
        for dy in range(-4, 5)
        for dx in range(-4, 5)
        if dy == 0 or dx == 0
    }

    def card(dy: int, dx: int) -> np.ndarray:
        return (
            eps
            + np.abs(xs[dy, dx] - xs[-dy, -dx])
            + np.abs(xs[0, 0] - xs[2 * dy, 2 * dx])
            + np.abs(xs[dy, dx] - xs[3 * dy, 3 * dx])
            + np.abs(xs[2 * dy, 2 * dx] - xs[4 * dy, 4 * dx])
        )

    gn, gs, gw, ge = card(-1, 0), card(1, 0), card(0, -1), card(0, 1)
    l0 = at(lpf, 0, 0, 4)

    def est(dy: int, dx: int) -> np.ndarray:
        return xs[dy, dx] * 2.0 * l0 / (eps + l0 + at(lpf, 2 * dy, 2 * dx, 4))

    vv = (gs * est(-1, 0) + gn * est(1, 0)) / (gn + gs)
    hh = (gw * est(0, 1) + ge * est(0, -1)) / (ge + gw)
    d = refined(vh)
    green = np.minimum(d * hh + (1 - d) * vv, 1.0)
    g[inner] = np.where(rb_site[inner], green, at(x, 0, 0, 4))
    # the other of red and blue at R and B sites (diagonals)
    red, blue = base[..., 0] / scale, base[..., 2] / scale
    red[inner] = np.where(c[inner] == 0, at(x, 0, 0, 4), red[inner])
    blue[inner] = np.where(c[inner] == 2, at(x, 0, 0, 4), blue[inner])

    def diag(dy: int, dx: int) -> np.ndarray:
        return (
            eps
            + np.abs(at(x, dy, dx, 4) - at(x, -dy, -dx, 4))
            + np.abs(at(x, dy, dx, 4) - at(x, 3 * dy, 3 * dx, 4))
            + np.abs(at(g, 0, 0, 4) - at(g, 2 * dy, 2 * dx, 4))
        )

    gnw, gne, gsw, gse = diag(-1, -1), diag(-1, 1), diag(1, -1), diag(1, 1)

    def diff(dy: int, dx: int) -> np.ndarray:
        return at(x, dy, dx, 4) - at(g, dy, dx, 4)

    pe = (gnw * diff(1, 1) + gse * diff(-1, -1)) / (gnw + gse)
    qe = (gne * diff(1, -1) + gsw * diff(-1, 1)) / (gne + gsw)
    d = refined(pq)
    other = np.minimum(at(g, 0, 0, 4) + (1 - d) * pe + d * qe, 1.0)
    red[inner] = np.where(c[inner] == 2, other, red[inner])
    blue[inner] = np.where(c[inner] == 0, other, blue[inner])
    # red and blue at G sites (cardinals), from the planes just completed
    d = refined(vh)
    done = {}
    for name, a in (("r", red), ("b", blue)):

        def cg(dy: int, dx: int, a=a) -> np.ndarray:
            return (
                eps
                + np.abs(at(g, 0, 0, 4) - at(g, 2 * dy, 2 * dx, 4))
                + np.abs(at(a, dy, dx, 4) - at(a, -dy, -dx, 4))
                + np.abs(at(a, dy, dx, 4) - at(a, 3 * dy, 3 * dx, 4))
            )

        gn, gs, gw, ge = cg(-1, 0), cg(1, 0), cg(0, -1), cg(0, 1)

        def cd(dy: int, dx: int, a=a) -> np.ndarray:
            return at(a, dy, dx, 4) - at(g, dy, dx, 4)

        vv = (gn * cd(1, 0) + gs * cd(-1, 0)) / (gn + gs)
        hh = (ge * cd(0, -1) + gw * cd(0, 1)) / (ge + gw)
        done[name] = np.minimum(at(g, 0, 0, 4) + (1 - d) * vv + d * hh, 1.0)
    for k, name, a in ((0, "r", red), (2, "b", blue)):
        out[..., k][inner] = np.where(c[inner] == 1, done[name], a[inner]) * scale
    out[..., 1][inner] = g[inner] * scale
    return out
