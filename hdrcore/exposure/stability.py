"""Region jack-knife of a histogram exposure ratio: an honest error and a motion detector.

Beyond Cerman & Hlavac (2006, section 5). The standard error of the weighted fit of eq. 4 is far
too small: neighbouring equations come from neighbouring quantiles of the same cumulative
histograms and are strongly correlated. And the histogram method assumes both frames see the same
scene content, which hand-held motion breaks at the borders (content enters one frame and leaves
the other), biasing the ratio by percents while the fit stays tight.

Both show up when the image is cut into ``R`` regions (a grid) and the ratio is re-estimated ``R``
times, each time with one region left out of both frames (Quenouille-Tukey jack-knife)::

    se_jk = sqrt((R - 1) / R * sum_r (k_(-r) - mean k_(-r))^2)

On a tripod, leaving out a region removes the same content from both frames and ``k`` barely
moves: ``se_jk`` is the sampling error of the estimate. With motion, the left-out regions hold
different content in the two frames and ``k_(-r)`` scatters by about the size of the bias.

Each leave-one-out fit samples the brightness transfer functions at every ``f``-th bin edge (at
most ``max_groups`` equations per channel and direction, each weighted by the square root of
the counts of its ``f`` levels) and all ``R`` fits run as one vectorised 3V iteration
(:func:`hdrcore.exposure._core.solve_3v_batch`). The part that depends only on the histograms
(cumulative histograms, transferred positions) is computed once and cached by the caller, so a
re-fit after a change of saturation level, noise floor or response is cheap.

References: J. Cerman, V. Hlavac, CVWW 2006, section 5 (eq. 4, 3V); M. H. Quenouille, "Notes
on bias in estimation", Biometrika 43, 1956; J. W. Tukey, "Bias and confidence in not-quite large
samples", Ann. Math. Statist. 29, 1958.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..btf import quantile_levels
from ._core import as_lut, level_group_size, solve_3v_batch

__all__ = ["JackknifeSkeleton", "jackknife_skeleton", "region_jackknife"]


@dataclass(frozen=True, eq=False)
class JackknifeSkeleton:
    """What the leave-one-out fits need that depends only on the histograms.

    Arrays are ``(R, C, G)``: ``pos_*`` the sampled bin edges (levels of the frame the equation
    comes from), ``t_*`` their transfer into the other frame, ``count_*`` the summed counts of the
    ``f`` levels each equation stands for, ``inner_*`` whether the edge lies strictly inside the
    occupied range of its cumulative histogram.
    """

    pos: np.ndarray
    t_fwd: np.ndarray
    t_inv: np.ndarray
    count_dark: np.ndarray
    count_bright: np.ndarray
    inner_dark: np.ndarray
    inner_bright: np.ndarray
    group_size: int
    n_regions: int
    n_levels: int


def jackknife_std_error(leave_one_out: np.ndarray) -> tuple[float, int]:
    """Jack-knife standard error ``sqrt((m - 1) / m * sum((k_(-r) - mean)^2))`` of the finite,
    positive leave-one-out estimates, and their number ``m``."""
    kk = np.asarray(leave_one_out, np.float64)
    kk = kk[np.isfinite(kk) & (kk > 0)]
    m = kk.size
    if m == 0:
        return float("nan"), 0
    return float(np.sqrt((m - 1) / m * np.sum((kk - kk.mean()) ** 2))), m


def _leave_one_out(regions: np.ndarray) -> np.ndarray:
    r = np.asarray(regions, np.float64)
    return r.sum(axis=0, keepdims=True) - r


def jackknife_skeleton(
    regions_dark: np.ndarray, regions_bright: np.ndarray, *, max_groups: int = 256
) -> JackknifeSkeleton:
    """Leave-one-region-out transfer functions sampled at every ``f``-th bin edge.

    ``regions_*``: ``(R, C, L)`` histograms of the same ``R`` regions of both frames.
    """
    loo_d = _leave_one_out(regions_dark)
    loo_b = _leave_one_out(regions_bright)
    n_r, n_ch, n = loo_d.shape
    f = level_group_size(n, max_groups)
    n_g = -(-n // f)
    top = np.minimum(np.arange(n_g) * f + f - 1, n - 1)  # last level of each group
    pad = n_g * f - n

    def cdf(h: np.ndarray) -> np.ndarray:
        c = np.cumsum(h, axis=-1)
        tot = c[..., -1:]
        return np.where(tot > 0, c / np.where(tot > 0, tot, 1.0), 0.0)

    def grouped(h: np.ndarray) -> np.ndarray:
        return np.pad(h, [(0, 0), (0, 0), (0, pad)]).reshape(n_r, n_ch, n_g, f).sum(axis=-1)

    cd, cb = cdf(loo_d), cdf(loo_b)
    t_fwd = np.empty((n_r, n_ch, n_g))
    t_inv = np.empty((n_r, n_ch, n_g))
    for r in range(n_r):
        for c in range(n_ch):
            t_fwd[r, c] = quantile_levels(cb[r, c], cd[r, c, top])
            t_inv[r, c] = quantile_levels(cd[r, c], cb[r, c, top])
    qd, qb = cd[..., top], cb[..., top]
    return JackknifeSkeleton(
        pos=np.broadcast_to(top + 0.5, (n_r, n_ch, n_g)),
        t_fwd=t_fwd,
        t_inv=t_inv,
        count_dark=grouped(loo_d),
        count_bright=grouped(loo_b),
        inner_dark=(qd > 0) & (qd < 1),
        inner_bright=(qb > 0) & (qb < 1),
        group_size=f,
        n_regions=n_r,
        n_levels=n,
    )


def region_jackknife(
    skeleton: JackknifeSkeleton,
    *,
    saturation: float,
    noise_floor: float,
    lut: np.ndarray | None = None,
    weight_power: float = 0.5,
    precision: float = 1e-6,
    max_iterations: int = 10,
) -> tuple[np.ndarray, float]:
    """Leave-one-region-out ratios ``k_(-r)`` ``(R,)`` and their jack-knife standard error.

    Uses the equations of eq. 4 (forward and inverse, every channel) under the given saturation
    level ``Z``, noise floor and linearisation, fitted with the 3V iteration (at most
    ``max_iterations``: the spread of the ``k_(-r)`` is needed to a few 1e-5, not to 1e-7).
    The error is ``nan`` when fewer than three leave-one-out fits succeed.
    """
    sk = skeleton
    n_r, n_ch, n_g = sk.pos.shape
    n_levels = sk.n_levels
    g = None if lut is None else as_lut(lut, n_ch, n_levels - 1)
    levels = np.arange(n_levels, dtype=np.float64)

    def lin(v: np.ndarray, c: int) -> np.ndarray:
        if g is None:
            return np.clip(v, 0.0, n_levels - 1) / (n_levels - 1)
        return np.interp(v, levels, g[c])

    z, floor = float(saturation), float(noise_floor)
    pos = sk.pos
    fwd = (sk.count_dark > 0) & sk.inner_dark & (pos > floor) & (pos < z) & (sk.t_fwd < z)
    inv = (sk.count_bright > 0) & sk.inner_bright & (pos < z) & (pos > floor) & (sk.t_inv > floor)
    x: np.ndarray = np.empty((n_r, n_ch, 2, n_g))
    y: np.ndarray = np.empty((n_r, n_ch, 2, n_g))
    for c in range(n_ch):
        x[:, c, 0] = lin(pos[:, c], c)
        y[:, c, 0] = lin(sk.t_fwd[:, c], c)
        x[:, c, 1] = lin(sk.t_inv[:, c], c)
        y[:, c, 1] = lin(pos[:, c], c)
    w2 = np.stack([sk.count_dark, sk.count_bright], axis=2) ** (2.0 * weight_power)
    use = np.stack([fwd, inv], axis=2)
    w2 = np.where(use, w2, 0.0).reshape(n_r, -1)
    x = x.reshape(n_r, -1)
    y = y.reshape(n_r, -1)
    n = use.reshape(n_r, -1).astype(np.float64)
    k = solve_3v_batch(
        w2 * x * x, w2 * x * y, w2 * y * y, n, precision=precision, max_iterations=max_iterations
    )
    se, m = jackknife_std_error(k)
    return k, se if m >= 3 else float("nan")
