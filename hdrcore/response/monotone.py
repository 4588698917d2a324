"""Monotone least-squares fits of inverse camera responses.

Cerman & Hlavac (2006, section 4.2) observe that unconstrained fits go non-monotone on noisy,
quantised data and ask how much enforcing monotonicity helps. Both model families used in this
package are fitted as *constrained* linear least squares:

* non-parametric log response (Debevec & Malik 1997): the unknowns are the increments
  ``d_k = u_k - u_{k-1}`` of ``u = ln g`` at the nodes; monotone means ``d_k >= 0`` (non-negative
  least squares, :func:`scipy.optimize.nnls`);
* polynomial response (Mitsunaga & Nayar 1999, Grossberg & Nayar 2003): written in the Bernstein
  basis of order ``n`` with coefficients ``b_0 = 0 <= b_1 <= ... <= b_n = 1``; non-negative
  increments of the coefficients are sufficient for a non-decreasing polynomial, and
  ``g(0) = 0``, ``g(1) = 1`` hold by construction.

Both return the number of active (binding) constraints, which the diagnostics report.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
from scipy.special import comb

from ..errors import EstimationError

__all__ = [
    "bernstein_cumulative",
    "fit_increments",
    "PolynomialFit",
    "fit_bernstein_homogeneous",
    "bernstein_value",
]


def fit_increments(
    data: np.ndarray,
    target: np.ndarray,
    smooth_weight: np.ndarray,
    *,
    monotone: bool = True,
) -> tuple[np.ndarray, int, float]:
    """Solve for node values ``u`` (``u[0] = 0``) of a curve from linear observations.

    Minimises ``||data @ u - target||^2 + sum_k (smooth_weight[k] * (u[k-1] - 2 u[k] +
    u[k+1]))^2`` over ``u = cumsum([0, d])`` with ``d >= 0`` when ``monotone``.
    ``data`` is ``(rows, K)``, ``smooth_weight`` ``(K,)`` (the ends are unused).
    Returns ``(u, active_constraints, data_residual_rms)``.
    """
    rows, k = data.shape
    if k < 3:
        raise EstimationError("too few curve nodes", expected=">= 3", found=str(k))
    # data @ u with u_j = sum_{i <= j} d_i  ->  columns are reverse cumulative sums (drop u_0)
    m_data = np.cumsum(data[:, ::-1], axis=1)[:, ::-1][:, 1:]
    # second difference u_{j-1} - 2 u_j + u_{j+1} = d_{j+1} - d_j for j = 1 .. K-2
    j = np.arange(1, k - 1)
    m_smooth = np.zeros((k - 2, k - 1))
    m_smooth[j - 1, j] = smooth_weight[j]
    m_smooth[j - 1, j - 1] = -smooth_weight[j]
    a = np.vstack([m_data, m_smooth])
    rhs = np.concatenate([target, np.zeros(k - 2)])
    d = _least_squares(a, rhs)
    active = 0
    if monotone and np.any(d < 0):
        # the unconstrained optimum is not monotone: non-negative least squares (all the
        # unknowns are increments, so the bounds are exactly d >= 0)
        from scipy.optimize import nnls  # here: scipy.optimize is 0.2 s to import

        d = nnls(a, rhs, maxiter=50 * k)[0]
        active = int(np.sum(d <= 1e-9 * max(1.0, float(np.abs(d).max()))))
    u = np.concatenate([[0.0], np.cumsum(d)])
    r = m_data @ d - target
    rms = float(np.sqrt(np.mean(r**2))) if rows else float("nan")
    return u, active, rms


def _least_squares(a: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Unconstrained least squares through the normal equations (Cholesky; the smoothness rows
    keep them well posed), falling back to an SVD solve when they are singular."""
    ata = a.T @ a
    atb = a.T @ rhs
    try:
        c = scipy.linalg.cho_factor(ata, check_finite=False)
        d = scipy.linalg.cho_solve(c, atb, check_finite=False)
        if np.all(np.isfinite(d)):
            return d
    except np.linalg.LinAlgError:
        pass
    return np.linalg.lstsq(a, rhs, rcond=None)[0]


def bernstein_cumulative(x: np.ndarray, order: int) -> np.ndarray:
    """Columns ``C_i(x) = sum_{j >= i} B_{j,n}(x)`` for ``i = 1 .. n``, shape ``(len(x), n)``.

    With ``b_j = sum_{i <= j} d_i`` the Bernstein polynomial ``sum_j b_j B_{j,n}(x)`` equals
    ``C(x) @ d``.
    """
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    n = int(order)
    j = np.arange(n + 1)
    basis = comb(n, j) * x[:, None] ** j * (1.0 - x[:, None]) ** (n - j)
    return np.cumsum(basis[:, ::-1], axis=1)[:, ::-1][:, 1:]


