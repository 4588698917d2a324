"""Joint response recovery: one shared monotone shape for all channels, separate curves only
when the data support them.

The project's own method, built on the seed's histogram variant of Debevec & Malik (Cerman &
Hlavac 2006, section 4.1; :mod:`.debevec_histogram`): every channel's brightness transfer
functions give level pairs ``(z, T_k(z))`` with

    u_c(T_k(z)) - u_c(z) = ln(t_{k+1} / t_k)          (u_c = ln g_c, DM eq. 2)

and the log inverse response lives on level nodes. Three things differ from the per-channel
fit, each because of a failure seen on real JPEG brackets (issue 15):

* **Channels fitted jointly.** A camera applies one tone curve to white-balanced RGB, so the
  default model is one shape ``U`` shared by the channels, with a per-channel exponent
  ``u_c = a_c U`` (a gain in the log domain: film's dye layers differ in contrast); the fully
  separate model is kept only when held-back correspondences (:mod:`.holdout`) are explained
  better by more than :data:`SEPARATE_GAIN`. Three channels of evidence for one shape cannot
  drift apart into a colour cast, and a channel with little data (a blue sky) borrows the
  others' shape.
* **A prior that degrades gracefully.** With equal exposure steps ``R`` the data fix ``u`` only
  up to a periodic component of period ``ln R`` (Grossberg & Nayar 2003, section 5), which
  only a smoothness prior resolves. The second derivative is penalised in the coordinate
  ``s = logit(z / (max + 1))`` (straight lines there are log-logistic curves: power laws at
  the bottom, shoulders at the top; a gamma curve is nearly straight), with one weight at
  every node instead of DM's hat (which fades the prior exactly where the histogram carries
  no information and let the ends kink). Above :data:`LEVEL_PRIOR_FROM` of the range the
  coordinate continues linearly in the level: beyond the data (the saturation cut) ``ln g``
  continues straight, as in the seed's fix.
* **Diagnostics for degeneracy.** Per channel and per level the residuals of the fit, the
  binding monotonicity constraints and the flat stretches inside the data range are returned
  for :mod:`.degeneracy`.

Seed protocol (6 frames 4x apart, 8 bits, sigma 1 level, 2 scenes x 2 seeds,
``bench/bench_response.py``): the RMS error of ``g`` over levels 2..98 % after one exposure
scale stays at or under 0.11 % of the range, worst channel, for gamma, sRGB, poly3, S-curve,
filmic and toe-shoulder responses (the per-channel DM-histogram fit: up to 1.40 %, OpenCV's
Debevec and Robertson 10-21 %). Level pairs near black are weighted by the inverse of their
log noise (:func:`.samples.pair_weight`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

from ..errors import EstimationError, ParameterError
from .curve import ChannelFit, ResponseCurve, normalise_curve
from .samples import (
    Correspondences,
    btf_pairs,
    check_bracket,
    consecutive_ratios,
    pair_weight,
    pixel_pairs,
    pixel_samples,
    valid_range,
)

__all__ = [
    "JOINT_MODELS",
    "LEVEL_PRIOR_FROM",
    "SEPARATE_GAIN",
    "JointFit",
    "fit_joint",
    "joint_histogram",
    "joint_pixels",
    "level_residuals",
]

#: Models of the channels, simplest first: one shape; one shape with a per-channel exponent
#: (gain of ``ln g``); a curve per channel.
JOINT_MODELS = ("shared", "gains", "separate")

#: A more complex model is chosen only when it lowers the held-back residual by this fraction.
SEPARATE_GAIN = 0.10

#: Fraction of the level range above which the prior continues ``ln g`` linearly in the level.
LEVEL_PRIOR_FROM = 0.90

#: Default strength of the smoothness prior (relative to the data term, size independent).
#: Scanned on the seed protocol (4 scenes x 2 seeds, 8 response shapes): the shape error stays
#: under 0.7 % from 0.03 to 0.1 (0.33 % at 0.1); 0.2 and more bend the toes; smaller values
#: extrapolate steep shoulders a little better but follow more noise.
DEFAULT_SMOOTHING = 0.1


@dataclass(frozen=True, eq=False)
class JointFit:
    """One joint fit: ``g`` per channel, the node values and the diagnostics.

    ``u`` are the node values of ``ln g`` per channel (before normalisation), ``gains`` the
    per-channel exponents (1 for ``shared`` and ``separate``), ``active`` the binding
    monotonicity constraints per channel, ``rms`` the weighted data residual per channel (ln
    units), ``residuals`` ``(C, L)`` the weighted mean residual at every level (NaN where no
    correspondence touches it), ``data_range`` the lowest and highest level with data per
    channel.
    """

    g: np.ndarray
    model: str
    nodes: np.ndarray
    u: np.ndarray
    gains: tuple[float, ...]
    active: tuple[int, ...]
    rms: tuple[float, ...]
    n_rows: tuple[int, ...]
    residuals: np.ndarray
    data_range: tuple[tuple[float, float], ...]


def _coordinate(z: np.ndarray, max_level: int) -> np.ndarray:
    """The prior's coordinate: ``logit(z / (max + 1))``, continued linearly in ``z`` above
    :data:`LEVEL_PRIOR_FROM` of the range."""
    z = np.asarray(z, dtype=np.float64)
    top = float(max_level) + 1.0
    knee = LEVEL_PRIOR_FROM * max_level
    s = np.log(z / (top - z))
    s_knee = np.log(knee / (top - knee))
    slope = 1.0 / knee + 1.0 / (top - knee)
    return np.where(z <= knee, s, s_knee + slope * (z - knee))


def _nodes(max_level: int, n_nodes: int) -> np.ndarray:
    if n_nodes < 8:
        raise ParameterError("n_nodes must be >= 8", found=str(n_nodes))
    return np.linspace(1.0, float(max_level), min(int(max_level), int(n_nodes)))


def _interpolation(z: np.ndarray, nodes: np.ndarray) -> scipy.sparse.csr_matrix:
    """Sparse ``(len(z), K)`` linear-interpolation matrix on uniformly spaced nodes."""
    z = np.asarray(z, dtype=np.float64).ravel()
    k = nodes.size
    step = (nodes[-1] - nodes[0]) / (k - 1)
    pos = np.clip((z - nodes[0]) / step, 0.0, k - 1.0)
    i0 = np.minimum(np.floor(pos).astype(np.intp), k - 2)
    f = pos - i0
    rows = np.arange(z.size)
    return scipy.sparse.csr_matrix(
        (
            np.concatenate([1.0 - f, f]),
            (np.concatenate([rows, rows]), np.concatenate([i0, i0 + 1])),
        ),
        shape=(z.size, k),
    )


def _smoothness(nodes: np.ndarray, max_level: int) -> scipy.sparse.csr_matrix:
    """``(K - 2, K)`` rows of the second derivative in the prior's coordinate, each weighted
    by the square root of its share of the coordinate (a discretised integral of ``u''^2``)."""
    s = _coordinate(nodes, max_level)
    h1 = s[1:-1] - s[:-2]
    h2 = s[2:] - s[1:-1]
    a = 2.0 / (h1 * (h1 + h2))
    c = 2.0 / (h2 * (h1 + h2))
    w = np.sqrt(0.5 * (h1 + h2))
    k = nodes.size
    j = np.arange(k - 2)
    return scipy.sparse.csr_matrix(
        (
            np.concatenate([a * w, -(a + c) * w, c * w]),
            (np.concatenate([j, j, j]), np.concatenate([j, j + 1, j + 2])),
        ),
        shape=(k - 2, k),
    )


def checked_mask(mask: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray | None:
    """``mask`` as booleans of the frames' ``shape`` (``None``: every pixel)."""
    base = None if mask is None else np.asarray(mask, bool)
    if base is not None and base.shape != tuple(shape):
        raise ParameterError(
            "mask must match the frame size", expected=str(tuple(shape)), found=str(base.shape)
        )
    return base


