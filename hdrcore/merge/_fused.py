"""The fused merge kernel: one pass over the pixels, every frame and channel in registers.

Same arithmetic as the numpy reference (:class:`hdrcore.merge.merge._Kernel`), in the same float32
order, so both give the same radiance, shares, weight sums and maps (bit for bit for integer
frames; within float32 rounding of ``exp`` for the Gaussian weight of float frames).

Integer frames use per-level tables built *by the reference itself* (its linearisation and weight
function applied to every level ``0..L-1`` of every frame and channel): for each level the table
holds ``E_k = g(M) / dt``, ``w`` (noise floor applied), ``w var(E_k)``, ``w E_k`` and
``w E_k**2``, so the kernel does five loads and five adds per sample. Float frames (already
linear) compute the same terms inline.

The kernel is compiled by numba with ``nogil=True`` and runs over row blocks on the caller's
thread pool rather than numba's own ``prange``: numba's default (workqueue) threading layer
aborts the process when two Python threads launch parallel kernels at once, and the inspector
merges on a background thread; a ``nogil`` kernel has no such restriction and keeps the
``workers`` parameter meaning what it says. ``cache=True`` stores the machine code next to this
file (``__pycache__``), so only the first call on a machine pays the compilation; see
:func:`warm_up`.
"""

from __future__ import annotations

import logging
import time

import numpy as np

logger = logging.getLogger(__name__)

try:  # numba is a dependency; the numpy reference keeps working without it
    import numba

    _njit = numba.njit(nogil=True, cache=True, fastmath=False, error_model="numpy")
    AVAILABLE = True
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None
    AVAILABLE = False

    def _njit(fn):
        return fn


WEIGHT_CODES = {"hat": 0, "gaussian": 1, "noise-aware": 2, "uniform": 3}
"""Weighting names of :data:`hdrcore.merge.weights.WEIGHTS` -> the kernel's inline code."""

_F16_MAX = np.float32(65504.0)
_TINY = np.float32(1e-30)
_ONE_F16 = np.uint16(0x3C00)  # 1.0 as float16 bits


@_njit
def _f16_bits(v, fbuf, ibuf):
    """float16 bits of a non-negative float32, as :func:`maps.to_float16_nonnegative`."""
    if v > _F16_MAX:
        v = _F16_MAX
    fbuf[0] = v
    s = (ibuf[0] + np.int32(0x1000)) >> np.int32(13)
    s -= np.int32(112 << 10)
    if s < 0:
        s = np.int32(0)
    return np.uint16(s)


@_njit
def _finish_pixel(
    y, x, n, c, order, den, num, s2, sv, share, dark, bad, clip, nbad,
    me2, thr, rad, wsum_out, shares, clipped_out, under_out, gscore, ghost, fbuf, ibuf,
):
    """Radiance, ghost score, shares and fallbacks of one pixel (reference ``_finish``).

    Returns ``(mode, frame)``: mode 0 nothing more to do; 1 every channel takes ``frame``'s
    linear value over its time (float64, then float32); 2 the channels with no weight do.
    """
    spread = np.float32(0.0)
    noise = np.float32(0.0)
    wsum = np.float32(0.0)
    anyzero = False
    for ch in range(c):
        d = den[ch]
        inv = d if d >= _TINY else _TINY
        inv = np.float32(1.0) / inv
        a = num[ch] * inv
        rad[y, x, ch] = a
        b = s2[ch] * inv
        a2 = a * a
        b = b - a2
        if b < np.float32(0.0):
            b = np.float32(0.0)
        spread = b if ch == 0 else spread + b
        a2 = a2 * me2
        b = sv[ch] * inv
        b = b + a2
        noise = b if ch == 0 else noise + b
        wsum = d if ch == 0 else wsum + d
        if d <= np.float32(0.0):
            anyzero = True
    if noise < _TINY:
        noise = _TINY
    spread = spread / noise
    ghost[y, x] = spread > thr
    gscore[y, x] = _f16_bits(spread, fbuf, ibuf)
    wsum_out[y, x] = wsum
    invw = wsum if wsum >= _TINY else _TINY
    invw = np.float32(1.0) / invw
    for k in range(n):
        shares[k, y, x] = _f16_bits(share[k] * invw, fbuf, ibuf)
    is_clipped = nbad == n
    under = False
    mode = 0
    pick = 0
    if anyzero:
        if is_clipped:
            dk = order[0]
            if not (bad[dk] and not clip[dk]):
                for ch in range(c):
                    rad[y, x, ch] = dark[ch]
                pick = dk
            else:
                pick = -1
                for j in range(n):
                    k = order[j]
                    if not (bad[k] and not clip[k]):
                        pick = k
                        break
                if pick < 0:  # no valid frame at all: unknown, not clipped
                    pick = dk
                    is_clipped = False
                mode = 1
            for k in range(n):
                shares[k, y, x] = np.uint16(0)
            shares[pick, y, x] = _ONE_F16
        elif nbad < n:
            last = 0
            for j in range(n):
                if not bad[order[j]]:
                    last = j
            pick = order[last]
            mode = 2
            whole = True
            for ch in range(c):
                if den[ch] > np.float32(0.0):
                    whole = False
            if whole:
                for kk in range(n):
                    shares[kk, y, x] = np.uint16(0)
                shares[pick, y, x] = _ONE_F16
            under = True
    clipped_out[y, x] = is_clipped
    under_out[y, x] = under
    return mode, pick


