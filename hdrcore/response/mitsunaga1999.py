"""Mitsunaga & Nayar (1999) polynomial response with iterated exposure ratios.

T. Mitsunaga, S. K. Nayar, "Radiometric Self Calibration", CVPR 1999, vol. 1, pp. 374-380.
DOI: 10.1109/CVPR.1999.786966

The inverse response is a polynomial ``g(M) = sum_n c_n M^n`` of normalised levels (eq. 4) with
``g(1) = 1`` (eq. 5). For pixel samples of consecutive frames ``q, q+1`` it minimises (eq. 6)

    sum_q sum_p [g(M_{p,q}) - R_q g(M_{p,q+1})]^2,   R_q = t_q / t_{q+1},

solving for the coefficients with ``R`` fixed and then updating ``R`` from the curve (eq. 8,
here the least-squares update of the same objective) until the ratios settle; the rough
initial ratios come from EXIF. Mitsunaga & Nayar choose the order with the smallest error; here
the order is chosen automatically by K-fold cross-validation over the correspondences (the
smallest order within 1 % of the best held-out error), which avoids the over-fitting of high
orders that Cerman & Hlavac (2006, section 4.2) report for an unconstrained 10th-order fit.

Monotonicity, ``g(0) = 0`` and ``g(1) = 1`` are enforced by fitting in the Bernstein basis with
non-negative coefficient increments (:mod:`.monotone`); ``monotone=False`` gives the
unconstrained polynomial of the same order (the seed's comparison).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import EstimationError, ParameterError
from ..status import ResponseStatus
from .curve import ChannelFit, ResponseCurve, normalise_curve
from .monotone import bernstein_cumulative, bernstein_value, fit_bernstein_homogeneous
from .samples import (
    Correspondences,
    check_bracket,
    check_ratios,
    consecutive_ratios,
    pixel_pairs,
    pixel_samples,
    valid_range,
)

__all__ = ["mitsunaga1999", "fit_polynomial_channel", "initial_ratios"]

ORDER_TOLERANCE = 0.01


def initial_ratios(
    exposure_times: Sequence[float] | None,
    ratios: Sequence[float] | None,
    n_frames: int,
    method: str,
) -> tuple[float, ...]:
    """Starting ratios ``t[k+1] / t[k]``: given ratios, else from the exposure times."""
    if ratios is not None:
        return check_ratios(ratios, n_frames)
    r = consecutive_ratios(exposure_times, n_frames, required=False, method=method)
    if r is None:
        raise ParameterError(
            f"{method} needs rough exposure ratios to start from",
            expected="exposure_times (EXIF or --times FILE) or initial_ratios",
            found="none",
        )
    return r


def _cv_score(
    corr: Correspondences,
    ratios: tuple[float, ...],
    order: int,
    monotone: bool,
    folds: np.ndarray,
    n_folds: int,
) -> float:
    err = 0.0
    count = 0
    for f in range(n_folds):
        train, test = folds != f, folds == f
        if not test.any() or train.sum() < order + 1:
            continue
        fit = fit_bernstein_homogeneous(
            corr.dark[train],
            corr.bright[train],
            corr.pair[train],
            corr.weight[train],
            ratios,
            order,
            monotone=monotone,
            refine_ratios=False,
        )
        r = np.asarray(ratios)[corr.pair[test]]
        gd = bernstein_cumulative(corr.dark[test], order) @ fit.increments
        gb = bernstein_cumulative(corr.bright[test], order) @ fit.increments
        res = corr.weight[test] * (gd - gb / r)
        err += float(np.sum(res**2))
        count += int(test.sum())
    return err / max(count, 1)


def fit_polynomial_channel(
    corr: Correspondences,
    max_level: int,
    ratios: tuple[float, ...],
    *,
    domain: float | None = None,
    order: int | str = "auto",
    max_order: int = 10,
    monotone: bool = True,
    refine_ratios: bool = False,
    n_folds: int = 5,
    seed: int = 0,
    channel: int = 0,
) -> tuple[np.ndarray, ChannelFit]:
    """Fit one channel's polynomial inverse response to level correspondences.

    ``corr`` holds levels (not normalised). The polynomial lives on levels ``[0, domain]``
    (default ``max_level``; the saturation cut when data above it are excluded); above
    ``domain`` the curve continues along the secant of its last 5 % (no data constrain a
    polynomial there, and a free high-order end would bias the normalisation ``g(max) = 1``).
    Returns ``g`` at every level (normalised) and the diagnostics.
    """
    top = float(max_level if domain is None else domain)
    if not 0 < top <= max_level:
        raise ParameterError("polynomial domain must be in (0, max_level]", found=str(domain))
    if len(corr) < 3:
        raise EstimationError(
            f"channel {channel}: too few corresponding levels for a polynomial fit",
            expected=">= 3 level pairs inside the valid range",
            found=str(len(corr)),
        )
    norm = Correspondences(
        dark=corr.dark / top,
        bright=corr.bright / top,
        pair=corr.pair,
        weight=corr.weight,
    )
    scores: list[tuple[int, float]] = []
    if isinstance(order, str):
        if order != "auto":
            raise ParameterError("order must be an integer or 'auto'", found=repr(order))
        if max_order < 1:
            raise ParameterError("max_order must be >= 1", found=str(max_order))
        rng = np.random.default_rng(seed + 31 * channel)
        folds = rng.integers(0, n_folds, size=len(norm))
        for n in range(1, max_order + 1):
            scores.append((n, _cv_score(norm, ratios, n, monotone, folds, n_folds)))
        best = min(s for _, s in scores)
        chosen = next(n for n, s in scores if s <= best * (1.0 + ORDER_TOLERANCE))
    else:
        chosen = int(order)
        if chosen < 1:
            raise ParameterError("polynomial order must be >= 1", found=str(order))
    fit = fit_bernstein_homogeneous(
        norm.dark,
        norm.bright,
        norm.pair,
        norm.weight,
        ratios,
        chosen,
        monotone=monotone,
        refine_ratios=refine_ratios,
    )
    levels = np.arange(max_level + 1, dtype=np.float64)
    g = bernstein_value(np.minimum(levels, top) / top, fit.increments)
    if top < max_level:
        x0 = 0.95
        slope = (1.0 - float(bernstein_value(np.array([x0]), fit.increments)[0])) / (
            (1.0 - x0) * top
        )
        above = levels > top
        g[above] = 1.0 + max(slope, 0.0) * (levels[above] - top)
    g = g / g[-1]
    g[0] = 0.0
    steps = int(np.sum(np.diff(g) < 0))
    diag = ChannelFit(
        residual_rms=fit.residual_rms,
        n_constraints=len(norm),
        exposure_ratios=fit.ratios,
        order=chosen,
        active_constraints=fit.active_constraints,
        iterations=fit.iterations,
        order_scores=tuple(scores),
        non_monotone_steps=steps,
    )
    return g, diag


def finish_polynomial(
    method: str,
    curves: list[np.ndarray],
    fits: list[ChannelFit],
    parameters: dict,
) -> ResponseCurve:
    """Assemble the response object; a non-monotone unconstrained fit is flagged, then made
    monotone (running maximum) so that it can still be used."""
    g = np.stack(curves)
    msgs = []
    status: ResponseStatus = "ok"
    bad = [c for c, f in enumerate(fits) if f.non_monotone_steps]
    if bad:
        status = "warning"
        msgs.append(
            f"unconstrained polynomial not monotone in channel(s) {bad}; "
            "clamped with a running maximum"
        )
    if np.any(g[:, 1:-1] < 0) or np.any(g[:, 1:-1] > 1):
        status = "warning"
        msgs.append("polynomial leaves [0, 1] inside the level range")
    g = normalise_curve(np.clip(g, 0.0, None))
    ratios = np.exp(np.mean([np.log(f.exposure_ratios) for f in fits], axis=0))
    return ResponseCurve(
        g=g,
        method=method,
        exposure_ratios=tuple(float(r) for r in ratios),
        channels=tuple(fits),
        status=status,
        message="; ".join(msgs),
        parameters=parameters,
    )


def mitsunaga1999(
    frames: Sequence[np.ndarray],
    exposure_times: Sequence[float] | None = None,
    *,
    ratios: Sequence[float] | None = None,
    max_level: int | None = None,
    order: int | str = "auto",
    max_order: int = 10,
    monotone: bool = True,
    refine_ratios: bool = False,
    cutoff: float = 0.98,
    low_cut: float = 0.0,
    n_samples: int = 1000,
    mask: np.ndarray | None = None,
    seed: int = 0,
) -> ResponseCurve:
    """Recover each channel's polynomial inverse response from pixel samples (MN 1999).

    ``exposure_times`` (or initial consecutive ``ratios``) are the rough starting values; with
    ``refine_ratios`` the ratios are re-estimated per channel and their geometric mean over
    channels is reported in ``exposure_ratios``. ``order`` is an integer or ``"auto"``.
    """
    frames, max_level = check_bracket(frames, max_level)
    start = initial_ratios(exposure_times, ratios, len(frames), "mitsunaga1999")
    lo, hi = valid_range(max_level, cutoff, low_cut)
    curves, fits = [], []
    for c in range(frames[0].shape[2]):
        z = pixel_samples(frames, c, max_level, n_samples=n_samples, mask=mask, seed=seed)
        corr = pixel_pairs(z, lo, hi)
        g, fit = fit_polynomial_channel(
            corr,
            max_level,
            start,
            domain=hi,
            order=order,
            max_order=max_order,
            monotone=monotone,
            refine_ratios=refine_ratios,
            seed=seed,
            channel=c,
        )
        curves.append(g)
        fits.append(fit)
    return finish_polynomial(
        "mitsunaga1999",
        curves,
        fits,
        {
            "order": order,
            "max_order": max_order,
            "monotone": monotone,
            "refine_ratios": refine_ratios,
            "cutoff": cutoff,
            "low_cut": low_cut,
            "n_samples": n_samples,
            "seed": seed,
            "initial_ratios": list(start),
        },
    )
