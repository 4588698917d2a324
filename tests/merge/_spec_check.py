"""The merge (its compiled kernel) held to the whole-image specification
(:mod:`hdrcore.merge.spec`) on one input: the helper the merge tests share."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from hdrcore.merge import DEFAULT_GHOST_THRESHOLD, DEFAULT_MODEL_ERROR, MergeResult, merge
from hdrcore.merge.merge import default_feather
from hdrcore.merge.plan import make_plan
from hdrcore.merge.spec import merge_spec

FIELDS = (
    "radiance",
    "weight_sum",
    "shares",
    "clip_count",
    "clipped",
    "underexposed",
    "ghost_score",
    "ghost",
)


def kernel_vs_spec(frames, times, **kw) -> tuple[MergeResult, dict]:
    """``merge(frames, times, ghost_test="pixels", **kw)`` against :func:`merge_spec` of the
    same input; returns both. The decisions (clip counts, clipped, underexposed: which frame
    each fallback takes) must be the same to the bit, the values the same within float32
    rounding (radiance and weight sums 1e-4 relative, shares 1e-3 absolute: one float16 step),
    the ghost score within its float32 cancellation (``sum(w E^2) / sum(w) - E^2``) and the
    ghost map wherever the score is clear of the threshold."""
    plan = make_plan(
        frames,
        times,
        kw.get("response"),
        kw.get("max_level"),
        kw.get("masks"),
        kw.get("saturation_level"),
        kw.get("noise_floor"),
        kw.get("weighting"),
        kw.get("noise"),
        kw.get("transforms"),
        kw.get("fields"),
    )
    feather = kw.get("feather")
    plan = replace(
        plan,
        resample=kw.get("resample", "cubic"),
        feather=(default_feather(plan.shape[:2]) if feather is None else float(feather))
        if plan.warped
        else 0.0,
    )
    threshold = kw.get("ghost_threshold", DEFAULT_GHOST_THRESHOLD)
    spec = merge_spec(
        plan, ghost_threshold=threshold, model_error=kw.get("model_error", DEFAULT_MODEL_ERROR)
    )
    res = merge(frames, times, ghost_test="pixels", **kw)
    assert res.engine == "numba"
    for name in FIELDS:
        assert getattr(res, name).shape == np.shape(spec[name]), name
    for name in ("clip_count", "clipped", "underexposed"):
        np.testing.assert_array_equal(getattr(res, name), spec[name], err_msg=name)
    np.testing.assert_allclose(res.radiance, spec["radiance"], rtol=1e-4, atol=1e-12)
    np.testing.assert_allclose(res.weight_sum, spec["weight_sum"], rtol=1e-4, atol=1e-12)
    np.testing.assert_allclose(res.shares.astype(np.float64), spec["shares"], atol=1e-3)
    score = res.ghost_score.astype(np.float64)
    small = spec["ghost_score"] < 6e4  # float16's range
    np.testing.assert_allclose(score[small], spec["ghost_score"][small], rtol=5e-3, atol=0.5)
    clear = np.abs(spec["ghost_score"] - threshold) > 0.6
    np.testing.assert_array_equal(res.ghost[clear], spec["ghost"][clear])
    return res, spec


def same_bits(a: MergeResult, b: MergeResult, names=FIELDS) -> None:
    """Two merges' outputs identical to the bit."""
    for name in names:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape, name
        np.testing.assert_array_equal(x, y, err_msg=name)
