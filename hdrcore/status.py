"""The words a result's ``status`` and a verdict's ``severity`` may take, defined once.

Each is a :data:`typing.Literal` of the exact strings the JSON outputs carry (so the JSON is
unchanged and mypy rejects a misspelt or undeclared word where a result is built); the tuple
next to each lists the same words for code that checks or documents them at run time.

- :data:`Severity`: a :class:`hdrcore.diagnose.Verdict`'s (and the inspector's notifications').
- :data:`RatioStatus`: one pair's exposure ratio
  (:class:`hdrcore.exposure.ExposureRatioResult`). ``"ok"`` and ``"uncertain"`` are decided
  from the 95 % interval (:mod:`hdrcore.exposure.interval`); ``"unstable"`` marks regions that
  disagree; ``"channels-disagree"``, ``"few-equations"``, ``"failed"`` a fit that cannot be
  trusted; ``"no-overlap"``, ``"no-signal"``, ``"unregistered"`` a pair that could not be
  measured; ``"inconsistent"`` a pair the chain of the other pairs contradicts.
- :data:`ChainStatus`: a whole bracket's ratios
  (:class:`hdrcore.exposure.BracketExposureResult`): ``"broken-chain"`` when some frame is not
  linked to the others, ``"not-ok"`` when some pair is not ok.
- :data:`SignalStatus`: one frame's usable signal (:class:`hdrcore.signal.FrameSignal`).
- :data:`ResponseStatus`: a recovered response curve
  (:class:`hdrcore.response.ResponseCurve`): ``"warning"`` when a channel's fit is degenerate,
  ``"fallback"`` when the automatic choice fell back on another curve.
- :data:`BatchStatus`: one bracket of ``hdrcore batch`` (:class:`hdrcore.batch.BracketRecord`):
  merged ``"ok"``, with a ``"warning"``, with an ``"error"`` verdict (exit 1), or ``"failed"``
  (nothing written).
"""

from __future__ import annotations

from typing import Literal, TypeGuard, get_args

__all__ = [
    "BATCH_STATUSES",
    "CHAIN_STATUSES",
    "RATIO_STATUSES",
    "SEVERITIES",
    "SIGNAL_STATUSES",
    "BatchStatus",
    "ChainStatus",
    "RESPONSE_STATUSES",
    "RatioStatus",
    "ResponseStatus",
    "Severity",
    "SignalStatus",
    "is_batch_status",
    "is_response_status",
]

Severity = Literal["error", "warning", "info"]
#: worst first
SEVERITIES: tuple[Severity, ...] = get_args(Severity)

RatioStatus = Literal[
    "ok",
    "uncertain",
    "unstable",
    "channels-disagree",
    "few-equations",
    "failed",
    "no-overlap",
    "no-signal",
    "unregistered",
    "inconsistent",
]
RATIO_STATUSES: tuple[RatioStatus, ...] = get_args(RatioStatus)

ChainStatus = Literal["ok", "not-ok", "broken-chain"]
CHAIN_STATUSES: tuple[ChainStatus, ...] = get_args(ChainStatus)

SignalStatus = Literal["ok", "black", "saturated", "unlinked"]
SIGNAL_STATUSES: tuple[SignalStatus, ...] = get_args(SignalStatus)

BatchStatus = Literal["ok", "warning", "error", "failed"]
BATCH_STATUSES: tuple[BatchStatus, ...] = get_args(BatchStatus)


def is_batch_status(value: object) -> TypeGuard[BatchStatus]:
    """``value`` is one of :data:`BATCH_STATUSES` (a record read back from a file)."""
    return value in BATCH_STATUSES


ResponseStatus = Literal["ok", "warning", "fallback"]
RESPONSE_STATUSES: tuple[ResponseStatus, ...] = get_args(ResponseStatus)


def is_response_status(value: object) -> TypeGuard[ResponseStatus]:
    """``value`` is one of :data:`RESPONSE_STATUSES` (a curve read back from a file)."""
    return value in RESPONSE_STATUSES


FailedRegistrationStatus = Literal["saturated", "flat", "weak-peak", "no-overlap", "diverged"]
"""A pair that produced no transform (its motion is the identity)."""
FAILED_REGISTRATION_STATUSES: tuple[FailedRegistrationStatus, ...] = get_args(
    FailedRegistrationStatus
)

RegistrationStatus = Literal["ok", "weak", FailedRegistrationStatus]
"""A registered pair: ``ok``; ``weak`` (its motion used, the residual check not satisfied); or
one of the failures (:data:`FAILED_REGISTRATION_STATUSES`)."""
REGISTRATION_STATUSES: tuple[RegistrationStatus, ...] = get_args(RegistrationStatus)

ResidualStatus = Literal["aligned", "misaligned", "unmeasured"]
"""The residual motion of a registered pair, measured independently of its model."""
RESIDUAL_STATUSES: tuple[ResidualStatus, ...] = get_args(ResidualStatus)
