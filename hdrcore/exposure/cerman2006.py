"""Exposure ratio of a pair from its histograms, as published (Cerman & Hlavac 2006, section 5).

The brightness transfer function ``T`` of the pair (dark frame A, bright frame B; Grossberg &
Nayar 2002) is sampled at every level. For a linear camera ``k M_A = T(M_A)``; with a response,
``k g(M_A) = g(T(M_A))``. System S0 (eq. 4) stacks

* one equation per dark level ``M_A`` with ``T(M_A) < Z``, multiplied by ``sqrt(h_A(M_A))``, and
* one equation per bright level ``M_B < Z`` through ``T^-1``, multiplied by ``sqrt(h_B(M_B))``,

discarding levels below the noise floor. Its least-squares solution is ``k0``; then (section
5.1) the mean squared error ``V`` is computed, equations with squared error ``>= 3V`` are dropped
and the system is solved again, until ``k`` changes less than the required precision.

This module keeps the paper's choices (BTF sampled at level centres, square-root histogram
weights) so the inspector can show the published method; :mod:`.refined` is the default.

Reference: J. Cerman, V. Hlavac, "Exposure time estimation for high dynamic range imaging with
hand held camera", Computer Vision Winter Workshop 2006, section 5, eq. 4.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ._core import FitOptions, estimate_pair, solve_3v
from .result import ExposureRatioResult

__all__ = ["CERMAN2006", "exposure_ratio_cerman2006", "solve_3v"]

CERMAN2006 = FitOptions(name="Cerman 2006", at_edges=False, weight_power=0.5)


def exposure_ratio_cerman2006(
    hist_dark: np.ndarray,
    hist_bright: np.ndarray,
    *,
    saturation: float | None = None,
    noise_floor: float | None = None,
    lut: np.ndarray | None = None,
    **kwargs: Any,
) -> ExposureRatioResult:
    """The paper's estimator (eq. 4 + 3V iteration) on ``(C, max_level + 1)`` histograms.

    ``saturation`` is ``Z`` in levels, ``noise_floor`` the lowest level used, ``lut`` an optional
    linearisation table ``g`` (``(L,)`` or ``(C, L)``, ``g(max_level) = 1``).
    """
    kwargs.pop("noise_sigma", None)
    return estimate_pair(
        hist_dark,
        hist_bright,
        CERMAN2006,
        saturation=saturation,
        noise_floor=noise_floor,
        lut=lut,
        **kwargs,
    )
