"""Relative exposure times of a bracket from pairwise ratios (Cerman & Hlavac 2006, section 5).

The seed chains the consecutive ratios: ``e_0 = 1``, ``e_{j+1} = e_j k_{j,j+1}``. Going beyond
it, pairs of non-consecutive frames that still overlap in brightness are estimated too, and the
relative exposures are the weighted least-squares solution in log exposure of all usable pairs,
``log e_j - log e_i = log k_ij``. With consecutive pairs only this is exactly the chain; with more
pairs an error in one pair shows up as a residual (``chain_residuals_stops``), and a consecutive
pair that disagrees with the others is marked ``"inconsistent"``.

The bracket estimate works on cached histograms (:class:`BracketHistograms`): changing only the
saturation level or the noise floor re-fits without touching the images, and without recomputing
the brightness transfer functions (cached per pair). Every pair also gets the region jack-knife of
:mod:`.stability`; a pair whose regions disagree is marked ``"unstable"``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from ..errors import ParameterError
from ..status import ChainStatus
from .interval import judge
from .pair_histograms import BracketHistograms, PairHistograms, bracket_histograms
from .result import BracketExposureResult, ExposureRatioResult
from .stability import region_jackknife

__all__ = [
    "BracketHistograms",
    "bracket_histograms",
    "solve_chain",
    "chain_bracket",
    "assemble_bracket",
]


def solve_chain(
    n: int,
    pairs: Sequence[ExposureRatioResult],
    *,
    min_relative_error: float = 2e-4,
    non_consecutive_weight: float = 0.01,
) -> tuple[np.ndarray, dict[tuple[int, int], float]]:
    """Relative exposures (frame 0 = 1) from pair ratios by weighted least squares in log2.

    Pairs with a non-finite ratio are skipped; ok pairs weigh ``1 / max(rel. error, floor)``,
    others ten times less, non-consecutive pairs ``non_consecutive_weight`` times less again.
    Frames not connected to frame 0 get ``nan``.
    Returns the exposures and, per pair used, ``log2(k_ij / (e_j / e_i))``.
    """
    rows, rhs, wts, used = [], [], [], []
    for p in pairs:
        if not (np.isfinite(p.ratio) and p.ratio > 0):
            continue
        se = p.honest_std_error
        rel = max(se / p.ratio if np.isfinite(se) else 1.0, min_relative_error)
        w = 1.0 / rel if p.ok else 0.1 / rel
        if p.bright - p.dark > 1:
            # Non-consecutive pairs overlap less and their errors are correlated with the
            # consecutive ones: they bridge gaps and reveal loops, they do not pull the chain.
            w *= non_consecutive_weight
        row = np.zeros(n)
        row[p.bright] += 1.0
        row[p.dark] -= 1.0
        rows.append(row)
        rhs.append(np.log2(p.ratio))
        wts.append(w)
        used.append((p.dark, p.bright))
    log_e = np.full(n, np.nan)
    log_e[0] = 0.0
    if not rows:
        return np.where(np.arange(n) == 0, 1.0, np.nan), {}
    a = np.array(rows)
    b = np.array(rhs)
    wv = np.array(wts)
    # Connectivity to frame 0 (union-find over the used pairs).
    parent = list(range(n))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, j in used:
        parent[find(i)] = find(j)
    connected = np.array([find(i) == find(0) for i in range(n)])
    cols = np.flatnonzero(connected)[1:]
    keep_rows = np.array([connected[i] and connected[j] for i, j in used])
    if cols.size:
        sol, *_ = np.linalg.lstsq(
            a[keep_rows][:, cols] * wv[keep_rows, None], b[keep_rows] * wv[keep_rows], rcond=None
        )
        log_e[cols] = sol
    residuals = {}
    for (i, j), bi in zip(used, b, strict=True):
        if connected[i] and connected[j]:
            residuals[(i, j)] = float(bi - (log_e[j] - log_e[i]))
    return np.exp2(log_e), residuals


_REGION_OVERRIDES = ("ok", "channels-disagree", "uncertain")


def _with_diagnostics(
    r: ExposureRatioResult,
    ph: PairHistograms,
    *,
    lut: np.ndarray | None,
    jackknife: bool,
    max_region_error: float,
    jackknife_groups: int,
) -> ExposureRatioResult:
    """Add the overlap restriction and the region jack-knife to a pair's result."""
    changes: dict = {}
    sk = ph.jackknife_skeleton(jackknife_groups) if jackknife and np.isfinite(r.ratio) else None
    if sk is not None:
        ks, se = region_jackknife(sk, saturation=r.saturation, noise_floor=r.noise_floor, lut=lut)
        # The calibrated interval rests on the jack-knife: ok / uncertain decided again on it.
        judged = judge(replace(r, region_ratios=tuple(float(v) for v in ks), region_std_error=se))
        changes.update(
            region_ratios=judged.region_ratios,
            region_std_error=se,
            status=judged.status,
            message=judged.message,
        )
        r = judged
        rel = se / r.ratio if r.ratio > 0 else float("inf")
        # Motion explains disagreeing channels and a poor fit too, and the remedy differs:
        # "unstable" takes precedence over those, not over a missing overlap or a failed fit.
        if r.status in _REGION_OVERRIDES and np.isfinite(rel) and rel > max_region_error:
            changes["status"] = "unstable"
            if ph.overlap_restricted:
                hint = (
                    "even within the common field of view: a moving object, a poor "
                    "registration or a scene change"
                )
            else:
                hint = (
                    "content entering or leaving at the borders (hand-held motion) or a "
                    "moving object disturbs the histograms; register the frames first and "
                    "measure from the registered pixels ('hdrcore ratios --registered', "
                    "hdrcore.exposure.registered)"
                )
            changes["message"] = (
                f"ratio {r.ratio:.4f} of frames {r.dark} and {r.bright} is unstable: leaving out "
                f"one of {sk.n_regions} image regions moves it by {rel:.2%} (jack-knife standard "
                f"error, over {max_region_error:.2%}); {hint}"
                + ("" if r.ok else f" (the fit alone reported: {r.status})")
            )
    if ph.overlap_restricted:
        changes.update(overlap_restricted=True, common_fraction=ph.common_fraction)
        if np.isfinite(r.ratio):
            changes["message"] = (
                f"{changes.get('message', r.message)}; histograms restricted "
                f"to the common field of view ({ph.common_fraction:.1%} of "
                "the bright frame)"
            )
    return replace(r, **changes) if changes else r


