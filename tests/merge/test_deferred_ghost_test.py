"""``merge(..., defer_ghost_test=True)`` and ``Pipeline.run(checks="later")``: the region
ghost test left for later gives, once done, the merge made with it, and the radiance and preview
do not wait for it."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.io import Bracket
from hdrcore.io.frame import Frame, FrameMetadata
from hdrcore.merge import merge
from hdrcore.pipeline import Pipeline, PipelineParams

from ._brackets import bracket
from .test_deghost import SQUARE, _with_object


def test_a_deferred_ghost_test_completes_to_the_same_merge():
    sb = bracket(bits=12, response="linear", noise_sigma=1.0, seed=2)
    frames = _with_object(sb, 1)
    kw = dict(max_level=sb.max_level)
    now = merge(frames, sb.exposure_times, **kw)
    later = merge(frames, sb.exposure_times, defer_ghost_test=True, **kw)
    assert now.ghost[SQUARE].mean() > 0.5  # the object is found
    # pending: the picture is there, no ghost is known yet
    assert later.ghost_test_pending and not now.ghost_test_pending
    np.testing.assert_array_equal(later.radiance, now.radiance)
    assert not later.ghost.any() and later.ghost_regions is None
    assert "ghosts" not in later.message
    done = later.with_ghost_test()
    assert not done.ghost_test_pending
    np.testing.assert_array_equal(done.ghost, now.ghost)
    assert done.message == now.message and done.status == now.status
    regions = [
        {k: v for k, v in m.summary()["ghost_regions"].items() if k != "timings"}
        for m in (done, now)
    ]
    assert regions[0] == regions[1]
    assert later.with_ghost_test() is done  # run once
    # deghost reads the test: never deferred
    filled = merge(frames, sb.exposure_times, defer_ghost_test=True, deghost=True, **kw)
    assert not filled.ghost_test_pending and filled.deghosted is not None


def _as_bracket(sb, frames) -> Bracket:
    return Bracket(
        frames=tuple(
            Frame(
                levels=np.ascontiguousarray(f),
                meta=FrameMetadata(
                    path=f"/sim/frame{k}.tif",
                    format="tiff",
                    bit_depth=12,
                    max_level=sb.max_level,
                    is_linear=True,
                    exposure_time=t,
                ),
            )
            for k, (f, t) in enumerate(zip(frames, sb.exposure_times, strict=True))
        ),
        warnings=(),
        order_source="exposure",
        input_order=tuple(range(len(frames))),
    )


def test_the_pipeline_finishes_the_ghost_test_later_to_the_same_result():
    sb = bracket(bits=12, response="linear", noise_sigma=1.0, seed=2)
    b = _as_bracket(sb, _with_object(sb, 1))
    p = PipelineParams(align="none")
    now = Pipeline(b).run(p)
    pipe = Pipeline(b)
    later = pipe.run(p, checks="later")
    assert later.merge.ghost_test_pending and later.preview is not None
    assert "ghosts" not in {v.code for v in later.verdicts}
    done = pipe.finish_checks(later)
    assert not done.merge.ghost_test_pending
    np.testing.assert_array_equal(done.merge.ghost, now.merge.ghost)
    assert [v.to_json() for v in done.verdicts] == [v.to_json() for v in now.verdicts]
    assert pipe.last_result is done
    # the cached merge serves the next run, complete
    again = pipe.run(p)
    assert "merge" not in again.stages_run and not again.merge.ghost_test_pending
    np.testing.assert_array_equal(again.merge.ghost, now.merge.ghost)


def test_the_former_names_still_work_with_a_warning():
    sb = bracket(bits=12, response="linear", noise_sigma=1.0, seed=2)
    b = _as_bracket(sb, _with_object(sb, 1))
    pipe = Pipeline(b)
    with pytest.warns(DeprecationWarning, match="checks="):
        later = pipe.run(PipelineParams(align="none"), ghost_test="later")
    assert later.checks_pending
    with pytest.warns(DeprecationWarning, match="finish_checks"):
        done = pipe.finish_ghost_test(later)
    assert not done.checks_pending
