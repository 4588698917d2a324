"""Where the frames of a bracket disagree: a consistency test on blocks, in coherent regions.

The merge's per-pixel test (:mod:`hdrcore.merge.maps`: the frames' weighted spread against
their predicted noise plus a 10 % model error) fires on static non-linear brackets: JPEG
quantisation and ringing, demosaicing, sub-pixel misregistration of resampled frames and the
response's own error (a camera's tone curve is not one global ``g``; film has a toe and a
shoulder and each scan its own film base; phones tone-map locally) make frames disagree by
10-50 % at single pixels (5 % of the memorial scans flagged, 14 % of a hand-held phone bracket).
:func:`consistency_regions` asks the question where those effects are modelled or average out:

1. Chains. Each output pixel reads every frame (a resampled frame at its nearest source
   pixel). A channel above the noise floor, below its saturation level and, for non-linear
   frames, outside ``edge_margin`` of the ends of the level range is *recorded*, and compared
   with the previous frame in exposure order that recorded the same channel of the pixel:
   ``r = ln(E_b / E_a)``, ``E = g(M) / dt``. In a static scene that is the next frame (a frame
   that clipped or sank below the floor has no recorded neighbour beyond it), unless a mask or
   a frame's border steps over one; a comparison that steps over a frame is no sample of the
   pair's transfer and is tested as it is.
2. The brightness transfer error. On a regular subsample of the pixels, the median of ``r`` of
   consecutive frames per pair, channel and level of the darker frame (a joint histogram, as
   the brightness transfer functions of Grossberg & Nayar) is the pair's systematic error: the
   response's error at those levels and the exposure ratio's. Each level bin takes the median
   of the measured bins within two of it (an object filling one or two bins is not taken for
   the response's error), at most ``max_bias`` (a factor 2: a larger systematic difference is
   the scene, not the curve); a pair measured nowhere takes its nearest neighbour's.
3. Blocks. Per ``block x block`` output block, pair and channel, the corrected residuals
   ``r - bias(level)`` are averaged with inverse-variance weights ``1 / (var_a + var_b)`` (the
   relative variances of the noise model: noise and quantisation through the inverse response's
   slope, :class:`~hdrcore.merge.weights.NoiseModel`) over the pixels both frames recorded (at
   least ``min_shared`` of the block). The mean's variance is ``4 / sum(w)`` (JPEG and
   demosaicing correlate neighbouring pixels: about a quarter of them are independent) plus the
   block's mean of ``(g'(M) level_error / g(M))**2``, an offset of the levels (black level, film
   base, JPEG's DC step) that is the same over the block and does not average away.
4. The test. ``z = |mean| / sqrt(scale**2 + var + (delta / block * contrast)**2 +
   floor**2)``: ``scale`` the pair's robust spread of block means (1.4826 MAD: what the noise
   model does not predict, JPEG, local tone mapping), ``contrast`` the smaller of the two frames'
   largest ln step to a neighbouring block (an edge present in both frames moves a block's mean
   by ``delta / block`` of its step when they are misregistered by ``delta`` pixels: 0.25 px for
   frames used as they are, 1 px when one is resampled). A block disagrees when ``z > z`` and
   ``|mean| > min_change`` (ln units) in some channel of some pair.
5. Regions. Connected groups (8-neighbours) of at least ``min_blocks`` disagreeing blocks are
   ghost regions: one odd block is JPEG, a scan defect or a glint, not an object. At pixel
   resolution a ghost is a pixel of a region whose per-pixel score is at least ``core_score``
   (1: the frames' spread there reaches their predicted noise) or 0 (one frame alone made it:
   the merge had nothing to compare), or a pixel within
   ``pixel_grow`` blocks of one that the per-pixel test flagged, with the holes this leaves
   inside an object filled.

The defaults are calibrated on the brackets of ``../shared/data`` (nothing in them moves) and
on moving objects pasted into the tripod ones, re-exposed through each frame
(``bench/bench_ghost.py``).

References
----------
.. [1] M. Granados, K. I. Kim, J. Tompkin, C. Theobalt, "Automatic noise modeling for ghost-free
   HDR reconstruction", ACM TOG 32(6), 2013 (consistency of exposures against their predicted
   noise). doi:10.1145/2508363.2508410
.. [2] O. Gallo, N. Gelfand, W.-C. Chen, M. Tico, K. Pulli, "Artifact-free high dynamic range
   imaging", ICCP 2009 (the test on patches, against the brightness transfer of the pair).
   doi:10.1109/ICCPHOT.2009.5559003
.. [3] M. D. Grossberg, S. K. Nayar, "Determining the camera response from images: what is
   knowable?", IEEE TPAMI 25(11), 2003 (brightness transfer functions from joint histograms).
   doi:10.1109/TPAMI.2003.1240119
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .._numba import AVAILABLE
from .._numba import njit as _njit
from .._threads import thread_map, worker_count
from ..errors import ParameterError
from .weights import NoiseModel

__all__ = [
    "GhostTestParams",
    "GhostRegions",
    "PairConsistency",
    "PairResiduals",
    "pair_residuals",
    "consistency_regions",
]


@dataclass(frozen=True)
class GhostTestParams:
    """Parameters of :func:`consistency_regions` (defaults calibrated by
    ``bench/bench_ghost.py``, see the module docstring)."""

    block: int = 8
    """Block side in pixels (8: JPEG's block)."""
    pixel_step: int = 1
    """Every ``pixel_step``-th pixel of a block (in both directions) enters its sums; the
    variance ``4 / sum(w)`` (a quarter of a block's pixels independent) becomes ``(4 /
    pixel_step**2) / sum(w)`` and ``min_shared`` counts the sampled pixels. Must divide
    ``block``. 2 is 2.5x cheaper (24 MP: 2.3-2.8 -> 0.9-1.1 CPU s) and finds as much of a
    moving object (memorial, frobisher, x4 and x0.25: within 0.4 %), but flags more where
    nothing moved (memorial 1.86 -> 2.50 %, frobisher 0 -> 0.06 % away from an object): not
    the default."""
    z: float = 5.0
    """Normalised residual above which a block disagrees."""
    min_change: float = 0.2
    """Smallest disagreement that counts, in ln units (0.2: 22 %)."""
    min_blocks: int = 4
    """Smallest ghost region, in blocks (8-connected)."""
    min_shared: float = 0.5
    """Fraction of a block's pixels a pair must both have recorded for the block to count."""
    registration_error: float = 1.0
    """Misregistration (pixels) assumed between a resampled frame and the others."""
    direct_error: float = 0.25
    """Misregistration (pixels) assumed between frames used as they are (JPEG, demosaicing)."""
    edge_margin: float = 0.04
    """Non-linear frames: fraction of the level range at each end not compared (the hat weight
    there is below 0.08: the response is least known on its toe and shoulder)."""
    level_error: float = 0.01
    """Non-linear frames: an offset of the levels (black level, a scan's film base, JPEG's DC
    quantisation) as a fraction of the range, through the response's slope; it is the same over
    a block, so it is not averaged away (memorial scans: film bases 13-24 levels apart)."""
    max_bias: float = 0.7
    """Largest brightness transfer error (ln units, a factor 2) taken for a response error: a
    larger systematic difference is not a curve but the scene (an object filling a level bin
    that static pixels never reach)."""
    level_bins: int = 32
    """Level bins of the darker frame for the brightness transfer error."""
    sample_pixels: int = 250_000
    """Pixels sampled (a regular grid) to measure the brightness transfer error."""
    min_bin_samples: int = 64
    """Samples a level bin needs for its own median."""
    scale_floor: float = 0.01
    """Smallest spread (ln units): the response and the times are never better than 1 %."""
    pixel_grow: int = 2
    """Blocks around a region within which pixels flagged by the per-pixel test join it."""
    core_score: float = 1.0
    """A region's own pixels are ghosts where their per-pixel score (when given) is at least
    this (the spread of the frames there is at least their predicted noise and model error) or
    0 (one frame alone made the pixel)."""

    def __post_init__(self) -> None:
        for name in ("block", "min_blocks", "level_bins", "sample_pixels", "min_bin_samples"):
            if int(getattr(self, name)) < 1:
                raise ParameterError(
                    f"ghost test {name} must be >= 1", found=str(getattr(self, name))
                )
        if not 0.0 <= float(self.edge_margin) < 0.5:
            raise ParameterError(
                "ghost test edge_margin must be in [0, 0.5)", found=str(self.edge_margin)
            )
        if not 0.0 < float(self.min_shared) <= 1.0:
            raise ParameterError(
                "ghost test min_shared must be in (0, 1]", found=str(self.min_shared)
            )
        for name in (
            "z",
            "min_change",
            "registration_error",
            "direct_error",
            "scale_floor",
            "level_error",
            "max_bias",
        ):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v < 0:
                raise ParameterError(f"ghost test {name} must be finite and >= 0", found=str(v))
        if int(self.pixel_step) < 1 or int(self.block) % int(self.pixel_step):
            raise ParameterError(
                "ghost test pixel_step must be >= 1 and divide the block",
                found=f"pixel_step {self.pixel_step}, block {self.block}",
            )
        if int(self.pixel_grow) < 0:
            raise ParameterError("ghost test pixel_grow must be >= 0", found=str(self.pixel_grow))


_HIST_RANGE = 3.0  # ln ratios beyond e**3 fall in the end bins of the transfer histograms
_HIST_BINS = 240


# --------------------------------------------------------------------------------------------
# Per-level tables and the frames' samples


@dataclass(frozen=True, eq=False)
class _Tables:
    """Per channel and integer level: ``ln x``, the relative variance ``var(x) / x**2``, the
    level bin and whether the level is compared (``ok``: above the floor, inside the margins,
    below the saturation level); float frames compute them per sample."""

    integer: bool
    ln_x: np.ndarray
    rel_var: np.ndarray
    add_var: np.ndarray
    lbin: np.ndarray
    ok: np.ndarray
    sat: np.ndarray
    floor: float
    shot: float
    const_var: float
    bins: int

    def packed(self) -> np.ndarray:
        """``(C, L, 4)``: ``ln x``, ``rel_var``, ``add_var`` and the level bin side by side,
        the bin -1 where the level is not compared (the compiled kernel's one lookup)."""
        if not self.integer:
            return np.zeros((1, 1, 4))
        return np.ascontiguousarray(
            np.stack(
                [
                    self.ln_x,
                    self.rel_var,
                    self.add_var,
                    np.where(self.ok, self.lbin, -1).astype(np.float64),
                ],
                axis=-1,
            )
        )


def _tables(
    frames: Sequence[np.ndarray],
    c: int,
    lut: np.ndarray | None,
    max_level: int | None,
    noise: NoiseModel,
    saturation: Sequence[float],
    floor: float,
    margin: float,
    bins: int,
    level_error: float = 0.0,
) -> _Tables:
    integer = frames[0].dtype.kind == "u"
    sat = np.broadcast_to(np.asarray(saturation, np.float64).ravel(), (c,)).copy()
    const = noise.read_noise**2
    shot = float(noise.shot_gain)
    if not integer:
        z = np.zeros((1, 1))
        return _Tables(
            False,
            z,
            z,
            z,
            np.zeros((1, 1), np.int64),
            np.zeros((1, 1), bool),
            sat,
            float(floor),
            shot,
            float(max(const, 1e-12)),
            int(bins),
        )
    g = None
    if lut is not None:
        g = np.asarray(lut, np.float64)
        if g.ndim == 1:
            g = np.broadcast_to(g, (c, g.size))
        if max_level is None:
            max_level = g.shape[1] - 1
    elif max_level is None:
        max_level = int(np.iinfo(frames[0].dtype).max)
    top = max(int(f.max(initial=0)) for f in frames)
    levels = g.shape[1] if g is not None else int(max_level) + 1
    if top >= levels:
        if g is not None:
            raise ParameterError(
                "levels above max_level have no response LUT entry",
                expected=f"levels 0..{levels - 1}",
                found=str(top),
            )
        levels = top + 1
    lv = np.arange(levels, dtype=np.float64)
    inv_max = 1.0 / float(max_level)
    add = np.zeros((c, levels))
    if g is not None:
        x = g[:, :levels]
        slope = np.gradient(g, axis=1)[:, :levels]
        var = slope**2 * noise.level_variance() + shot * x + max(const, 1e-12)
        add = (slope * level_error * max_level) ** 2
    else:
        x = np.tile(lv * inv_max, (c, 1))
        var = shot * x + max(const + noise.level_variance() * inv_max**2, 1e-12)
    ok = (lv[None, :] < sat[:, None]) & (lv[None, :] > floor) & (x > 0)
    if g is not None and margin > 0:
        ok &= (lv >= margin * max_level) & (lv <= (1.0 - margin) * max_level)
    with np.errstate(divide="ignore", invalid="ignore"):
        ln_x = np.where(x > 0, np.log(np.where(x > 0, x, 1.0)), 0.0)
        rel = np.where(x > 0, var / np.where(x > 0, x, 1.0) ** 2, 0.0)
        add = np.where(x > 0, add / np.where(x > 0, x, 1.0) ** 2, 0.0)
    lbin = np.clip((lv * inv_max * bins).astype(np.int64), 0, bins - 1)
    return _Tables(
        True,
        np.ascontiguousarray(ln_x),
        np.ascontiguousarray(rel),
        np.ascontiguousarray(add),
        np.ascontiguousarray(np.tile(lbin, (c, 1))),
        np.ascontiguousarray(ok),
        sat,
        float(floor),
        shot,
        float(max(const, 1e-12)),
        int(bins),
    )


#: Most frames the compiled ghost test takes (more: the numpy reference).
MAX_KERNEL_FRAMES = 32


def _read_only(a: np.ndarray, dtype) -> np.ndarray:
    v = np.ascontiguousarray(a, dtype=dtype).view()
    v.flags.writeable = False
    return v


@_njit
def _chain_rows(
    n,
    fl,
    ml,
    integer,
    tab,
    sat,
    floor,
    shot,
    const_var,
    bins,
    has_t,
    ts,
    has_mask,
    ln_t,
    y0,
    gh,
    gw,
    stride,
    hist,
    bias,
    b,
    sums,
    count,
):  # pragma: no cover - compiled
    """Every frame (``fl[s]``, ``s < n``, rank ``s`` in exposure order, ``ml[s]`` its mask in
    output coordinates) over the output pixels ``(y0 + stride // 2 + i * stride, stride // 2 + j *
    stride)``, ``i < gh``, ``j < gw``: one output row at a time, the frames in exposure order
    along it, so each pixel's chain (per channel: the previous frame that recorded it, its
    ``ln E``, relative variances and level bin) lives in one row's state, in cache.

    Integer frames read ``tab[ch, level] = (ln x, var / x**2, additive var / x**2, level bin)``
    (the bin -1 where the level is not compared: one lookup a sample); float frames compute
    them. Each frame is read at the nearest source pixel (no data outside the frame or where
    masked); each channel compared (above the floor, below the saturation level, inside the
    margins) is compared with the previous frame that recorded that channel of the pixel.
    With a non-empty ``hist`` the comparison ``ln(E / E_prev)`` of consecutive frames goes to
    the transfer histogram of the earlier frame's slot, the channel and its level bin; else
    the residual, less the slot's transfer error when the frames are consecutive, goes to the
    slot's sums for the pixel's block, ``sums[by, bx, slot, ch] = (sum w r, sum w, sum
    additive, sum ln E_a, sum ln E_b)`` (one block's sums side by side) and ``count``. The
    sampling is written out here once, not in a helper: a helper's array arguments cost ten
    times the work per pixel. References: :func:`_transfer_hist_numpy`,
    :func:`_residuals_numpy`."""
    c = tab.shape[0] if integer else sat.shape[0]
    to_hist = hist.shape[0] > 0
    hb = hist.shape[3]
    hscale = hb / (2.0 * _HIST_RANGE)
    off = stride // 2
    prev = np.empty((gw, c), np.int64)
    st = np.zeros((gw, c, 4))  # the chain: ln E, rel var, additive rel var, level bin
    for gy in range(gh):
        y = y0 + off + gy * stride
        by = y // b
        prev[:, :] = -1
        for s in range(n):
            f = fl[s]
            mask = ml[s]
            hm = has_mask[s]
            ht = has_t[s]
            lt = ln_t[s]
            h = f.shape[0]
            w = f.shape[1]
            t00 = ts[s, 0, 0]
            t01 = ts[s, 0, 1]
            t02 = ts[s, 0, 2]
            t10 = ts[s, 1, 0]
            t11 = ts[s, 1, 1]
            t12 = ts[s, 1, 2]
            t20 = ts[s, 2, 0]
            t21 = ts[s, 2, 1]
            t22 = ts[s, 2, 2]
            for gx in range(gw):
                x = off + gx * stride
                if hm and not mask[y, x]:
                    continue
                sy = y
                sx = x
                if ht:
                    sw_ = t20 * x + t21 * y + t22
                    fx = (t00 * x + t01 * y + t02) / sw_
                    fy = (t10 * x + t11 * y + t12) / sw_
                    if not (fx > -0.5 and fx < w - 0.5 and fy > -0.5 and fy < h - 0.5):
                        continue
                    sx = int(np.floor(fx + 0.5))
                    sy = int(np.floor(fy + 0.5))
                bx = x // b
                for ch in range(c):
                    if integer:
                        i = np.int64(f[sy, sx, ch])
                        lbc = tab[ch, i, 3]
                        if lbc < 0.0:
                            continue
                        lnc = tab[ch, i, 0] - lt
                        rvc = tab[ch, i, 1]
                        adc = tab[ch, i, 2]
                    else:
                        xl = np.float64(f[sy, sx, ch])
                        if not (xl < sat[ch] and xl > floor and xl > 0.0):
                            continue
                        lnc = np.log(xl) - lt
                        rvc = (shot * xl + const_var) / (xl * xl)
                        adc = 0.0
                        lbc = np.float64(min(bins - 1, max(0, int(xl * bins))))
                    q = prev[gx, ch]
                    if q >= 0:
                        if to_hist:
                            # a frame stepped over is not the pair's transfer (in a static
                            # scene only a mask or a frame's border steps over one)
                            if q == s - 1:
                                j = int(np.floor((lnc - st[gx, ch, 0] + _HIST_RANGE) * hscale))
                                hist[q, ch, int(st[gx, ch, 3]), min(hb - 1, max(0, j))] += 1
                        else:
                            r = lnc - st[gx, ch, 0]
                            if q == s - 1:
                                r -= bias[q, ch, int(st[gx, ch, 3])]
                            wt = 1.0 / (st[gx, ch, 1] + rvc)
                            o = sums[by, bx, q, ch]
                            o[0] += wt * r
                            o[1] += wt
                            o[2] += st[gx, ch, 2] + adc
                            o[3] += st[gx, ch, 0]
                            o[4] += lnc
                            count[by, bx, q, ch] += 1
                    st[gx, ch, 0] = lnc
                    st[gx, ch, 1] = rvc
                    st[gx, ch, 2] = adc
                    st[gx, ch, 3] = lbc
                    prev[gx, ch] = s


# --------------------------------------------------------------------------------------------
# numpy references (the tests compare them with the kernels; the path without numba)


def _frame_samples(fs, k, ys, xs, t: _Tables, has_t, ts, ms, ln_t):
    """``(compared (.., C), ln E, rel_var, additive rel_var, level bin)`` of frame ``k`` at
    output pixels ``ys, xs``."""
    f = fs[k]
    h, w, c = f.shape
    ok = np.ones(ys.shape, bool)
    sy, sx = ys, xs
    if has_t[k]:
        m = ts[k]
        sw_ = m[2, 0] * xs + m[2, 1] * ys + m[2, 2]
        fx = (m[0, 0] * xs + m[0, 1] * ys + m[0, 2]) / sw_
        fy = (m[1, 0] * xs + m[1, 1] * ys + m[1, 2]) / sw_
        ok = (fx > -0.5) & (fx < w - 0.5) & (fy > -0.5) & (fy < h - 0.5)
        sx = np.clip(np.floor(fx + 0.5), 0, w - 1).astype(np.int64)
        sy = np.clip(np.floor(fy + 0.5), 0, h - 1).astype(np.int64)
    if ms[k] is not None:
        ok &= ms[k][ys, xs]
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


def _chains_numpy(fs, order, t: _Tables, has_t, ts, ms, ln_t, ys, xs):
    """Yield ``(slot, rank, selected (.., C), ln_a, rv_a, ad_a, lbin_a, ln_b, rv_b, ad_b)``
    for every frame (``rank`` in exposure order) and, per channel, the previous one that
    recorded the same pixel (``slot``: the kernels' chains)."""
    n = len(order)
    c = fs[0].shape[2]
    shape = ys.shape + (c,)
    prev = np.full(shape, -1)
    ln_p = np.zeros(shape)
    rv_p = np.zeros(shape)
    ad_p = np.zeros(shape)
    lb_p = np.zeros(shape, np.int64)
    for s in range(n):
        ok, ln, rv, ad, lbn = _frame_samples(fs, int(order[s]), ys, xs, t, has_t, ts, ms, ln_t)
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


def _transfer_hist_numpy(fs, order, t: _Tables, has_t, ts, ms, ln_t, stride, hist) -> None:
    h, w = fs[0].shape[:2]
    ys, xs = np.mgrid[stride // 2 : h : stride, stride // 2 : w : stride]
    hb = hist.shape[3]
    for q, s, sel, ln_a, _, _, lb_a, ln_b, _, _ in _chains_numpy(
        fs, order, t, has_t, ts, ms, ln_t, ys, xs
    ):
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


def _residuals_numpy(
    fs, order, t: _Tables, has_t, ts, ms, ln_t, bias, b, swr, sw, sa, la, lb, count, step: int = 1
) -> None:
    hb, wb = count.shape[2:]
    ys, xs = np.mgrid[step // 2 : hb * b : step, step // 2 : wb * b : step]
    bs = b // step

    def bsum(a: np.ndarray) -> np.ndarray:
        return np.moveaxis(a.reshape(hb, bs, wb, bs, a.shape[-1]).sum(axis=(1, 3)), -1, 0)

    for q, s, sel, ln_a, rv_a, ad_a, lb_a, ln_b, rv_b, ad_b in _chains_numpy(
        fs, order, t, has_t, ts, ms, ln_t, ys, xs
    ):
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


# --------------------------------------------------------------------------------------------
# The brightness transfer error of each pair


def _hist_median(h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Median (interpolated within its bin) and sample count of histograms over the last
    axis (bins spanning ``[-_HIST_RANGE, _HIST_RANGE]``)."""
    n = h.sum(axis=-1)
    cum = np.cumsum(h, axis=-1)
    half = 0.5 * n
    j = np.argmax(cum >= half[..., None], axis=-1)
    before = (
        np.take_along_axis(cum, j[..., None], axis=-1)[..., 0]
        - np.take_along_axis(h, j[..., None], axis=-1)[..., 0]
    )
    inside = np.take_along_axis(h, j[..., None], axis=-1)[..., 0]
    width = 2.0 * _HIST_RANGE / h.shape[-1]
    frac = np.where(inside > 0, (half - before) / np.maximum(inside, 1), 0.5)
    return -_HIST_RANGE + (j + frac) * width, n


def _transfer_bias(hist: np.ndarray, p: GhostTestParams) -> tuple[np.ndarray, list[str]]:
    """Per slot, channel and level bin: the pair's brightness transfer error (ln units), and
    per slot where it came from (``"measured"``, ``"borrowed ..."``, ``"none"``)."""
    med, cnt = _hist_median(hist.astype(np.float64))
    slots, c, nb = med.shape
    bias = np.zeros((slots, c, nb))
    source = ["none"] * slots
    measured = []
    for q in range(slots):
        for ch in range(c):
            own = np.flatnonzero(cnt[q, ch] >= p.min_bin_samples)
            if own.size == 0:
                continue
            # the transfer error changes slowly with the level: each bin takes the median of
            # the measured bins within two of it (at least the three nearest), so an object
            # filling one or two bins is not taken for the response's error; bins outside the
            # measured levels take the nearest measured value
            for i in range(nb):
                dist = np.abs(own - i)
                k = max(3, int(np.sum(dist <= 2)))
                bias[q, ch, i] = float(
                    np.median(med[q, ch, own[np.argsort(dist, kind="stable")[:k]]])
                )
        if np.any(cnt[q] >= p.min_bin_samples):
            source[q] = "measured"
            measured.append(q)
    np.clip(bias, -p.max_bias, p.max_bias, out=bias)
    for q in range(slots):
        if source[q] != "measured" and measured:
            near = min(measured, key=lambda j: (abs(j - q), j))
            bias[q] = bias[near]
            source[q] = f"borrowed from pair {near}"
    return bias, source


# --------------------------------------------------------------------------------------------
# Public: the sums and the test


@dataclass(frozen=True, eq=False)
class PairResiduals:
    """Per block and pair slot (slot ``s``: frame ``order[s]`` against the next frame in
    exposure order that recorded the same pixel), sums over the pixels both recorded.

    ``weighted`` and ``weights`` float64 ``(N - 1, C, hb, wb)``: ``sum(w r)`` and ``sum(w)`` of
    the corrected residuals ``r = ln(E_b / E_a) - bias`` with ``w = 1 / (var_a + var_b)``
    (relative variances); ``first``, ``second`` the sums of the two frames' ``ln E``;
    ``count`` int32 the pixels compared (all ``(N - 1, C, hb, wb)``: each channel is compared
    where both frames recorded it); ``bias`` ``(N - 1, C,
    level_bins)`` the brightness transfer error removed and ``bias_source`` where it came from;
    ``order`` the frames by exposure time.
    """

    weighted: np.ndarray
    weights: np.ndarray
    additive: np.ndarray
    first: np.ndarray
    second: np.ndarray
    count: np.ndarray
    bias: np.ndarray
    bias_source: tuple[str, ...]
    order: np.ndarray
    block: int
    samples: int


def pair_residuals(
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
    workers: int | None = None,
    engine: str | None = None,
) -> PairResiduals:
    """:class:`PairResiduals` of ``frames`` (steps 1-3 of the module docstring).

        ``frames``: integer levels (with ``lut``/``max_level``) or float linear values, one shape;
    X
        output grid) as :func:`hdrcore.merge.merge` takes them; ``saturation`` (per channel) and
        ``floor`` in the frames' units. ``engine``: ``"numba"`` (default when installed) or
        ``"numpy"`` (the reference).
    """
    p = params or GhostTestParams()
    fs = [np.asarray(f) for f in frames]
    fs = [f[..., None] if f.ndim == 2 else f for f in fs]
    n = len(fs)
    h, w, c = fs[0].shape
    b = int(p.block)
    hb, wb = h // b, w // b
    times = np.asarray(exposure_times, np.float64)
    order = np.argsort(times, kind="stable").astype(np.int64)
    ln_t = np.log(times)
    t = _tables(
        fs,
        c,
        lut,
        max_level,
        noise or NoiseModel(),
        saturation,
        floor,
        p.edge_margin,
        p.level_bins,
        p.level_error,
    )
    ts = np.zeros((n, 3, 3))  # homogeneous: affine motions and homographies alike
    has_t = np.zeros(n, bool)
    tf = list(transforms) if transforms is not None else [None] * n
    for k, m in enumerate(tf):
        ts[k] = np.eye(3)
        if m is not None:
            a = np.asarray(m, np.float64)
            ts[k][: a.shape[0]] = a
            ts[k] /= ts[k][2, 2]
        has_t[k] = m is not None and not np.allclose(ts[k], np.eye(3), atol=1e-12)
    ms = list(masks) if masks is not None else [None] * n
    ms = [None if m is None else np.ascontiguousarray(m, dtype=bool) for m in ms]
    has_mask = np.array([m is not None for m in ms])
    mask_t = tuple(np.ones((1, 1), bool) if m is None else m for m in ms)
    slots = max(n - 1, 0)
    stride = max(1, int(np.sqrt(h * w / float(p.sample_pixels))))
    hist = np.zeros((slots, c, p.level_bins, _HIST_BINS), np.int64)
    if engine is None:
        engine = "numba" if AVAILABLE else "numpy"
    fast = engine == "numba" and AVAILABLE
    no_hist = np.zeros((0, c, 1, 1), np.int64)
    no_bias = np.zeros((1, c, 1))
    if fast and n > MAX_KERNEL_FRAMES:
        fast = False  # the numpy reference takes any number of frames
    if fast and slots and hb and wb:
        # The kernel takes the frames (and masks) as tuples of MAX_KERNEL_FRAMES read-only
        # arrays, padded with placeholders: one compiled specialisation for every bracket
        # length (numba's typed lists compile their own methods in every new process: 10 s).
        dtype = np.result_type(*fs)
        fl = tuple(_read_only(fs[k], dtype) for k in order)  # rank s in exposure order
        ml = tuple(_read_only(mask_t[k], bool) for k in order)
        fl += (_read_only(np.zeros((1, 1, c), dtype), dtype),) * (MAX_KERNEL_FRAMES - n)
        ml += (_read_only(np.ones((1, 1), bool), bool),) * (MAX_KERNEL_FRAMES - n)
        per = (
            n,
            fl,
            ml,
            t.integer,
            t.packed(),
            t.sat,
            t.floor,
            t.shot,
            t.const_var,
            t.bins,
            np.ascontiguousarray(has_t[order]),
            np.ascontiguousarray(ts[order]),
            np.ascontiguousarray(has_mask[order]),
            np.ascontiguousarray(ln_t[order]),
        )
    if slots and hb and wb:
        if fast:
            gh, gw = len(range(stride // 2, h, stride)), len(range(stride // 2, w, stride))
            _chain_rows(
                *per,
                0,
                gh,
                gw,
                stride,
                hist,
                no_bias,
                b,
                np.zeros((1, 1, 1, c, 5)),
                np.zeros((1, 1, 1, c), np.int32),
            )
        else:
            _transfer_hist_numpy(fs, order, t, has_t, ts, ms, ln_t, stride, hist)
    bias, source = _transfer_bias(hist, p) if slots else (np.zeros((0, c, p.level_bins)), [])
    if fast:
        # one block's sums side by side in the kernel; the fields are views of them
        sums = np.zeros((hb, wb, slots, c, 5))
        counts = np.zeros((hb, wb, slots, c), np.int32)
        weighted, weights, additive, first, second = (
            np.moveaxis(sums[..., i], (0, 1), (2, 3)) for i in range(5)
        )
        count = np.moveaxis(counts, (0, 1), (2, 3))
    else:
        weighted = np.zeros((slots, c, hb, wb))
        weights = np.zeros_like(weighted)
        additive = np.zeros_like(weighted)
        first = np.zeros_like(weighted)
        second = np.zeros_like(weighted)
        count = np.zeros((slots, c, hb, wb), np.int32)
    if slots and hb and wb:
        if fast:
            # block rows per piece of work: a few per worker (load balance); each row's chains
            # live in the kernel's one-row state
            span = max(1, -(-hb // (8 * worker_count(workers))))

            step = int(p.pixel_step)

            def work(r0: int) -> None:
                r1 = min(hb, r0 + span)
                _chain_rows(
                    *per,
                    r0 * b,
                    (r1 - r0) * b // step,
                    wb * b // step,
                    step,
                    no_hist,
                    bias,
                    b,
                    sums,
                    counts,
                )

            thread_map(work, range(0, hb, span), workers)
        else:
            _residuals_numpy(
                fs,
                order,
                t,
                has_t,
                ts,
                ms,
                ln_t,
                bias,
                b,
                weighted,
                weights,
                additive,
                first,
                second,
                count,
                int(p.pixel_step),
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
        order=order,
        block=b,
        samples=int(hist.sum()),
    )


@dataclass(frozen=True, eq=False)
class PairConsistency:
    """One pair slot of the test: frame ``frames[0]`` against the next frame in exposure order
    (``frames[1]``, or a later one where that did not record the pixel).

    ``blocks`` the blocks compared, ``flagged`` those that disagreed; ``bias`` (ln, ``(C,
    level_bins)``) the brightness transfer error removed and ``bias_source`` where it came from;
    ``scale`` (ln, per channel) the robust spread of the blocks' mean residuals; ``delta`` the
    misregistration assumed (px).
    """

    frames: tuple[int, int]
    blocks: int
    flagged: int
    bias: np.ndarray
    bias_source: str
    scale: np.ndarray
    delta: float

    def to_json(self) -> dict:
        return {
            "frames": list(self.frames),
            "blocks": self.blocks,
            "flagged": self.flagged,
            "transfer_error": [float(v) for v in np.median(self.bias, axis=1)],
            "transfer_error_source": self.bias_source,
            "scale": [float(v) for v in self.scale],
            "misregistration_px": self.delta,
        }


@dataclass(frozen=True, eq=False)
class GhostRegions:
    """Result of :func:`consistency_regions`.

    ``blocks`` bool ``(hb, wb)``: blocks of the ghost regions (after the minimum area);
    ``z`` float32 ``(hb, wb)``: each block's largest normalised residual; ``tested`` bool
    ``(hb, wb)``: blocks some pair compared; ``ghost`` bool ``(H, W)``: the pixel map;
    ``pairs`` one :class:`PairConsistency` per pair slot compared.
    """

    blocks: np.ndarray
    z: np.ndarray
    tested: np.ndarray
    ghost: np.ndarray
    regions: int
    pairs: tuple[PairConsistency, ...]
    params: GhostTestParams
    candidate_fraction: float
    message: str = ""
    timings: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> dict:
        n = max(self.blocks.size, 1)
        return {
            "test": "regions",
            "block": self.params.block,
            "tested_fraction": float(np.count_nonzero(self.tested)) / n,
            "flagged_block_fraction": float(np.count_nonzero(self.blocks)) / n,
            "regions": self.regions,
            "pixel_candidate_fraction": self.candidate_fraction,
            "pairs": [q.to_json() for q in self.pairs],
            "message": self.message,
            "timings": dict(self.timings),
        }


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


def _pixel_map(
    blocks: np.ndarray,
    candidates: np.ndarray | None,
    shape: tuple[int, int],
    b: int,
    grow: int,
    score: np.ndarray | None = None,
    core_score: float = 0.0,
) -> np.ndarray:
    """Pixels of the ghost regions: each region's blocks (where ``score``, when given, is at
    least ``core_score``), and the pixels within ``grow`` blocks of it that the per-pixel test
    flagged (``candidates``), holes inside filled; region by region over their bounding
    boxes."""
    from scipy import ndimage

    h, w = shape
    out = np.zeros((h, w), bool)
    if not blocks.any():
        return out
    grown = (
        ndimage.binary_dilation(blocks, structure=np.ones((3, 3), bool), iterations=int(grow))
        if grow > 0
        else blocks
    )
    labels, _ = ndimage.label(grown, structure=np.ones((3, 3), bool))
    hb, wb = blocks.shape
    for i, sl in enumerate(ndimage.find_objects(labels), start=1):
        if sl is None:
            continue
        zone_b = labels[sl] == i
        core_b = blocks[sl] & zone_b
        y0, x0 = sl[0].start * b, sl[1].start * b
        # the last block row / column also covers the pixels the blocks leave over
        y1 = h if sl[0].stop == hb else sl[0].stop * b
        x1 = w if sl[1].stop == wb else sl[1].stop * b

        def up(m: np.ndarray, y0=y0, y1=y1, x0=x0, x1=x1) -> np.ndarray:
            full = np.repeat(np.repeat(m, b, axis=0), b, axis=1)
            return np.pad(
                full, ((0, y1 - y0 - full.shape[0]), (0, x1 - x0 - full.shape[1])), mode="edge"
            )

        zone = up(zone_b)
        if candidates is None:
            pix = up(core_b)
        else:
            pix = candidates[y0:y1, x0:x1] & zone
            core = up(core_b)
            if score is not None and core_score > 0:
                # a score of 0: one frame alone made the pixel, nothing for the per-pixel test
                # to compare; the block's verdict stands
                sc = score[y0:y1, x0:x1]
                core &= (sc >= core_score) | (sc == 0)
            pix |= core
            pix = ndimage.binary_fill_holes(pix) & zone
        out[y0:y1, x0:x1] |= pix
    return out


def _block_test_numpy(
    res: PairResiduals, q: int, use: np.ndarray, delta: float, p: GhostTestParams
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 4 for pair slot ``q``: ``(scale per channel, z (C, hb, wb), disagreeing blocks)``
    (the reference of :func:`_block_test`)."""
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


@_njit
def _block_test(
    weighted,
    weights,
    additive,
    first,
    second,
    count,
    need,
    scale,
    reg_scale,
    floor2,
    z_min,
    min_change,
    indep,
    z,
    hit,
):  # pragma: no cover - compiled
    """Step 4 of the module docstring for one pair slot, block by block (``z`` and ``hit``
    written; reference :func:`_block_test_numpy`, the same arithmetic in the same order)."""
    c, hb, wb = count.shape
    la = np.zeros((hb, wb))
    lb = np.zeros((hb, wb))
    for ch in range(c):
        for by in range(hb):
            for bx in range(wb):
                nn = max(count[ch, by, bx], 1)
                la[by, bx] = first[ch, by, bx] / nn
                lb[by, bx] = second[ch, by, bx] / nn
        s_ch = scale[ch] ** 2
        for by in range(hb):
            for bx in range(wb):
                if count[ch, by, bx] < need:
                    continue
                ca = 0.0
                cb = 0.0
                for dy in range(-1, 2):
                    ny = by + dy
                    if ny < 0 or ny >= hb:
                        continue
                    for dx in range(-1, 2):
                        nx = bx + dx
                        if (dy == 0 and dx == 0) or nx < 0 or nx >= wb:
                            continue
                        if count[ch, ny, nx] < need:
                            continue
                        ca = max(ca, abs(la[ny, nx] - la[by, bx]))
                        cb = max(cb, abs(lb[ny, nx] - lb[by, bx]))
                reg = reg_scale * min(ca, cb)
                sw = weights[ch, by, bx]
                mean = weighted[ch, by, bx] / sw
                nn = max(count[ch, by, bx], 1)
                s2 = s_ch + indep / sw + additive[ch, by, bx] / nn + reg**2 + floor2
                zz = abs(mean) / np.sqrt(s2)
                z[ch, by, bx] = zz
                if zz > z_min and abs(mean) > min_change:
                    hit[by, bx] = True


def consistency_regions(
    frames: Sequence[np.ndarray],
    exposure_times: Sequence[float],
    *,
    saturation: Sequence[float],
    floor: float,
    lut: np.ndarray | None = None,
    max_level: int | None = None,
    noise: NoiseModel | None = None,
    masks: Sequence[np.ndarray | None] | None = None,
    transforms: Sequence[np.ndarray | None] | None = None,
    candidates: np.ndarray | None = None,
    score: np.ndarray | None = None,
    params: GhostTestParams | None = None,
    workers: int | None = None,
    engine: str | None = None,
) -> GhostRegions:
    """Where the frames disagree beyond their noise, misregistration and the brightness
    transfer error of each pair, as spatially coherent regions (the module docstring).

    The inputs are the merge's (see :func:`pair_residuals`); ``candidates`` (bool ``(H, W)``,
    the merge's per-pixel test) and ``score`` (its per-pixel score) shape the regions at pixel
    resolution.
    """
    from scipy import ndimage

    t0 = time.perf_counter()
    p = params or GhostTestParams()
    n = len(frames)
    first = np.asarray(frames[0])
    h, w = first.shape[:2]
    b = int(p.block)
    hb, wb = h // b, w // b
    cand_frac = 0.0 if candidates is None else float(np.mean(candidates))
    if n < 2 or hb == 0 or wb == 0:
        return GhostRegions(
            blocks=np.zeros((hb, wb), bool),
            z=np.zeros((hb, wb), np.float32),
            tested=np.zeros((hb, wb), bool),
            ghost=np.zeros((h, w), bool),
            regions=0,
            pairs=(),
            params=p,
            candidate_fraction=cand_frac,
            message="no block to test",
        )
    tf = list(transforms) if transforms is not None else [None] * n
    resampled = [
        m is not None
        and not np.allclose(
            np.asarray(m, np.float64), np.eye(3)[: np.asarray(m).shape[0]], atol=1e-12
        )
        for m in tf
    ]
    res = pair_residuals(
        frames,
        exposure_times,
        saturation=saturation,
        floor=floor,
        lut=lut,
        max_level=max_level,
        noise=noise,
        transforms=tf,
        masks=masks,
        params=p,
        workers=workers,
        engine=engine,
    )
    t1 = time.perf_counter()
    need = max(1, int(np.ceil(p.min_shared * (b // p.pixel_step) ** 2)))
    indep = 4.0 / p.pixel_step**2  # 4 / sum(w) for every pixel of a block
    fast = (engine or ("numba" if AVAILABLE else "numpy")) == "numba" and AVAILABLE
    zmax = np.zeros((hb, wb), np.float32)
    flagged = np.zeros((hb, wb), bool)
    tested = np.zeros((hb, wb), bool)
    pairs = []
    for q in range(n - 1):
        a, k = int(res.order[q]), int(res.order[q + 1])
        use = res.count[q] >= need  # (C, hb, wb)
        if not use.any():
            continue
        tested |= use.any(axis=0)
        delta = p.registration_error if (resampled[a] or resampled[k]) else p.direct_error
        if fast:
            scale = np.array(
                [
                    1.4826 * float(np.median(np.abs(m - np.median(m)))) if m.size else 0.0
                    for m in (
                        res.weighted[q, ch][use[ch]] / res.weights[q, ch][use[ch]]
                        for ch in range(use.shape[0])
                    )
                ]
            )
            z = np.zeros(use.shape)
            hit = np.zeros((hb, wb), bool)
            _block_test(
                res.weighted[q],
                res.weights[q],
                res.additive[q],
                res.first[q],
                res.second[q],
                res.count[q],
                need,
                scale,
                delta / b,
                p.scale_floor**2,
                float(p.z),
                float(p.min_change),
                indep,
                z,
                hit,
            )
        else:
            scale, z, hit = _block_test_numpy(res, q, use, delta, p)
        np.maximum(zmax, z.max(axis=0), out=zmax)
        flagged |= hit
        pairs.append(
            PairConsistency(
                frames=(a, k),
                blocks=int(use.any(axis=0).sum()),
                flagged=int(hit.sum()),
                bias=res.bias[q],
                bias_source=res.bias_source[q],
                scale=scale,
                delta=float(delta),
            )
        )
    labels, count = ndimage.label(flagged, structure=np.ones((3, 3), bool))
    area = np.bincount(labels.ravel(), minlength=count + 1)
    keep = area >= int(p.min_blocks)
    keep[0] = False
    blocks = keep[labels]
    regions = int(np.count_nonzero(keep))
    t2 = time.perf_counter()
    ghost = _pixel_map(blocks, candidates, (h, w), b, p.pixel_grow, score, p.core_score)
    t3 = time.perf_counter()
    nt = max(int(tested.sum()), 1)
    msg = (
        f"{regions} ghost region(s): {100.0 * blocks.sum() / nt:.2f} % of the {nt} blocks "
        f"compared; {100.0 * flagged.sum() / nt:.2f} % disagreed before the "
        f"{p.min_blocks}-block minimum"
    )
    return GhostRegions(
        blocks=blocks,
        z=zmax,
        tested=tested,
        ghost=ghost,
        regions=regions,
        pairs=tuple(pairs),
        params=p,
        candidate_fraction=cand_frac,
        message=msg,
        timings={"sums": t1 - t0, "test": t2 - t1, "pixels": t3 - t2, "total": t3 - t0},
    )