def fold_mask(base: np.ndarray | None, fold, shape: tuple[int, int]) -> np.ndarray | None:
    """``base`` restricted to a cross-validation fold (``fold(shape)``: a boolean image)."""
    if fold is None:
        return base
    f = fold(shape)
    return f if base is None else (base & f)


def _solve(
    data: scipy.sparse.spmatrix, target: np.ndarray, smooth: scipy.sparse.spmatrix, monotone: bool
) -> tuple[np.ndarray, int]:
    """Node values ``u`` (``u[0] = 0``) minimising ``|data u - target|^2 + |smooth u|^2``,
    non-decreasing when ``monotone`` (then as non-negative increments, :func:`nnls`)."""
    k = data.shape[1]
    a = scipy.sparse.vstack([data, smooth]).tocsc()[:, 1:]
    rhs = np.concatenate([target, np.zeros(smooth.shape[0])])
    # sparse normal equations through SuperLU: a dense LAPACK factorisation of this small
    # system waits for BLAS threads on a loaded machine (0.5 s instead of 0.5 ms)
    ata = (a.T @ a).tocsc()
    atb = a.T @ rhs
    u = scipy.sparse.linalg.spsolve(ata, atb)
    if not np.all(np.isfinite(u)):
        u = scipy.sparse.linalg.lsqr(a, rhs, atol=1e-12, btol=1e-12)[0]
    u = np.concatenate([[0.0], u])
    if not monotone or np.all(np.diff(u) >= 0):
        return u, 0
    # the unconstrained optimum goes down somewhere: non-negative increments d, u = cumsum(d).
    # |A d - b|^2 = |R d - c|^2 + const with R^T R = A^T A (Cholesky) and R^T c = A^T b: the
    # same non-negative least squares on a k x k system instead of one row per level pair
    # (a 14-bit bracket has tens of thousands: 2.5 s a solve, now milliseconds).
    to_u = np.tril(np.ones((k, k - 1)), -1)
    stacked = scipy.sparse.vstack([data, smooth]).tocsr()
    sts = (stacked.T @ stacked).toarray()
    ata = to_u.T @ sts @ to_u
    atb = to_u.T @ (stacked.T @ rhs)
    from scipy.optimize import nnls  # here: scipy.optimize is 0.2 s to import

    try:
        low = np.linalg.cholesky(ata + 1e-12 * np.trace(ata) / len(ata) * np.eye(len(ata)))
        r = low.T
        c = scipy.linalg.solve_triangular(low, atb, lower=True)
        d = nnls(r, c, maxiter=50 * k)[0]
    except np.linalg.LinAlgError:
        d = nnls(np.asarray(stacked @ to_u), rhs, maxiter=50 * k)[0]
    active = int(np.sum(d <= 1e-9 * max(1.0, float(np.abs(d).max()))))
    return to_u @ d, active


