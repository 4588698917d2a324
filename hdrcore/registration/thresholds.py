"""The saturation level and noise floor the registration reads: the requested ones, snapped
to a ladder of the bracket's own levels.

The registration leaves out samples at or above the saturation level and at or below the noise
floor. Moving either by a few levels changes which samples count for a handful of pixels, and the
registration's answer by less than its own repeatability, yet a registration keyed on the exact
value runs again for every step of a slider (the README has its cost). So the registration
reads :func:`snap_levels` of the requested levels instead: the levels of the channel it reads,
counted over every frame, are cut into runs of at most ``fraction`` of the samples (a quantile
ladder, a property of the bracket alone), and a threshold is moved to the end of its run that
leaves out more:

* the saturation level ``s`` down to the lowest level ``s'`` of its run: the samples the
  registration then leaves out beyond the requested ones, those with ``s' <= z < s``, are fewer
  than ``fraction`` of all (:data:`MASK_FRACTION`: 0.5 %);
* the noise floor ``f`` up to the highest level ``f'`` of its run: those with ``f < z <= f'``,
  likewise.

Every threshold inside one run snaps to the same level, so the registration's cache key (the
snapped levels) does not move while a slider stays inside a run, and the result is a function
of the parameters alone (no history: a fresh run gives the same registration). Where one level
holds more than ``fraction`` of the samples (8-bit frames, often) it is a run of its own and the
threshold is used as it is. The merge and the exposure ratios read the requested levels.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import ParameterError

__all__ = ["MASK_FRACTION", "MAX_STEP", "MIN_STEP_LEVELS", "snap_levels"]

#: Largest fraction of a channel's samples (all frames) a snapped threshold leaves out beyond the
#: requested one. Measured on the real hand-held phone brackets (8-bit JPEGs, ``../shared/data``):
#: a saturation level moved by 3 levels (0.1-0.5 % of the samples) moved the registration's
#: transforms by at most 0.013 px at the frame corners (Xperia, 8 frames) and 0.027 px (Pixel 7;
#: 0.10 px on its dim darkest frame, whose pair is the least constrained); 1 level, 0.001-0.1 px.
MASK_FRACTION = 5e-3
#: Largest move of a snapped threshold, as a fraction of the level range: the registration also
#: compares the darker frame's values times the exposure ratio with the thresholds, which the
#: sample counts above do not bound (an empty stretch of levels, 14-bit data in 16-bit files,
#: would otherwise move the saturation level by a quarter of the range).
MAX_STEP = 1.0 / 512
#: ...but never less than this many levels: on 8-bit frames 1/512 of the range is under one
#: level, and every slider step re-ran a registration of 10-12 s on the real phone brackets
#: (the moves measured above).
MIN_STEP_LEVELS = 3


def snap_levels(
    counts: np.ndarray,
    saturation: float,
    noise_floor: float,
    fraction: float = MASK_FRACTION,
    max_step: float = MAX_STEP,
    min_step: int = MIN_STEP_LEVELS,
) -> tuple[float, float]:
    """``(saturation', noise_floor')``: the thresholds the registration reads (see the module).

    ``counts``: per-level sample counts of the channel the registration reads, ``(L,)`` or
    ``(N, L)`` (summed over the frames); ``saturation`` and ``noise_floor`` in levels (samples
    ``z`` with ``noise_floor < z < saturation`` are used). The ladder's runs hold fewer than
    ``fraction`` of the samples (a level that holds more is a run of its own) and span at most
    ``max_step`` of the range (``min_step`` levels when that is more). The snapped saturation
    is at most the requested one, the snapped floor at least the requested one (within one
    level: both are levels, the ends of their runs, so every threshold inside a run gives the
    same pair and integer samples are never kept that the requested pair leaves out), each
    moved by at most that step and with fewer than ``fraction`` of the samples in between;
    ``fraction`` or ``max_step`` 0 returns them as they are, and so does a snapped pair with no
    level between them.
    """
    c = np.asarray(counts, dtype=np.float64)
    if c.ndim == 2:
        c = c.sum(axis=0)
    if c.ndim != 1 or c.size < 2:
        raise ParameterError("counts must be (L,) or (N, L) per-level counts", found=str(c.shape))
    s, f = float(saturation), float(noise_floor)
    if not (
        math.isfinite(s)
        and math.isfinite(f)
        and 0.0 <= float(fraction) < 1.0
        and 0.0 <= float(max_step) <= 1.0
    ):
        raise ParameterError(
            "levels must be finite, fraction in [0, 1) and max_step in [0, 1]",
            found=f"saturation {s}, noise floor {f}, fraction {fraction}, max_step {max_step}",
        )
    levels = c.size  # L = max_level + 1
    unit = float(fraction) * float(c.sum())
    step = int(math.floor(float(max_step) * (levels - 1)))
    if float(max_step) > 0.0:
        step = max(step, int(min_step))
    if unit <= 0.0 or step < 1:
        return s, f
    below = np.concatenate([[0.0], np.cumsum(c)])  # below[l]: samples z < l, l = 0..L
    grid = np.arange(0, levels + 1, step)
    marks = np.arange(0, math.floor(below[-1] / unit) + 1) * unit
    # saturation: the kept samples are z < ceil(s); runs start where `below` first reaches a
    # multiple of `unit` (so a run's samples below its last level are fewer than `unit`)
    starts = np.union1d(np.searchsorted(below, marks, side="left"), grid)
    top = int(min(max(math.ceil(s), 0), levels))
    s_new = float(starts[np.searchsorted(starts, top, side="right") - 1])
    # noise floor: the kept samples are z >= floor(f) + 1; runs end where `below` last stays
    # within a multiple of `unit`
    ends = np.union1d(np.searchsorted(below, marks, side="right") - 1, grid)
    first = int(min(max(math.floor(f) + 1, 0), levels))
    i = int(np.searchsorted(ends, first, side="left"))
    f_new = float(ends[i] - 1) if i < ends.size else float(first - 1)
    if s_new - f_new <= 1.0:
        return s, f
    return s_new, f_new
