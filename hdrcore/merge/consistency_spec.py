"""The ghost test's kernels written as plainly as numpy allows: the specification the tests
hold :mod:`hdrcore.merge.consistency` to.

Used by the tests only (the ghost test runs the compiled kernels, ``_chain_rows`` and
``_block_test`` in :mod:`hdrcore.merge.consistency`, for any number of frames). Whole images,
float64, one frame at a time: every frame of the bracket in exposure order, and for each pixel
and channel it recorded the previous frame that recorded the same channel of the pixel (the
chain, :func:`_chains`); steps 1-4 of :mod:`hdrcore.merge.consistency`'s docstring on those
pairs. It shares with the kernels what is no kernel: the input checks and per-level tables
(``_inputs``) and the transfer error from the histograms (``_transfer_bias``). The kernels add
in their own order, so a test compares sums with a tolerance (1e-9 relative); the decisions
(which blocks are compared and disagree) are the same (``tests/merge/_ghost_spec_check.py``
holds the kernels to it, a 40-frame bracket included).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .consistency import (
    _HIST_BINS,
    _HIST_RANGE,
    GhostTestParams,
    PairResiduals,
    _Inputs,
    _inputs,
    _transfer_bias,
)
from .weights import NoiseModel

__all__ = ["block_test_spec", "pair_residuals_spec"]


def _frame_samples(inp: _Inputs, k: int, ys: np.ndarray, xs: np.ndarray):
    """``(compared (.., C), ln E, rel_var, additive rel_var, level bin)`` of frame ``k`` at
    output pixels ``ys, xs``."""
    f, t, ln_t = inp.fs[k], inp.tables, inp.ln_t
    h, w, c = f.shape
    ok = np.ones(ys.shape, bool)
    sy, sx = ys, xs
    if inp.has_t[k]:
        m = inp.ts[k]
        sw_ = m[2, 0] * xs + m[2, 1] * ys + m[2, 2]
        fx = (m[0, 0] * xs + m[0, 1] * ys + m[0, 2]) / sw_
        fy = (m[1, 0] * xs + m[1, 1] * ys + m[1, 2]) / sw_
        ok = (fx > -0.5) & (fx < w - 0.5) & (fy > -0.5) & (fy < h - 0.5)
        sx = np.clip(np.floor(fx + 0.5), 0, w - 1).astype(np.int64)
        sy = np.clip(np.floor(fy + 0.5), 0, h - 1).astype(np.int64)
    mask = inp.masks[k]
    if mask is not None:
        ok &= mask[ys, xs]
    v = f[sy, sx]
    if t.integer:
        i = v.astype(np.int64)
        okc = np.stack([t.ok[ch][i[..., ch]] for ch in range(c)], -1)
        ln = np.stack([t.ln_x[ch][i[..., ch]] for ch in range(c)], -1) - ln_t[k]
        rv = np.stack([t.rel_var[ch][i[..., ch]] for ch in range(c)], -1)
        ad = np.stack([t.add_var[ch][i[..., ch]] for ch in range(c)], -1)
        lbn = np.stack([t.lbin[ch][i[..., ch]] for ch in range(c)], -1)
    else:
        xl = v.astype(np.float64)
        okc = (xl < t.sat) & (xl > t.floor) & (xl > 0)
        safe = np.where(xl > 0, xl, 1.0)
        ln = np.log(safe) - ln_t[k]
        rv = (t.shot * xl + t.const_var) / safe**2
        ad = np.zeros_like(rv)
        lbn = np.clip((xl * t.bins).astype(np.int64), 0, t.bins - 1)
    return okc & ok[..., None], ln, rv, ad, lbn


def _chains(inp: _Inputs, ys: np.ndarray, xs: np.ndarray):
    """Yield ``(slot, rank, selected (.., C), ln_a, rv_a, ad_a, lbin_a, ln_b, rv_b, ad_b)``
    for every frame (``rank`` in exposure order) and, per channel, the previous one that
    recorded the same pixel (``slot``: the kernels' chains)."""
    n = len(inp.order)
    c = inp.channels
    shape = ys.shape + (c,)
    prev = np.full(shape, -1)
    ln_p = np.zeros(shape)
    rv_p = np.zeros(shape)
    ad_p = np.zeros(shape)
    lb_p = np.zeros(shape, np.int64)
    for s in range(n):
        ok, ln, rv, ad, lbn = _frame_samples(inp, int(inp.order[s]), ys, xs)
        pair = ok & (prev >= 0)
        for q in range(n - 1):
            sel = pair & (prev == q)
            if sel.any():
                yield q, s, sel, ln_p, rv_p, ad_p, lb_p, ln, rv, ad
        prev = np.where(ok, s, prev)
        ln_p = np.where(ok, ln, ln_p)
        rv_p = np.where(ok, rv, rv_p)
        ad_p = np.where(ok, ad, ad_p)
        lb_p = np.where(ok, lbn, lb_p)


def _transfer_hist(inp: _Inputs, hist: np.ndarray) -> None:
    """Step 2's joint histograms (added to ``hist``, ``(N - 1, C, level_bins, bins)``) on the
    sample grid: ``ln(E_b / E_a)`` of consecutive frames per pair slot, channel and level bin
    of the darker frame."""
    stride = inp.stride
    h, w = inp.fs[0].shape[:2]
    ys, xs = np.mgrid[stride // 2 : h : stride, stride // 2 : w : stride]
    hb = hist.shape[3]
    for q, s, sel, ln_a, _, _, lb_a, ln_b, _, _ in _chains(inp, ys, xs):
        if q != s - 1:
            continue
        j = np.clip(
            np.floor((ln_b - ln_a + _HIST_RANGE) * (hb / (2.0 * _HIST_RANGE))).astype(np.int64),
            0,
            hb - 1,
        )
        for ch in range(ln_a.shape[-1]):
            m = sel[..., ch]
            np.add.at(hist[q, ch], (lb_a[..., ch][m], j[..., ch][m]), 1)


def _residuals(inp: _Inputs, bias, b, swr, sw, sa, la, lb, count, step: int = 1) -> None:
    """Step 3's sums per pair slot, channel and block (added to ``swr`` ... ``count``, ``(N - 1,
    C, hb, wb)``), every ``step``-th pixel of a block."""
    hb, wb = count.shape[2:]
    ys, xs = np.mgrid[step // 2 : hb * b : step, step // 2 : wb * b : step]
    bs = b // step

    def bsum(a: np.ndarray) -> np.ndarray:
        return np.moveaxis(a.reshape(hb, bs, wb, bs, a.shape[-1]).sum(axis=(1, 3)), -1, 0)

    for q, s, sel, ln_a, rv_a, ad_a, lb_a, ln_b, rv_b, ad_b in _chains(inp, ys, xs):
        c = ln_a.shape[-1]
        corr = np.stack([bias[q, ch][lb_a[..., ch]] for ch in range(c)], -1)
        if q != s - 1:
            corr = np.zeros_like(corr)  # a frame stepped over: no measured transfer
        with np.errstate(divide="ignore"):
            wt = np.where(sel, 1.0 / (rv_a + rv_b), 0.0)
        r = ln_b - ln_a - corr
        swr[q] += bsum(np.where(sel, wt * r, 0.0))
        sw[q] += bsum(wt)
        sa[q] += bsum(np.where(sel, ad_a + ad_b, 0.0))
        la[q] += bsum(np.where(sel, ln_a, 0.0))
        lb[q] += bsum(np.where(sel, ln_b, 0.0))
        count[q] += bsum(sel.astype(np.int64)).astype(np.int32)


def _log_contrast(log_mean: np.ndarray, use: np.ndarray) -> np.ndarray:
    """The largest |ln step| from each block to its 8 neighbours (neighbours not compared are
    left out)."""
    hb, wb = log_mean.shape
    out = np.zeros_like(log_mean)
    pad = np.pad(log_mean, 1, mode="edge")
    ok = np.pad(use, 1, mode="constant")
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy == 0 and dx == 0:
                continue
            nb = pad[1 + dy : 1 + dy + hb, 1 + dx : 1 + dx + wb]
            nok = ok[1 + dy : 1 + dy + hb, 1 + dx : 1 + dx + wb]
            np.maximum(out, np.where(nok, np.abs(nb - log_mean), 0.0), out=out)
    return out


def block_test_spec(
    res: PairResiduals, q: int, use: np.ndarray, delta: float, p: GhostTestParams
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 4 for pair slot ``q`` of ``res`` (the blocks ``use``, ``(C, hb, wb)``, compared;
    ``delta`` the misregistration assumed): ``(scale per channel, z (C, hb, wb), disagreeing
    blocks (hb, wb))``, what :func:`hdrcore.merge.consistency._block_test` computes."""
    b = res.block
    sw = np.where(use, res.weights[q], 1.0)
    mean = res.weighted[q] / sw
    # 4 / sum(w): about a quarter of a block's pixels are independent
    var = (4.0 / p.pixel_step**2) / sw
    scale = np.array(
        [
            1.4826 * float(np.median(np.abs(m[u] - np.median(m[u])))) if u.any() else 0.0
            for m, u in zip(mean, use, strict=True)
        ]
    )
    nn = np.maximum(res.count[q], 1)
    la = res.first[q] / nn  # each frame's geometric-mean radiance over the block (ln)
    lb = res.second[q] / nn
    reg = (
        delta
        / b
        * np.minimum(
            np.stack([_log_contrast(la[ch], use[ch]) for ch in range(len(la))]),
            np.stack([_log_contrast(lb[ch], use[ch]) for ch in range(len(lb))]),
        )
    )
    # an offset of the levels (black level, a scan's film base) is the same over a block:
    # its variance is the block's mean, not divided by the pixels
    add = res.additive[q] / nn
    s2 = scale[:, None, None] ** 2 + var + add + reg**2 + p.scale_floor**2
    z = np.abs(mean) / np.sqrt(s2)
    z *= use
    hit = ((z > p.z) & (np.abs(mean) > p.min_change)).any(axis=0)
    return scale, z, hit


def pair_residuals_spec(
    frames: Sequence[np.ndarray],
    exposure_times: Sequence[float],
    *,
    saturation: Sequence[float],
    floor: float,
    lut: np.ndarray | None = None,
    max_level: int | None = None,
    noise: NoiseModel | None = None,
    transforms: Sequence[np.ndarray | None] | None = None,
    masks: Sequence[np.ndarray | None] | None = None,
    params: GhostTestParams | None = None,
) -> PairResiduals:
    """:func:`hdrcore.merge.consistency.pair_residuals` (the same arguments) by the plain numpy
    steps above."""
    p = params or GhostTestParams()
    inp = _inputs(
        frames, exposure_times, saturation, floor, lut, max_level, noise, transforms, masks, p
    )
    n = len(inp.fs)
    h, w, c = inp.fs[0].shape
    b = int(p.block)
    hb, wb = h // b, w // b
    slots = max(n - 1, 0)
    hist = np.zeros((slots, c, p.level_bins, _HIST_BINS), np.int64)
    if slots and hb and wb:
        _transfer_hist(inp, hist)
    bias, source = _transfer_bias(hist, p) if slots else (np.zeros((0, c, p.level_bins)), [])
    weighted, weights, additive, first, second = (np.zeros((slots, c, hb, wb)) for _ in range(5))
    count = np.zeros((slots, c, hb, wb), np.int32)
    if slots and hb and wb:
        _residuals(
            inp, bias, b, weighted, weights, additive, first, second, count, int(p.pixel_step)
        )
    return PairResiduals(
        weighted=weighted,
        weights=weights,
        additive=additive,
        first=first,
        second=second,
        count=count,
        bias=bias,
        bias_source=tuple(source),
        order=inp.order,
        block=b,
        samples=int(hist.sum()),
    )