def chain_bracket(
    hists: BracketHistograms,
    estimate: Callable[..., ExposureRatioResult],
    *,
    method: str,
    exposure_times: Sequence[float | None] | None = None,
    non_consecutive: bool = True,
    max_span: int = 3,
    consistency_stops: float = 0.02,
    jackknife: bool = True,
    max_region_error: float = 0.005,
    jackknife_groups: int = 256,
    **kwargs: Any,
) -> BracketExposureResult:
    """Estimate every consecutive pair (and overlapping non-consecutive ones), then chain.

    ``jackknife`` runs the region jack-knife on every pair (when region histograms were
    counted); a pair whose jack-knife standard error exceeds ``max_region_error`` (relative) is
    marked ``"unstable"``.
    """
    n = hists.n_frames
    lut = kwargs.get("lut")
    diag: dict[str, Any] = dict(
        lut=lut,
        jackknife=jackknife,
        max_region_error=max_region_error,
        jackknife_groups=jackknife_groups,
    )

    def one(i: int, j: int) -> ExposureRatioResult:
        ph = hists.pair(i, j)
        r = estimate(ph.counts_dark, ph.counts_bright, dark=i, bright=j, btfs=ph.btfs(), **kwargs)
        return _with_diagnostics(r, ph, **diag)

    pairs = [one(i, i + 1) for i in range(n - 1)]
    extra = []
    if non_consecutive:
        for span in range(2, min(max_span, n - 1) + 1):
            for i in range(n - span):
                r = one(i, i + span)
                if r.status not in ("no-overlap", "no-signal"):
                    extra.append(r)
    message_suffix = (
        "; histograms restricted to each pair's common field of view"
        if hists.overlap_restricted
        else ""
    )
    return assemble_bracket(
        n,
        pairs,
        extra,
        method=method,
        exposure_times=exposure_times,
        max_level=hists.max_level,
        consistency_stops=consistency_stops,
        message_suffix=message_suffix,
    )


