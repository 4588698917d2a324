"""The merge written as plainly as numpy allows: the specification the tests hold the kernel to.

Used by the tests only (the merge runs the compiled kernel, :mod:`hdrcore.merge._fused`). Whole
images, float64, one statement per rule, any channel count, no chunks, no scratch buffers, no
speed. It takes a validated :class:`~hdrcore.merge.plan.Plan` (so it checks no input) and returns
the arrays of a :class:`~hdrcore.merge.result.MergeResult` that depend only on the frames (not
the region ghost test, deghosting or colour). The kernel computes the same in float32, in its own
order, so a test compares with a tolerance; the decisions (clipped, below the floor, which frame a
fallback takes) are the same to the bit: thresholds are compared as the kernel compares them.

For each frame ``k`` (exposure time ``t_k``) and output pixel: the sample (the frame's own, or
read at ``T_k (x, y, 1)`` plus its displacement field: Keys cubic or bilinear taps of the levels,
clamped), valid (mask, and the whole support inside the frame), clipped (valid and any tap of any
channel at or above its saturation level), usable (valid, not clipped). Per channel:
``x = g(level)`` (the LUT read linearly between entries; linear levels without one),
``var = read**2 + x / full_well + g'**2 (level_noise**2 + 1/12)``, ``E_k = x / t_k``,
``w = weight(level, x, t_k, var)`` where usable and the level is above the noise floor, else 0;
``E = sum(w E_k) / sum(w)`` (Debevec & Malik 1997, eq. 6). Ghost score: the weighted spread of
the ``E_k`` over their weighted variance plus ``(model_error E)**2``, summed over channels
(:mod:`hdrcore.merge.maps`). Fallbacks: see :mod:`hdrcore.merge.merge`.
"""

from __future__ import annotations

import numpy as np

from ..geometry import keys_weights
from ._fused import FEATHER_FLOOR
from .plan import Plan
from .weights import WEIGHTS

__all__ = ["merge_spec"]


def _positions(plan: Plan, k: int, t: np.ndarray) -> tuple[np.ndarray, ...]:
    """``(xx, yy, sx, sy)``: every output pixel and where frame ``k`` is read for it (its
    transform ``t``, then its displacement field)."""
    h, w, _ = plan.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    den = t[2, 0] * xx + t[2, 1] * yy + t[2, 2]
    sx = (t[0, 0] * xx + t[0, 1] * yy + t[0, 2]) / den
    sy = (t[1, 0] * xx + t[1, 1] * yy + t[1, 2]) / den
    fld = plan.fields[k] if plan.fields else None
    if fld is not None:
        dx, dy = fld.at(xx, yy)
        sx, sy = sx + dx, sy + dy
    return xx, yy, sx, sy


def border_clamp(
    sx: np.ndarray, sy: np.ndarray, w: int, h: int, ntap: int, first: int
) -> tuple[np.ndarray, np.ndarray]:
    """``(sx, sy)`` with each point inside the frame (``-0.5 .. w - 0.5``, ``-0.5 .. h - 0.5``:
    within its pixels) moved to the nearest position whose ``ntap x ntap`` support lies in the
    frame (top-left tap ``first .. w - ntap + first``); points outside as they are. Without it
    a frame moved by a tenth of a pixel gave nothing in its outermost one or two columns and
    rows, which then fell to the reference frame alone (where it is clipped, to its lower
    bound: a dark border line on the real tripod frobisher)."""
    wlim, hlim = float(w - ntap + first), float(h - ntap + first)
    ok = (sx >= -0.5) & (sx <= w - 0.5) & (sy >= -0.5) & (sy <= h - 0.5)
    cx = np.where(ok, np.minimum(np.maximum(sx, float(first)), wlim), sx)
    cy = np.where(ok, np.minimum(np.maximum(sy, float(first)), hlim), sy)
    return cx, cy


