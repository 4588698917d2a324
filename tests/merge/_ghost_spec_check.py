"""The region ghost test (its compiled kernels, :mod:`hdrcore.merge.consistency`) held to its
numpy specification (:mod:`hdrcore.merge.consistency_spec`) on one input: the helper the ghost
tests share."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from hdrcore.merge import GhostTestParams
from hdrcore.merge.consistency import GhostRegions, consistency_regions, pair_residuals
from hdrcore.merge.consistency_spec import block_test_spec, pair_residuals_spec

SUMS = ("weighted", "weights", "additive", "first", "second", "count", "bias")


def sums_vs_spec(frames, times, **kw):
    """``pair_residuals`` against :func:`pair_residuals_spec`: the sums within 1e-9 (the
    kernel adds in its own order; its float32 weights and additive variances within 2e-6), the
    counts, samples and transfer errors' sources equal."""
    a = pair_residuals(frames, times, **kw)
    kw.pop("workers", None)
    b = pair_residuals_spec(frames, times, **kw)
    assert a.samples == b.samples and a.bias_source == b.bias_source
    np.testing.assert_array_equal(a.order, b.order)
    np.testing.assert_array_equal(a.count, b.count)
    for name in SUMS:
        # the weights and additive variances are summed in float32 (positive terms, at most
        # block**2 of them): ~1e-6 relative; the rest in float64
        rtol = 2e-6 if name in ("weights", "additive") else 1e-9
        np.testing.assert_allclose(
            getattr(a, name), getattr(b, name), rtol=rtol, atol=1e-12, err_msg=name
        )
    return a, b


def regions_vs_spec(frames, times, **kw) -> GhostRegions:
    """``consistency_regions`` against the specification's steps 1-4 (then the same region
    labelling): each pair's blocks compared and flagged, scale, the largest z per block, the
    regions' blocks."""
    res = consistency_regions(frames, times, **kw)
    p = kw.get("params") or GhostTestParams()
    _, spec = sums_vs_spec(
        frames,
        times,
        **{k: v for k, v in kw.items() if k not in ("candidates", "score")},
    )
    b = p.block
    need = max(1, int(np.ceil(p.min_shared * (b // p.pixel_step) ** 2)))
    tf = kw.get("transforms") or [None] * len(frames)
    moved = [
        t is not None
        and not np.allclose(np.asarray(t, float), np.eye(3)[: np.asarray(t).shape[0]], atol=1e-12)
        for t in tf
    ]
    zmax = np.zeros(res.z.shape)
    flagged = np.zeros(res.blocks.shape, bool)
    pairs = []
    for q in range(len(frames) - 1):
        use = spec.count[q] >= need
        if not use.any():
            continue
        a, k = int(spec.order[q]), int(spec.order[q + 1])
        delta = p.registration_error if (moved[a] or moved[k]) else p.direct_error
        scale, z, hit = block_test_spec(spec, q, use, delta, p)
        zmax = np.maximum(zmax, z.max(axis=0))
        flagged |= hit
        pairs.append(((a, k), int(use.any(axis=0).sum()), int(hit.sum()), scale, delta))
    assert len(pairs) == len(res.pairs)
    for got, (frames_ak, blocks, n_hit, scale, delta) in zip(res.pairs, pairs, strict=True):
        assert got.frames == frames_ak and got.blocks == blocks and got.delta == delta
        assert got.flagged == n_hit
        # (the scale reads the float32 weights: ~1e-7 relative)
        np.testing.assert_allclose(got.scale, scale, rtol=1e-6, atol=1e-15)
    np.testing.assert_allclose(res.z, zmax, rtol=1e-6, atol=1e-6)
    labels, count = ndimage.label(flagged, structure=np.ones((3, 3), bool))
    area = np.bincount(labels.ravel(), minlength=count + 1)
    keep = area >= p.min_blocks
    keep[0] = False
    np.testing.assert_array_equal(res.blocks, keep[labels])
    assert res.regions == int(keep.sum())
    return res