@dataclass(frozen=True, eq=False)
class _Rows:
    """Weighted level pairs of one channel (both levels inside the data range)."""

    dark: np.ndarray
    bright: np.ndarray
    pair: np.ndarray
    weight: np.ndarray


def _rows(corr: Correspondences, lo: float, hi: float, max_level: int) -> _Rows:
    w = pair_weight(corr, lo, hi, max_level)
    keep = w > 0
    return _Rows(corr.dark[keep], corr.bright[keep], corr.pair[keep], w[keep])


def fit_joint(
    pairs: Sequence[Correspondences],
    log_ratios: np.ndarray,
    max_level: int,
    *,
    model: str = "shared",
    smoothing: float = DEFAULT_SMOOTHING,
    cutoff: float = 0.98,
    low_cut: float = 0.0,
    monotone: bool = True,
    n_nodes: int = 256,
    iterations: int = 6,
    residuals: bool = True,
) -> JointFit:
    """Fit the log inverse responses of all channels to their level pairs at once.

    ``pairs[c]`` are channel ``c``'s correspondences (:func:`.samples.btf_pairs` or
    :func:`.samples.pixel_pairs`); ``log_ratios[k]`` is ``ln(t[k+1] / t[k])``. ``model`` is
    one of :data:`JOINT_MODELS`.
    """
    if model not in JOINT_MODELS:
        raise ParameterError(
            f"unknown joint model {model!r}", expected=f"one of {', '.join(JOINT_MODELS)}"
        )
    if smoothing < 0:
        raise ParameterError("smoothing must be >= 0", found=str(smoothing))
    lo, hi = valid_range(max_level, cutoff, low_cut)
    log_r = np.asarray(log_ratios, dtype=np.float64)
    nodes = _nodes(max_level, n_nodes)
    n_ch = len(pairs)
    rows = [_rows(p, lo, hi, max_level) for p in pairs]
    for c, r in enumerate(rows):
        if r.weight.size < 2:
            raise EstimationError(
                f"channel {c}: no usable level pairs for the response",
                expected="overlapping well-exposed levels in consecutive frames",
                found=f"{r.weight.size} pair(s)",
            )
    mats = [
        scipy.sparse.diags(r.weight)
        @ (_interpolation(r.bright, nodes) - _interpolation(r.dark, nodes))
        for r in rows
    ]
    targets = [r.weight * log_r[r.pair] for r in rows]
    smooth = _smoothness(nodes, max_level)

    def strength(ws: Sequence[np.ndarray]) -> float:
        total = sum(float(np.sum(w**2)) for w in ws)
        return smoothing * np.sqrt(total / nodes.size)

    gains = np.ones(n_ch)
    if model == "separate":
        us, active = [], []
        for c in range(n_ch):
            u, act = _solve(mats[c], targets[c], smooth * strength([rows[c].weight]), monotone)
            us.append(u)
            active.append(act)
        u_all = np.stack(us)
    else:
        lam = strength([r.weight for r in rows])
        act = 0
        shape = np.zeros(nodes.size)
        for _ in range(iterations if model == "gains" else 1):
            # u_c = a_c U: the rows of channel c scaled by a_c (the target stays ln R)
            data = scipy.sparse.vstack([gains[c] * mats[c] for c in range(n_ch)])
            shape, act = _solve(data, np.concatenate(targets), smooth * lam, monotone)
            if model != "gains":
                break
            new = gains.copy()
            for c in range(n_ch):
                pred = mats[c] @ shape
                den = float(pred @ pred)
                if den > 0:
                    new[c] = max(float(pred @ targets[c]) / den, 1e-3)
            new /= np.exp(np.mean(np.log(new)))  # geometric mean 1: U carries the scale
            converged = np.max(np.abs(np.log(new / gains))) < 1e-5
            gains = new
            if converged:
                break
        if model == "gains":
            data = scipy.sparse.vstack([gains[c] * mats[c] for c in range(n_ch)])
            shape, act = _solve(data, np.concatenate(targets), smooth * lam, monotone)
        u_all = gains[:, None] * shape[None, :]
        active = [act] * n_ch
    levels = np.arange(max_level + 1, dtype=np.float64)
    g = np.empty((n_ch, max_level + 1))
    rms, n_rows, ranges = [], [], []
    for c in range(n_ch):
        ua = np.interp(levels, nodes, u_all[c])
        gc = np.exp(ua - ua.max())
        gc[0] = 0.0
        g[c] = normalise_curve(gc)[0]
        r = mats[c] @ u_all[c] - targets[c]
        rms.append(float(np.sqrt(np.sum(r**2) / np.sum(rows[c].weight ** 2))))
        n_rows.append(int(rows[c].weight.size))
        both = np.concatenate([rows[c].dark, rows[c].bright])
        ranges.append((float(both.min()), float(both.max())))
    per_level = level_residuals(g, pairs, log_r, lo, hi) if residuals else np.full(g.shape, np.nan)
    return JointFit(
        g=g,
        model=model,
        nodes=nodes,
        u=u_all,
        gains=tuple(float(v) for v in gains),
        active=tuple(int(a) for a in active),
        rms=tuple(rms),
        n_rows=tuple(n_rows),
        residuals=per_level,
        data_range=tuple(ranges),
    )


