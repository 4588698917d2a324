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
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .._numba import AVAILABLE
from .._numba import njit as _njit
from .._threads import thread_map, worker_count
from ..errors import ParameterError, validate_method
from .plan import levels_past_lut
from .weights import NoiseModel

__all__ = [
    "GhostTestParams",
    "GhostRegions",
    "PairConsistency",
    "PairResiduals",
    "pair_residuals",
    "consistency_regions",
    "block_sums_bytes",
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
    ``block``. 2 is about 2.5x cheaper (``bench/bench_ghost.py``) and finds as much of a
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
            raise levels_past_lut(levels - 1, str(top))
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


#: Frames per call of the compiled chains (its tuple slots); a longer bracket goes through in
#: groups of this many frames, the chains carried from one group to the next.
MAX_KERNEL_FRAMES = 32


def _read_only(a: np.ndarray, dtype) -> np.ndarray:
    v = np.ascontiguousarray(a, dtype=dtype).view()
    v.flags.writeable = False
    return v


@_njit
def _chain_rows(
    s0,
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
    sums32,
    count,
    prev,
    st,
):  # pragma: no cover - compiled
    """Frames ``fl[s]``, ``s < n`` (rank ``s0 + s`` in exposure order, ``ml[s]`` its mask in
    output coordinates; ``has_t``, ``ts``, ``has_mask``, ``ln_t`` indexed by ``s``) over the
    output pixels ``(y0 + stride // 2 + i * stride, stride // 2 + j *
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
    slot's sums for the pixel's block, ``sums[by, bx, slot, ch] = (sum w r, sum ln E_a, sum
    ln E_b)`` (float64: terms of either sign), ``sums32[by, bx, slot, ch] = (sum w, sum
    additive)`` (float32: positive terms, at most ``b**2`` of them, ~1e-6 relative) and
    ``count``. The
    sampling is written out here once, not in a helper: a helper's array arguments cost ten
    times the work per pixel.

    The chains' state, ``prev[r, gx, ch]`` (the rank of the last frame that recorded the
    channel, -1: none) and ``st[r, gx, ch]`` (its ln E, rel var, additive rel var and level bin),
    is the caller's: one row (``r`` 0 for every row: a call with every frame, ``s0 == 0``) or
    one per output row (``r = gy``: a bracket longer than the kernel's tuple slots goes through
    in calls of up to ``MAX_KERNEL_FRAMES`` frames, each continuing the chains the previous
    call left). A call with ``s0 == 0`` starts the chains. The specification:
    :mod:`hdrcore.merge.consistency_spec`."""
    c = tab.shape[0] if integer else sat.shape[0]
    to_hist = hist.shape[0] > 0
    hb = hist.shape[3]
    hscale = hb / (2.0 * _HIST_RANGE)
    off = stride // 2
    per_row = prev.shape[0] > 1
    for gy in range(gh):
        y = y0 + off + gy * stride
        by = y // b
        r_ = gy if per_row else 0
        pv = prev[r_]
        sv = st[r_]
        if s0 == 0:
            pv[:, :] = -1
        for s in range(n):
            gs = s0 + s
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
            affine = t20 == 0.0 and t21 == 0.0 and t22 == 1.0
            for gx in range(gw):
                x = off + gx * stride
                if hm and not mask[y, x]:
                    continue
                sy = y
                sx = x
                if ht:
                    if affine:  # the same values: the denominator is exactly 1
                        fx = t00 * x + t01 * y + t02
                        fy = t10 * x + t11 * y + t12
                    else:
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
                    q = pv[gx, ch]
                    if q >= 0:
                        if to_hist:
                            # a frame stepped over is not the pair's transfer (in a static
                            # scene only a mask or a frame's border steps over one)
                            if q == gs - 1:
                                j = int(np.floor((lnc - sv[gx, ch, 0] + _HIST_RANGE) * hscale))
                                hist[q, ch, int(sv[gx, ch, 3]), min(hb - 1, max(0, j))] += 1
                        else:
                            r = lnc - sv[gx, ch, 0]
                            if q == gs - 1:
                                r -= bias[q, ch, int(sv[gx, ch, 3])]
                            wt = 1.0 / (sv[gx, ch, 1] + rvc)
                            o = sums[by, bx, q, ch]
                            o32 = sums32[by, bx, q, ch]
                            o[0] += wt * r
                            o32[0] += wt
                            o32[1] += sv[gx, ch, 2] + adc
                            o[1] += sv[gx, ch, 0]
                            o[2] += lnc
                            count[by, bx, q, ch] += 1
                    sv[gx, ch, 0] = lnc
                    sv[gx, ch, 1] = rvc
                    sv[gx, ch, 2] = adc
                    sv[gx, ch, 3] = lbc
                    pv[gx, ch] = gs


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


@dataclass(frozen=True, eq=False)
class _Inputs:
    """The frames of :func:`pair_residuals` as the kernel and the specification read them:
    ``fs`` ``(H, W, C)`` each, ``order`` the frames by exposure time, the per-level tables,
    the homogeneous transforms (``has_t``: not the identity), the masks, ``ln t`` and the
    stride of the transfer histograms' sample grid."""

    fs: list[np.ndarray]
    order: np.ndarray
    tables: _Tables
    has_t: np.ndarray
    ts: np.ndarray
    masks: list[np.ndarray | None]
    ln_t: np.ndarray
    stride: int

    @property
    def channels(self) -> int:
        return int(self.fs[0].shape[2])


def _inputs(
    frames: Sequence[np.ndarray],
    exposure_times: Sequence[float],
    saturation: Sequence[float],
    floor: float,
    lut: np.ndarray | None,
    max_level: int | None,
    noise: NoiseModel | None,
    transforms: Sequence[np.ndarray | None] | None,
    masks: Sequence[np.ndarray | None] | None,
    p: GhostTestParams,
) -> _Inputs:
    fs = [np.asarray(f) for f in frames]
    fs = [f[..., None] if f.ndim == 2 else f for f in fs]
    n = len(fs)
    h, w, c = fs[0].shape
    times = np.asarray(exposure_times, np.float64)
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
    return _Inputs(
        fs=fs,
        order=np.argsort(times, kind="stable").astype(np.int64),
        tables=t,
        has_t=has_t,
        ts=ts,
        masks=[None if m is None else np.ascontiguousarray(m, dtype=bool) for m in ms],
        ln_t=np.log(times),
        stride=max(1, int(np.sqrt(h * w / float(p.sample_pixels)))),
    )


#: Bytes of chain state (per output row: ``(W, C)`` ranks and ``(W, C, 4)`` values) a call of
#: a bracket longer than ``MAX_KERNEL_FRAMES`` keeps for its rows between the frame groups.
_STATE_BYTES = 8 << 20


class _Chains:
    """Calls :func:`_chain_rows` with every frame of a bracket: the frames (and masks) go in
    tuples of ``MAX_KERNEL_FRAMES`` read-only arrays, padded with placeholders (one compiled
    specialisation for every bracket length: numba's typed lists compile their own methods in
    every new process); a longer bracket in several such groups, in exposure order, the
    chains' state carried from one to the next."""

    def __init__(self, inp: _Inputs) -> None:
        t = inp.tables
        order = inp.order
        n = len(order)
        c = inp.channels
        self.c = c
        dtype = np.result_type(*inp.fs)
        mask_t = [np.ones((1, 1), bool) if m is None else m for m in inp.masks]
        fl = [_read_only(inp.fs[k], dtype) for k in order]  # rank s in exposure order
        ml = [_read_only(mask_t[k], bool) for k in order]
        has_t = np.ascontiguousarray(inp.has_t[order])
        ts = np.ascontiguousarray(inp.ts[order])
        has_mask = np.array([inp.masks[k] is not None for k in order])
        ln_t = np.ascontiguousarray(inp.ln_t[order])
        pad_f = _read_only(np.zeros((1, 1, c), dtype), dtype)
        pad_m = _read_only(np.ones((1, 1), bool), bool)
        self.groups = []
        for s0 in range(0, n, MAX_KERNEL_FRAMES):
            s1 = min(n, s0 + MAX_KERNEL_FRAMES)
            pad = MAX_KERNEL_FRAMES - (s1 - s0)
            self.groups.append(
                (
                    s0,
                    s1 - s0,
                    tuple(fl[s0:s1]) + (pad_f,) * pad,
                    tuple(ml[s0:s1]) + (pad_m,) * pad,
                    t.integer,
                    t.packed(),
                    t.sat,
                    t.floor,
                    t.shot,
                    t.const_var,
                    t.bins,
                    has_t[s0:s1].copy(),
                    ts[s0:s1].copy(),
                    has_mask[s0:s1].copy(),
                    ln_t[s0:s1].copy(),
                )
            )

    def run(self, y0, gh, gw, stride, hist, bias, b, sums, sums32, counts, unit=1) -> None:
        """The output rows ``y0 + stride // 2 + i * stride``, ``i < gh`` (see
        :func:`_chain_rows`). A long bracket goes through in groups of rows, a multiple of
        ``unit`` (the sample rows of a block: a block's sums are then added in the same order
        however the rows are cut into pieces of work, so the thread count changes no bit)."""
        c = self.c
        if len(self.groups) == 1:
            prev = np.empty((1, gw, c), np.int64)
            st = np.zeros((1, gw, c, 4))
            _chain_rows(
                *self.groups[0], y0, gh, gw, stride, hist, bias, b, sums, sums32, counts, prev, st
            )
            return
        # a long bracket: a few rows at a time through every group of frames, the rows'
        # chains kept between the groups
        rows = min(gh, max(1, _STATE_BYTES // (gw * c * 40 * unit)) * unit)
        for g0 in range(0, gh, rows):
            g1 = min(gh, g0 + rows)
            prev = np.empty((max(2, g1 - g0), gw, c), np.int64)  # > 1 row: one per row
            st = np.zeros((max(2, g1 - g0), gw, c, 4))
            for group in self.groups:
                _chain_rows(
                    *group,
                    y0 + g0 * stride,
                    g1 - g0,
                    gw,
                    stride,
                    hist,
                    bias,
                    b,
                    sums,
                    sums32,
                    counts,
                    prev,
                    st,
                )


def _resolve_engine(engine: str | None, what: str) -> None:
    """``engine=None`` or ``"numba"``: the compiled kernels; ``"numpy"``, the removed numpy
    path, is a deprecated alias of them for one release (a ``DeprecationWarning``)."""
    if isinstance(engine, str) and engine.strip().lower() == "numpy":
        warnings.warn(
            f"{what}(engine='numpy') is deprecated: the ghost test's numpy path was removed "
            "and the compiled kernels run instead (same results); drop the argument",
            DeprecationWarning,
            stacklevel=3,
        )
        engine = None
    if engine is not None:
        validate_method(engine, {"numba": "the compiled kernels"}, "ghost test engine")
    if not AVAILABLE:
        raise ParameterError(
            "the ghost test needs numba (a dependency of hdrcore)",
            expected="numba installed",
            found="numba not importable",
        )


def block_sums_bytes(
    shape: tuple[int, ...], frames: int, params: GhostTestParams | None = None
) -> int:
    """Bytes of the per-block sums :func:`pair_residuals` holds for ``frames`` frames of
    ``shape`` (``(H, W)`` or ``(H, W, C)``): its working memory beyond its inputs (3 x 24 MP
    RGB: 77 MiB; 5 x 45 MP: 320 MiB)."""
    p = params or GhostTestParams()
    h, w = int(shape[0]), int(shape[1])
    c = int(shape[2]) if len(shape) > 2 else 1
    blocks = (h // int(p.block)) * (w // int(p.block))
    # three float64 and two float32 fields, an int32 count
    return blocks * max(int(frames) - 1, 0) * c * (3 * 8 + 2 * 4 + 4)


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
    """:class:`PairResiduals` of ``frames`` (steps 1-3 of the module docstring), any number
    of frames, by the compiled kernel (:mod:`hdrcore.merge.consistency_spec` states the same
    as plain numpy, for the tests).

    ``frames``: integer levels (with ``lut``/``max_level``) or float linear values, one shape;
    ``transforms`` (output grid to frame), ``masks`` (output grid) as
    :func:`hdrcore.merge.merge` takes them; ``saturation`` (per channel) and ``floor`` in the
    frames' units. ``engine``: ``None`` or ``"numba"``; ``"numpy"`` (the numpy path, removed)
    is a deprecated alias of the kernel for one release.
    """
    _resolve_engine(engine, "pair_residuals")
    p = params or GhostTestParams()
    inp = _inputs(
        frames, exposure_times, saturation, floor, lut, max_level, noise, transforms, masks, p
    )
    n = len(inp.fs)
    h, w, c = inp.fs[0].shape
    b = int(p.block)
    hb, wb = h // b, w // b
    slots = max(n - 1, 0)
    stride = inp.stride
    hist = np.zeros((slots, c, p.level_bins, _HIST_BINS), np.int64)
    # one block's sums side by side in the kernel; the fields are views of them. The weights
    # and additive variances (positive terms) in float32: at 45 MP x 5 frames the five float64
    # fields were 356 MiB, two of them at half the bytes save 71 MiB of that
    sums = np.zeros((hb, wb, slots, c, 3))
    sums32 = np.zeros((hb, wb, slots, c, 2), np.float32)
    counts = np.zeros((hb, wb, slots, c), np.int32)
    chains = _Chains(inp) if slots and hb and wb else None
    if chains is not None:
        gh, gw = len(range(stride // 2, h, stride)), len(range(stride // 2, w, stride))
        chains.run(
            0,
            gh,
            gw,
            stride,
            hist,
            np.zeros((1, c, 1)),
            b,
            np.zeros((1, 1, 1, c, 3)),
            np.zeros((1, 1, 1, c, 2), np.float32),
            np.zeros((1, 1, 1, c), np.int32),
        )
    bias, source = _transfer_bias(hist, p) if slots else (np.zeros((0, c, p.level_bins)), [])
    if chains is not None:
        # block rows per piece of work: a few per worker (load balance); each row's chains
        # live in the kernel's one-row state
        span = max(1, -(-hb // (8 * worker_count(workers))))
        step = int(p.pixel_step)
        no_hist = np.zeros((0, c, 1, 1), np.int64)

        def work(r0: int) -> None:
            r1 = min(hb, r0 + span)
            chains.run(
                r0 * b,
                (r1 - r0) * b // step,
                wb * b // step,
                step,
                no_hist,
                bias,
                b,
                sums,
                sums32,
                counts,
                unit=b // step,
            )

        thread_map(work, range(0, hb, span), workers)
    weighted, first, second = (np.moveaxis(sums[..., i], (0, 1), (2, 3)) for i in range(3))
    weights, additive = (np.moveaxis(sums32[..., i], (0, 1), (2, 3)) for i in range(2))
    return PairResiduals(
        weighted=weighted,
        weights=weights,
        additive=additive,
        first=first,
        second=second,
        count=np.moveaxis(counts, (0, 1), (2, 3)),
        bias=bias,
        bias_source=tuple(source),
        order=inp.order,
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


def _block_scale(res: PairResiduals, q: int, use: np.ndarray) -> np.ndarray:
    """Per channel, the robust spread (1.4826 MAD) of pair slot ``q``'s block means over the
    blocks compared (``use``, ``(C, hb, wb)``)."""
    return np.array(
        [
            1.4826 * float(np.median(np.abs(m - np.median(m)))) if m.size else 0.0
            for m in (
                res.weighted[q, ch][use[ch]] / res.weights[q, ch][use[ch]]
                for ch in range(use.shape[0])
            )
        ]
    )


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
    written; the specification: :func:`hdrcore.merge.consistency_spec.block_test_spec`)."""
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

    The inputs are the merge's (see :func:`pair_residuals`; any number of frames, through the
    compiled kernels); ``candidates`` (bool ``(H, W)``, the merge's per-pixel test) and
    ``score`` (its per-pixel score) shape the regions at pixel resolution. ``engine``: as
    :func:`pair_residuals` takes it (``"numpy"`` a deprecated alias of the kernels).
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
    _resolve_engine(engine, "consistency_regions")
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
    )
    t1 = time.perf_counter()
    need = max(1, int(np.ceil(p.min_shared * (b // p.pixel_step) ** 2)))
    indep = 4.0 / p.pixel_step**2  # 4 / sum(w) for every pixel of a block
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
        scale = _block_scale(res, q, use)
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
