"""The calibrated 95 % interval of an exposure ratio, and the rule that makes a pair ``"ok"``.

Beyond Cerman & Hlavac (2006): the paper reports a ratio without an error. A pair's interval is
built in log ratio from three measured pieces,

    h = sqrt( (z c s)^2 + b^2 + f^2 ),    interval = (k e^-h, k e^h),

* ``s`` the honest relative standard error of ``k``: the region jack-knife's
  (``region_std_error``, :mod:`.stability` and :mod:`.registered`) wherever it was computed,
  else the weighted fit's times :data:`FIT_ONLY_FACTOR`;
* ``c`` the calibration factor of the estimator (:data:`CALIBRATION`, ``z`` = 1.96);
* ``b`` the spread of the ratio across brightness (:func:`brightness_band_ratios`: the standard
  deviation of ``log k`` fitted on four bands of the pair's equations ordered by their dark
  value). A wrong response or linearisation makes ``k`` depend on brightness; the regions of the
  jack-knife all see every brightness and cannot show it;
* ``f`` a floor for the model error that neither can see (:data:`MODEL_ERROR_PER_STOP`,
  proportional to the stops between the frames): the response of non-linear input (a recovered
  response, JPEG, 8-bit scans) is never exact.

A pair is ``"ok"`` when ``h`` is at most the tolerance :data:`OK_TOLERANCE` (0.8 %),
``"uncertain"`` otherwise (:func:`judge`); the other statuses (no-overlap, no-signal,
channels-disagree, unstable, ...) say what else is wrong and are left alone. The tolerance keeps
the errors of ok pairs under 1 % with margin: 1 % is 2.45 standard errors of an ok pair at the
limit, and most ok pairs are far inside it.

Measured by ``python bench/bench_coverage.py`` (``--dump`` writes the fields per pair to
re-calibrate). Simulated: the seed's protocol, 6 frames 1..1024 s (x4), linear camera, sigma 1
level, 256x384, four scenes x 6 seeds, 8 (PNG: the pipeline recovers a response), 12 and 14
bits (DNG), tripod and hand-held (shift <= 20 px, rotation <= 1 deg); the library's histogram
estimate and the pipeline's estimates before and after registration.

* The fit's standard error of eq. 4 is far too small: the jack-knife's is 12-41 times larger on
  simulated tripod pairs (median 22; neighbouring equations come from neighbouring quantiles of
  the same histograms) and up to thousands of times under motion, so no factor on it covers
  (x 20: 20-78 %, x 100: 61-88 % of the simulated pairs, by group). The jack-knife is the
  honest error. A pair estimated without one (a single pair from its histograms) uses the
  fit's error x 25 (:data:`FIT_ONLY_FACTOR`, about the median ratio on tripod pairs); that
  interval is not calibrated and cannot see motion.
* ``c``: 1.3 for the registered pixels (their jack-knife has 15 degrees of freedom and tiles
  that share content) and 1.2 for the histograms: with the bands and floors below, 96-99 % of
  the simulated RAW pixel pairs and 94-100 % of the consecutive histogram pairs are covered,
  group by group.
  1.0 for the histograms let a memorial pair 1.06 % off be ok.
* ``b`` catches a wrong linearisation: linear frames read through the sRGB curve give band
  ratios 12.1-15.3 around 14.0 (truth 4), ``h`` 12.6 %; a response wrong only in its exponent
  (``g^(1+e)``) scales every ratio to ``k^(1+e)`` at every brightness and is not seen by it.
* ``f`` = 0.2 % per stop for non-linear input (:data:`MODEL_ERROR_PER_STOP`), from the real
  Canon JPEG bracket (frobisher, times 1/8, 1, 8 s: powers of two): the registered pixels are
  0.47 and 0.56 % off on its 3-stop pairs (0.16-0.19 %/stop) with jack-knife errors of 0.05 and
  0.23 %; simulated 8-bit frames through a recovered response need 0.05 %/stop. 0.05 % per stop
  for linear levels seen by the histograms (simulated only: demosaiced DNG frames and the noise
  of low levels bias x16 and x64 pairs by up to 1.3 %), none for the registered pixels of
  linear levels (the CFA sites of RAW; simulated only: covered without it).

Results with these constants (``bench_coverage.py``, full run; "ok" coverage = fraction of the
ok pairs whose interval holds the truth):

* simulated, consecutive pairs (x4): 2222 measured, 1372 ok, coverage 98.3 % (histograms
  98.3, pipeline histograms 97.2, registered pixels 98.8), median error of ok pairs 0.016 %
  (8 bits 0.042 %, 12 bits 0.007 %, 14 bits 0.003 %), maximum 0.62 %, none over 1 %;
* simulated, non-consecutive pairs (x16, x64): 944 ok, coverage 93.1 %, maximum 1.34 %, 7
  over 1 %: the histograms' x16 pairs at 8 bits (coverage 56 %, the noise bias of dark levels
  5-15, which noise matching only halves) and the pipeline's histograms of 12-bit DNG frames
  (coverage 75 %); the registered pixels 97.6 %, maximum 0.84 %;
* left out of both: the pipeline's registered pixels of 8-bit hand-held brackets, whose response
  was recovered from the frames before registration: that response is off, every ratio through
  it too (34 of 118 pairs ok, coverage 21 %, up to 5.8 % off). With the true response the same
  estimator's ok pairs are covered 98.3 %, maximum 0.62 %. The response must be recovered after
  registration; no interval of one pair can see an exponent error of the response.
* real (only 2 of 98 measured pairs are ok, both covered: frobisher 1/8-1 s 0.47 % off,
  interval +-0.65 %; Xperia 1-2 0.02 % off, +-0.76 %). Coverage of all measured pairs:
  Pixel 7 100 % (24 pairs; intervals +-4-28 %: a noisy, dark, hand-held JPEG bracket), frobisher
  83 % (its x64 pair is 2.9 % off, channels-disagree), memorial 75 % (film scans; the nominal
  film shutter times are themselves uncertain by percents), Xperia 11 % (an auto-exposure
  phone: its time x ISO is off by up to 12 % on pairs the two estimators agree on to 0.3 %; no
  pair far off is ok).

"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from ..status import RatioStatus

if TYPE_CHECKING:
    from .result import ExposureEquations, ExposureRatioResult

__all__ = [
    "Z95",
    "CALIBRATION",
    "FIT_ONLY_FACTOR",
    "MODEL_ERROR_PER_STOP",
    "OK_TOLERANCE",
    "N_BANDS",
    "JUDGED",
    "calibration_factor",
    "model_error_floor",
    "brightness_band_ratios",
    "band_spread",
    "interval_std_error",
    "ci95_relative",
    "interval",
    "judge",
]

Z95 = 1.959963984540054
"""Two-sided 95 % quantile of the normal distribution."""

CALIBRATION: dict[str, float] = {"registered pixels": 1.3, "histograms": 1.2}
"""Factor on the honest standard error per estimator family (see the module docstring)."""

FIT_ONLY_FACTOR = 25.0
"""Factor on the fit's standard error when no jack-knife was computed (not calibrated)."""