def level_residuals(
    g: np.ndarray, pairs: Sequence[Correspondences], log_ratios: np.ndarray, lo: float, hi: float
) -> np.ndarray:
    """Weighted mean residual of ``ln g`` at every level, per channel, ``(C, L)``.

    A pair ``(z, T(z))`` with residual ``r = ln g(T) - ln g(z) - ln R`` counts ``+r/2`` at its
    bright level and ``-r/2`` at its dark level (shared by the two integer levels around each,
    as linear interpolation weights): how far the curve would have to move there to fit. NaN
    where no pair touches a level.
    """
    g = np.atleast_2d(np.asarray(g, dtype=np.float64))
    n_ch, n_lv = g.shape
    out = np.full((n_ch, n_lv), np.nan)
    x = np.arange(n_lv, dtype=np.float64)
    for c, corr in enumerate(pairs[:n_ch]):
        r_ = _rows(corr, lo, hi, n_lv - 1)
        if r_.weight.size == 0:
            continue
        lg = np.log(np.maximum(g[c], 1e-12))
        res = np.interp(r_.bright, x, lg) - np.interp(r_.dark, x, lg) - log_ratios[r_.pair]
        w2 = r_.weight**2
        num = np.zeros(n_lv)
        den = np.zeros(n_lv)
        for z, sign in ((r_.bright, 0.5), (r_.dark, -0.5)):
            # shared by the two levels around z as linear interpolation weights
            lo_i = np.clip(np.floor(z).astype(np.intp), 0, n_lv - 1)
            hi_i = np.minimum(lo_i + 1, n_lv - 1)
            f = np.clip(z - lo_i, 0.0, 1.0)
            for idx, share in ((lo_i, 1.0 - f), (hi_i, f)):
                np.add.at(num, idx, share * sign * w2 * res)
                np.add.at(den, idx, share * w2)
        ok = den > 0
        out[c, ok] = num[ok] / den[ok]
    return out


