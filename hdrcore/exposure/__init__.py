"""Exposure ratios from histograms (Cerman & Hlavac 2006, section 5), with diagnostics.

Methods (registry :data:`EXPOSURE_METHODS`, chosen by name, case-insensitive):

* ``"Cerman 2006 refined"`` (default, :mod:`.refined`): eq. 4 + 3V on the BTF sampled at bin
  edges, optional noise matching, per-channel fits.
* ``"Cerman 2006"`` (:mod:`.cerman2006`): the published estimator, eq. 4 + 3V at level centres.

Every bracket estimate also runs the region jack-knife (:mod:`.stability`): an honest standard
error, and status ``"unstable"`` for pairs that hand-held motion disturbs. Such brackets are
estimated again after registration: from the registered pixels themselves
(:mod:`.registered`, :func:`bracket_exposures_from_pixels`, what the pipeline uses), or from the
histograms of each pair's common field of view (:func:`bracket_exposures_registered`,
:func:`pair_histograms_in_overlap`).

Entry points: :func:`exposure_ratio` (a pair, from histograms), :func:`exposure_ratio_frames`
(a pair, from frames), :func:`bracket_exposures` (a bracket, from frames),
:func:`bracket_exposures_registered` (a bracket, histograms of each pair's common field of view) and
:func:`bracket_exposures_from_histograms` (re-fit from cached histograms, e.g. after a change of
saturation level or noise floor).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ..errors import validate_method
from ..histogram import histograms
from ._core import default_noise_floor, default_saturation
from .cerman2006 import exposure_ratio_cerman2006
from .chain import chain_bracket, solve_chain
from .linearisation import linear_lut, srgb_lut
from .pair_histograms import (
    DEFAULT_REGIONS,
    BracketHistograms,
    PairHistograms,
    bracket_histograms,
    chain_pair_matrix,
    common_field_masks,
    pair_histograms_in_overlap,
    region_histograms,
)
from .refined import exposure_ratio_refined
from .registered import bracket_exposures_from_pixels, cfa_planes, exposure_ratio_registered
from .result import BracketExposureResult, ExposureEquations, ExposureRatioResult

__all__ = [
    "EXPOSURE_METHODS",
    "DEFAULT_METHOD",
    "exposure_ratio",
    "exposure_ratio_frames",
    "bracket_exposures",
    "bracket_exposures_from_histograms",
    "bracket_exposures_registered",
    "bracket_exposures_from_pixels",
    "exposure_ratio_registered",
    "cfa_planes",
    "bracket_histograms",
    "BracketHistograms",
    "PairHistograms",
    "pair_histograms_in_overlap",
    "common_field_masks",
    "chain_pair_matrix",
    "region_histograms",
    "BracketExposureResult",
    "ExposureEquations",
    "ExposureRatioResult",
    "solve_chain",
    "default_saturation",
    "default_noise_floor",
    "linear_lut",
    "srgb_lut",
]

EXPOSURE_METHODS: dict[str, Callable[..., ExposureRatioResult]] = {
    "Cerman 2006 refined": exposure_ratio_refined,
    "Cerman 2006": exposure_ratio_cerman2006,
}
DEFAULT_METHOD = "Cerman 2006 refined"


def exposure_ratio(
    hist_dark: np.ndarray,
    hist_bright: np.ndarray,
    *,
    method: str = DEFAULT_METHOD,
    **kwargs: Any,
) -> ExposureRatioResult:
    """Exposure ratio ``t_bright / t_dark`` of a pair from ``(C, L)`` (or ``(L,)``) histograms.

    Keyword arguments: ``saturation`` (Z, levels), ``noise_floor`` (levels), ``lut``
    (linearisation ``(L,)`` or ``(C, L)``), ``noise_sigma`` (refined method only), ``precision``,
    ``max_iterations``, ``max_relative_error``, ``min_overlap``, ``max_groups`` (groups of
    neighbouring levels in the 3V test), ``btfs`` (known transfer functions), ``dark``,
    ``bright``. The bracket functions also take ``jackknife``, ``max_region_error`` and
    ``jackknife_groups`` (:func:`hdrcore.exposure.chain.chain_bracket`).
    """
    key = validate_method(method, EXPOSURE_METHODS, "exposure")
    return EXPOSURE_METHODS[key](hist_dark, hist_bright, **kwargs)


def exposure_ratio_frames(
    dark: np.ndarray,
    bright: np.ndarray,
    max_level: int,
    *,
    mask: np.ndarray | None = None,
    method: str = DEFAULT_METHOD,
    **kwargs: Any,
) -> ExposureRatioResult:
    """As :func:`exposure_ratio` from two ``(H, W, C)`` integer frames."""
    return exposure_ratio(
        histograms(dark, max_level, mask),
        histograms(bright, max_level, mask),
        method=method,
        **kwargs,
    )


def bracket_exposures_from_histograms(
    hists: BracketHistograms,
    *,
    method: str = DEFAULT_METHOD,
    exposure_times: Sequence[float | None] | None = None,
    non_consecutive: bool = True,
    **kwargs: Any,
) -> BracketExposureResult:
    """Relative exposures of a bracket from cached histograms (fast re-fit)."""
    key = validate_method(method, EXPOSURE_METHODS, "exposure")
    return chain_bracket(
        hists,
        EXPOSURE_METHODS[key],
        method=key,
        exposure_times=exposure_times,
        non_consecutive=non_consecutive,
        **kwargs,
    )


def bracket_exposures(
    frames: Sequence[np.ndarray],
    max_level: int,
    *,
    method: str = DEFAULT_METHOD,
    exposure_times: Sequence[float | None] | None = None,
    mask: np.ndarray | None = None,
    stride: int | None = None,
    non_consecutive: bool = True,
    regions: tuple[int, int] | None = DEFAULT_REGIONS,
    pair_matrices: Sequence[np.ndarray] | None = None,
    margin: float = 2.0,
    **kwargs: Any,
) -> BracketExposureResult:
    """Relative exposures (darkest = 1) of ``frames`` (darkest first, integer ``(H, W, C)``).

    ``regions`` is the image grid of the region jack-knife (``None`` switches it off);
    ``pair_matrices`` restricts every pair's histograms to its common field of view (see
    :func:`bracket_exposures_registered`).
    """
    hists = bracket_histograms(
        frames,
        max_level,
        mask=mask,
        stride=stride,
        regions=regions,
        pair_matrices=pair_matrices,
        margin=margin,
    )
    return bracket_exposures_from_histograms(
        hists,
        method=method,
        exposure_times=exposure_times,
        non_consecutive=non_consecutive,
        **kwargs,
    )


def bracket_exposures_registered(
    frames: Sequence[np.ndarray],
    max_level: int,
    pair_matrices: Sequence[np.ndarray],
    *,
    margin: float = 2.0,
    **kwargs: Any,
) -> BracketExposureResult:
    """Relative exposures of a hand-held bracket from histograms of each pair's common field of
    view.

    ``pair_matrices[i]`` (2x3) maps pixel coordinates of frame ``i + 1`` to frame ``i`` (e.g.
    ``[p.matrix for p in hdrcore.registration.register_bracket(...).pairs]``, or an integer
    shift from eq. 5 as a translation). Each pair's histograms count only the pixels the other
    frame also sees (:func:`pair_histograms_in_overlap`), so content entering or leaving at the
    borders no longer biases the ratio; no pixel value is warped. Other arguments as
    :func:`bracket_exposures`.
    """
    return bracket_exposures(
        frames, max_level, pair_matrices=pair_matrices, margin=margin, **kwargs
    )
