"""hdrcore.draft: the binned bracket's rules and the draft preview against the full run."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from hdrcore.draft import (
    DraftCache,
    bin_bracket,
    bin_frame,
    bin_levels,
    draft_bracket,
    draft_factor,
    run_draft,
)
from hdrcore.draft_spec import bin_levels_spec
from hdrcore.errors import ParameterError
from hdrcore.io import Bracket, load_bracket
from hdrcore.io.frame import Frame, FrameMetadata
from hdrcore.pipeline import Pipeline, PipelineParams
from hdrcore.synthetic import simulate_bracket

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def _bracket(shape=(192, 288), bits=8, response="gamma") -> Bracket:
    sim = simulate_bracket(
        scene="window",
        shape=shape,
        exposure_times=(1.0, 4.0, 16.0),
        bits=bits,
        response=response,
        noise_sigma=1.0,
        max_shift=2.0,
        max_rotation_deg=0.3,
        seed=3,
    )
    m = (1 << bits) - 1
    dtype = np.uint8 if bits == 8 else np.uint16
    frames = tuple(
        Frame(
            levels=np.ascontiguousarray(f.astype(dtype)),
            meta=FrameMetadata(
                path=f"/sim/frame{k}.png",
                format="png",
                bit_depth=bits,
                max_level=m,
                is_linear=response == "linear",
                exposure_time=t,
            ),
        )
        for k, (f, t) in enumerate(zip(sim.frames, sim.exposure_times, strict=True))
    )
    return Bracket(frames=frames, warnings=(), order_source="exposure", input_order=(0, 1, 2))


@pytest.mark.parametrize("dtype,top", [(np.uint8, 255), (np.uint16, 16383)])
@pytest.mark.parametrize("exclude", [None, (0, 0, 255)])
def test_compiled_binning_equals_the_spec(dtype, top, exclude) -> None:
    rng = np.random.default_rng(1)
    lv = rng.integers(0, top + 1, (67, 53, 3)).astype(dtype)  # ragged edges for factor 4
    lv[10:14, 20:22] = (0, 0, 255)
    lut = (np.arange(top + 1) / top) ** np.array([[2.2], [2.0], [1.8]])
    for f in (1, 3, 4):
        for table in (None, lut, lut[1]):
            kw = dict(saturation=0.9 * top, max_level=top, exclude_colour=exclude, lut=table)
            a = bin_levels(lv, f, **kw)
            b = bin_levels_spec(lv, f, **kw)
            assert a.dtype == (dtype if table is None else np.uint16) == b.dtype
            assert a.shape == (67 // f, 53 // f, 3)
            np.testing.assert_array_equal(a, b)
            if exclude is not None and f == 4:
                k = 1 if table is None else max(1, 4095 // top)  # FINE_TOP // max_level
                assert tuple(a[2, 5]) == tuple(np.array(exclude) * k)


@pytest.mark.parametrize("exclude", [None, (0, 0, 255)])
def test_binned_once_clipped_at_any_saturation_is_the_spec(exclude) -> None:
    """A slider step applies only the saturation rule to the frames binned once."""
    rng = np.random.default_rng(4)
    top = 16383
    lv = rng.integers(0, top + 1, (67, 53, 3)).astype(np.uint16)
    lv[10:14, 20:22] = (0, 0, 255)
    lv[30:36, 30:36] = top  # a clipped patch, whole blocks and parts of blocks
    lut = (np.arange(top + 1) / top) ** np.array([[2.2], [2.0], [1.8]])
    for table in (None, lut):
        once = bin_frame(lv, 4, max_level=top, exclude_colour=exclude, lut=table)
        for sat in (0.5 * top, 0.9 * top, top):
            kw = dict(saturation=sat, max_level=top, exclude_colour=exclude, lut=table)
            np.testing.assert_array_equal(once.clipped(sat), bin_levels_spec(lv, 4, **kw))
        assert not np.array_equal(once.clipped(0.5 * top), once.clipped(0.9 * top))


def test_draft_bracket_takes_frames_binned_once() -> None:
    b = _bracket((64, 96))
    binned = bin_bracket(b, 4)
    for sat in (200, 250):
        a = draft_bracket(b, 4, saturation=sat, binned=binned)
        c = draft_bracket(b, 4, saturation=sat)
        for x, y in zip(a.frames, c.frames, strict=True):
            np.testing.assert_array_equal(x.levels, y.levels)
    with pytest.raises(ParameterError, match="not of this bracket"):
        draft_bracket(b, 4, saturation=250, binned=binned[:2])
    cache = DraftCache()
    first = cache.binned(b, 4, exclude_colour=None, lut=None)
    assert cache.binned(b, 4, exclude_colour=None, lut=None) is first
    assert cache.binnings == 1
    cache.binned(b, 4, exclude_colour=(0, 0, 255), lut=None)
    cache.binned(b, 2, exclude_colour=(0, 0, 255), lut=None)
    cache.binned(_bracket((64, 96)), 2, exclude_colour=(0, 0, 255), lut=None)  # another bracket
    assert cache.binnings == 4


def test_a_response_that_barely_moved_bins_nothing_again() -> None:
    """A hand-held bracket's response is recovered again after each registration (the real
    Xperia's moved by 2.6e-5 of its top): within DRAFT_LUT_TOLERANCE the binned frames serve;
    a curve further off bins anew."""
    from hdrcore.draft import DRAFT_LUT_TOLERANCE

    b = _bracket((64, 96))
    g = np.tile(np.linspace(0.0, 1.0, 256) ** 2.2, (3, 1))
    cache = DraftCache()
    first = cache.binned(b, 4, exclude_colour=None, lut=g)
    nudged = g + 0.5 * DRAFT_LUT_TOLERANCE * np.sin(np.arange(256))[None]
    assert cache.binned(b, 4, exclude_colour=None, lut=nudged) is first
    assert cache.binnings == 1
    far = g + 4 * DRAFT_LUT_TOLERANCE * (np.arange(256) == 128)[None]
    assert cache.binned(b, 4, exclude_colour=None, lut=far) is not first
    assert cache.binnings == 2
    assert cache.binned(b, 4, exclude_colour=None, lut=None) is not first  # linear: anew
    assert cache.binnings == 3
    # what the nudged curve bins to differs from the first curve's by at most 2 fine levels
    # (1/8 of a frame's level: 16 fine levels a level; the dark end, where g is flattest)
    exact = bin_bracket(b, 4, lut=nudged)
    for x, y in zip(first, exact, strict=True):
        assert x.top == y.top == 16 * 255
        assert int(np.max(np.abs(x.levels.astype(int) - y.levels.astype(int)))) <= 2


def test_numpy_engine_is_a_deprecated_alias() -> None:
    rng = np.random.default_rng(2)
    lv = rng.integers(0, 256, (32, 40, 3)).astype(np.uint8)
    lut = (np.arange(256) / 255.0) ** 2.2
    for table in (None, lut):
        kw = dict(saturation=240, max_level=255, lut=table)
        with pytest.warns(DeprecationWarning, match="engine='numpy'"):
            old = bin_levels(lv, 3, engine="numpy", **kw)
        np.testing.assert_array_equal(old, bin_levels(lv, 3, **kw))
        np.testing.assert_array_equal(old, bin_levels(lv, 3, engine="numba", **kw))
    with pytest.raises(ParameterError, match="binning engine"):
        bin_levels(lv, 3, saturation=240, max_level=255, engine="cuda")


def test_binning_rules() -> None:
    lv = np.full((4, 4, 3), 100, np.uint8)
    lv[0, 0, 0] = 250  # one clipped red sample in the first 2x2 block
    lv[2, 3] = (0, 0, 255)  # the excluded colour in the last block
    lv[0:2, 2:4, 1] = ((10, 11), (12, 13))  # green mean 11.5 rounds up
    out = bin_levels(lv, 2, saturation=240, max_level=255, exclude_colour=(0, 0, 255))
    assert tuple(out[0, 0]) == (255, 100, 100)  # clipped red -> max level, the others kept
    assert tuple(out[0, 1]) == (100, 12, 100)
    assert tuple(out[1, 1]) == (0, 0, 255)
    assert tuple(out[1, 0]) == (100, 100, 100)
    # A block at the saturation level is clipped even though its mean is below it.
    assert bin_levels(lv, 2, saturation=250, max_level=255)[0, 0, 0] == 255
    assert bin_levels(lv, 2, saturation=251, max_level=255)[0, 0, 0] == 138  # 137.5 rounds up


def test_bad_input_is_a_clear_error() -> None:
    with pytest.raises(ParameterError, match="integer"):
        bin_levels(np.zeros((8, 8, 3), np.float32), 2, saturation=1, max_level=1)
    with pytest.raises(ParameterError, match="fit the frame"):
        bin_levels(np.zeros((8, 8, 3), np.uint8), 9, saturation=250, max_level=255)
    with pytest.raises(ParameterError, match="16 px"):
        draft_factor((100, 100), 8)
    b = _bracket((64, 96))
    with pytest.raises(ParameterError, match="one exposure time per frame"):
        draft_bracket(b, 2, saturation=250, exposure_times=(1.0, 2.0))
    with pytest.raises(ParameterError, match="saturation and noise floor"):
        run_draft(b, PipelineParams())


def test_draft_bracket_keeps_the_metadata_and_takes_the_times() -> None:
    b = _bracket((64, 96))
    d = draft_bracket(b, 4, saturation=250, exposure_times=(0.5, 2.0, 8.5))
    assert d.shape == (16, 24) and len(d) == 3
    assert d.exif_exposures() == (0.5, 2.0, 8.5)
    assert [f.path for f in d.frames] == [f.path for f in b.frames]


@pytest.mark.parametrize("bits,response", [(8, "gamma"), (12, "linear")])
def test_draft_preview_is_near_the_full_runs_at_its_size(bits, response) -> None:
    """The draft (binned 4x4) against the full run's own preview at the draft's size (the
    full radiance map area-reduced, the same operator). Measured on this scene: mean
    difference 2.8 (8-bit gamma) and 2.2 (12-bit linear) levels of 255, 99th percentile 37
    and 39: a block across the window's hard edge is clipped in the long exposure as a whole
    (as the merge treats a clipped tap), so the draft takes it from the shorter ones."""
    b = _bracket((384, 576), bits=bits, response=response)
    pipe = Pipeline(b)
    full = pipe.run()
    p = full.params
    if full.response is not None:
        p = p.replace(response=full.response)
    draft = run_draft(b, p, max_side=144, exposure_times=full.exposure_times)
    assert draft.preview_factor == 4
    img = np.asarray(draft.preview.image)
    assert img.shape == (96, 144, 3)
    assert draft.preview.method == full.preview.method
    ref = pipe.run(full.params.replace(preview_max_side=144)).preview.image
    d = np.abs(img.astype(float) - np.asarray(ref, float)).max(axis=2)
    assert d.mean() < 4.0
    assert np.percentile(d, 99) < 50
    # With the full run's motion (scaled) in place of the binned frames' own registration,
    # the same picture. Measured: mean 2.752 -> 2.758 (8-bit gamma), 2.211 -> 2.210 (12-bit
    # linear) levels, 99th percentile 38 and 39 either way.
    given = run_draft(
        b,
        p,
        max_side=144,
        exposure_times=full.exposure_times,
        registration=full.registration,
    )
    assert given.registration is not None and given.registration.local is None
    e = np.abs(np.asarray(given.preview.image, float) - np.asarray(ref, float)).max(axis=2)
    assert e.mean() <= d.mean() + 0.05
    assert np.percentile(e, 99) <= np.percentile(d, 99) + 1


def test_factor_one_is_the_bracket_itself() -> None:
    b = _bracket((64, 96))
    d = draft_bracket(b, 1, saturation=255)
    for a, c in zip(b.frames, d.frames, strict=True):
        np.testing.assert_array_equal(a.levels, c.levels)
    # nothing binned: the draft's own registration is the full-resolution one for its
    # parameters, preferred to a given one (a step old); binned, the given one scaled
    full = Pipeline(b).run()
    p = full.params.replace(response=full.response)
    kw = dict(exposure_times=full.exposure_times, registration=full.registration)
    own = run_draft(b, p, max_side=96, **kw).registration
    scaled = run_draft(b, p, max_side=48, **kw).registration
    assert own is not None and scaled is not None
    assert all("scaled to the draft" not in q.message for q in own.pairs)
    assert all("scaled to the draft binned 2x2" in q.message for q in scaled.pairs)


@pytest.mark.skipif(not (DATA / "frobisher-colour-hdri").is_dir(), reason="no real data")
def test_real_bracket_draft_is_near_the_full_preview() -> None:
    """frobisher (640x426 JPEG, tripod) binned 2x2: measured mean 0.61, 99th percentile 5
    levels against the full run's preview at the draft's size (binned in levels, not in
    exposure: 1.07 and 6)."""
    d = DATA / "frobisher-colour-hdri"
    b = load_bracket(sorted(d.glob("*.jpg")))
    pipe = Pipeline(b)
    full = pipe.run()
    draft = run_draft(
        b,
        full.params.replace(response=full.response),
        max_side=320,
        exposure_times=full.exposure_times,
    )
    img = np.asarray(draft.preview.image)
    ref = pipe.run(full.params.replace(preview_max_side=320)).preview.image
    diff = np.abs(img.astype(float) - np.asarray(ref, float)[: img.shape[0], : img.shape[1]])
    diff = diff.max(axis=2)
    assert diff.mean() < 1.5
    assert np.percentile(diff, 99) < 10


def test_a_draft_merged_with_given_times_takes_given_ratios() -> None:
    """With the full run's times the draft only reports its whole-frame ratios: the full
    frames' (``ratios=``) stand in for its own fit, the picture is the same; without the
    times they are not used (the draft measures the times it merges with)."""
    b = _bracket((384, 576))
    full = Pipeline(b).run()
    p = full.params.replace(response=full.response)
    kw = dict(max_side=144, exposure_times=full.exposure_times, registration=full.registration)
    own = run_draft(b, p, **kw)
    given = run_draft(b, p, **kw, ratios=full.exposures_histogram)
    assert given.exposures_histogram is full.exposures_histogram
    assert own.exposures_histogram is not full.exposures_histogram
    np.testing.assert_array_equal(given.radiance, own.radiance)
    np.testing.assert_array_equal(given.preview.image, own.preview.image)
    alone = run_draft(b, p, max_side=144, ratios=full.exposures_histogram)
    assert alone.exposures_histogram is not full.exposures_histogram
    short = dataclasses.replace(own.exposures_histogram, pairs=own.exposures_histogram.pairs[:1])
    with pytest.raises(ParameterError, match="a pair per neighbouring frames"):
        Pipeline(b, ratios=short)


def test_a_draft_with_the_full_runs_motion_takes_its_frame_measures() -> None:
    """With the full run's motion and response the draft takes that run's white balance per
    frame and local tone mapping test (``frame_measures=``), measured on the full frames; a
    draft that registers its own frames measures its own."""
    b = _bracket((384, 576))
    full = Pipeline(b).run()
    assert full.frame_measures is not None
    p = full.params.replace(response=full.response)
    kw = dict(max_side=144, exposure_times=full.exposure_times)
    measures = full.frame_measures
    given = run_draft(b, p, **kw, registration=full.registration, frame_measures=measures)
    assert given.frame_measures is not None
    assert given.frame_measures.balance is full.frame_measures.balance
    assert given.frame_measures.shared is not full.frame_measures.shared  # its own samples
    own = run_draft(b, p, **kw, frame_measures=full.frame_measures)  # registers its own frames
    assert own.frame_measures is not None
    assert own.frame_measures.balance is not full.frame_measures.balance
    # the same picture within what the balance measured on binned frames moves
    d = np.abs(np.asarray(given.preview.image, float) - np.asarray(own.preview.image, float))
    assert d.mean() < 2.0
