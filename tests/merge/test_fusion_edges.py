"""Exposure fusion at the edges of a hand-held bracket: where a warped frame does not reach,
the preview must not darken or draw a line (issue 15, the Pixel 7's preview edges)."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.merge.fusion import exposure_fusion


def _frames() -> list[np.ndarray]:
    """Three frames of a flat grey scene rendered alike (a phone's locally tone-mapped frames
    look alike), with a little noise (8 bits): every shift of
    a frame leaves its content as it was."""
    rng = np.random.default_rng(1)
    out = []
    for level in (115.0, 125.0, 135.0):
        noisy = level + rng.normal(0.0, 1.0, (120, 160, 3))
        out.append(np.clip(np.rint(noisy), 0, 255).astype(np.uint8))
    return out


def test_a_frame_that_does_not_reach_the_edge_leaves_no_band() -> None:
    frames = _frames()
    every = exposure_fusion(frames, max_level=255).mean(-1).astype(float)
    two = exposure_fusion(frames[:2], max_level=255).mean(-1).astype(float)
    # frame 2 reaches the reference through a 7 px vertical, 5 px horizontal shift: it covers
    # all but a 7 px strip at the top and a 5 px strip at the left
    to_ref = [np.eye(3), np.eye(3), np.array([[1.0, 0, 5.0], [0, 1.0, 7.0], [0, 0, 1.0]])]
    out = exposure_fusion(frames, max_level=255, to_reference=to_ref).mean(-1).astype(float)
    # rows (over the columns frame 2 covers) and columns (over the rows it covers), as means:
    # where frame 2 is missing, the other two frames' fusion; far inside, all three's; between,
    # a ramp from one to the other, no darker or brighter line (pixel noise averages out)
    for axis, edge in ((1, 7), (0, 5)):
        sel = (slice(None), slice(20, None)) if axis == 1 else (slice(20, None), slice(None))
        o, t, e = (a[sel].mean(axis=axis) for a in (out, two, every))
        assert np.abs(o[:edge] / t[:edge] - 1).max() < 0.015
        assert np.abs(o[edge + 15 :] / e[edge + 15 :] - 1).max() < 0.01
        assert np.all((o >= np.minimum(t, e) * 0.99) & (o <= np.maximum(t, e) * 1.01))


@pytest.mark.parametrize("shape", [(5, 7, 3), (6, 8), (1, 1, 3), (2, 3)])
def test_upsampling_is_repetition_smoothed_by_1_2_1(shape) -> None:
    # _up computes what repeating every pixel and smoothing by 1-2-1 gives (its spec), without
    # the repeated copy
    from scipy import ndimage

    from hdrcore.merge.fusion import _KERNEL, _up

    a = np.random.default_rng(0).random(shape).astype(np.float32)
    for size in [(2 * shape[0], 2 * shape[1]), (2 * shape[0] - 1, 2 * shape[1])]:
        spec = np.repeat(np.repeat(a, 2, axis=0), 2, axis=1)[: size[0], : size[1]]
        for axis in (0, 1):
            spec = ndimage.correlate1d(spec, _KERNEL, axis=axis, mode="nearest")
        got = _up(a, size)
        assert got.shape == spec.shape and got.dtype == np.float32
        assert np.abs(got - spec).max() < 1e-6


def test_weights_are_mertens_contrast_saturation_exposedness() -> None:
    from scipy import ndimage

    from hdrcore.merge.fusion import WELL_EXPOSED_SIGMA, fusion_weights

    img = np.random.default_rng(1).random((40, 60, 3)).astype(np.float32)
    c = np.abs(ndimage.laplace(img.mean(axis=-1)))
    s = img.std(axis=-1)
    e = np.exp(-np.sum((img - 0.5) ** 2, axis=-1) / (2 * WELL_EXPOSED_SIGMA**2))
    want = (c + 1e-6) * (s + 1e-6) * e
    assert np.allclose(fusion_weights(img), want, rtol=1e-5, atol=1e-12)
