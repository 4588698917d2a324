"""The anchoring's per-pixel pass (colour_check._anchor_pass): steps 1-3 in one compiled pass,
steps 1-2 skipped where a frame gives the pixel its colour fully, against the numpy path that
runs every step on every pixel (colour_check._apply_numpy, then _band_numpy / _blend_numpy)."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.merge import colour_check as cc
from hdrcore.merge import merge
from hdrcore.synthetic import simulate_bracket

TIMES = (1.0, 4.0, 16.0)


@pytest.fixture(scope="module")
def moved_bracket():
    """A gamma-2.2 bracket (the re-decoding to sRGB is then not the identity) whose outer
    frames are shifted and re-balanced, with its merge."""
    sim = simulate_bracket(
        scene="patches",
        shape=(96, 140),
        exposure_times=TIMES,
        bits=8,
        response="srgb",
        noise_sigma=0.5,
        seed=11,
    )
    frames = [f.astype(np.uint8) for f in sim.frames]
    tint = [(1.05, 1.0, 0.95), (1.0, 1.0, 1.0), (0.95, 1.0, 1.05)]
    frames = [
        np.clip(np.round(f * np.asarray(t)), 0, 255).astype(np.uint8)
        for f, t in zip(frames, tint, strict=True)
    ]
    frames[0] = np.roll(frames[0], (2, 3), axis=(0, 1))
    frames[2] = np.roll(frames[2], (-1, 4), axis=(0, 1))
    to_ref = [
        np.array([[1.0, 0.0, -3.0], [0.0, 1.0, -2.0]]),
        None,
        np.array([[1.0, 0.0, -4.0], [0.0, 1.0, 1.0]]),
    ]
    lut = np.tile((np.arange(256) / 255.0) ** 2.2, (3, 1))
    res = merge(frames, TIMES, response=lut, max_level=255)
    return frames, to_ref, lut, res


@pytest.mark.parametrize("shares_dtype", [np.float16, np.float32])
@pytest.mark.parametrize("band", ["frames", "reference"])
@pytest.mark.parametrize("with_masks", [False, True])
def test_one_pass_equals_every_step_on_every_pixel(
    moved_bracket, monkeypatch, shares_dtype, band: str, with_masks: bool
) -> None:
    if not cc.AVAILABLE:
        pytest.skip("the compiled pass needs numba")
    frames, to_ref, lut, res = moved_bracket
    rng = np.random.default_rng(2)
    masks = None
    if with_masks:
        masks = [rng.random(frames[0].shape[:2]) > 0.2, None, rng.random(frames[0].shape[:2]) > 0.1]
    kw = dict(
        max_level=255,
        saturation=250,
        noise_floor=3,
        reference=1,
        to_reference=to_ref,
        masks=masks,
        lut=lut,
        exposure_times=TIMES,
        shares=np.asarray(res.shares).astype(shares_dtype),
        gains=np.array([[1.05, 1.0, 0.95], [1.0, 1.0, 1.0], [0.95, 1.0, 1.05]]),
    )
    if band == "reference":
        kw.update(frame_band=None, reference_band=cc.REFERENCE_BAND)
    runs = {}
    for compiled in (True, False):
        monkeypatch.setattr(cc, "AVAILABLE", compiled)
        rad = np.asarray(res.radiance).copy()
        done = cc.anchor_colour(rad, frames, cc.srgb_decode_lut(255), **kw)
        runs[compiled] = (rad, done)
    (fast, fast_done), (spec, spec_done) = runs[True], runs[False]
    assert fast_done.own_colour_fraction == pytest.approx(spec_done.own_colour_fraction)
    if band == "frames":
        # both kinds of pixel are in the test: given a frame's colour fully, and not
        assert 0.2 < fast_done.own_colour_fraction < 0.9
    # the pixels whose steps 1-2 were skipped differ by the rounding of their luminance only
    np.testing.assert_allclose(fast, spec, rtol=2e-5, atol=1e-7)
    assert not np.array_equal(fast, np.asarray(res.radiance))


def test_grid_sums_compiled_equal_the_numpy_spec():
    """Step 2's sums over the grid (compiled, one pass over the cells) are the numpy spec's to
    the bit: frames with colourless cells (sum 0), zero weights and per-frame gains."""
    rng = np.random.default_rng(3)
    m, n = 5000, 3
    lins = tuple(rng.uniform(0.0, 1.0, (m, 3)) for _ in range(n))
    lins[1][:50] = 0.0  # no colour: divided by 1
    weights = tuple(np.where(rng.random(m) < 0.3, 0.0, rng.random(m)) for _ in range(n))
    gains = rng.uniform(0.8, 1.25, (n, 3))
    qm = rng.dirichlet((1.0, 1.0, 1.0), m)
    got = cc._grid_sums(lins, weights, gains, qm)
    want = cc._grid_sums_numpy(lins, weights, gains, qm)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g, w)
    assert np.any(got[2] == 0) and np.any(got[2] > 0) and np.any(got[0][:50] > 0)
