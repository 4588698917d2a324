"""Grossberg & Nayar (2003): a polynomial inverse response constrained by the BTFs.

M. D. Grossberg, S. K. Nayar, "Determining the Camera Response from Images: What Is Knowable?",
IEEE TPAMI 25(11), 2003, pp. 1455-1467. DOI: 10.1109/TPAMI.2003.1240119

The brightness transfer function ``T`` of two exposures (histogram matching, section 4 of the
paper; :mod:`hdrcore.btf`) satisfies ``g(T(z)) = R g(z)`` with ``R = t_bright / t_dark``
(eq. 4), so histograms alone constrain the inverse response -- no registration. As Cerman &
Hlavac (2006, section 4) use it, ``g`` is a polynomial fitted to these constraints with
``g(0) = 0``, ``g(1) = 1``; the paper also shows the exponential ambiguity (``g -> g^gamma``,
``R -> R^gamma`` fit equally well, section 5), so the ratios must come from outside (exposure
times) unless ``refine_ratios`` is asked for, which iterates them as Mitsunaga & Nayar do.

Monotonicity is enforced (Bernstein coefficients with non-negative increments), and the order
is chosen automatically by cross-validation over the level pairs (:mod:`.mitsunaga1999`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .curve import ResponseCurve
from .mitsunaga1999 import finish_polynomial, fit_polynomial_channel, initial_ratios
from .samples import btf_pairs, check_bracket, valid_range

__all__ = ["grossberg2003"]


def grossberg2003(
    frames: Sequence[np.ndarray],
    exposure_times: Sequence[float] | None = None,
    *,
    ratios: Sequence[float] | None = None,
    max_level: int | None = None,
    order: int | str = "auto",
    max_order: int = 10,
    monotone: bool = True,
    refine_ratios: bool = False,
    cutoff: float = 0.98,
    low_cut: float = 0.0,
    mask: np.ndarray | None = None,
    stride: int = 1,
    seed: int = 0,
) -> ResponseCurve:
    """Recover each channel's polynomial inverse response from histograms only.

    ``exposure_times`` (or consecutive ``ratios``) give the ratios; ``mask`` ``(H, W)`` selects
    the pixels counted in the histograms. Other parameters as :func:`.mitsunaga1999`.
    """
    frames, max_level = check_bracket(frames, max_level)
    start = initial_ratios(exposure_times, ratios, len(frames), "grossberg2003")
    lo, hi = valid_range(max_level, cutoff, low_cut)
    curves, fits = [], []
    for c in range(frames[0].shape[2]):
        corr = btf_pairs(frames, c, max_level, lo, hi, mask=mask, stride=stride)
        g, fit = fit_polynomial_channel(
            corr,
            max_level,
            start,
            domain=hi,
            order=order,
            max_order=max_order,
            monotone=monotone,
            refine_ratios=refine_ratios,
            seed=seed,
            channel=c,
        )
        curves.append(g)
        fits.append(fit)
    return finish_polynomial(
        "grossberg2003",
        curves,
        fits,
        {
            "order": order,
            "max_order": max_order,
            "monotone": monotone,
            "refine_ratios": refine_ratios,
            "cutoff": cutoff,
            "low_cut": low_cut,
            "stride": stride,
            "seed": seed,
            "initial_ratios": list(start),
        },
    )
