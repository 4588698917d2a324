"""Fast default: coarse-to-fine Gauss-Newton on the seed's eq. 6/7 cost.

Same cost as :mod:`hdrcore.registration.cerman2006` (Cerman & Hlavac 2006, section 6, eqs. 6-7;
see :mod:`hdrcore.registration._problem`), same eq. 5 start, a different search:

* a 2x2 mean pyramid of both frames, clipped to the exposure range they share (so the coarse
  levels of the two frames are the same function of radiance); level 1 is built straight from
  the raw frames in one pass (:mod:`hdrcore.registration._kernels`);
* on each level, from coarse to full resolution, Gauss-Newton on the eq. 7 residuals with the
  exact derivative of the normalisation, over a fixed set of well-exposed, high-gradient pixels
  of the dark frame's grid (at most ``max_samples`` at full resolution, ``coarse_samples`` on
  the coarser levels), spread over the frame and kept in raster order;
* the bright frame is sampled with Keys cubic convolution at the transformed points only, with
  its analytic gradient, and the eq. 6 sum and the normal equations are accumulated in one
  compiled pass, so a 24-megapixel pair costs a few hundred thousand interpolations per
  iteration, not a full warp. On large frames more full-resolution samples than the first
  version (up to 250 000 instead of 60 000) cost little in raster order and lower the worst
  corner error (``bench/bench_registration.py``, large-frame section);
* a step that raises the cost is halved (a simple line search); a level ends when the update
  moves the image corners by less than ``tolerance`` pixels of that level;
* on each finer level the estimate carried from the coarser one competes with the eq. 5 start,
  so a coarse level misled by a photometric mismatch or too little detail cannot drag the
  search away.

Reference: J. Cerman, V. Hlavac, "Exposure time estimation for high dynamic range imaging with
hand held camera", Computer Vision Winter Workshop, 2006. Gauss-Newton image alignment: B. Lucas,
T. Kanade, IJCAI 1981; S. Baker, I. Matthews, "Lucas-Kanade 20 years on", IJCV 56(3), 2004.
"""

from __future__ import annotations

import numpy as np

from ._problem import (
    MODELS,
    PairData,
    RefineResult,
    Samples,
    level_to_full,
    normal_equations,
    register_with,
    rigid_to_level,
    select_samples,
)
from .result import PairRegistration
from .transform import rigid_matrix

__all__ = ["register_pair_fast", "refine_gauss_newton"]

#: Bounds of the default full-resolution sample budget (see :func:`refine_gauss_newton`).
MIN_SAMPLES, MAX_SAMPLES = 60_000, 250_000


def _level_cost(
    data: PairData, level: int, p: np.ndarray, shape_l: tuple[int, int], s: Samples
) -> float:
    m = rigid_matrix(p[0], p[1], np.rad2deg(p[2]), shape_l)
    ssum, count, _, _ = normal_equations(data, level, m, s, gradient=False)
    return ssum / count if count else np.inf


def refine_gauss_newton(
    data: PairData,
    initial: np.ndarray,
    model: str,
    *,
    max_samples: int | None = None,
    coarse_samples: int = 20_000,
    max_iterations: int = 30,
    coarse_iterations: int = 12,
    tolerance: float = 2e-3,
    coarsest_size: int = 40,
) -> RefineResult:
    """Coarse-to-fine Gauss-Newton from ``initial`` (``coarse_iterations`` per coarse level,
    ``max_iterations`` at full resolution).

    ``max_samples`` (full resolution) defaults to a quarter of the frame's pixels, at least
    60 000 and at most 250 000: on small frames the most informative quarter (more, weaker
    samples raised the worst 8-bit corner error in the bench), on large frames a budget that
    does not grow with the megapixels.

    ``initial`` and the returned matrix map dark-frame coordinates to the bright frame (the
    inverse of the pair matrix; see :func:`hdrcore.registration._problem.select_samples`), at
    full resolution.
    """
    n_par = MODELS[model]
    if max_samples is None:
        h, w = data.shape
        max_samples = min(MAX_SAMPLES, max(MIN_SAMPLES, h * w // 4))
    top = 0
    while top + 1 < len(data.levels) and min(data.level_shape(top + 1)) >= coarsest_size:
        top += 1
    matrix = np.asarray(initial, float)
    history: list[float] = []
    levels: list[int] = []
    iterations = 0
    for level in range(top, -1, -1):
        shape_l = data.level_shape(level)
        h, w = shape_l
        cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
        radius = float(np.hypot(cx, cy))
        s = select_samples(data, level, max_samples if level == 0 else coarse_samples)
        if s.b.size < 8:
            continue
        p = rigid_to_level(matrix, level, shape_l)
        if level < top:  # a coarse level can mislead (photometric mismatch, little detail):
            p0 = rigid_to_level(initial, level, shape_l)  # restart if the start is better here
            sub = s  # the choice needs a rough cost only: at most ~coarse_samples points
            stride = s.b.size // max(coarse_samples, 1)
            if stride > 1:
                sub = Samples(*(np.ascontiguousarray(a[::stride]) for a in (s.x, s.y, s.b)))
            if (_level_cost(data, level, p0, shape_l, sub)
                    < _level_cost(data, level, p, shape_l, sub)):
                p = p0
        prev_p = None
        prev_cost = np.inf
        step = None
        best_c, best_p = np.inf, p
        for _ in range(max_iterations if level == 0 else coarse_iterations):
            m = rigid_matrix(p[0], p[1], np.rad2deg(p[2]), shape_l)
            ssum, count, hess, grad = normal_equations(data, level, m, s, n_par=n_par)
            c = ssum / count if count else np.inf
            history.append(c)
            levels.append(level)
            iterations += 1
            if c < best_c:
                best_c, best_p = c, p
            if step is not None and c > prev_cost:  # the step went too far: halve it
                step = step / 2.0
                if np.abs(step[:2]).max() + abs(step[2]) * radius < tolerance:
                    p = best_p
                    break
                p = prev_p + step
                continue
            if step is not None and prev_cost - c < 1e-6 * prev_cost:
                break  # no further decrease: converged to the noise floor of the cost
            if count < n_par * 4:
                break
            try:
                delta = -np.linalg.solve(hess, grad)
            except np.linalg.LinAlgError:
                delta = -np.linalg.lstsq(hess, grad, rcond=None)[0]
            if n_par == 2:
                delta = np.append(delta, 0.0)
            prev_p, prev_cost, step = p.copy(), c, delta
            p = p + delta
            if np.abs(delta[:2]).max() + abs(delta[2]) * radius < tolerance:
                break  # a tiny move from an evaluated point: keep it
        else:
            p = best_p
        matrix = level_to_full(p, level, shape_l)
    return RefineResult(matrix, iterations, history, levels)


def register_pair_fast(
    dark: np.ndarray, bright: np.ndarray, ratio: float, **options
) -> PairRegistration:
    """Register a pair with the fast coarse-to-fine Gauss-Newton search (see module docstring).

    ``dark`` and ``bright`` are single-channel linear images, ``ratio`` the exposure ratio
    ``t_bright / t_dark``. Options: those of the common driver (``saturation``, ``noise_floor``,
    ``threshold``, ``model``, ``initial``, ``previews``, ...) and of
    :func:`refine_gauss_newton` (``max_samples``, ``max_iterations``, ``tolerance``).
    """
    return register_with(refine_gauss_newton, "fast", dark, bright, ratio, **options)
