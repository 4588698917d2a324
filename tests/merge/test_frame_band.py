"""The colour pass's per-frame band (colour_check._frame_band): the compiled one-pass kernel
against the numpy specification of the per-frame sums and the blend."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.geometry import homogeneous, invert
from hdrcore.merge import colour_check as cc


@pytest.mark.parametrize("with_masks", [False, True])
def test_one_pass_kernel_equals_the_per_frame_specification(with_masks: bool) -> None:
    rng = np.random.default_rng(3)
    h, w = 61, 83
    frames = [
        np.clip(rng.normal(90 + 50 * k, 60, (h, w, 3)), 0, 255).astype(np.uint8) for k in range(3)
    ]
    rad = (rng.random((h, w, 3)) + 0.05).astype(np.float32)
    table = np.tile((np.arange(256) / 255.0) ** 2.2, (3, 1))
    gains = [np.array([0.97, 1.0, 1.04]), np.ones(3), np.array([1.02, 1.0, 0.98])]
    to_ref = [
        np.array([[1.0, 0.0, 1.6], [0.0, 1.0, -2.3]]),
        None,
        np.array([[1.0, 0.002, -3.2], [-0.002, 1.0, 2.4]]),
    ]
    masks = None
    if with_masks:
        masks = [rng.random((h, w)) > 0.2, None, rng.random((h, w)) > 0.1]
    kw = dict(
        max_level=255,
        noise_floor=5,
        saturation=250,
        reference=1,
        to_reference=to_ref,
        masks=masks,
        band=cc.FRAME_BAND,
        sigma=cc.FRAME_SIGMA,
    )
    got = rad.copy()
    own = cc._frame_band(got, frames, table, gains, **kw)

    want = rad.copy()
    acc = np.zeros((h, w, 3), np.float32)
    wsum = np.zeros((h, w), np.float32)
    amax = np.zeros((h, w), np.float32)
    inv_2s2 = 1.0 / (2.0 * cc.FRAME_SIGMA**2)
    for k, f in enumerate(frames):
        hm = None if to_ref[k] is None else homogeneous(invert(np.asarray(to_ref[k], float)))
        mk = None if masks is None or masks[k] is None else masks[k]
        cc._band_numpy(
            acc, wsum, amax, f, hm, mk, table, gains[k], cc.FRAME_BAND, inv_2s2, 5.0, 250.0, 255, 16
        )
    cc._blend_numpy(want, acc, wsum, amax, 16)
    assert own == pytest.approx(float(np.mean(amax >= 1.0)))
    assert 0.05 < own < 0.95  # both kinds of pixels are in the test
    np.testing.assert_allclose(got, want, rtol=2e-6, atol=0)
    assert not np.array_equal(got, rad)  # the pass changed colours
