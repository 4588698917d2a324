"""Fast default: coarse-to-fine Gauss-Newton on the seed's eq. 6/7 cost.

Same cost as :mod:`hdrcore.registration.cerman2006` (Cerman & Hlavac 2006, section 6, eqs. 6-7;
see :mod:`hdrcore.registration._problem`), same eq. 5 start, a different search:

* a 2x2 mean pyramid of both frames, clipped to the exposure range they share (so the coarse
  levels of the two frames are the same function of radiance); level 1 is built straight from
  the raw frames in one pass (:mod:`hdrcore.registration._kernels`);
* on each level, from coarse to full resolution, Gauss-Newton on the eq. 7 residuals with the
  exact derivative of the normalisation, over a fixed set of well-exposed, high-gradient pixels
  of the dark frame's grid (at most ``max_samples`` at full resolution, ``coarse_samples`` on
  the coarser levels), spread over the frame and kept in raster order, their validity decided
  at the level's start so the cost is continuous in the motion (decided again once if the
  search moves more than ``RESELECT`` pixels; see :mod:`hdrcore.registration._problem`);
* the motion models nest, one Jacobian column (a generator of the motion, acting on the bright
  frame: ``B <- G(delta) B``) at a time: shift x, y; + rotation (euclidean); + scale
  (similarity); + stretch, shear and two perspective terms (homography). The estimate is a 3x3
  homography throughout; the affine models' updates keep its last row ``(0, 0, 1)`` exactly;
* the bright frame is sampled with Keys cubic convolution at the transformed points only, with
  its analytic gradient, and the eq. 6 sum and the normal equations are accumulated in one
  compiled pass, so a 24-megapixel pair costs a few hundred thousand interpolations per
  iteration, not a full warp. On large frames more full-resolution samples than the first
  version (up to 250 000 instead of 60 000) cost little in raster order and lower the worst
  corner error (``bench/bench_registration.py``, large-frame section);
* each step is the Gauss-Newton step times a factor learnt from the cost along the previous
  one (:func:`_step_scale`: on real phone frames ``J'WJ`` over-estimates the curvature 2.5-3
  times); a step that raises the cost is halved (a simple line search); a level ends when the
  plain Gauss-Newton update
  moves the image corners by less than ``tolerance`` pixels of that level (0.01: on the
  real Pixel 7 pairs 0.002 took 39-63 iterations a pair for a result that moves by at most
  0.016 px, 0.01 takes 28-45; the simulated accuracy is the same to 0.001 px);
* on each finer level the estimate carried from the coarser one competes with the eq. 5 start,
  so a coarse level misled by a photometric mismatch or too little detail cannot drag the
  search away.

Reference: J. Cerman, V. Hlavac, "Exposure time estimation for high dynamic range imaging with
hand held camera", Computer Vision Winter Workshop, 2006. Gauss-Newton image alignment: B. Lucas,
T. Kanade, IJCAI 1981; S. Baker, I. Matthews, "Lucas-Kanade 20 years on", IJCV 56(3), 2004.
"""

from __future__ import annotations

import numpy as np

from ..geometry import homogeneous
from ._problem import (
    MODELS,
    PairData,
    RefineResult,
    Samples,
    corner_move,
    motion_update,
    normal_equations,
    register_with,
    select_samples,
    to_full,
    to_level,
)
from .result import PairRegistration

__all__ = ["register_pair_fast", "refine_gauss_newton"]

#: Bounds of the default full-resolution sample budget (see :func:`refine_gauss_newton`).
MIN_SAMPLES, MAX_SAMPLES = 60_000, 250_000

#: The samples' validity is decided at the level's starting motion with the bright frame's
#: support widened by REACH pixels against saturation; a search that moves more than RESELECT
#: pixels (of the level) from its start decides it again (once) and goes on.
REACH = 0
RESELECT = 0.5

#: Free coefficients of the gain refined with the motion (:func:`refine_gauss_newton`): the
#: exposure ratio and its linear change across the frame. The real Pixel 7 bracket needs
#: them: its frames differ from the listed ratio by a factor 1.14-1.35 and by up to 17 % across
#: the frame, which eq. 6 otherwise takes for perspective (see bench/bench_models_real.py).
GAIN_TERMS = 3

#: Scale of Cauchy's loss in units of the RMS eq. 7 residual at each level's start (0: the
#: plain sum of squares of eq. 6). Measured with 2 against 0 (bench_registration's simulated
#: pairs, 6 a row, mean / worst corner px): two planes 12-bit 0.838 / 7.27 -> 0.212 / 1.85
#: (8-bit 1.29 / 13.4 -> 1.25 / 13.9: the near plane is lost in the noise there), homography
#: 8-bit 0.025 / 0.112 -> 0.021 / 0.081, similarity 8-bit 0.009 / 0.017 -> 0.007 / 0.014,
#: 12-bit the same; real brackets, independent residual median / worst pair: Pixel 7
#: homography 0.410 / 0.665 -> 0.419 / 0.609 (4 of 5 pairs lower), similarity 0.694 / 1.264
#: -> 0.689 / 1.138, Xperia homography 0.246 / 0.339 -> 0.243 / 0.334, similarity 0.461 /
#: 0.912 -> 0.433 / 0.883.
ROBUST = 2.0

