"""The seed's search: Nelder-Mead simplex on the eq. 6/7 cost (Cerman & Hlavac 2006, section 6).

After the integer shift of eq. 5 (:mod:`hdrcore.registration.fourier`), the seed refines the
sub-pixel shift and the rotation by minimising the cost of eq. 6, built on the normalised
difference of eq. 7 with threshold ``t`` (see :mod:`hdrcore.registration._problem`), with the
downhill simplex method of Nelder and Mead. Pixels above the saturation level or below the noise
floor, in either frame, are discarded.

The search runs at full resolution on a fixed random subset of well-exposed pixels
(``max_samples``, all of them on small frames); the frames are interpolated with Keys cubic
convolution. It needs no derivatives, but many cost evaluations and a start within a few pixels
of the answer; :mod:`hdrcore.registration.fast` minimises the same cost faster.

Reference: J. Cerman, V. Hlavac, "Exposure time estimation for high dynamic range imaging with
hand held camera", Computer Vision Winter Workshop, 2006. J. A. Nelder, R. Mead, "A simplex
method for function minimization", The Computer Journal 7(4), 1965.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

from ._problem import PairData, RefineResult, cost, register_with, select_samples
from .result import PairRegistration
from .transform import rigid_matrix, rigid_parameters

__all__ = ["register_pair_cerman2006", "refine_nelder_mead"]


def refine_nelder_mead(
    data: PairData,
    initial: np.ndarray,
    model: str,
    *,
    max_samples: int = 100_000,
    max_iterations: int = 600,
    xatol: float = 1e-3,
    initial_step: tuple[float, float] = (1.0, 0.2),
) -> RefineResult:
    """Nelder-Mead on ``(dx, dy[, angle_deg])`` from ``initial``.

    ``initial`` and the returned matrix map dark-frame coordinates to the bright frame (the
    inverse of the pair matrix), at full resolution. ``initial_step``: the simplex's first
    steps in pixels and degrees; ``xatol``: convergence in the same units.
    """
    shape = data.shape
    s = select_samples(data, 0, max_samples, by_gradient=False, seed=3)
    dx0, dy0, a0 = rigid_parameters(initial, shape)
    history: list[float] = []
    euclidean = model == "euclidean"

    def matrix(p: np.ndarray) -> np.ndarray:
        return rigid_matrix(p[0], p[1], p[2] if euclidean else a0, shape)

    def f(p: np.ndarray) -> float:
        c, _ = cost(data, 0, matrix(p), s)  # eq. 6
        return c if np.isfinite(c) else 1e6

    p0 = np.array([dx0, dy0, a0] if euclidean else [dx0, dy0])
    step = np.array([initial_step[0], initial_step[0], initial_step[1]][: p0.size])
    simplex = np.vstack([p0] + [p0 + np.eye(p0.size)[i] * step[i] for i in range(p0.size)])
    res = minimize(
        f, p0, method="Nelder-Mead",
        callback=lambda xk: history.append(f(xk)),
        options={"initial_simplex": simplex, "xatol": xatol, "fatol": 1e-12,
                 "maxiter": max_iterations},
    )
    message = "converged" if res.success else f"Nelder-Mead: {res.message}"
    return RefineResult(matrix(res.x), int(res.nit), history, [0] * len(history), message)


def register_pair_cerman2006(
    dark: np.ndarray, bright: np.ndarray, ratio: float, **options
) -> PairRegistration:
    """Register a pair with the seed's method: eq. 5 shift, then Nelder-Mead on eqs. 6-7.

    Arguments as :func:`hdrcore.registration.fast.register_pair_fast`; refinement options are
    those of :func:`refine_nelder_mead`.
    """
    return register_with(refine_nelder_mead, "Cerman 2006", dark, bright, ratio, **options)
