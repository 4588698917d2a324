"""Result objects of the exposure stage: one pair, and a whole bracket.

They carry the estimate and everything the browser inspector draws (the equations of eq. 4 with
their weights and directions, the 3V inlier mask, every iterate) so nothing is recomputed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from ..btf import BrightnessTransferFunction
from ..status import ChainStatus, RatioStatus
from . import interval as _interval

__all__ = [
    "ExposureEquations",
    "ExposureRatioResult",
    "BracketExposureResult",
    "PairKey",
    "FORWARD",
    "INVERSE",
    "LEVEL_CLASSES",
    "UNUSED",
    "INLIER",
    "OUTLIER",
    "UNDER",
    "SATURATED",
]

PairKey = tuple[int, int]

FORWARD = 0
"""Direction code of an equation made from a dark level ``M_A`` and ``T(M_A)``."""
INVERSE = 1
"""Direction code of an equation made from a bright level ``M_B`` and ``T^-1(M_B)``."""

# Classes of a frame's levels (:meth:`ExposureRatioResult.level_classes`).
UNUSED, INLIER, OUTLIER, UNDER, SATURATED = 0, 1, 2, 3, 4
LEVEL_CLASSES = ("not used", "inlier", "outlier (3V)", "under noise floor", "saturated (≥ Z)")
"""What each class code means, by code."""


def _finite_or_none(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


@dataclass(frozen=True, eq=False)
class ExposureEquations:
    """The equations ``k * x = y`` of system S0 (Cerman & Hlavac 2006, eq. 4), one per row.

    ``x`` is the linearised dark value, ``y`` the linearised bright value, ``weights`` the
    square-root weights multiplying each equation, ``direction`` :data:`FORWARD` (from a dark level
    through ``T``) or :data:`INVERSE` (from a bright level through ``T^-1``), ``channel`` the colour
    channel, ``level`` the (continuous) level in the frame the equation came from.
    """

    x: np.ndarray
    y: np.ndarray
    weights: np.ndarray
    direction: np.ndarray
    channel: np.ndarray
    level: np.ndarray

    def __len__(self) -> int:
        return int(self.x.size)


@dataclass(frozen=True, eq=False)
class ExposureRatioResult:
    """Exposure ratio ``k = t_bright / t_dark`` of one pair with its diagnostics.

    ``ratio`` is the final estimate from all channels together; ``initial_ratio`` the solution of
    S0 before outlier removal (``k0``); ``iterates`` every value of the 3V iteration starting with
    ``k0``. ``inlier_mask`` and ``residuals`` (weighted, ``w * (y - k x)``) run over
    ``equations``. ``std_error`` is the standard error of ``ratio`` from the weighted fit,
    ``overlap`` the fraction of the darker frame's pixels whose levels enter the equations.
    ``status`` is ``"ok"`` or a short word (``"no-overlap"``, ``"no-signal"``, ``"uncertain"``,
    ``"channels-disagree"``, ``"few-equations"``); ``message`` says what it means.
    ``channel_ratios`` are the same fit per colour channel; ``channels_disagree`` flags a
    spread larger than their errors allow (a white-level or colour-cast problem).

    Beyond the paper: ``level_group_size`` neighbouring levels form one group in the 3V test
    (1 at 8 bits). ``region_ratios`` are the jack-knife estimates with one image region left out
    each and ``region_std_error`` their jack-knife standard error: an honest error (the fit's
    ``std_error`` ignores that neighbouring equations are correlated) that also grows when
    content entering or leaving at the borders (hand-held motion) disturbs the histograms;
    status ``"unstable"`` marks a pair whose regions disagree. ``overlap_restricted`` says the
    histograms were counted over the common field of view of the pair only (after
    registration), ``common_fraction`` the fraction of the bright frame's pixels kept.

    The calibrated 95 % interval (:mod:`.interval`): :attr:`interval` and
    :attr:`ci95_relative` (its relative half-width) follow from ``std_error``,
    ``region_std_error``, ``band_ratios`` (the ratio fitted on bands of the equations ordered by
    brightness, darkest first), :attr:`model_error` (the floor for model error, larger when
    ``non_linear``: the levels were linearised through a response table) and the estimator's
    calibration, so they stay right when a field is replaced (e.g. the
    jack-knife added). A pair is ``"ok"`` when ``ci95_relative <= tolerance`` and no other
    check failed, ``"uncertain"`` when only the interval is too wide
    (:func:`~hdrcore.exposure.interval.judge` decides again after a change); ``evidence`` says
    what the estimate rests on (the end of an ok pair's message).
    """

    method: str
    ratio: float
    initial_ratio: float
    iterates: tuple[float, ...]
    iterations: int
    equations: ExposureEquations
    inlier_mask: np.ndarray
    residuals: np.ndarray
    std_error: float
    overlap: float
    status: RatioStatus
    message: str
    channel_ratios: tuple[float, ...]
    channel_std_errors: tuple[float, ...]
    channels_disagree: bool
    saturation: float
    noise_floor: float
    max_level: int
    btfs: tuple[BrightnessTransferFunction, ...] = field(default=(), repr=False)
    dark: int = 0
    bright: int = 1
    level_group_size: int = 1
    region_ratios: tuple[float, ...] = ()
    region_std_error: float = float("nan")
    overlap_restricted: bool = False
    common_fraction: float = 1.0
    band_ratios: tuple[float, ...] = ()
    non_linear: bool = False
    tolerance: float = _interval.OK_TOLERANCE
    evidence: str = ""
    response_error_per_stop: float = 0.0

    @classmethod
    def unmeasured(
        cls,
        *,
        status: RatioStatus,
        message: str,
        n_channels: int,
        equations: ExposureEquations | None = None,
        overlap: float = 0.0,
        **fields: Any,
    ) -> ExposureRatioResult:
        """A pair whose ratio could not be measured (no overlap, no signal, not registered):
        ratio ``nan``, infinite errors, no inliers; ``fields`` fill the rest (``method``,
        ``saturation``, ``noise_floor``, ``max_level``, ``dark``, ``bright``, ...)."""
        if equations is None:
            empty = np.zeros(0)
            equations = ExposureEquations(
                x=empty,
                y=empty,
                weights=empty,
                direction=empty.astype(np.int8),
                channel=empty.astype(np.int8),
                level=empty,
            )
        n = len(equations)
        return cls(
            ratio=float("nan"),
            initial_ratio=float("nan"),
            iterates=(),
            iterations=0,
            equations=equations,
            inlier_mask=np.zeros(n, bool),
            residuals=np.zeros(n),
            std_error=float("inf"),
            overlap=overlap,
            status=status,
            message=message,
            channel_ratios=(float("nan"),) * n_channels,
            channel_std_errors=(float("inf"),) * n_channels,
            channels_disagree=False,
            **fields,
        )

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def level_classes(self, which: Literal["dark", "bright"]) -> np.ndarray:
        """``(C, max_level + 1)`` int8 class of every level of the pair's dark or bright frame:
        :data:`INLIER` / :data:`OUTLIER` where an equation of that frame's direction (eq. 4,
        :data:`FORWARD` from the dark frame, :data:`INVERSE` from the bright one) starts at that
        level and was kept / dropped by the 3V rule, :data:`UNDER` at or below the noise floor,
        :data:`SATURATED` at or above ``Z`` (whatever equation ends there), else
        :data:`UNUSED`."""
        direction = FORWARD if which == "dark" else INVERSE
        eq = self.equations
        n_ch = len(self.btfs) if self.btfs else int(np.max(eq.channel, initial=0)) + 1
        n = int(self.max_level) + 1
        levels = np.arange(n)
        table = np.full((n_ch, n), UNUSED, np.int8)
        sel = np.asarray(eq.direction) == direction
        idx = np.clip(np.floor(np.asarray(eq.level)[sel]).astype(np.int64), 0, n - 1)
        ch = np.asarray(eq.channel)[sel].astype(np.int64)
        inl = np.asarray(self.inlier_mask, bool)[sel]
        table[ch, idx] = np.where(inl, INLIER, OUTLIER)
        table[:, levels <= self.noise_floor] = UNDER
        table[:, levels >= self.saturation] = SATURATED
        return table

    @property
    def model_error(self) -> float:
        """The model-error floor ``f`` of the interval (relative; grows with the stops): the
        estimator's (:func:`~hdrcore.exposure.interval.model_error_floor`), or
        ``response_error_per_stop`` per stop when the caller knows the linearisation is less
        certain (a response recovered from a moved bracket), whichever is larger."""
        table = _interval.model_error_floor(
            self.ratio, non_linear=self.non_linear, method=self.method
        )
        if self.response_error_per_stop > 0 and np.isfinite(self.ratio) and self.ratio > 0:
            return float(max(table, self.response_error_per_stop * abs(np.log2(self.ratio))))
        return table

    @property
    def ci95_relative(self) -> float:
        """Relative half-width ``h`` of the calibrated 95 % interval (``inf`` when unknown)."""
        return _interval.ci95_relative(
            self.ratio,
            self.std_error,
            self.region_std_error,
            method=self.method,
            band_ratios=self.band_ratios,
            model_error=self.model_error,
        )

    @property
    def interval(self) -> tuple[float, float]:
        """The calibrated 95 % interval ``(low, high)`` of ``ratio`` (``nan`` when unknown)."""
        return _interval.interval(self.ratio, self.ci95_relative)

    @property
    def ci95_basis(self) -> str:
        """What the interval's standard error is: ``"jack-knife"`` or ``"fit"``."""
        return _interval.interval_std_error(self.std_error, self.region_std_error)[1]

    @property
    def band_spread(self) -> float:
        """Standard deviation of ``log`` of the ``band_ratios`` (0 with fewer than two)."""
        return _interval.band_spread(self.band_ratios)

    @property
    def honest_std_error(self) -> float:
        """The larger of the fit's and the region jack-knife's standard error."""
        if np.isfinite(self.region_std_error):
            return float(max(self.std_error, self.region_std_error))
        return float(self.std_error)

    @property
    def n_equations(self) -> int:
        return len(self.equations)

    @property
    def n_inliers(self) -> int:
        return int(np.count_nonzero(self.inlier_mask))

    @property
    def relative_std_error(self) -> float:
        return float(self.std_error / self.ratio) if self.ratio > 0 else float("inf")

    def to_json(self) -> dict[str, Any]:
        """The fields of ``hdrcore ratios --json`` for one pair (without the EXIF comparison)."""
        return {
            "dark": int(self.dark),
            "bright": int(self.bright),
            "ratio": float(self.ratio),
            "initial_ratio": float(self.initial_ratio),
            "iterations": int(self.iterations),
            "equations": self.n_equations,
            "inliers": self.n_inliers,
            "std_error": float(self.std_error),
            "region_std_error": _finite_or_none(self.region_std_error),
            "ci95_low": _finite_or_none(self.interval[0]),
            "ci95_high": _finite_or_none(self.interval[1]),
            "ci95_relative": _finite_or_none(self.ci95_relative),
            "ci95_basis": self.ci95_basis,
            "band_ratios": [_finite_or_none(v) for v in self.band_ratios],
            "model_error": float(self.model_error),
            "non_linear": bool(self.non_linear),
            "overlap_restricted": bool(self.overlap_restricted),
            "common_fraction": float(self.common_fraction),
            "status": self.status,
            "message": self.message,
        }


