"""Shared numerical pieces of the histogram exposure estimators (private).

Equations of system S0 (Cerman & Hlavac 2006, eq. 4) from brightness transfer functions, the
weighted least-squares solution of ``k x = y`` with the seed's 3V outlier iteration (section 5.1),
and the status logic of section 5.2 (not enough overlap, poor confidence: a 95 % interval
wider than the tolerance, :mod:`.interval`; a black or saturated frame: ``"no-signal"``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from ..btf import BrightnessTransferFunction, brightness_transfer_function
from ..errors import ParameterError
from ..status import RatioStatus
from .interval import OK_TOLERANCE, brightness_band_ratios, verdict
from .result import FORWARD, INVERSE, ExposureEquations, ExposureRatioResult

__all__ = [
    "FitOptions",
    "as_lut",
    "check_histograms",
    "default_saturation",
    "default_noise_floor",
    "solve_3v",
    "solve_3v_groups",
    "solve_3v_batch",
    "group_statistics",
    "level_group_size",
    "pair_btfs",
    "estimate_pair",
]


@dataclass(frozen=True)
class FitOptions:
    """How a method builds and solves its equations.

    ``at_edges``: sample the BTF at bin edges ``m + 1/2`` (exact quantiles of the frame the
    equation comes from) instead of at level centres ``m`` (the paper's choice).
    ``weight_power``: equations are multiplied by ``h ** weight_power`` (the paper: 1/2).
    ``relative_error``: also divide each equation by ``x`` so that every equation measures ``k``
    on the same relative scale (``k - y/x``) weighted by its information.
    """

    name: str
    at_edges: bool
    weight_power: float = 0.5
    relative_error: bool = False
    min_level_fraction: float = 0.0


def default_saturation(max_level: int) -> float:
    """Default saturation level ``Z``: 97 % of the largest level (keeps clipped noise out)."""
    return 0.97 * max_level


def default_noise_floor(max_level: int) -> float:
    """Default noise floor: 2 % of the largest level, at least 3 levels."""
    return max(3.0, 0.02 * max_level)


def check_levels(
    max_level: int, saturation: float | None, noise_floor: float | None
) -> tuple[float, float]:
    """``(Z, noise floor)`` in levels, defaults filled in and their order checked."""
    z = default_saturation(max_level) if saturation is None else float(saturation)
    floor = default_noise_floor(max_level) if noise_floor is None else float(noise_floor)
    if not 0 <= floor < z <= max_level + 1:
        raise ParameterError(
            "need 0 <= noise floor < saturation <= max_level + 1",
            found=f"noise floor {floor:g}, saturation {z:g}",
        )
    return z, floor


def channels_disagree(
    ratios: np.ndarray, std_errors: np.ndarray, k: float, tolerance: float
) -> bool:
    """Whether a colour channel's ratio is off the joint ``k`` by more than ``tolerance`` and
    four of its standard errors (a white-level, colour-cast or response problem)."""
    finite = np.isfinite(ratios)
    if ratios.size < 2 or np.count_nonzero(finite) < 2:
        return False
    dev = np.abs(ratios[finite] / k - 1)
    allowed = np.maximum(tolerance, 4 * std_errors[finite] / k)
    return bool(np.any(dev > allowed))


def as_lut(lut: np.ndarray | None, n_channels: int, max_level: int) -> np.ndarray:
    """A ``(C, max_level + 1)`` float64 linearisation table; ``None`` means linear levels."""
    n = max_level + 1
    if lut is None:
        return np.broadcast_to(np.arange(n, dtype=np.float64) / max_level, (n_channels, n))
    g = np.asarray(lut, np.float64)
    if g.ndim == 1:
        g = np.broadcast_to(g, (n_channels, g.size))
    if g.ndim != 2 or g.shape[1] != n or g.shape[0] not in (1, n_channels):
        raise ParameterError(
            "linearisation table has the wrong shape",
            expected=f"({n},) or ({n_channels}, {n})",
            found=str(np.asarray(lut).shape),
        )
    if g.shape[0] == 1:
        g = np.broadcast_to(g, (n_channels, n))
    if not np.all(np.isfinite(g)) or np.any(np.diff(g, axis=1) < 0):
        raise ParameterError("linearisation table must be finite and non-decreasing")
    return g


def check_histograms(hist_dark: np.ndarray, hist_bright: np.ndarray) -> tuple[np.ndarray, ...]:
    hd = np.asarray(hist_dark)
    hb = np.asarray(hist_bright)
    if hd.ndim == 1:
        hd = hd[None]
    if hb.ndim == 1:
        hb = hb[None]
    if hd.ndim != 2 or hd.shape != hb.shape or hd.shape[1] < 2:
        raise ParameterError(
            "histograms of a pair must have the same shape (C, max_level + 1)",
            found=f"{np.asarray(hist_dark).shape} and {np.asarray(hist_bright).shape}",
        )
    if np.any(hd < 0) or np.any(hb < 0):
        raise ParameterError("histogram counts must be non-negative")
    return hd, hb


def _level_range(n: int, noise_floor: float, saturation: float) -> tuple[int, int]:
    """Slice ``lo:hi`` of the levels ``m`` with ``noise_floor < m < saturation``."""
    lo = int(np.floor(noise_floor)) + 1
    hi = int(np.ceil(saturation))
    return min(max(lo, 0), n), min(max(hi, 0), n)


def _unusable(hist: np.ndarray, saturation: float, noise_floor: float) -> str | None:
    """Why a whole frame gives no equation (``"no pixels"``, ``"black (at or below the noise
    floor)"``, ``"saturated"``), or ``None`` when some pixel lies between the floor and ``Z``."""
    total = hist.sum()
    if total <= 0:
        return "no pixels"
    lo, hi = _level_range(hist.shape[-1], noise_floor, saturation)
    if hist[..., lo:hi].sum() > 0:
        return None
    low = hist[..., :lo].sum()
    return "black (at or below the noise floor)" if low >= total / 2 else "saturated"


def _no_signal(
    which: str,
    kind: str,
    *,
    method: str,
    n_ch: int,
    saturation: float,
    noise_floor: float,
    max_level: int,
    dark: int,
    bright: int,
    tolerance: float,
) -> ExposureRatioResult:
    """The result of a pair one of whose frames is black, saturated or empty (no ratio)."""
    index = dark if which == "darker" else bright
    if kind == "no pixels":
        what = f"the {which} frame (frame {index}) has no pixels to count"
    else:
        what = (
            f"the {which} frame is entirely {kind}; no exposure ratio can be estimated "
            f"from it (expected pixels between noise floor {noise_floor:g} and saturation "
            f"{saturation:g}, found none)"
        )
    return ExposureRatioResult.unmeasured(
        status="no-signal",
        message=f"frames {dark} and {bright}: {what}",
        n_channels=n_ch,
        method=method,
        saturation=saturation,
        noise_floor=noise_floor,
        max_level=int(max_level),
        dark=dark,
        bright=bright,
        tolerance=tolerance,
    )


def group_statistics(
    wx: np.ndarray, wy: np.ndarray, groups: np.ndarray, n_groups: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Sufficient statistics ``(Sxx, Sxy, Syy, n)`` of the weighted equations in each group.

    The least-squares solution of ``w k x = w y`` over any union of whole groups is exactly
    ``k = sum Sxy / sum Sxx``, so merging neighbouring levels into groups loses nothing in the
    fit; only the 3V outlier test then acts on whole groups.
    """
    sxx = np.bincount(groups, wx * wx, minlength=n_groups)
    sxy = np.bincount(groups, wx * wy, minlength=n_groups)
    syy = np.bincount(groups, wy * wy, minlength=n_groups)
    n = np.bincount(groups, minlength=n_groups).astype(np.float64)
    return sxx, sxy, syy, n


def solve_3v_groups(
    sxx: np.ndarray,
    sxy: np.ndarray,
    syy: np.ndarray,
    n: np.ndarray,
    *,
    precision: float = 1e-7,
    max_iterations: int = 100,
) -> tuple[float, tuple[float, ...], np.ndarray, int, float]:
    """The seed's least squares + 3V iteration (section 5.1) on grouped equations.

    ``k = sum(w^2 x y) / sum(w^2 x^2)`` in closed form over the inlier groups; ``V`` is the mean
    squared weighted residual per equation of the inliers; a group stays an inlier while its mean
    squared residual is below ``3 V``. Stops when ``k`` changes by less than ``precision``
    (relative), when the inlier set stops changing, or after ``max_iterations``.
    Returns ``(k, iterates, inlier_groups, iterations, std_error)``.
    """
    occupied = n > 0
    stats = np.stack([sxx, sxy, syy, n])  # one matrix-vector product sums all four

    def sums(mask: np.ndarray) -> np.ndarray:
        return stats @ mask.astype(np.float64)

    def ssr(k: float) -> np.ndarray:
        return np.maximum(syy - 2.0 * k * sxy + k * k * sxx, 0.0)

    def fit(mask: np.ndarray) -> float:
        s_xx, s_xy = sums(mask)[:2]
        return float(s_xy / s_xx) if s_xx > 0 else float("nan")

    mask = occupied.copy()
    k = fit(mask)
    iterates = [k]
    if np.isfinite(k):
        for _ in range(max_iterations):
            r2 = ssr(k)
            v = float(np.dot(r2, mask) / np.dot(n, mask))
            if v <= 0:
                break
            new_mask = occupied & (r2 < 3.0 * v * n)
            if np.count_nonzero(new_mask) < 2 or np.array_equal(new_mask, mask):
                break  # too few left, or the inlier set no longer changes: k is final
            mask = new_mask
            k_new = fit(mask)
            iterates.append(k_new)
            done = abs(k_new - k) <= precision * abs(k)
            k = k_new
            if done:
                break
    s_xx, _, _, n_in = sums(mask)
    if n_in > 1 and s_xx > 0 and np.isfinite(k):
        se = float(np.sqrt(float(np.dot(ssr(k), mask)) / (n_in - 1) / s_xx))
    else:
        se = float("inf")
    return k, tuple(iterates), mask, len(iterates) - 1, se


def solve_3v_batch(
    sxx: np.ndarray,
    sxy: np.ndarray,
    syy: np.ndarray,
    n: np.ndarray,
    *,
    precision: float = 1e-7,
    max_iterations: int = 50,
) -> np.ndarray:
    """:func:`solve_3v_groups` for a batch ``(B, G)`` of independent problems at once: ``k (B,)``.

    Used by the region jack-knife, where the same equations are fitted once per left-out region.
    """
    occupied = n > 0
    mask = occupied.copy()

    def fit(m: np.ndarray) -> np.ndarray:
        den = np.einsum("bg,bg->b", m, sxx)
        num = np.einsum("bg,bg->b", m, sxy)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(den > 0, num / np.where(den > 0, den, 1.0), np.nan)

    k = fit(mask.astype(np.float64))
    active = np.isfinite(k)
    for _ in range(max_iterations):
        if not active.any():
            break
        mf = mask.astype(np.float64)
        r2 = np.maximum(syy - 2.0 * k[:, None] * sxy + (k * k)[:, None] * sxx, 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            v = np.einsum("bg,bg->b", mf, r2) / np.einsum("bg,bg->b", mf, n)
            new_mask = occupied & (r2 < 3.0 * v[:, None] * n)
        stop = (v <= 0) | (new_mask.sum(axis=1) < 2) | np.all(new_mask == mask, axis=1)
        active &= ~stop
        mask = np.where(active[:, None], new_mask, mask)
        k_new = fit(mask.astype(np.float64))
        done = np.abs(k_new - k) <= precision * np.abs(k)
        k = np.where(active, k_new, k)
        active &= ~done
    return k


def solve_3v(
    x: np.ndarray,
    y: np.ndarray,
    w: np.ndarray,
    *,
    precision: float = 1e-7,
    max_iterations: int = 100,
    groups: np.ndarray | None = None,
) -> tuple[float, tuple[float, ...], np.ndarray, np.ndarray, int, float]:
    """Solve ``w k x = w y`` by least squares, then the seed's 3V iteration (section 5.1).

    Repeat: ``V`` = mean squared weighted residual of the current inliers, keep equations whose
    squared residual is below ``3 V``, re-solve, until ``k`` changes by less than ``precision``
    (relative) or the inlier set stops changing. ``groups`` (non-negative integers, one per
    equation) lets neighbouring equations be tested together (:func:`solve_3v_groups`);
    ``None`` tests every equation on its own. Returns
    ``(k, iterates, inlier_mask, residuals, iterations, std_error)`` over the equations.
    """
    x = np.asarray(x, np.float64)
    wx = w * x
    wy = w * np.asarray(y, np.float64)
    if groups is None:
        groups = np.arange(x.size)
    n_groups = int(groups.max()) + 1 if groups.size else 0
    stats = group_statistics(wx, wy, groups, n_groups)
    k, iterates, gmask, iterations, se = solve_3v_groups(
        *stats, precision=precision, max_iterations=max_iterations
    )
    mask = gmask[groups] if groups.size else np.zeros(0, bool)
    return k, iterates, mask, wy - k * wx, iterations, se


def _sampled_btf(btf: BrightnessTransferFunction, at_edges: bool) -> tuple[np.ndarray, ...]:
    """What the equations of one channel need that depends on the histograms only (cached in
    the BTF): sample positions, transfers and the indices of occupied, interior levels."""
    key = ("equations", at_edges)
    cached = btf._memo.get(key)
    if cached is not None:
        return cached
    n = btf.hist_dark.size
    levels = np.arange(n, dtype=np.float64)
    if at_edges:
        pos = levels + 0.5
        t_fwd, t_inv = btf.forward_at_edges(), btf.inverse_at_edges()
        inner_d = (btf.cdf_dark > 0) & (btf.cdf_dark < 1)
        inner_b = (btf.cdf_bright > 0) & (btf.cdf_bright < 1)
    else:
        pos = levels
        t_fwd, t_inv = btf.forward, btf.inverse
        inner_d = inner_b = np.ones(n, bool)
    base_d = np.flatnonzero((btf.hist_dark > 0) & inner_d)
    base_b = np.flatnonzero((btf.hist_bright > 0) & inner_b)
    out = (pos, np.asarray(t_fwd), np.asarray(t_inv), base_d, base_b)
    btf._memo[key] = out
    return out


def _select(base: np.ndarray, lo: int, hi: int) -> np.ndarray:
    """Entries of the sorted index array ``base`` in ``[lo, hi)``."""
    return base[np.searchsorted(base, lo) : np.searchsorted(base, max(lo, hi))]


def _equations_for_channel(
    btf: BrightnessTransferFunction,
    g: np.ndarray | None,
    saturation: float,
    noise_floor: float,
    options: FitOptions,
    channel: int,
) -> tuple[np.ndarray, ...]:
    """Rows of eq. 4 for one channel: forward rows from dark levels ``noise floor < M_A < Z``
    with ``T(M_A) < Z``, inverse rows from bright levels ``noise floor < M_B < Z`` with
    ``T^-1(M_B) > noise floor``. Positions and transfers are non-decreasing, so each condition
    selects a range of levels (found by bisection; a re-fit costs no mask over all levels)."""
    n = btf.hist_dark.size
    levels = np.arange(n, dtype=np.float64)

    def lin(pos: np.ndarray) -> np.ndarray:
        if g is None:  # linear levels: g(m) = m / max_level (np.interp clamps the same way)
            return np.clip(pos, 0.0, n - 1) / (n - 1)
        return np.interp(pos, levels, g)

    pos, t_fwd, t_inv, base_d, base_b = _sampled_btf(btf, options.at_edges)
    z, floor = saturation, noise_floor
    above_floor = int(np.searchsorted(pos, floor, side="right"))
    below_z = int(np.searchsorted(pos, z, side="left"))
    fwd = _select(base_d, above_floor, min(below_z, int(np.searchsorted(t_fwd, z, side="left"))))
    inv = _select(
        base_b, max(above_floor, int(np.searchsorted(t_inv, floor, side="right"))), below_z
    )
    hd, hb = btf.hist_dark, btf.hist_bright
    x = np.concatenate([lin(pos[fwd]), lin(t_inv[inv])])
    y = np.concatenate([lin(t_fwd[fwd]), lin(pos[inv])])
    counts = np.concatenate([hd[fwd], hb[inv]]).astype(np.float64)
    w = counts**options.weight_power
    direction = np.concatenate(
        [np.full(fwd.size, FORWARD, np.int8), np.full(inv.size, INVERSE, np.int8)]
    )
    level = np.concatenate([pos[fwd], pos[inv]])
    ch = np.full(x.size, channel, np.int8)
    return x, y, w, direction, ch, level


def _overlap(
    hd: np.ndarray,
    btfs: tuple[BrightnessTransferFunction, ...],
    saturation: float,
    noise_floor: float,
) -> float:
    """Fraction of the darker frame's pixels above the floor whose transfer stays below ``Z``."""
    fractions = []
    lo, hi = _level_range(hd.shape[1], noise_floor, saturation)
    for c, btf in enumerate(btfs):
        total = hd[c].sum()
        if total <= 0:
            continue
        usable = btf.forward[lo:hi] < saturation
        fractions.append(hd[c, lo:hi][usable].sum() / total)
    return float(np.mean(fractions)) if fractions else 0.0


def level_group_size(n_levels: int, max_groups: int) -> int:
    """Levels merged into one group so that at most ``max_groups`` groups remain (>= 1)."""
    return max(1, -(-int(n_levels) // max(int(max_groups), 1)))


def pair_btfs(hd: np.ndarray, hb: np.ndarray) -> tuple[BrightnessTransferFunction, ...]:
    """One brightness transfer function per channel of ``(C, L)`` histograms."""
    return tuple(brightness_transfer_function(hd[c], hb[c]) for c in range(hd.shape[0]))


def estimate_pair(
    hist_dark: np.ndarray,
    hist_bright: np.ndarray,
    options: FitOptions,
    *,
    saturation: float | None = None,
    noise_floor: float | None = None,
    lut: np.ndarray | None = None,
    precision: float = 1e-7,
    max_iterations: int = 100,
    max_relative_error: float = OK_TOLERANCE,
    min_overlap: float = 0.02,
    min_equations: int = 6,
    disagreement_tolerance: float = 0.01,
    max_groups: int = 1024,
    btfs: tuple[BrightnessTransferFunction, ...] | None = None,
    dark: int = 0,
    bright: int = 1,
    refine: Callable[..., float] | None = None,
) -> ExposureRatioResult:
    """Estimate ``k = t_bright / t_dark`` from the histograms of a pair (all channels).

    ``hist_dark``/``hist_bright``: ``(C, max_level + 1)`` or ``(max_level + 1,)``.
    ``max_groups``: at most this many groups of neighbouring levels per channel and direction
    enter the 3V iteration (their sufficient statistics are summed, so the least-squares fit is
    unchanged; 8-bit frames keep one level per group). ``btfs``: the pair's brightness transfer
    functions when already known (they depend on the histograms only; a re-fit reuses them).

    ``max_relative_error``: the largest relative half-width of the calibrated 95 % interval of
    an ``"ok"`` pair (:mod:`.interval`; not the standard error). A pair one of whose frames is
    entirely black or saturated gets status ``"no-signal"`` and no ratio.
    """
    hd, hb = check_histograms(hist_dark, hist_bright)
    n_ch, n = hd.shape
    max_level = n - 1
    z, floor = check_levels(max_level, saturation, noise_floor)
    for which, hist in (("darker", hd), ("brighter", hb)):
        kind = _unusable(hist, z, floor)
        if kind is not None:
            return _no_signal(
                which,
                kind,
                method=options.name,
                n_ch=n_ch,
                saturation=z,
                noise_floor=floor,
                max_level=max_level,
                dark=dark,
                bright=bright,
                tolerance=max_relative_error,
            )
    g = None if lut is None else as_lut(lut, n_ch, max_level)

    if btfs is None or len(btfs) != n_ch:
        btfs = pair_btfs(hd, hb)
    parts = [
        _equations_for_channel(btfs[c], None if g is None else g[c], z, floor, options, c)
        for c in range(n_ch)
    ]
    x, y, w, direction, ch, level = (np.concatenate(p) for p in zip(*parts, strict=True))
    if options.relative_error:
        keep = x > 0
        x, y, w, direction, ch, level = (a[keep] for a in (x, y, w, direction, ch, level))
        w = w / x
    eqs = ExposureEquations(x=x, y=y, weights=w, direction=direction, channel=ch, level=level)
    overlap = _overlap(hd, btfs, z, floor)

    common = dict(
        method=options.name,
        equations=eqs,
        overlap=overlap,
        btfs=btfs,
        saturation=z,
        noise_floor=floor,
        max_level=max_level,
        dark=dark,
        bright=bright,
        non_linear=lut is not None,
        tolerance=max_relative_error,
    )
    if x.size < min_equations or overlap < min_overlap:
        return ExposureRatioResult.unmeasured(
            status="no-overlap",
            message=(
                f"frames {dark} and {bright} do not overlap enough in brightness: "
                f"{overlap:.1%} of the darker frame's pixels lie above the noise floor "
                f"({floor:g}) and stay below saturation ({z:g}) in the brighter frame, "
                f"{x.size} equations; use frames closer in exposure or lower the noise floor"
            ),
            n_channels=n_ch,
            **common,
        )

    # Neighbouring levels of one channel and direction form a group (eq. 4 rows merged).
    f = level_group_size(n, max_groups)
    n_g = -(-n // f)
    lvl = np.clip(np.floor(level).astype(np.int64), 0, n - 1)
    groups = (ch.astype(np.int64) * 2 + direction) * n_g + lvl // f
    n_groups = n_ch * 2 * n_g
    wx, wy = w * x, w * y
    stats = group_statistics(wx, wy, groups, n_groups)
    k, iterates, gmask, iterations, se = solve_3v_groups(
        *stats, precision=precision, max_iterations=max_iterations
    )
    mask = gmask[groups]
    if refine is not None:
        k = refine(eqs, mask, k)
    residuals = wy - k * wx
    group_channel = np.arange(n_groups) // (2 * n_g)
    channel_ratios, channel_se = [], []
    for c in range(n_ch):
        sel = group_channel == c
        if np.count_nonzero(ch == c) >= min_equations:
            kc, _, _, _, sec = solve_3v_groups(
                *(a[sel] for a in stats), precision=precision, max_iterations=max_iterations
            )
        else:
            kc, sec = float("nan"), float("inf")
        channel_ratios.append(kc)
        channel_se.append(sec)
    cr = np.array(channel_ratios)
    cse = np.array(channel_se)
    disagree = channels_disagree(cr, cse, k, disagreement_tolerance)

    n_inliers = int(np.count_nonzero(mask))
    bands = brightness_band_ratios(eqs, mask, ratio_of_sums=False)
    result = ExposureRatioResult(
        ratio=float(k),
        initial_ratio=float(iterates[0]),
        iterates=iterates,
        iterations=iterations,
        inlier_mask=mask,
        residuals=residuals,
        std_error=float(se),
        status="ok",
        message="",
        channel_ratios=tuple(float(v) for v in cr),
        channel_std_errors=tuple(float(v) for v in cse),
        channels_disagree=disagree,
        level_group_size=f,
        band_ratios=bands,
        **common,
    )
    status: RatioStatus
    if not np.isfinite(k) or k <= 0:
        status, message = "failed", f"the fit of frames {dark} and {bright} gave no positive ratio"
    elif n_inliers < min_equations:
        status = "few-equations"
        message = (
            f"only {n_inliers} of {x.size} equations survived the 3V outlier "
            f"removal for frames {dark} and {bright}"
        )
    elif disagree:
        status = "channels-disagree"
        message = (
            "the colour channels give different ratios ("
            + ", ".join(f"{v:.4f}" for v in cr)
            + f") for frames {dark} and {bright}: a wrong white level, a colour cast or "
            "a wrong response"
        )
    else:
        # The interval rule (ok / uncertain); the region jack-knife, when a bracket function
        # adds it, widens the interval and the pair is judged again (interval.judge).
        evidence = (
            f"from a small overlap ({overlap:.1%} of the darker frame's pixels)"
            if overlap < 5 * min_overlap
            else f"from {n_inliers} equations"
        )
        result = replace(result, evidence=evidence)
        status, message = verdict(result, max_relative_error, evidence)
    return replace(result, status=status, message=message)
