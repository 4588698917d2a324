"""Debevec-Malik response recovery from brightness transfer functions (the seed's variant).

J. Cerman, V. Hlavac, "Exposure time estimation for high dynamic range imaging with hand held
camera", Computer Vision Winter Workshop 2006, section 4.1: instead of sampled pixels (which
need registered frames), the correspondences of the Debevec & Malik (1997) objective come from
the brightness transfer functions of consecutive frames (histogram matching, Grossberg & Nayar
2002). A dark level ``z`` and its transferred level ``T(z)`` see the same irradiance, so with the
log inverse response ``u = ln g`` (DM eq. 2)

    u(T_k(z)) - u(z) = ln(t_{k+1} / t_k)

for every level; these rows replace the per-pixel rows of DM eq. 3, weighted by the square root
of the pixel count at the level and the hat weights of both levels, and the same smoothness term
and monotone constrained solver (:mod:`.monotone`) are used. No per-pixel irradiances appear.
The seed's saturation fix applies as in :mod:`.debevec1997` (``cutoff=0.98``; ``1.0`` is naive).

P. E. Debevec, J. Malik, SIGGRAPH 1997, DOI: 10.1145/258734.258884.
M. D. Grossberg, S. K. Nayar, "What can be known about the radiometric response from images?",
ECCV 2002.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import EstimationError, ParameterError
from .curve import ChannelFit, ResponseCurve
from .debevec1997 import LogCurveGrid, _status
from .monotone import fit_increments
from .samples import btf_pairs, check_bracket, consecutive_ratios, hat_weight, valid_range

__all__ = ["debevec_histogram"]


def debevec_histogram(
    frames: Sequence[np.ndarray],
    exposure_times: Sequence[float] | None,
    *,
    max_level: int | None = None,
    smoothing: float = 32.0,
    cutoff: float = 0.98,
    low_cut: float = 0.0,
    mask: np.ndarray | None = None,
    monotone: bool = True,
    n_nodes: int = 256,
    above_cutoff: str = "extrapolate",
    stride: int = 1,
) -> ResponseCurve:
    """Recover each channel's inverse response from histograms only (seed section 4.1).

    Frames need not be registered (hand-held brackets), but must see the same scene content.
    ``mask`` (``(H, W)`` bool) selects the pixels counted in every histogram; ``stride``
    subsamples them. Other parameters as :func:`.debevec1997`.
    """
    frames, max_level = check_bracket(frames, max_level)
    ratios = consecutive_ratios(
        exposure_times, len(frames), required=True, method="debevec-histogram"
    )
    if smoothing < 0:
        raise ParameterError("smoothing must be >= 0", found=str(smoothing))
    lo, hi = valid_range(max_level, cutoff, low_cut)
    grid = LogCurveGrid(max_level, n_nodes)
    log_r = np.log(np.asarray(ratios))
    curves, fits, coverage = [], [], []
    for c in range(frames[0].shape[2]):
        corr = btf_pairs(frames, c, max_level, lo, hi, mask=mask, stride=stride)
        w = corr.weight * np.sqrt(hat_weight(corr.dark, lo, hi) * hat_weight(corr.bright, lo, hi))
        keep = w > 0
        if keep.sum() < 2:
            raise EstimationError(
                f"channel {c}: the brightness transfer functions give no usable level pairs",
                expected="overlapping well-exposed levels in consecutive frames",
                found=f"{int(keep.sum())} pair(s)",
            )
        d, b, p, w = corr.dark[keep], corr.bright[keep], corr.pair[keep], w[keep]
        data = w[:, None] * (grid.interpolation(b) - grid.interpolation(d))
        target = w * log_r[p]
        strength = smoothing * np.sqrt(np.sum(w**2) / grid.size)
        u, active, rms = fit_increments(
            data, target, grid.smooth_weight(lo, hi, strength), monotone=monotone
        )
        curves.append(grid.to_levels(u, hi, above_cutoff))
        covered = np.concatenate([d, b])
        coverage.append(float((covered.max() - covered.min()) / max(hi - lo, 1.0)))
        fits.append(
            ChannelFit(
                residual_rms=rms / max(float(np.sqrt(np.mean(w**2))), 1e-300),
                n_constraints=int(keep.sum()),
                exposure_ratios=ratios,
                active_constraints=active,
                iterations=1,
                non_monotone_steps=int(np.sum(np.diff(u) < 0)),
            )
        )
    status, message = _status(fits, grid.size, coverage)
    return ResponseCurve(
        g=np.stack(curves),
        method="debevec-histogram",
        exposure_ratios=ratios,
        channels=tuple(fits),
        status=status,
        message=message,
        parameters={
            "smoothing": smoothing,
            "cutoff": cutoff,
            "low_cut": low_cut,
            "monotone": monotone,
            "n_nodes": grid.size,
            "above_cutoff": above_cutoff,
            "stride": stride,
        },
    )