def assemble_bracket(
    n: int,
    pairs: Sequence[ExposureRatioResult],
    extra: Sequence[ExposureRatioResult],
    *,
    method: str,
    max_level: int,
    exposure_times: Sequence[float | None] | None = None,
    consistency_stops: float = 0.02,
    message_suffix: str = "",
) -> BracketExposureResult:
    """The bracket result from its consecutive ``pairs`` and estimated ``extra`` pairs.

    Solves the chain (:func:`solve_chain`), marks consecutive pairs that a closed loop
    contradicts ``"inconsistent"`` and puts the EXIF ratios beside the estimates. Shared by the
    histogram estimators (:func:`chain_bracket`) and the registered-pixel estimator
    (:mod:`.registered`).
    """
    pairs = list(pairs)
    extra = list(extra)
    exposures, residuals = solve_chain(n, pairs + extra)
    chained = [1.0]
    for p in pairs:
        chained.append(chained[-1] * p.ratio if np.isfinite(p.ratio) else float("nan"))

    # Mark consecutive pairs that a closed loop contradicts: a non-consecutive pair (i, j) whose
    # ratio differs from the chain over i..j by more than ``consistency_stops``.
    broken_loops = [
        e for e in extra if e.ok and abs(residuals.get((e.dark, e.bright), 0.0)) > consistency_stops
    ]
    checked = []
    for p in pairs:
        loops = [e for e in broken_loops if e.dark <= p.dark and e.bright >= p.bright]
        if p.ok and loops:
            worst = max(loops, key=lambda e: abs(residuals[(e.dark, e.bright)]))
            res = residuals[(worst.dark, worst.bright)]
            p = replace(
                p,
                status="inconsistent",
                message=(
                    f"ratio {p.ratio:.4f} of frames {p.dark} and {p.bright}: the direct estimate "
                    "of "
                    f"frames {worst.dark} and {worst.bright} differs from the chain by {res:+.3f} "
                    "stops; a histogram is disturbed (motion at the borders, a moving object, a "
                    "wrong response)"
                ),
            )
        checked.append(p)
    pairs = checked

    if exposure_times is None:
        times: tuple[float | None, ...] = (None,) * n
    else:
        if len(exposure_times) != n:
            raise ParameterError(
                "one exposure time per frame", expected=str(n), found=str(len(exposure_times))
            )
        times = tuple(None if t is None else float(t) for t in exposure_times)
    exif_ratios: list[float | None] = []
    mismatch: list[float | None] = []
    for p in pairs:
        ti, tj = times[p.dark], times[p.bright]
        if ti and tj and ti > 0 and tj > 0:
            er = tj / ti
            exif_ratios.append(er)
            mismatch.append(float(np.log2(p.ratio / er)) if np.isfinite(p.ratio) else None)
        else:
            exif_ratios.append(None)
            mismatch.append(None)

    bad = [p for p in pairs if not p.ok]
    status: ChainStatus
    if np.any(~np.isfinite(exposures)):
        status = "broken-chain"
        message = "the chain of exposures is broken: " + "; ".join(
            p.message for p in bad if p.status in ("no-overlap", "no-signal")
        )
    elif bad:
        status = "not-ok"
        message = f"{len(bad)} of {len(pairs)} pairs are not ok: " + "; ".join(
            f"{p.dark}-{p.bright} {p.status}" for p in bad
        )
    else:
        status = "ok"
        message = f"{n} frames, {len(pairs)} consecutive and {len(extra)} further pairs, all ok"
    message += message_suffix
    first = pairs[0]
    return BracketExposureResult(
        relative_exposures=tuple(float(v) for v in exposures),
        chained_exposures=tuple(float(v) for v in chained),
        pairs=tuple(pairs),
        extra_pairs=tuple(extra),
        exif_times=times,
        exif_ratios=tuple(exif_ratios),
        mismatch_stops=tuple(mismatch),
        chain_residuals_stops=residuals,
        status=status,
        message=message,
        method=method,
        saturation=first.saturation,
        noise_floor=first.noise_floor,
        max_level=max_level,
    )