def _fit_to_curve(
    fit: JointFit, method: str, ratios: tuple[float, ...], parameters: dict, extra_message: str = ""
) -> ResponseCurve:
    from .degeneracy import channel_fits_status

    fits = tuple(
        ChannelFit(
            residual_rms=fit.rms[c],
            n_constraints=fit.n_rows[c],
            exposure_ratios=ratios,
            active_constraints=fit.active[c],
            iterations=1,
        )
        for c in range(fit.g.shape[0])
    )
    status, message = channel_fits_status(fit)
    if extra_message:
        message = f"{extra_message}; {message}" if message else extra_message
    return ResponseCurve(
        g=fit.g,
        method=method,
        exposure_ratios=ratios,
        channels=fits,
        status=status,
        message=message,
        parameters={**parameters, "model": fit.model, "gains": list(fit.gains)},
        residuals=fit.residuals,
    )


def _choose_model(fold_fits: dict[str, float], models: Sequence[str]) -> tuple[str, str]:
    """The simplest model unless a more complex one is better by :data:`SEPARATE_GAIN`."""
    best = models[0]
    for m in models[1:]:
        if fold_fits[m] < (1.0 - SEPARATE_GAIN) * fold_fits[best]:
            best = m
    text = ", ".join(f"{m} {100 * fold_fits[m]:.2f} %" for m in models)
    return best, f"channel model {best} (held-back residual {text})"


def _select_and_fit(
    make_pairs,
    n_ch: int,
    log_r: np.ndarray,
    max_level: int,
    model: str,
    fit_kw: dict,
) -> tuple[JointFit, str, dict[str, float]]:
    """Fit ``model`` (or choose it by 2-fold held-back residuals when ``"auto"``)."""
    from .holdout import fold_masks, heldout_residual

    all_pairs = make_pairs(None)
    if model != "auto":
        return fit_joint(all_pairs, log_r, max_level, model=model, **fit_kw), "", {}
    folds = fold_masks(2)
    fold_pairs = [make_pairs(f) for f in folds]
    models = list(JOINT_MODELS) if n_ch > 1 else ["shared"]
    scores: dict[str, float] = {}
    lo, hi = valid_range(max_level, fit_kw.get("cutoff", 0.98), fit_kw.get("low_cut", 0.0))
    for m in models:
        total, weight = 0.0, 0.0
        for i in range(2):
            try:
                f = fit_joint(fold_pairs[i], log_r, max_level, model=m, residuals=False, **fit_kw)
            except EstimationError:
                total, weight = np.inf, 1.0
                break
            s, w = heldout_residual(f.g, fold_pairs[1 - i], lo, hi, log_ratios=None)
            total += s**2 * w
            weight += w
        scores[m] = float(np.sqrt(total / weight)) if weight > 0 else np.inf
    chosen, text = _choose_model(scores, models)
    return fit_joint(all_pairs, log_r, max_level, model=chosen, **fit_kw), text, scores