MODEL_ERROR_PER_STOP: dict[str, float] = {
    "non-linear": 0.002,
    "linear histograms": 0.0005,
    "linear pixels": 0.0,
}
"""Floor ``f`` of the relative half-width for model error per stop of the pair's ratio
(``f = e |log2 k|``), by kind of input: non-linear levels (a linearisation table), linear levels
seen by the histograms (demosaiced RAW, the noise of low levels), linear levels compared pixel by
pixel (the CFA sites of RAW)."""

OK_TOLERANCE = 0.008
"""Largest relative half-width ``h`` of the 95 % interval of an ``"ok"`` pair."""

N_BANDS = 4
"""Brightness bands of :func:`brightness_band_ratios`."""

JUDGED: tuple[RatioStatus, ...] = ("ok", "uncertain")
"""The statuses :func:`judge` decides between; every other status is kept as it is."""

_PIXELS = "registered pixels"


def calibration_factor(method: str) -> float:
    """``c`` of an estimator: the registered pixels' or the histograms' (every other method)."""
    return CALIBRATION[_PIXELS] if method == _PIXELS else CALIBRATION["histograms"]


def model_error_floor(ratio: float, *, non_linear: bool, method: str) -> float:
    """``f = e |log2 k|``: the model-error floor of a pair of ratio ``k`` for non-linear input
    (a linearisation table was used) or linear input, by estimator (0 for a non-finite ratio).

    A linearisation whose log slope is off by ``e`` makes every ratio off by ``e ln k``: the
    error grows with the stops between the frames, and a doubled exposure (``k = 1``) has none.
    """
    if not (np.isfinite(ratio) and ratio > 0):
        return 0.0
    if non_linear:
        kind = "non-linear"
    else:
        kind = "linear pixels" if method == _PIXELS else "linear histograms"
    return float(MODEL_ERROR_PER_STOP[kind] * abs(np.log2(ratio)))


