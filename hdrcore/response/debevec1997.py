"""Debevec & Malik (1997) response recovery from pixel samples, with the seed's saturation fix.

P. E. Debevec, J. Malik, "Recovering High Dynamic Range Radiance Maps from Photographs",
SIGGRAPH 1997, pp. 369-378. DOI: 10.1145/258734.258884

The log inverse response ``u(z) = ln g(z)`` and the log irradiances ``ln E_i`` of sampled pixels
minimise (eq. 3 of the paper)

    sum_ij [w(Z_ij) (u(Z_ij) - ln E_i - ln t_j)]^2 + lambda^2 sum_z [w(z) u''(z)]^2

with the hat weighting ``w`` (eq. 4). Here ``ln E_i`` is eliminated in closed form (its weighted
mean over the frames), ``u`` lives on up to ``n_nodes`` nodes (every level for 8-bit data) with
linear interpolation between them, and monotonicity is enforced as non-negative increments
(:mod:`.monotone`).

The seed's fix (Cerman & Hlavac 2006, section 4.2): with noise, values close to saturation are
biased and the naive fit fails; only levels in ``(0, 0.98 * max_level)`` enter the data term,
and above the cut the curve is continued by the smoothness term alone (second difference zero,
a straight continuation of ``ln g``). The seed holds ``g`` constant there; continuing it keeps
the normalisation ``g(max_level) = 1`` unbiased (``above_cutoff="constant"`` gives the seed's
literal variant). ``cutoff=1.0`` is the naive method.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import EstimationError, ParameterError
from ..status import ResponseStatus
from .curve import ChannelFit, ResponseCurve, normalise_curve
from .monotone import fit_increments
from .samples import check_bracket, consecutive_ratios, hat_weight, pixel_samples, valid_range

__all__ = ["debevec1997", "LogCurveGrid"]


class LogCurveGrid:
    """Nodes of a non-parametric log response on levels ``1 .. max_level``.

    Level 0 has ``g = 0`` (``ln g = -inf``) and is never a node.
    """

    def __init__(self, max_level: int, n_nodes: int = 256) -> None:
        if n_nodes < 8:
            raise ParameterError("n_nodes must be >= 8", found=str(n_nodes))
        self.max_level = int(max_level)
        k = min(self.max_level, int(n_nodes))
        self.nodes = np.linspace(1.0, float(self.max_level), k)
        self.step = (self.nodes[-1] - self.nodes[0]) / (k - 1)

    @property
    def size(self) -> int:
        return int(self.nodes.size)

    def interpolation(self, z: np.ndarray) -> np.ndarray:
        """Dense ``(len(z), K)`` matrix with ``u(z) = M @ u_nodes`` (linear interpolation)."""
        z = np.asarray(z, dtype=np.float64).ravel()
        k = self.size
        pos = np.clip((z - self.nodes[0]) / self.step, 0.0, k - 1.0)
        i0 = np.minimum(np.floor(pos).astype(np.intp), k - 2)
        f = pos - i0
        m = np.zeros((z.size, k))
        rows = np.arange(z.size)
        m[rows, i0] = 1.0 - f
        m[rows, i0 + 1] += f
        return m

    def smooth_weight(self, lo: float, hi: float, strength: float, floor: float = 0.02):
        """Smoothness weight per node: ``strength * max(hat(z), floor)`` (DM eq. 3)."""
        return strength * np.maximum(hat_weight(self.nodes, lo, hi), floor)

    def to_levels(self, u: np.ndarray, hi: float, above_cutoff: str = "extrapolate") -> np.ndarray:
        """Normalised linear ``g`` at every level 0..max from node values of ``ln g``."""
        levels = np.arange(self.max_level + 1, dtype=np.float64)
        u_all = np.interp(levels, self.nodes, u)
        if above_cutoff == "constant":
            top = levels >= hi
            if top.any() and not top.all():
                u_all[top] = u_all[np.flatnonzero(~top)[-1]]
        elif above_cutoff != "extrapolate":
            raise ParameterError(
                "unknown above_cutoff",
                expected="'extrapolate' or 'constant'",
                found=repr(above_cutoff),
            )
        g = np.exp(u_all - u_all.max())
        g[0] = 0.0
        return normalise_curve(g)[0]


def _status(
    fits: Sequence[ChannelFit], n_nodes: int, coverage: Sequence[float]
) -> tuple[ResponseStatus, str]:
    msgs = []
    for c, (f, cov) in enumerate(zip(fits, coverage, strict=True)):
        if f.active_constraints > 0.1 * n_nodes:
            msgs.append(
                f"channel {c}: monotonicity binding at {f.active_constraints} nodes "
                "(noisy or inconsistent data)"
            )
        if f.non_monotone_steps:
            msgs.append(
                f"channel {c}: unconstrained fit decreases at {f.non_monotone_steps} level "
                "steps; repaired with a running maximum"
            )
        if cov < 0.5:
            msgs.append(f"channel {c}: samples cover only {100 * cov:.0f}% of the levels")
    return ("warning", "; ".join(msgs)) if msgs else ("ok", "")


def debevec1997(
    frames: Sequence[np.ndarray],
    exposure_times: Sequence[float] | None,
    *,
    max_level: int | None = None,
    smoothing: float = 32.0,
    cutoff: float = 0.98,
    low_cut: float = 0.0,
    n_samples: int = 1000,
    mask: np.ndarray | None = None,
    monotone: bool = True,
    n_nodes: int = 256,
    above_cutoff: str = "extrapolate",
    seed: int = 0,
) -> ResponseCurve:
    """Recover the inverse response of each channel from pixel samples (DM 1997, eq. 3).

    Parameters
    ----------
    frames : integer frames ``(H, W[, C])``, registered, darkest first.
    exposure_times : seconds per frame (only their ratios matter).
    smoothing : lambda of eq. 3, relative to the data term (independent of the sample count).
    cutoff, low_cut : only levels in ``(low_cut, cutoff) * max_level`` enter the data term
        (seed's fix: ``cutoff=0.98``; naive: ``1.0``).
    n_samples : number of sampled pixels per channel (stratified over levels of every frame).
    mask : ``(H, W)`` bool, pixels that may be sampled (e.g. to exclude borders).
    monotone : enforce a non-decreasing curve (constrained least squares).
    """
    frames, max_level = check_bracket(frames, max_level)
    ratios = consecutive_ratios(exposure_times, len(frames), required=True, method="debevec1997")
    if smoothing < 0:
        raise ParameterError("smoothing must be >= 0", found=str(smoothing))
    log_t = np.concatenate([[0.0], np.cumsum(np.log(ratios))])
    lo, hi = valid_range(max_level, cutoff, low_cut)
    grid = LogCurveGrid(max_level, n_nodes)
    n_ch = frames[0].shape[2]
    curves, fits, coverage = [], [], []
    for c in range(n_ch):
        z = pixel_samples(frames, c, max_level, n_samples=n_samples, mask=mask, seed=seed)
        valid = (z > lo) & (z < hi)
        w = hat_weight(z, lo, hi) * valid
        keep = np.count_nonzero(w > 0, axis=1) >= 2
        z, w = z[keep], w[keep]
        if z.shape[0] < 2:
            raise EstimationError(
                f"channel {c}: no pixel is well exposed in two frames",
                expected="pixels inside the valid level range in >= 2 frames",
                found=f"{z.shape[0]} sample(s)",
            )
        n, p = z.shape
        # eliminate ln E_i: weighted mean over frames with weights w^2
        w2 = w**2
        pi = w2 / w2.sum(axis=1, keepdims=True)
        a = grid.interpolation(z.ravel()).reshape(n, p, grid.size)
        a_bar = np.einsum("np,npk->nk", pi, a)
        t_bar = pi @ log_t
        data = (w[..., None] * (a - a_bar[:, None, :])).reshape(n * p, grid.size)
        target = (w * (log_t[None, :] - t_bar[:, None])).ravel()
        rows = w.ravel() > 0
        data, target = data[rows], target[rows]
        strength = smoothing * np.sqrt(np.sum(w2) / grid.size)
        u, active, rms = fit_increments(
            data, target, grid.smooth_weight(lo, hi, strength), monotone=monotone
        )
        curves.append(grid.to_levels(u, hi, above_cutoff))
        zs = z[w > 0]
        coverage.append(float((zs.max() - zs.min()) / max(hi - lo, 1.0)))
        fits.append(
            ChannelFit(
                residual_rms=rms,
                n_constraints=int(rows.sum()),
                exposure_ratios=ratios,
                active_constraints=active,
                iterations=1,
                non_monotone_steps=int(np.sum(np.diff(u) < 0)),
            )
        )
    status, message = _status(fits, grid.size, coverage)
    return ResponseCurve(
        g=np.stack(curves),
        method="debevec1997",
        exposure_ratios=ratios,
        channels=tuple(fits),
        status=status,
        message=message,
        parameters={
            "smoothing": smoothing,
            "cutoff": cutoff,
            "low_cut": low_cut,
            "n_samples": n_samples,
            "monotone": monotone,
            "n_nodes": grid.size,
            "above_cutoff": above_cutoff,
            "seed": seed,
        },
    )
