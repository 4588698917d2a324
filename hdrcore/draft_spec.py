"""The draft's binning (:func:`hdrcore.draft.bin_levels`) written as plainly as numpy allows:
the specification the tests hold its compiled kernels to.

Used by the tests only (the draft runs the kernels ``_bin_rows`` and ``_levels_rows`` of
:mod:`hdrcore.draft`). Whole frames, float64, no input checks (it takes what ``bin_levels``
accepts). The rules (:mod:`hdrcore.draft`'s docstring), per ``f x f`` block and channel (the
ragged edge cropped):

* the mean of ``g(level)`` over the block's samples (``g`` the response ``lut``, or the level
  itself without one);
* a block with a sample at or above ``saturation`` in a channel is clipped in that channel: the
  top level (``max_level``, or ``k * max_level`` with a ``lut``);
* a block holding a pixel of ``exclude_colour`` is that colour (times ``k`` with a ``lut``),
  before the clipping rule;
* otherwise, without a ``lut``, the mean rounded half up to the frames' levels; with one, the
  level of ``k = FINE_TOP // max_level`` times finer steps whose ``g`` (read at ``level / k``,
  linearly between entries) is nearest to the mean (:func:`to_fine_levels`), as uint16.

The kernels add a block's samples in their own order, so a mean can differ in its last bits;
the tests compare the levels, which are the same.
"""

from __future__ import annotations

import numpy as np

from .draft import FINE_TOP

__all__ = ["bin_levels_spec", "to_fine_levels"]


def to_fine_levels(table: np.ndarray, values: np.ndarray, k: int) -> np.ndarray:
    """The level of ``k`` times finer steps whose value, ``table`` (increasing, one entry a
    level) read linearly between entries, is nearest to each value."""
    j = np.clip(np.searchsorted(table, values, side="right") - 1, 0, table.size - 2)
    lo, hi = table[j], table[j + 1]
    step = np.where(hi > lo, hi - lo, 1.0)
    frac = np.clip((values - lo) / step, 0.0, 1.0)
    return j * k + np.rint(frac * k).astype(np.intp)


def bin_levels_spec(
    levels: np.ndarray,
    factor: int,
    *,
    saturation: float,
    max_level: int,
    exclude_colour: tuple[int, int, int] | None = None,
    lut: np.ndarray | None = None,
) -> np.ndarray:
    """What :func:`hdrcore.draft.bin_levels` returns for the same (valid) arguments."""
    f, m = int(factor), int(max_level)
    h, w, c = levels.shape
    hh, ww = h // f, w // f
    blocks = levels[: hh * f, : ww * f].reshape(hh, f, ww, f, c).astype(np.intp)
    if lut is None:
        g = np.tile(np.arange(m + 1, dtype=np.float64), (c, 1))
    else:
        g = np.broadcast_to(np.asarray(lut, np.float64), (c, m + 1))
    exposure = np.stack([g[ch][blocks[..., ch]] for ch in range(c)], axis=-1)
    mean = exposure.mean(axis=(1, 3))
    clipped = blocks.max(axis=(1, 3)) >= saturation
    excluded = np.zeros((hh, ww), bool)
    if exclude_colour is not None:
        excluded = np.all(blocks == np.asarray(exclude_colour, np.intp), axis=-1).any(axis=(1, 3))
    ex = np.asarray(exclude_colour if exclude_colour is not None else (0,) * c, np.int64)
    if lut is None:
        out = np.floor(mean + 0.5)
        out[clipped] = m
        out[excluded] = ex
        return out.astype(levels.dtype)
    k = max(1, FINE_TOP // m)
    out = np.stack([to_fine_levels(g[ch], mean[..., ch], k) for ch in range(c)], axis=-1)
    out[clipped] = k * m
    out[excluded] = k * ex
    return out.astype(np.uint16)
