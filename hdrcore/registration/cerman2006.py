"""The seed's search: Nelder-Mead simplex on the eq. 6/7 cost (Cerman & Hlavac 2006, section 6).

After the integer shift of eq. 5 (:mod:`hdrcore.registration.fourier`), the seed refines the
sub-pixel shift and the rotation (and here, with the ``"similarity"`` model, a scale) by
minimising the cost of eq. 6, built on the normalised
difference of eq. 7 with threshold ``t`` (see :mod:`hdrcore.registration._problem`), with the
downhill simplex method of Nelder and Mead. Pixels above the saturation level or below the noise
floor, in either frame, are discarded.

The search runs at full resolution on a fixed random subset of well-exposed pixels
(``max_samples``, all of them on small frames); the frames are interpolated with Keys cubic
convolution. It needs no derivatives, but many cost evaluations and a start within a few pixels
of the answer; :mod:`hdrcore.registration.fast` minimises the same cost faster. The simplex
search supports the ``"shift"``, ``"euclidean"`` and ``"similarity"`` models; an 8-parameter
``"homography"`` is refused (a ParameterError): use the fast method for it.

Reference: J. Cerman, V. Hlavac, "Exposure time estimation for high dynamic range imaging with
hand held camera", Computer Vision Winter Workshop, 2006. J. A. Nelder, R. Mead, "A simplex
method for function minimization", The Computer Journal 7(4), 1965.
"""

from __future__ import annotations

import numpy as np

from ..geometry import corner_error, similarity_matrix, similarity_parameters
from ._problem import PairData, RefineResult, cost, register_with, select_samples
from .result import PairRegistration

__all__ = ["register_pair_cerman2006", "refine_nelder_mead", "MODELS"]

#: The motion models the simplex search supports (the parameters it varies).
MODELS = ("shift", "euclidean", "similarity")


def refine_nelder_mead(
    data: PairData,
    initial: np.ndarray,
    model: str,
    *,
    max_samples: int = 100_000,
    max_iterations: int = 600,
    xatol: float = 1e-3,
    initial_step: tuple[float, float, float] = (1.0, 0.2, 0.002),
) -> RefineResult:
    """Nelder-Mead on ``(dx, dy[, angle_deg[, scale]])`` from ``initial``.

    ``initial`` and the returned matrix map dark-frame coordinates to the bright frame (the
    inverse of the pair matrix), at full resolution. ``initial_step``: the simplex's first
    steps in pixels, degrees and scale; ``xatol``: convergence in the same units.
    """
    from scipy.optimize import minimize  # here: scipy.optimize is 0.2 s to import

    shape = data.shape
    n_par = {"shift": 2, "euclidean": 3, "similarity": 4}[model]
    history: list[float] = []
    dx0, dy0, a0, sc0 = similarity_parameters(initial, shape)

    def matrix(p: np.ndarray) -> np.ndarray:
        return similarity_matrix(
            p[0], p[1], p[2] if n_par > 2 else a0, p[3] if n_par > 3 else sc0, shape
        )

    p = np.array([dx0, dy0, a0, sc0][:n_par])
    step = np.array([initial_step[0], initial_step[0], initial_step[1], initial_step[2]][:n_par])
    iterations, message = 0, "converged"
    for _ in range(2):
        # The samples and their validity are fixed during a search (a continuous cost), decided
        # at its start; a search that moved by more than half a pixel runs again from its result.
        s = select_samples(
            data, 0, max_samples, motion=matrix(p), by_gradient=False, seed=3, reach=0
        )

        def f(q: np.ndarray, s=s) -> float:
            c, _ = cost(data, 0, matrix(q), s)  # eq. 6
            return c if np.isfinite(c) else 1e6

        simplex = np.vstack([p] + [p + np.eye(p.size)[i] * step[i] for i in range(p.size)])
        res = minimize(
            f,
            p,
            method="Nelder-Mead",
            callback=lambda xk, f=f: history.append(f(xk)),
            options={
                "initial_simplex": simplex,
                "xatol": xatol,
                "fatol": 1e-12,
                "maxiter": max_iterations,
            },
        )
        iterations += int(res.nit)
        message = "converged" if res.success else f"Nelder-Mead: {res.message}"
        moved = float(corner_error(matrix(res.x), matrix(p), shape).max())
        p = res.x
        if moved <= 0.5:
            break
        step = step / 4.0
    return RefineResult(matrix(p), iterations, history, [0] * len(history), message)


def register_pair_cerman2006(
    dark: np.ndarray, bright: np.ndarray, ratio: float, **options
) -> PairRegistration:
    """Register a pair with the seed's method: eq. 5 shift, then Nelder-Mead on eqs. 6-7.

    Arguments as :func:`hdrcore.registration.fast.register_pair_fast`; refinement options are
    those of :func:`refine_nelder_mead`.
    """
    return register_with(
        refine_nelder_mead, "Cerman 2006", dark, bright, ratio, models=MODELS, **options
    )
