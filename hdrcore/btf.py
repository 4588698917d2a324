"""Brightness transfer functions by cumulative histogram matching (Grossberg & Nayar 2002).

Two frames of a static scene taken with exposures ``t_dark < t_bright`` see the same radiance
distribution, so a level ``M`` of the darker frame and ``T(M)`` of the brighter frame have equal
cumulative frequencies: ``T(M) = H_bright^-1(H_dark(M))``. No pixel correspondence is needed,
which is why Cerman & Hlavac (2006, section 5) can estimate exposure ratios of a hand-held bracket
before registration.

Level model: level ``m`` collects the continuous values in ``[m - 1/2, m + 1/2)``. The cumulative
histogram is therefore exact at the bin *edges* ``m + 1/2`` (``F(m + 1/2) = C(m)``, ``F(-1/2) = 0``)
and interpolated linearly inside a bin. ``T`` maps any continuous dark value ``x`` to a continuous
bright value; ``forward[m] = T(m)`` samples it at the level centres. Where the bright cumulative
histogram is flat (empty bins) the inverse takes the middle of the flat run.

References
----------
.. [1] M. D. Grossberg, S. K. Nayar, "What can be known about the radiometric response from
   images?", ECCV 2002 (section 4: the brightness transfer function from histograms).
.. [2] J. Cerman, V. Hlavac, "Exposure time estimation for high dynamic range imaging with hand
   held camera", Computer Vision Winter Workshop 2006, section 5.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ._numba import njit as _njit
from .errors import EstimationError, ParameterError
from .histogram import cumulative

__all__ = ["BrightnessTransferFunction", "brightness_transfer_function", "quantile_levels"]


def _edges(n_levels: int) -> np.ndarray:
    """Positions ``-1/2, 1/2, ..., max_level + 1/2`` of the bin edges (``n_levels + 1`` values)."""
    return np.arange(n_levels + 1, dtype=np.float64) - 0.5


def _knots(cdf: np.ndarray) -> np.ndarray:
    """Cumulative fraction at every bin edge, starting with 0 at ``-1/2``."""
    return np.concatenate([[0.0], cdf])


def quantile_levels(cdf: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Continuous level where the piecewise-linear cumulative histogram ``cdf`` reaches ``q``.

    ``cdf[m]`` is the fraction of pixels with level ``<= m``. Flat runs (empty bins) resolve to
    their middle; ``q`` outside ``[0, 1]`` clips to the ends of the occupied range.
    """
    knots = _knots(np.asarray(cdf, np.float64))
    n = knots.size
    q = np.clip(np.asarray(q, np.float64), 0.0, knots[-1])
    if q.ndim == 1 and q.size >= SORTED_SCAN_MIN and bool(np.all(q[1:] >= q[:-1])):
        # rising queries (a cumulative histogram's values: every BTF and its inverse) in one
        # merged pass, O(levels) instead of two binary searches a query: the same values
        out = np.empty(q.size)
        _quantiles_rising(knots, q, out)
        return out
    x = _edges(n - 1)
    # lo: first edge where F >= q; hi: last edge where F <= q (equal inside a rising segment).
    j = np.clip(np.searchsorted(knots, q, side="left"), 1, n - 1)
    k0, k1 = knots[j - 1], knots[j]
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(k1 > k0, (q - k0) / (k1 - k0), 1.0)
    lo = np.where(knots[j] == q, x[j], x[j - 1] + frac)
    lo = np.where(q <= knots[0], x[0], lo)
    i = np.clip(np.searchsorted(knots, q, side="right") - 1, 0, n - 2)
    k0, k1 = knots[i], knots[i + 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(k1 > k0, (q - k0) / (k1 - k0), 0.0)
    hi = np.where(knots[i] == q, x[i], x[i] + frac)
    hi = np.where(q >= knots[-1], x[-1], hi)
    return 0.5 * (lo + hi)


#: Queries from this many on, when they rise, are answered by one merged pass
#: (:func:`_quantiles_rising`) instead of binary searches.
SORTED_SCAN_MIN = 64


@_njit
def _quantiles_rising(knots, q, out):  # pragma: no cover - compiled
    """:func:`quantile_levels` for rising ``q`` (already clipped to ``[0, knots[-1]]``): the two
    ``searchsorted`` of the numpy form as pointers that only move forward, then its arithmetic
    expression by expression (edges ``x[i] = i - 1/2``): the same values to the bit."""
    n = knots.size
    j = 0  # first index with knots[j] >= v (searchsorted left)
    r = 0  # first index with knots[r] > v (searchsorted right)
    for m in range(q.size):
        v = q[m]
        while j < n and knots[j] < v:
            j += 1
        while r < n and knots[r] <= v:
            r += 1
        a = min(max(j, 1), n - 1)
        k0 = knots[a - 1]
        k1 = knots[a]
        frac = (v - k0) / (k1 - k0) if k1 > k0 else 1.0
        lo = (a - 0.5) if knots[a] == v else (a - 1 - 0.5) + frac
        if v <= knots[0]:
            lo = -0.5
        i = min(max(r - 1, 0), n - 2)
        k0 = knots[i]
        k1 = knots[i + 1]
        frac = (v - k0) / (k1 - k0) if k1 > k0 else 0.0
        hi = (i - 0.5) if knots[i] == v else (i - 0.5) + frac
        if v >= knots[n - 1]:
            hi = (n - 1) - 0.5
        out[m] = 0.5 * (lo + hi)


def _cdf_at(cdf: np.ndarray, x: np.ndarray | float) -> np.ndarray:
    knots = _knots(np.asarray(cdf, np.float64))
    return np.interp(np.asarray(x, np.float64), _edges(knots.size - 1), knots)


@dataclass(frozen=True, eq=False)
class BrightnessTransferFunction:
    """The brightness transfer function of one channel of a (dark, bright) pair.

    Attributes
    ----------
    forward : float64 ``(max_level_dark + 1,)``, ``T(m)`` in bright levels at each dark level.
    inverse : float64 ``(max_level_bright + 1,)``, ``T^-1(m)`` in dark levels at each bright level.
    hist_dark, hist_bright : the histograms it was made from (int64, or float64 if given so).
    cdf_dark, cdf_bright : normalised cumulative histograms (fraction with level ``<= m``).
    """

    forward: np.ndarray
    inverse: np.ndarray
    hist_dark: np.ndarray
    hist_bright: np.ndarray
    cdf_dark: np.ndarray
    cdf_bright: np.ndarray
    _memo: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def max_level_dark(self) -> int:
        return int(self.hist_dark.size - 1)

    @property
    def max_level_bright(self) -> int:
        return int(self.hist_bright.size - 1)

    def transfer(self, x: np.ndarray | float) -> np.ndarray:
        """``T(x)`` at continuous dark values ``x`` (level ``m`` spans ``[m - 1/2, m + 1/2)``)."""
        return quantile_levels(self.cdf_bright, _cdf_at(self.cdf_dark, x))

    def inverse_transfer(self, y: np.ndarray | float) -> np.ndarray:
        """``T^-1(y)`` at continuous bright values ``y``."""
        return quantile_levels(self.cdf_dark, _cdf_at(self.cdf_bright, y))

    def forward_at_edges(self) -> np.ndarray:
        """``T(m + 1/2)`` for every dark level ``m``: exact dark quantiles, no interpolation.

        Computed once per object (read-only array): re-fits with another saturation level or
        noise floor reuse it.
        """
        return self._memoised("forward_at_edges", self.cdf_bright, self.cdf_dark)

    def inverse_at_edges(self) -> np.ndarray:
        """``T^-1(m + 1/2)`` for every bright level ``m`` (computed once, read-only)."""
        return self._memoised("inverse_at_edges", self.cdf_dark, self.cdf_bright)

    def _memoised(self, name: str, cdf_to: np.ndarray, cdf_from: np.ndarray) -> np.ndarray:
        out = self._memo.get(name)
        if out is None:
            out = quantile_levels(cdf_to, cdf_from)
            out.setflags(write=False)
            self._memo[name] = out
        return out


def brightness_transfer_function(
    hist_dark: np.ndarray, hist_bright: np.ndarray
) -> BrightnessTransferFunction:
    """The BTF of two one-channel histograms by cumulative histogram matching.

    The histograms may have different lengths (bit depths) and totals (masks); they are
    normalised. Raises :class:`EstimationError` when either is empty.
    """
    hd = np.asarray(hist_dark)
    hb = np.asarray(hist_bright)
    if hd.ndim != 1 or hb.ndim != 1 or hd.size < 2 or hb.size < 2:
        raise ParameterError(
            "histograms must be one-dimensional with at least 2 bins",
            found=f"{hd.shape} and {hb.shape}",
        )
    if np.any(hd < 0) or np.any(hb < 0):
        raise ParameterError("histogram counts must be non-negative")
    if hd.sum() <= 0 or hb.sum() <= 0:
        which = "dark" if hd.sum() <= 0 else "bright"
        raise EstimationError(
            f"the {which} histogram is empty: no pixels to match",
            expected="at least one counted pixel",
            found="0",
        )
    # Integer counts stay int64; blurred (float) histograms are accepted as float64.
    hd = np.array(hd, np.int64 if np.issubdtype(hd.dtype, np.integer) else np.float64)
    hb = np.array(hb, np.int64 if np.issubdtype(hb.dtype, np.integer) else np.float64)
    cd = cumulative(hd)
    cb = cumulative(hb)
    centres_d = np.arange(hd.size, dtype=np.float64)
    centres_b = np.arange(hb.size, dtype=np.float64)
    forward = quantile_levels(cb, _cdf_at(cd, centres_d))
    inverse = quantile_levels(cd, _cdf_at(cb, centres_b))
    for a in (forward, inverse, hd, hb, cd, cb):
        a.setflags(write=False)
    return BrightnessTransferFunction(
        forward=forward, inverse=inverse, hist_dark=hd, hist_bright=hb, cdf_dark=cd, cdf_bright=cb
    )
