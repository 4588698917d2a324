"""A merge weighting is one scalar function (issue 17): registered in ``WEIGHTS`` it runs in the
kernel (through a compiled function pointer), in its per-level tables and in the specification
(:mod:`hdrcore.merge.spec`), with the same result; the built-ins are the same kind of function,
inlined, and a registered copy of one gives its results to the bit."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.errors import ParameterError
from hdrcore.merge import WEIGHTS, Weighting, merge, weights

from ._spec_check import kernel_vs_spec, same_bits

pytest.importorskip("numba")


def squares(level, linear, exposure_time_sq, variance):  # noqa: ANN001, ANN201
    return level * level


def hat_copy(level, linear, exposure_time_sq, variance):  # noqa: ANN001, ANN201
    """:func:`hdrcore.merge.weights.weight_hat`'s body, registered under another name: the
    kernel calls it through its pointer (scalar code) instead of inlining it (SIMD)."""
    w = level * np.float32(2.0)
    w = w - np.float32(1.0)
    return np.float32(1.0) - abs(w)


def test_a_weighting_is_one_function(monkeypatch) -> None:
    monkeypatch.setitem(WEIGHTS, "squares", Weighting(squares))
    frames = [np.full((4, 5, 3), v, np.float32) for v in (0.2, 0.6)]
    fused, _ = kernel_vs_spec(frames, (1.0, 2.0), weighting="squares")
    # E_k = 0.2 and 0.3, weights 0.04 and 0.36: the toy did the work (hat gives 0.2667)
    np.testing.assert_allclose(fused.radiance, (0.04 * 0.2 + 0.36 * 0.3) / 0.4, rtol=1e-6)
    assert fused.weighting == "squares"
    np.testing.assert_allclose(
        weights(np.float32([0.5]), np.float32([0.5]), 1.0, np.float32([1.0]), "squares"), [0.25]
    )


@pytest.mark.parametrize("c", [3, 4, 1])
@pytest.mark.parametrize("resample", ["cubic", "bilinear"])
def test_a_registered_weighting_on_every_kernel_path(monkeypatch, resample, c) -> None:
    """Levels read in place through the per-level tables (a LUT), levels resampled with a LUT
    and linear levels resampled and in place, float frames: the specification's result, and a
    registered copy of the hat weighting gives the inlined hat's bits."""
    monkeypatch.setitem(WEIGHTS, "squares", Weighting(squares))
    monkeypatch.setitem(WEIGHTS, "hat-copy", Weighting(hat_copy))
    assert WEIGHTS["hat-copy"].code == -1
    rng = np.random.default_rng(3)
    frames = [
        np.clip(rng.normal(40 * 4**k, 10, (24, 32, c)), 0, 255).astype(np.uint8) for k in range(3)
    ]
    lut = np.linspace(0.0, 1.0, 256) ** 2.2
    tf = [np.array([[1.0, 0.01, 0.6], [-0.01, 1.0, -0.3]]), None, None]
    times = (1.0, 4.0, 16.0)
    floats = [f.astype(np.float32) / np.float32(255) for f in frames]
    for fr, kw in ((frames, {"response": lut}), (frames, {"max_level": 255}), (floats, {})):
        ref, _ = kernel_vs_spec(fr, times, weighting="squares", **kw)
        hat = merge(fr, times, weighting="hat", **kw)
        assert not np.array_equal(ref.radiance, hat.radiance)
        kernel_vs_spec(fr, times, weighting="squares", transforms=tf, resample=resample, **kw)
        for tfs in (None, tf):
            kw2 = dict(transforms=tfs, resample=resample, ghost_test="pixels", **kw)
            copy = merge(fr, times, weighting="hat-copy", **kw2)
            same_bits(copy, merge(fr, times, weighting="hat", **kw2))


def test_built_in_weightings_are_inlined_and_unknown_names_refused() -> None:
    assert [WEIGHTS[k].code for k in ("hat", "gaussian", "noise-aware", "uniform")] == [0, 1, 2, 3]
    assert Weighting(squares).code == -1
    frames = [np.full((4, 5, 3), 0.5, np.float32)]
    with pytest.raises(ParameterError, match="unknown weighting method 'cubes'.*'hat'"):
        merge(frames, (1.0,), weighting="cubes")
    with pytest.raises(ParameterError, match="a weighting is a function"):
        Weighting(3)  # type: ignore[arg-type]