def brightness_band_ratios(
    equations: ExposureEquations,
    inlier_mask: np.ndarray,
    *,
    ratio_of_sums: bool,
    n_bands: int = N_BANDS,
) -> tuple[float, ...]:
    """The ratio fitted on each of ``n_bands`` bands of the inlier equations, darkest first.

    Bands split the equations at quantiles of ``log x`` (the linear dark value) weighted by each
    equation's information, so that each band carries about the same weight. ``ratio_of_sums``:
    the registered pixels' estimator (``sum y / sum x`` per direction, weight ``w^2`` the pixel
    count, geometric mean of the two directions); otherwise the weighted least squares of eq. 4
    (``sum w^2 x y / sum w^2 x^2``). Empty when there are too few equations.
    """
    x = np.asarray(equations.x, np.float64)
    y = np.asarray(equations.y, np.float64)
    w2 = np.asarray(equations.weights, np.float64) ** 2
    m = np.asarray(inlier_mask, bool) & (x > 0) & (y > 0) & np.isfinite(x) & np.isfinite(y)
    if np.count_nonzero(m) < 2 * n_bands:
        return ()
    x, y, w2, d = x[m], y[m], w2[m], np.asarray(equations.direction)[m]
    info = w2 if ratio_of_sums else w2 * x * x
    lx = np.log(x)
    order = np.argsort(lx, kind="stable")
    cum = np.cumsum(info[order])
    if not cum[-1] > 0:
        return ()
    edges = np.interp(np.arange(1, n_bands) / n_bands, cum / cum[-1], lx[order])
    band = np.searchsorted(edges, lx)
    out = []
    for j in range(n_bands):
        s = band == j
        if ratio_of_sums:
            ks = []
            for direction in (0, 1):
                sd = s & (d == direction)
                den = float(np.dot(w2[sd], x[sd]))
                ks.append(float(np.dot(w2[sd], y[sd])) / den if den > 0 else float("nan"))
            kb = float(np.sqrt(ks[0] * ks[1])) if ks[0] > 0 and ks[1] > 0 else float("nan")
        else:
            den = float(info[s].sum())
            kb = float(np.dot(w2[s] * x[s], y[s]) / den) if den > 0 else float("nan")
        out.append(kb)
    return tuple(out)


def band_spread(band_ratios: tuple[float, ...] | np.ndarray) -> float:
    """``b``: standard deviation of ``log k`` over the bands with a positive ratio (0 for
    fewer than two)."""
    kb = np.asarray(band_ratios, np.float64)
    kb = kb[np.isfinite(kb) & (kb > 0)]
    if kb.size < 2:
        return 0.0
    return float(np.std(np.log(kb), ddof=1))


def interval_std_error(std_error: float, region_std_error: float) -> tuple[float, str]:
    """``(s, basis)``: the standard error the interval rests on (absolute, as ``std_error``)
    and what it is, ``"jack-knife"`` or ``"fit"`` (the fit's error times
    :data:`FIT_ONLY_FACTOR`, when no jack-knife was computed)."""
    if np.isfinite(region_std_error):
        return float(
            max(region_std_error, std_error if np.isfinite(std_error) else 0.0)
        ), "jack-knife"
    return float(FIT_ONLY_FACTOR * std_error), "fit"


