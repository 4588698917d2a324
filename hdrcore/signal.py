"""Which frames of a bracket carry signal: a black or saturated frame is left out, not fatal.

A frame with (almost) no pixel between the noise floor and the saturation level ``Z`` gives no
equation of eq. 4, no gradient for eq. 6 and no sample to the merge: it is a failed shot (lens
cap, a flash that did not fire, a frame far beyond the scene's range). It is classified here from
the histograms the pipeline already counted and then left out of every stage, with a verdict
that names its file; the rest of the bracket is merged.

The test is deliberately strict, so that a dim but useful frame is never dropped: a frame is
unusable when fewer than :data:`MIN_SIGNAL_FRACTION` of its pixels lie strictly between twice
the noise floor and ``Z``. Twice the floor is six standard deviations of the noise when the floor
is measured (:mod:`hdrcore.noise`), a level pure noise does not reach, so the noise of a black
frame never passes for signal; the darkest frame of a RAW bracket whose brightest pixels sit a few
per cent above black keeps all of them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .status import SignalStatus

__all__ = ["MIN_SIGNAL_FRACTION", "FrameSignal", "frame_signal"]

#: A frame with fewer of its pixels between twice the noise floor and Z is unusable (1 in 10^4).
MIN_SIGNAL_FRACTION = 1e-4


@dataclass(frozen=True)
class FrameSignal:
    """How much of a frame is usable. ``status``: ``"ok"``, ``"black"``, ``"saturated"`` or
    ``"unlinked"`` (set by the pipeline: no ratio links it to the frames merged, no EXIF time).

    ``signal_fraction``: pixels strictly between twice the noise floor and ``Z`` (mean over the
    channels); ``black_fraction`` at or below the floor; ``saturated_fraction`` at or above ``Z``.
    """

    index: int
    path: str
    status: SignalStatus
    signal_fraction: float
    black_fraction: float
    saturated_fraction: float

    @property
    def usable(self) -> bool:
        return self.status == "ok"

    @property
    def reason(self) -> str:
        """What the status means, in words."""
        if self.status == "black":
            return (
                f"black: {self.black_fraction:.1%} of its pixels are at or below the noise "
                f"floor and only {self.signal_fraction:.3%} carry signal"
            )
        if self.status == "unlinked":
            return (
                "not linked to the other frames: no exposure ratio to them could be "
                "measured (no brightness overlap) and the files carry no exposure times"
            )
        if self.status == "saturated":
            return (
                f"saturated: {self.saturated_fraction:.1%} of its pixels are at or above the "
                f"saturation level and only {self.signal_fraction:.3%} carry signal"
            )
        return f"{self.signal_fraction:.1%} of its pixels carry signal"

    def to_json(self) -> dict[str, Any]:
        return {
            "index": self.index,
            "path": self.path,
            "status": self.status,
            "reason": self.reason,
            "signal_fraction": self.signal_fraction,
            "black_fraction": self.black_fraction,
            "saturated_fraction": self.saturated_fraction,
        }


def frame_signal(
    counts: np.ndarray,
    *,
    noise_floor: float,
    saturation: float,
    index: int = 0,
    path: str = "",
    min_fraction: float = MIN_SIGNAL_FRACTION,
) -> FrameSignal:
    """Classify one frame from its ``(C, L)`` histograms (see the module docstring)."""
    h = np.asarray(counts, np.float64)
    if h.ndim == 1:
        h = h[None]
    n = h.shape[-1]
    total = h.sum(axis=-1)
    total = np.where(total > 0, total, 1.0)
    lo_signal = min(n, int(np.floor(2.0 * noise_floor)) + 1)
    lo_black = min(n, int(np.floor(noise_floor)) + 1)
    hi = max(0, min(n, int(np.ceil(saturation))))
    signal = float(np.mean(h[:, lo_signal : max(lo_signal, hi)].sum(axis=-1) / total))
    black = float(np.mean(h[:, :lo_black].sum(axis=-1) / total))
    saturated = float(np.mean(h[:, hi:].sum(axis=-1) / total))
    status: SignalStatus
    if signal >= min_fraction:
        status = "ok"
    else:
        status = "saturated" if saturated > black else "black"
    return FrameSignal(
        index=int(index),
        path=str(path),
        status=status,
        signal_fraction=signal,
        black_fraction=black,
        saturated_fraction=saturated,
    )