def joint_histogram(
    frames: Sequence[np.ndarray],
    exposure_times: Sequence[float] | None,
    *,
    max_level: int | None = None,
    model: str = "auto",
    smoothing: float = DEFAULT_SMOOTHING,
    cutoff: float = 0.98,
    low_cut: float = 0.0,
    mask: np.ndarray | None = None,
    monotone: bool = True,
    n_nodes: int = 256,
    stride: int = 1,
) -> ResponseCurve:
    """Recover the inverse responses of all channels jointly from histograms only.

    ``model`` is one of :data:`JOINT_MODELS` or ``"auto"`` (the simplest model unless a more
    complex one explains held-back histograms better by :data:`SEPARATE_GAIN`). Frames need
    not be registered. ``mask`` ``(H, W)`` selects the pixels counted; ``stride`` subsamples.
    """
    frames, max_level = check_bracket(frames, max_level)
    ratios = consecutive_ratios(
        exposure_times, len(frames), required=True, method="joint-histogram"
    )
    if model != "auto" and model not in JOINT_MODELS:
        raise ParameterError(
            f"unknown joint model {model!r}", expected=f"'auto' or one of {', '.join(JOINT_MODELS)}"
        )
    lo, hi = valid_range(max_level, cutoff, low_cut)
    n_ch = frames[0].shape[2]
    h, w = frames[0].shape[:2]
    base = checked_mask(mask, (h, w))

    def make_pairs(fold):
        m = fold_mask(base, fold, (h, w))
        return [btf_pairs(frames, c, max_level, lo, hi, mask=m, stride=stride) for c in range(n_ch)]

    fit_kw = dict(
        smoothing=smoothing, cutoff=cutoff, low_cut=low_cut, monotone=monotone, n_nodes=n_nodes
    )
    fit, text, scores = _select_and_fit(make_pairs, n_ch, np.log(ratios), max_level, model, fit_kw)
    params = {**fit_kw, "stride": stride, "model_requested": model, "model_scores": scores}
    return _fit_to_curve(fit, "joint-histogram", ratios, params, text)


def joint_pixels(
    frames: Sequence[np.ndarray],
    exposure_times: Sequence[float] | None,
    *,
    max_level: int | None = None,
    model: str = "auto",
    smoothing: float = DEFAULT_SMOOTHING,
    cutoff: float = 0.98,
    low_cut: float = 0.0,
    n_samples: int = 4000,
    mask: np.ndarray | None = None,
    monotone: bool = True,
    n_nodes: int = 256,
    seed: int = 0,
) -> ResponseCurve:
    """The joint fit from sampled pixels of registered frames (consecutive-frame level pairs
    of every sampled pixel, DM 1997's data) instead of histograms."""
    frames, max_level = check_bracket(frames, max_level)
    ratios = consecutive_ratios(exposure_times, len(frames), required=True, method="joint-pixels")
    lo, hi = valid_range(max_level, cutoff, low_cut)
    n_ch = frames[0].shape[2]
    h, w = frames[0].shape[:2]
    base = None if mask is None else np.asarray(mask, bool)

    def make_pairs(fold):
        m = fold_mask(base, fold, (h, w))
        out = []
        for c in range(n_ch):
            z = pixel_samples(frames, c, max_level, n_samples=n_samples, mask=m, seed=seed)
            out.append(pixel_pairs(z, lo, hi))
        return out

    fit_kw = dict(
        smoothing=smoothing, cutoff=cutoff, low_cut=low_cut, monotone=monotone, n_nodes=n_nodes
    )
    fit, text, scores = _select_and_fit(make_pairs, n_ch, np.log(ratios), max_level, model, fit_kw)
    params = {
        **fit_kw,
        "n_samples": n_samples,
        "seed": seed,
        "model_requested": model,
        "model_scores": scores,
    }
    return _fit_to_curve(fit, "joint-pixels", ratios, params, text)