def bernstein_value(x: np.ndarray, increments: np.ndarray) -> np.ndarray:
    """Evaluate the polynomial with Bernstein coefficient increments ``d`` at ``x`` in [0, 1]."""
    d = np.asarray(increments, dtype=np.float64)
    return bernstein_cumulative(np.asarray(x).ravel(), d.size) @ d


@dataclass(frozen=True)
class PolynomialFit:
    increments: np.ndarray
    ratios: tuple[float, ...]
    residual_rms: float
    active_constraints: int
    iterations: int

    @property
    def order(self) -> int:
        return int(self.increments.size)


def _solve_homogeneous(a: np.ndarray, monotone: bool) -> tuple[np.ndarray, int]:
    """``min ||a d||`` subject to ``sum(d) = 1`` (and ``d >= 0`` when monotone).

    The problem is homogeneous in ``d``, so the penalised problem ``||a d||^2 + w^2 (1'd - 1)^2``
    has the constrained solution times a positive scale; dividing by ``sum(d)`` recovers it
    exactly.
    """
    n = a.shape[1]
    w = float(np.sqrt(np.sum(a**2) / max(a.shape[0], 1))) * 10.0 + 1e-12
    aa = np.vstack([a, np.full((1, n), w)])
    rhs = np.zeros(aa.shape[0])
    rhs[-1] = w
    if monotone:
        from scipy.optimize import nnls

        d = nnls(aa, rhs, maxiter=100 * n)[0]
    else:
        d = np.linalg.lstsq(aa, rhs, rcond=None)[0]
    s = float(d.sum())
    if not np.isfinite(s) or abs(s) < 1e-12:
        raise EstimationError("polynomial response fit degenerated (all-zero curve)")
    d = d / s
    active = int(np.sum(d <= 1e-10)) if monotone else 0
    return d, active


def fit_bernstein_homogeneous(
    dark: np.ndarray,
    bright: np.ndarray,
    pair: np.ndarray,
    weight: np.ndarray,
    ratios: tuple[float, ...],
    order: int,
    *,
    monotone: bool = True,
    refine_ratios: bool = True,
    max_iter: int = 50,
    tol: float = 1e-7,
) -> PolynomialFit:
    """Fit ``g(dark) = g(bright) / R[pair]`` (Mitsunaga & Nayar 1999, eq. 6) with a polynomial.

    ``dark``, ``bright`` are normalised levels in [0, 1]; ``ratios`` the initial consecutive
    ratios ``R = t[k+1] / t[k]``. With ``refine_ratios`` the ratios are re-estimated from the
    current curve (the least-squares update of eq. 8) and the fit repeated until they settle.
    """
    b_dark = bernstein_cumulative(dark, order)
    b_bright = bernstein_cumulative(bright, order)
    c_dark = b_dark * weight[:, None]
    c_bright = b_bright * weight[:, None]
    r = np.asarray(ratios, dtype=np.float64).copy()
    it = 0
    d = np.zeros(order)
    active = 0
    for it in range(1, max_iter + 1):  # noqa: B007
        a = c_dark - c_bright / r[pair][:, None]
        d, active = _solve_homogeneous(a, monotone)
        if not refine_ratios:
            break
        gd = b_dark @ d
        gb = b_bright @ d
        new = r.copy()
        for k in range(r.size):
            sel = pair == k
            num = float(np.sum(weight[sel] * gb[sel]))
            den = float(np.sum(weight[sel] * gd[sel]))
            if sel.any() and num > 0 and den > 0:
                # ratio of sums (MN eq. 8 averages ratios; sums are less sensitive to noise)
                new[k] = num / den
        change = float(np.max(np.abs(np.log(new / r)))) if r.size else 0.0
        r = new
        if change < tol:
            break
    a = c_dark - c_bright / r[pair][:, None]
    if refine_ratios:
        d, active = _solve_homogeneous(a, monotone)
    res = a @ d
    rms = float(np.sqrt(np.mean(res**2))) if res.size else float("nan")
    return PolynomialFit(
        increments=d,
        ratios=tuple(float(v) for v in r),
        residual_rms=rms,
        active_constraints=active,
        iterations=it,
    )
