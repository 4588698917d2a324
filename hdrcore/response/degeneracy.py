"""Signs that a recovered response went degenerate, said in words.

A response fitted to inconsistent data (a phone's local tone mapping, JPEG artefacts, a channel
with little range) does not fail: the monotone solver returns a curve that is flat where the
data pulled it down, kinked where the constraints bound, and different from channel to
channel, and the merge takes it with a colour cast (issue 15: a facade that the frames show as
(0.41, 0.33, 0.26) came out (0.42, 0.43, 0.15)). :func:`degeneracy` reads a curve and its fit
diagnostics and returns every sign found:

* ``binding`` -- the monotonicity constraint binds at more than :data:`MAX_BINDING_FRACTION`
  of the nodes: the data want the curve to go down;
* ``flat`` -- a stretch of at least :data:`FLAT_RUN` of the level range inside the data where
  ``ln g`` rises by less than :data:`FLAT_SLOPE` per level (8-bit units): levels that stand for
  one exposure;
* ``channels-disagree`` -- a grey level ``(z, z, z)`` decodes to a colour: the rg-chromaticity
  of ``(g_R(z), g_G(z), g_B(z))`` leaves neutral by more than :data:`MAX_NEUTRAL_DRIFT` over
  the middle levels (cameras apply one tone curve to white-balanced data);
* ``worse-than-srgb`` -- (:mod:`.select`) the curve explains held-back correspondences worse
  than plain sRGB decoding.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..status import ResponseStatus

__all__ = [
    "FLAT_RUN",
    "FLAT_SLOPE",
    "MAX_BINDING_FRACTION",
    "MAX_NEUTRAL_DRIFT",
    "Degeneracy",
    "channel_fits_status",
    "degeneracy",
    "neutral_drift",
]

MAX_BINDING_FRACTION = 0.10
FLAT_RUN = 0.04
FLAT_SLOPE = 1e-3
MAX_NEUTRAL_DRIFT = 0.02


@dataclass(frozen=True)
class Degeneracy:
    """One sign of a degenerate curve: a stable ``code``, the channel (``None``: all) and a
    sentence."""

    code: str
    message: str
    channel: int | None = None
    value: float = float("nan")

    def to_json(self) -> dict[str, Any]:
        return {
            "code": self.code,
            "message": self.message,
            "channel": self.channel,
            "value": None if not np.isfinite(self.value) else float(self.value),
        }


def neutral_drift(g: np.ndarray, lo: float = 0.1, hi: float = 0.9) -> tuple[float, int]:
    """Largest rg-chromaticity distance from neutral of ``(g_R(z), g_G(z), g_B(z))`` over the
    levels ``lo..hi`` of the range, and the level where it is reached (0, 0 for one channel)."""
    g = np.atleast_2d(np.asarray(g, dtype=np.float64))
    if g.shape[0] != 3:
        return 0.0, 0
    m = g.shape[1] - 1
    z = np.arange(int(np.ceil(lo * m)), int(np.floor(hi * m)) + 1)
    v = g[:, z]
    s = np.maximum(v.sum(axis=0), 1e-300)
    rg = v[:2] / s
    d = np.hypot(rg[0] - 1 / 3, rg[1] - 1 / 3)
    k = int(np.argmax(d))
    return float(d[k]), int(z[k])


def _flat_runs(g: np.ndarray, lo: float, hi: float) -> tuple[int, int]:
    """Longest run of level steps inside ``[lo, hi]`` where ``ln g`` rises by less than
    :data:`FLAT_SLOPE` (8-bit units), and where it starts."""
    m = g.size - 1
    a, b = max(int(np.ceil(lo)), 1), min(int(np.floor(hi)), m)
    if b - a < 2:
        return 0, a
    lg = np.log(np.maximum(g[a : b + 1], 1e-300))
    flat = np.diff(lg) < FLAT_SLOPE * 255.0 / m
    # the runs of flat steps from the edges of the padded mask (a loop over a 16-bit curve's
    # 65536 levels took 30-40 ms a channel); the first longest run, as a scan would find it
    edges = np.diff(np.concatenate(([0], flat.astype(np.int8), [0])))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    if starts.size == 0:
        return 0, a
    lengths = ends - starts
    i = int(np.argmax(lengths))
    return int(lengths[i]), a + int(starts[i])


def degeneracy(
    g: np.ndarray,
    *,
    data_range: Sequence[tuple[float, float]] | None = None,
    active: Sequence[int] | None = None,
    n_nodes: int | None = None,
    channels_fitted_apart: bool = True,
) -> list[Degeneracy]:
    """Every sign of degeneracy of curve ``g`` ``(C, L)``.

    ``data_range`` per channel (levels with data; default 2..98 % of the range), ``active``
    binding constraints per channel out of ``n_nodes``; ``channels_fitted_apart``: the
    channels' curves come from separate fits (a grey that drifts is then a defect; when the
    held-back data chose a per-channel model it is the camera's).
    """
    g = np.atleast_2d(np.asarray(g, dtype=np.float64))
    n_ch, n_lv = g.shape
    m = n_lv - 1
    names = ("R", "G", "B") if n_ch == 3 else tuple(f"c{k}" for k in range(n_ch))
    out: list[Degeneracy] = []
    for c in range(n_ch):
        lo, hi = (0.02 * m, 0.98 * m) if data_range is None else data_range[c]
        lo, hi = max(lo, 0.02 * m), min(hi, 0.98 * m)
        if active is not None and n_nodes:
            inside = max(1, int(round(n_nodes * (hi - lo) / m)))
            if active[c] > MAX_BINDING_FRACTION * inside:
                out.append(
                    Degeneracy(
                        "binding",
                        f"channel {names[c]}: monotonicity binding at {active[c]} "
                        f"nodes of {inside} (the data want the curve to go down)",
                        c,
                        float(active[c]),
                    )
                )
        run, start = _flat_runs(g[c], lo, hi)
        if run >= max(3, FLAT_RUN * m):
            out.append(
                Degeneracy(
                    "flat",
                    f"channel {names[c]}: flat from level {start} to {start + run} "
                    "(those levels decode to one exposure)",
                    c,
                    float(run),
                )
            )
    if channels_fitted_apart and n_ch == 3:
        drift, at = neutral_drift(g)
        if drift > MAX_NEUTRAL_DRIFT:
            v = g[:, at]
            rg = v[:2] / v.sum()
            out.append(
                Degeneracy(
                    "channels-disagree",
                    f"the channels' curves disagree: grey level {at} decodes "
                    f"to chromaticity ({rg[0]:.3f}, {rg[1]:.3f}), {drift:.3f} from neutral "
                    "(a colour cast)",
                    None,
                    drift,
                )
            )
    return out


def channel_fits_status(fit: Any) -> tuple[ResponseStatus, str]:
    """``(status, message)`` of a :class:`.joint.JointFit`: ``"warning"`` with the signs of
    degeneracy, else ``"ok"``."""
    found = degeneracy(
        fit.g,
        data_range=fit.data_range,
        active=fit.active,
        n_nodes=fit.nodes.size,
        channels_fitted_apart=False,
    )
    if not found:
        return "ok", ""
    return "warning", "; ".join(d.message for d in found)