@dataclass(frozen=True, eq=False)
class BracketExposureResult:
    """Relative exposures of a bracket (darkest first, darkest = 1) and every pair behind them.

    ``relative_exposures`` come from the consistent chain: a weighted least-squares fit in log
    exposure over all estimated pairs (consecutive and, where they overlap, non-consecutive), which
    reduces to plain chaining of the consecutive ratios when only those are usable.
    ``chained_exposures`` are the products of the consecutive ratios alone (the seed's chaining).
    ``pairs`` holds the consecutive pairs, ``extra_pairs`` the non-consecutive ones that were
    estimated. ``exif_times`` (seconds or ``None``), ``exif_ratios`` and ``mismatch_stops``
    (``log2(estimate / exif)`` per consecutive pair) put the metadata beside the estimates.
    ``chain_residuals_stops`` is, per pair used in the chain, ``log2`` of the pair's estimate over
    the ratio implied by ``relative_exposures``: large values mean inconsistent pairs.
    """

    relative_exposures: tuple[float, ...]
    chained_exposures: tuple[float, ...]
    pairs: tuple[ExposureRatioResult, ...]
    extra_pairs: tuple[ExposureRatioResult, ...]
    exif_times: tuple[float | None, ...]
    exif_ratios: tuple[float | None, ...]
    mismatch_stops: tuple[float | None, ...]
    chain_residuals_stops: dict[PairKey, float]
    status: ChainStatus
    message: str
    method: str
    saturation: float
    noise_floor: float
    max_level: int

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def ratios(self) -> tuple[float, ...]:
        """Consecutive ratios implied by ``relative_exposures``."""
        e = self.relative_exposures
        return tuple(e[k + 1] / e[k] for k in range(len(e) - 1))

    def starting_ratios(self, max_factor: float = 1.5) -> tuple[float, ...]:
        """Consecutive ratios to start a registration from (hand-held brackets).

        The estimated ratio of each consecutive pair, except where it is missing or off the
        bracket's median step by more than ``max_factor``: there the EXIF ratio when known,
        else the median step. (Registration tolerates ratio errors of a few percent, which is
        what motion leaves in the histogram-only estimate, but not a wild one.)
        """
        est = np.array(
            [p.ratio if np.isfinite(p.ratio) and p.ratio > 0 else np.nan for p in self.pairs]
        )
        finite = est[np.isfinite(est)]
        exif = [r for r in self.exif_ratios if r]
        med = float(np.median(finite)) if finite.size else (float(np.median(exif)) if exif else 1.0)
        out = []
        for k, r in enumerate(est):
            exif_k = self.exif_ratios[k]
            if np.isfinite(r) and abs(np.log(r / med)) <= np.log(max_factor):
                out.append(float(r))
            elif exif_k:
                out.append(float(exif_k))
            else:
                out.append(med)
        return tuple(out)