def _sample(plan: Plan, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frame ``k`` on the output grid: ``(values (H, W, C) float64, clipped (H, W), inside)``."""
    frame = plan.frames[k].astype(np.float64)
    h, w, c = plan.shape
    sat = np.asarray(plan.saturation, np.float64)
    t = plan.transforms[k] if plan.transforms else None
    if t is None:
        return frame, np.asarray((frame >= sat).any(axis=2)), np.ones((h, w), bool)
    xx, yy, sx, sy = _positions(plan, k, t)
    ntap, first = (4, 1) if plan.resample == "cubic" else (2, 0)
    # A point inside the frame whose support is not (its outermost pixels) is sampled at the
    # nearest position whose support fits (:func:`border_clamp`).
    sx, sy = border_clamp(sx, sy, w, h, ntap, first)
    x0, y0 = np.floor(sx), np.floor(sy)
    inside = (x0 >= first) & (x0 <= w - ntap + first) & (y0 >= first) & (y0 <= h - ntap + first)
    fx, fy = np.where(inside, sx - x0, 0.0), np.where(inside, sy - y0, 0.0)
    if ntap == 4:
        wx, wy = keys_weights(fx), keys_weights(fy)
    else:
        wx, wy = np.stack([1.0 - fx, fx]), np.stack([1.0 - fy, fy])
    ix = np.where(inside, x0 - first, 0).astype(np.intp)
    iy = np.where(inside, y0 - first, 0).astype(np.intp)
    values = np.zeros((h, w, c))
    clipped = np.zeros((h, w), bool)
    for jy in range(ntap):
        for jx in range(ntap):
            # (outside pixels read some in-frame sample: discarded below)
            tap = frame[np.minimum(iy + jy, h - 1), np.minimum(ix + jx, w - 1)]  # (H, W, C)
            values += (wy[jy] * wx[jx])[..., None] * tap
            clipped |= (tap >= sat).any(axis=2)
    hi = float(plan.max_level or 1) if plan.integer else 1.0
    values = np.where(inside[..., None], np.clip(values, 0.0, hi), 0.0)
    return values, clipped & inside, inside


def _feather(plan: Plan, k: int) -> np.ndarray | float:
    """Frame ``k``'s coverage feather per output pixel (1 without a transform or a width):
    its distance inside its support over ``min(width, the pixel's distance inside the grid)``,
    clamped to ``[FEATHER_FLOOR, 1]``, read where :func:`_sample` reads it."""
    t = plan.transforms[k] if plan.transforms else None
    if t is None or plan.feather <= 0:
        return 1.0
    h, w, _ = plan.shape
    xx, yy, sx, sy = _positions(plan, k, t)
    ntap, first = (4, 1) if plan.resample == "cubic" else (2, 0)
    wlim, hlim = w - ntap + first, h - ntap + first
    inside_frame = np.minimum(np.minimum(sx - first, wlim - sx), np.minimum(sy - first, hlim - sy))
    inside_grid = np.minimum(np.minimum(xx - first, wlim - xx), np.minimum(yy - first, hlim - yy))
    span = np.minimum(plan.feather, np.maximum(inside_grid, 1.0))
    return np.clip(inside_frame / span, FEATHER_FLOOR, 1.0)


def _linearise(plan: Plan, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(level, x, var)``, each ``(H, W, C)`` float64, of samples in the frames' units."""
    scale = float(plan.max_level or 1) if plan.integer else 1.0
    level = values / scale
    noise = plan.noise
    const = noise.read_noise**2
    if plan.lut is None:
        x = level
        if plan.integer:
            const += noise.level_variance() / scale**2
        var = x * noise.shot_gain + max(const, 1e-12)
        return level, x, var
    g = plan.lut.astype(np.float64)  # (C, L)
    # g'(M)**2 (level_noise**2 + 1/12) per level, as the plan holds it (made from the float64
    # response: the gradient of the float32 LUT would lose digits where g is flat)
    assert plan.lut_var is not None  # a plan with a LUT has both
    slope2 = plan.lut_var.astype(np.float64)
    x = np.empty_like(values)
    var = np.empty_like(values)
    grid = np.arange(g.shape[1])
    for ch in range(values.shape[2]):
        x[..., ch] = np.interp(values[..., ch], grid, g[ch])
        var[..., ch] = np.interp(values[..., ch], grid, slope2[ch])
    var += x * noise.shot_gain + max(const, 1e-12)
    return level, x, var


def merge_spec(plan: Plan, *, ghost_threshold: float, model_error: float) -> dict[str, np.ndarray]:
    """``radiance``, ``weight_sum``, ``shares``, ``clip_count``, ``clipped``, ``underexposed``,
    ``ghost_score`` and ``ghost`` (float64 and bool) of the merge the plan describes."""
    h, w, c = plan.shape
    n = len(plan.frames)
    order = list(plan.order)
    inv_max = np.float32(1.0 / plan.max_level) if plan.integer and plan.max_level else 1.0
    floor_level = float(np.float32(plan.floor * float(inv_max)))  # as the kernel compares it
    weight = WEIGHTS[plan.weighting]
    wk = np.zeros((n, h, w, c))
    ek = np.zeros((n, h, w, c))
    var_e = np.zeros((n, h, w, c))
    clipped_k = np.zeros((n, h, w), bool)
    usable_k = np.zeros((n, h, w), bool)
    for k in range(n):
        values, clipped, inside = _sample(plan, k)
        valid = inside if plan.masks[k] is None else inside & plan.masks[k]
        clipped_k[k] = clipped & valid
        usable_k[k] = valid & ~clipped
        level, x, var = _linearise(plan, values)
        t = float(plan.times[k])
        ek[k] = x / t
        var_e[k] = var / t**2
        # the normalised level in float32, as the kernel forms it (the floor is a threshold)
        lv32 = values.astype(np.float32) * np.float32(inv_max)
        wgt = weight(lv32, x.astype(np.float32), t, var.astype(np.float32))
        fea = np.float32(_feather(plan, k))  # as the kernel rounds it
        wk[k] = wgt * (usable_k[k][..., None] & (lv32 > floor_level)) * np.asarray(fea)[..., None]

    den = wk.sum(axis=0)  # (H, W, C)
    rad = np.divide((wk * ek).sum(axis=0), den, out=np.zeros_like(den), where=den > 0)
    spread = np.divide((wk * ek**2).sum(axis=0), den, out=np.zeros_like(den), where=den > 0)
    spread = np.maximum(spread - rad**2, 0.0)
    noise = np.divide((wk * var_e).sum(axis=0), den, out=np.zeros_like(den), where=den > 0)
    noise += (model_error * rad) ** 2
    score = spread.sum(axis=2) / np.maximum(noise.sum(axis=2), 1e-30)
    weight_sum = den.sum(axis=2)
    shares = np.divide(wk.sum(axis=3), weight_sum, out=np.zeros((n, h, w)), where=weight_sum > 0)

    # fallbacks, in exposure order j (frame order[j])
    gave = wk.sum(axis=3)[order] > 0  # (N, H, W): frame j gave the pixel weight
    clip_o, usable_o = clipped_k[order], usable_k[order]
    first_clip = np.where(clip_o.any(axis=0), np.argmax(clip_o, axis=0), n)
    last_usable = np.where(usable_o.any(axis=0), n - 1 - np.argmax(usable_o[::-1], axis=0), -1)
    seen_o = np.where(gave.any(axis=0), gave, usable_o)
    last_seen = n - 1 - np.argmax(seen_o[::-1], axis=0)
    none_valid = ~(clip_o | usable_o).any(axis=0)
    whole = weight_sum <= 0
    needs = (den <= 0).any(axis=2)
    every = whole & (((first_clip < n) & (last_usable < first_clip)) | none_valid)
    clipped_px = every & (first_clip < n)
    under = needs & ~every
    for py, px in zip(*np.nonzero(needs), strict=True):
        if every[py, px]:
            j = first_clip[py, px] if first_clip[py, px] < n else 0
        else:
            j = last_seen[py, px]
        k = order[j]
        chans = slice(None) if every[py, px] else den[py, px] <= 0
        rad[py, px, chans] = ek[k, py, px, chans]
        if whole[py, px]:
            shares[:, py, px] = 0.0
            shares[k, py, px] = 1.0
    return {
        "radiance": rad,
        "weight_sum": weight_sum,
        "shares": shares,
        "clip_count": clipped_k.sum(axis=0),
        "clipped": clipped_px,
        "underexposed": under,
        "ghost_score": score,
        "ghost": score > ghost_threshold,
    }