def ci95_relative(
    ratio: float,
    std_error: float,
    region_std_error: float,
    *,
    method: str,
    band_ratios: tuple[float, ...] = (),
    model_error: float = 0.0,
) -> float:
    """``h``, the relative half-width of the 95 % interval (in log ratio; ``inf`` when the ratio
    or its error is not finite)."""
    if not (np.isfinite(ratio) and ratio > 0):
        return float("inf")
    s, _ = interval_std_error(std_error, region_std_error)
    if not np.isfinite(s):
        return float("inf")
    zcs = Z95 * calibration_factor(method) * s / ratio
    return float(np.sqrt(zcs * zcs + band_spread(band_ratios) ** 2 + model_error**2))


def interval(ratio: float, half: float) -> tuple[float, float]:
    """``(k e^-h, k e^h)``; ``(nan, nan)`` when either is not finite."""
    if not (np.isfinite(ratio) and np.isfinite(half)):
        return float("nan"), float("nan")
    return float(ratio * np.exp(-half)), float(ratio * np.exp(half))


def _fmt_interval(lo: float, hi: float) -> str:
    """``"3.968-4.014"``: enough decimals to show the width to two figures (at least two)."""
    decimals = max(2, 1 - int(np.floor(np.log10(max(hi - lo, 1e-9)))))
    return f"{lo:.{decimals}f}-{hi:.{decimals}f}"


def verdict(
    result: ExposureRatioResult, tolerance: float, evidence: str
) -> tuple[RatioStatus, str]:
    """``(status, message)`` of a pair that passed every other check: ``"ok"`` when its
    interval's relative half-width is at most ``tolerance``, else ``"uncertain"`` with what
    widens it most."""
    k = result.ratio
    h = result.ci95_relative
    lo, hi = result.interval
    span = _fmt_interval(lo, hi)
    if np.isfinite(h) and h <= tolerance:
        tail = f" {evidence}" if evidence else ""
        return "ok", f"ratio {k:.4f} (95 % interval {span}, ±{h:.2%}){tail}"
    s, basis = interval_std_error(result.std_error, result.region_std_error)
    parts = {
        "error": Z95 * calibration_factor(result.method) * s / k if k > 0 else float("inf"),
        "bands": band_spread(result.band_ratios),
        "floor": result.model_error,
    }
    worst = max(parts, key=lambda p: parts[p] if np.isfinite(parts[p]) else float("inf"))
    if worst == "bands":
        why = (
            f"the ratio changes with brightness (±{parts['bands']:.2%} across "
            f"{len(result.band_ratios)} brightness bands): a wrong response or linearisation"
        )
    elif worst == "floor":
        why = (
            f"the model-error floor of non-linear input (±{parts['floor']:.2%}) leaves no "
            "room for its measurement error"
        )
    elif basis == "jack-knife":
        why = (
            f"leaving out one image region moves the ratio by {s / k:.2%} (jack-knife): the "
            "frames do not match well everywhere (a moving object, a poor registration, "
            "noise or a wrong response)"
        )
    else:
        why = (
            f"the fit's standard error ({result.std_error / k:.3%}) x {FIT_ONLY_FACTOR:g}; no "
            "region jack-knife was computed"
        )
    if not np.isfinite(h):
        return "uncertain", (
            f"ratio {k:.4f} of frames {result.dark} and {result.bright} has no finite error"
        )
    return "uncertain", (
        f"ratio {k:.4f} of frames {result.dark} and {result.bright}: 95 % "
        f"interval {span} (±{h:.2%}) is wider than the ±{tolerance:.2%} an ok "
        f"pair may have; {why}"
    )


def judge(result: ExposureRatioResult, tolerance: float | None = None) -> ExposureRatioResult:
    """The result with status ``"ok"`` or ``"uncertain"`` decided again from its interval.

    Call it after a change of the fields the interval rests on (e.g. once the region
    jack-knife was added). Results with any other status are returned unchanged; ``tolerance``
    defaults to the one the result was estimated with.
    """
    if result.status not in JUDGED:
        return result
    tol = result.tolerance if tolerance is None else float(tolerance)
    status, message = verdict(result, tol, result.evidence)
    if status == result.status and message == result.message and tol == result.tolerance:
        return result
    return replace(result, status=status, message=message, tolerance=tol)