#: Largest factor on the Gauss-Newton step (:func:`_step_scale`): above the 2.5-3 measured on
#: the real phone pairs, so the factor can follow it, and low enough that one step learnt on a
#: misleading parabola is undone by a halving or two.
MAX_STEP_SCALE = 4.0


def _level_cost(
    data: PairData, level: int, m: np.ndarray, s: Samples, gain: np.ndarray | None = None
) -> float:
    ssum, count, _, _ = normal_equations(data, level, m, s, gradient=False, gain=gain)
    return ssum / count if count > 0 else np.inf


def _solve(hess: np.ndarray, grad: np.ndarray) -> np.ndarray:
    """Gauss-Newton step ``-H^-1 g``, with the columns scaled to unit diagonal first (the
    generators' units differ; an 8-parameter system is badly scaled otherwise)."""
    d = np.sqrt(np.maximum(np.diag(hess), 1e-300))
    hs = hess / np.outer(d, d)
    gs = grad / d
    try:
        x = np.linalg.solve(hs, gs)
    except np.linalg.LinAlgError:
        x = np.linalg.lstsq(hs, gs, rcond=None)[0]
    return -x / d


def refine_gauss_newton(
    data: PairData,
    initial: np.ndarray,
    model: str,
    *,
    max_samples: int | None = None,
    coarse_samples: int = 20_000,
    max_iterations: int = 30,
    coarse_iterations: int = 12,
    tolerance: float = 1e-2,
    coarsest_size: int = 40,
    gain_terms: int = GAIN_TERMS,
    robust: float = ROBUST,
    exclude: np.ndarray | None = None,
) -> RefineResult:
    """Coarse-to-fine Gauss-Newton from ``initial`` (``coarse_iterations`` per coarse level,
    ``max_iterations`` at full resolution).

    ``max_samples`` (full resolution) defaults to a quarter of the frame's pixels, at least
    60 000 and at most 250 000: on small frames the most informative quarter (more, weaker
    samples raised the worst 8-bit corner error in the bench), on large frames a budget that
    does not grow with the megapixels.

    ``initial`` and the returned matrix (3x3) map dark-frame coordinates to the bright frame (the
    inverse of the pair matrix; see :func:`hdrcore.registration._problem.select_samples`), at
    full resolution. Each step updates the estimate on the bright side, ``B <- G(delta) B``,
    with ``G`` built from the model's generators (:func:`~._problem.motion_update`).

    ``gain_terms`` (0, 1 or 3): the exposure ratio is refined with the motion, as a gain
    ``exp(g0 + g1 X + g2 Y)`` on the bright frame (3: with a linear change across the frame;
    see :data:`GAIN_TERMS`). The gain found is in the result's ``gain``.

    ``robust`` (> 0; 0: plain eq. 6): on each level the search minimises Cauchy's loss with
    the scale ``robust`` times the RMS eq. 7 residual at the level's start, so samples of a
    second plane or a moving object weigh less (see :data:`ROBUST`).

    ``exclude``: full-resolution rectangles ``(K, 4)`` (``x0, y0, x1, y1`` on the dark frame)
    left out of the samples on every level (see :func:`~._problem.select_samples`).
    """
    n_par = MODELS[model]
    if max_samples is None:
        h, w = data.shape
        max_samples = min(MAX_SAMPLES, max(MIN_SAMPLES, h * w // 4))
    top = 0
    while top + 1 < len(data.levels) and min(data.level_shape(top + 1)) >= coarsest_size:
        top += 1
    initial = homogeneous(initial)
    matrix = initial
    history: list[float] = []
    levels: list[int] = []
    gain = np.zeros(3)  # level-independent: X, Y are normalised by each level's half-diagonal
    for level in range(top, -1, -1):
        n_samples = max_samples if level == 0 else coarse_samples
        m = to_level(matrix, level)
        # The samples and their validity are fixed while the motion changes: a continuous cost.
        s = select_samples(data, level, n_samples, motion=m, reach=REACH, exclude=exclude)
        if s.b.size < 4 * n_par:
            continue
        if level < top:  # a coarse level can mislead (photometric mismatch, little detail):
            m0 = to_level(initial, level)  # restart if the start is better here
            sub = s  # the choice needs a rough cost only: at most ~coarse_samples points
            stride = s.b.size // max(coarse_samples, 1)
            if stride > 1:
                sub = Samples(
                    np.ascontiguousarray(s.x[::stride]),
                    np.ascontiguousarray(s.y[::stride]),
                    np.ascontiguousarray(s.b[::stride]),
                )
            if _level_cost(data, level, m0, sub, gain) < _level_cost(data, level, m, sub, gain):
                m = m0
                s = select_samples(data, level, n_samples, motion=m, reach=REACH, exclude=exclude)
        budget = max_iterations if level == 0 else coarse_iterations
        start = m
        c = robust * np.sqrt(_level_cost(data, level, m, s, gain)) if robust > 0 else 0.0
        m, gain = _search(
            data, level, m, gain, s, n_par, gain_terms, budget, tolerance, history, levels, c
        )
        if corner_move(m, start, data.level_shape(level)) > RESELECT:
            # the search left the zone where the samples' validity was decided: decide again
            s = select_samples(data, level, n_samples, motion=m, reach=REACH, exclude=exclude)
            m, gain = _search(
                data, level, m, gain, s, n_par, gain_terms, budget, tolerance, history, levels, c
            )
        matrix = to_full(m, level)
    return RefineResult(matrix, len(history), history, levels, gain=tuple(float(g) for g in gain))


def _search(
    data: PairData,
    level: int,
    m: np.ndarray,
    gain: np.ndarray,
    s: Samples,
    n_par: int,
    n_gain: int,
    budget: int,
    tolerance: float,
    history: list[float],
    levels: list[int],
    robust: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton iterations on one level from ``m`` (3x3, level coordinates) and ``gain``,
    at most ``budget``; appends the costs to ``history`` / ``levels`` and returns the
    estimate (motion, gain).

    Each step is the Gauss-Newton step times a factor ``mu`` (from 1, at most
    :data:`MAX_STEP_SCALE`) learnt along the way (see :func:`_step_scale`)."""
    shape_l = data.level_shape(level)
    prev_m, prev_g = m, gain
    prev_cost = np.inf
    step = None
    slope = 0.0
    mu = 1.0
    best_c, best_m, best_g = np.inf, m, gain
    for _ in range(budget):
        ssum, count, hess, grad = normal_equations(
            data, level, m, s, n_par=n_par, gain=gain, n_gain=n_gain, robust=robust
        )
        c = ssum / count if count > 0 else np.inf
        history.append(c)
        levels.append(level)
        if c < best_c:
            best_c, best_m, best_g = c, m, gain
        if step is not None and c > prev_cost:  # the step went too far: halve it
            step = step / 2.0
            slope /= 2.0
            mu = max(1.0, mu / 2.0)
            trial = motion_update(step[:n_par], shape_l) @ prev_m
            if corner_move(trial, prev_m, shape_l) < tolerance:
                return best_m, best_g
            m, gain = trial, _gain_step(prev_g, step[n_par:])
            continue
        if step is not None and prev_cost - c < 1e-6 * prev_cost:
            return m, gain  # no further decrease: converged to the noise floor of the cost
        if count < (n_par + n_gain) * 4:
            return m, gain
        if step is not None:
            mu = _step_scale(mu, prev_cost, slope, c)
        step = mu * _solve(hess, grad)
        # the cost's derivative along the step at its start: d(sum)/d(delta) = 2 J'Wn
        slope = 2.0 * float(grad @ step) / count
        new_m = motion_update(step[:n_par], shape_l) @ m
        new_m /= new_m[2, 2]
        prev_m, prev_g, prev_cost = m, gain, c
        moved = corner_move(new_m, m, shape_l)
        m, gain = new_m, _gain_step(gain, step[n_par:])
        if moved < tolerance * mu:
            # the Gauss-Newton step itself is tiny (the factor only lengthens it): keep it
            return m, gain
    return best_m, best_g


def _step_scale(mu: float, before: float, slope: float, after: float) -> float:
    """The step factor after a step that lowered the cost from ``before`` to ``after``.

    The parabola through the cost at the step's start (value ``before``, derivative
    ``slope``) and at its end (``after``) has its minimum at ``a`` times the step: the factor
    is multiplied by ``a`` (by 0.5-2 at a time) and kept within 1-:data:`MAX_STEP_SCALE`.
    Gauss-Newton's ``J'WJ`` over-estimates the cost's curvature where the bright frame's
    gradients carry noise and fine texture the motion does not follow (phone JPEGs): on the
    real Pixel 7 pairs the best step along the Gauss-Newton direction was 2.5-3 times the step
    at every full-resolution iteration, and the plain search crept to the minimum in 12-25
    iterations (see :data:`MAX_STEP_SCALE`)."""
    q = after - before - slope
    if not (q > 0.0 and slope < 0.0):
        return mu
    a = -slope / (2.0 * q)
    return min(MAX_STEP_SCALE, max(1.0, mu * min(2.0, max(0.5, a))))


def _gain_step(gain: np.ndarray, delta: np.ndarray) -> np.ndarray:
    out = np.array(gain, float)
    out[: delta.size] += delta
    return out


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