@_njit
def merge_rows_integer(
    frames, masks, has_mask, order, times, tab, lut, has_lut, max_level, sat, me2, thr, r0, r1,
    rad, wsum_out, shares, clip_count, clipped_out, under_out, gscore, ghost,
):
    """Rows ``r0:r1`` of integer frames through the per-level tables ``tab (N, C, L, 5)``.

    Returns the number of samples whose level has no table entry (only possible with a LUT,
    levels above ``max_level``); such samples are clamped to the last entry.
    """
    n = len(frames)
    c = frames[0].shape[2]
    w = frames[0].shape[1]
    lmax = tab.shape[2] - 1
    den = np.empty(c, np.float32)
    num = np.empty(c, np.float32)
    s2 = np.empty(c, np.float32)
    sv = np.empty(c, np.float32)
    dark = np.empty(c, np.float32)
    share = np.empty(n, np.float32)
    bad = np.empty(n, np.bool_)
    clip = np.empty(n, np.bool_)
    fbuf = np.empty(1, np.float32)
    ibuf = fbuf.view(np.int32)
    out_of_range = 0

    for y in range(r0, r1):
        for x in range(w):
            den[:] = 0.0
            num[:] = 0.0
            s2[:] = 0.0
            sv[:] = 0.0
            nbad = 0
            ncl = 0
            for j in range(n):
                k = order[j]
                f = frames[k]
                cl = False
                for ch in range(c):
                    if np.float64(f[y, x, ch]) >= sat[ch]:
                        cl = True
                if has_mask[k]:
                    valid = masks[k][y, x]
                    cl = cl and valid
                    b = (not valid) or cl
                else:
                    b = cl
                clip[k] = cl
                bad[k] = b
                if cl:
                    ncl += 1
                if b:
                    nbad += 1
                sh = np.float32(0.0)
                for ch in range(c):
                    v = int(f[y, x, ch])
                    if v > lmax:
                        out_of_range += 1
                        v = lmax
                    if j == 0:
                        dark[ch] = tab[k, ch, v, 0]
                    if not b:
                        wk = tab[k, ch, v, 1]
                        den[ch] += wk
                        sh = wk if ch == 0 else sh + wk
                        sv[ch] += tab[k, ch, v, 2]
                        num[ch] += tab[k, ch, v, 3]
                        s2[ch] += tab[k, ch, v, 4]
                share[k] = sh
            clip_count[y, x] = ncl
            mode, pick = _finish_pixel(
                y, x, n, c, order, den, num, s2, sv, share, dark, bad, clip, nbad,
                me2, thr, rad, wsum_out, shares, clipped_out, under_out, gscore, ghost, fbuf,
                ibuf,
            )
            if mode != 0:
                fp = frames[pick]
                for ch in range(c):
                    if mode == 1 or den[ch] <= np.float32(0.0):
                        if has_lut:
                            vi = min(int(fp[y, x, ch]), lut.shape[1] - 1)
                            val = np.float64(lut[ch, vi])
                        else:
                            val = np.float64(fp[y, x, ch]) / max_level
                        rad[y, x, ch] = np.float32(val / times[pick])
    return out_of_range


@_njit
def merge_rows_float(
    frames, masks, has_mask, order, times, inv_t, inv_t2, t2, wcode, shot, const_var,
    floor_norm, sat, me2, thr, r0, r1,
    rad, wsum_out, shares, clip_count, clipped_out, under_out, gscore, ghost,
):
    """Rows ``r0:r1`` of float32 linear frames (the reference's float path, inline)."""
    n = len(frames)
    c = frames[0].shape[2]
    w = frames[0].shape[1]
    den = np.empty(c, np.float32)
    num = np.empty(c, np.float32)
    s2 = np.empty(c, np.float32)
    sv = np.empty(c, np.float32)
    dark = np.empty(c, np.float32)
    share = np.empty(n, np.float32)
    bad = np.empty(n, np.bool_)
    clip = np.empty(n, np.bool_)
    fbuf = np.empty(1, np.float32)
    ibuf = fbuf.view(np.int32)
    one = np.float32(1.0)
    two = np.float32(2.0)
    half = np.float32(0.5)
    m16 = np.float32(-16.0)
    zero = np.float32(0.0)

    for y in range(r0, r1):
        for x in range(w):
            den[:] = 0.0
            num[:] = 0.0
            s2[:] = 0.0
            sv[:] = 0.0
            nbad = 0
            ncl = 0
            for j in range(n):
                k = order[j]
                f = frames[k]
                cl = False
                for ch in range(c):
                    if np.float64(f[y, x, ch]) >= sat[ch]:
                        cl = True
                if has_mask[k]:
                    valid = masks[k][y, x]
                    cl = cl and valid
                    b = (not valid) or cl
                else:
                    b = cl
                clip[k] = cl
                bad[k] = b
                if cl:
                    ncl += 1
                if b:
                    nbad += 1
                ok = zero if b else one
                itk = inv_t[k]
                it2 = inv_t2[k]
                sh = zero
                for ch in range(c):
                    level = f[y, x, ch]
                    var = level * shot
                    var = var + const_var
                    e = level * itk
                    if j == 0:
                        dark[ch] = e
                    if wcode == 0:
                        wk = level * two
                        wk = wk - one
                        wk = abs(wk)
                        wk = one - wk
                    elif wcode == 1:
                        wk = level - half
                        wk = wk * wk
                        wk = wk * m16
                        wk = np.exp(wk)
                    elif wcode == 2:
                        wk = t2[k] / var
                    else:
                        wk = one
                    keep = ok if level > floor_norm else zero
                    wk = wk * keep
                    den[ch] += wk
                    sh = wk if ch == 0 else sh + wk
                    var = var * wk
                    var = var * it2
                    sv[ch] += var
                    wk = wk * e
                    num[ch] += wk
                    wk = wk * e
                    s2[ch] += wk
                share[k] = sh
            clip_count[y, x] = ncl
            mode, pick = _finish_pixel(
                y, x, n, c, order, den, num, s2, sv, share, dark, bad, clip, nbad,
                me2, thr, rad, wsum_out, shares, clipped_out, under_out, gscore, ghost, fbuf,
                ibuf,
            )
            if mode != 0:
                fp = frames[pick]
                for ch in range(c):
                    if mode == 1 or den[ch] <= np.float32(0.0):
                        rad[y, x, ch] = np.float32(np.float64(fp[y, x, ch]) / times[pick])


def warm_up() -> float:
    """Compile (or load from the on-disk cache) the kernels for 3 frames of uint16, uint8 and
    float32; returns the seconds it took. Call it on a background thread at start-up to keep
    the first merge fast; merging other frame counts compiles those on first use."""
    if not AVAILABLE:
        return 0.0
    from .merge import merge

    t0 = time.perf_counter()
    for dtype in (np.uint16, np.uint8):
        frames = [np.full((2, 3, 3), 10 * (k + 1), dtype) for k in range(3)]
        merge(frames, (1.0, 2.0, 4.0), max_level=255, engine="numba", workers=1)
        merge(
            frames, (1.0, 2.0, 4.0), response=np.linspace(0, 1, 256), engine="numba", workers=1
        )
    frames = [np.full((2, 3, 3), 0.1 * (k + 1), np.float32) for k in range(3)]
    merge(frames, (1.0, 2.0, 4.0), engine="numba", workers=1)
    mask = np.ones((2, 3), bool)
    merge(frames, (1.0, 2.0, 4.0), masks=[None, mask, mask], engine="numba", workers=1)
    return time.perf_counter() - t0
