"""``align="auto"`` (issue 14): the similarity first, the homography for a pair whose residual
shows perspective, kept when it leaves less; a pair the similarity explains keeps it."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import tifffile

from hdrcore.io import load_bracket
from hdrcore.pipeline import Pipeline, PipelineParams

from ..registration._pairs import perspective, render_frames


def test_auto_takes_the_homography_only_where_perspective_is_left(tmp_path) -> None:
    shape = (256, 384)
    tilt = perspective(shape, 1.5, -2.0, 0.2, 1.003, 0.012, -0.010)  # frame 2: perspective
    shift = perspective(shape, 2.0, 1.0, 0.0, 1.0, 0.0, 0.0)  # frame 0: a plain shift
    times = (1.0, 4.0, 16.0)
    frames, ml = render_frames(
        [shift, np.eye(3), tilt], times, bits=16, shape=shape, noise_sigma=2.0, scene="window"
    )
    for k, g in enumerate(frames):
        rgb = np.repeat((np.clip(g, 0, 1) * ml + 0.5).astype(np.uint16)[..., None], 3, axis=2)
        tifffile.imwrite(tmp_path / f"f{k}.tif", rgb)
    (tmp_path / "exposure_times.txt").write_text(
        "".join(f"f{k}.tif {t:g}\n" for k, t in enumerate(times))
    )
    bracket = load_bracket([tmp_path])
    auto = Pipeline(bracket, PipelineParams(align="auto", response="linear")).run(
        PipelineParams(align="auto", response="linear"), until="registration"
    )
    reg = auto.registration
    assert reg.pairs[0].model == "similarity"  # a shift: the simplest model that explains it
    assert reg.pairs[1].model == "homography" and "auto:" in reg.pairs[1].message
    assert reg.pairs[1].residual.median < 0.3
    assert len(reg.to_reference_homography) == 3


PIXEL7 = Path(__file__).resolve().parents[3] / "shared" / "data" / "handheld-pixel7-lab"


@pytest.mark.skipif(not PIXEL7.is_dir(), reason="../shared/data not available")
def test_auto_takes_the_homography_that_removes_a_perspective_tilt() -> None:
    """The Pixel 7's darkest pair: the similarity leaves a perspective tilt at the corners; the
    homography removes it and lowers the tiles' median, so ``auto`` keeps it (by the median
    falling by more than a fifth, or, when it falls less, by the pattern it removes). Measured
    through the recovered curve (the default since the selection weighs radiometry first):
    similarity 0.62 px median and a 2.2 px pattern, homography 0.47 px with no pattern since
    the residual check saturates a whole analysis block that holds a clipped pixel (0.51 px
    before, kept by the pattern rule); through the filmic fallback it chose before: 0.45 / 4.0
    and 0.41 / 0.1 px (the residual is measured on the linearised frames, so its scale
    follows the curve's shadows on this dark pair)."""
    b = load_bracket([PIXEL7])
    reg = (
        Pipeline(b, PipelineParams(local="off", registration_previews=False))
        .run(until="registration")
        .registration
    )
    q = reg.pairs[0]
    assert q.model == "homography", q.message
    assert max(q.residual.pattern.component_px().values()) < 1.0
    m = re.search(r"similarity left ([0-9.]+) px median.*homography ([0-9.]+) px", q.message)
    assert m is not None, q.message
    assert float(m.group(2)) < float(m.group(1))
    assert q.residual.median < 0.55


@pytest.mark.skipif(not PIXEL7.is_dir(), reason="../shared/data not available")
def test_the_defaults_leave_under_0_3_px_on_the_median_pixel7_pair() -> None:
    """Issue 14's real-data target with the pipeline's defaults (``--align auto --local
    auto``): the misalignment left, measured independently of the model, is at most 0.3 px on
    the median pair (measured 0.286: pairs 0.298, 0.286, 0.298, 0.271, 0.266 px, three of them
    through a field) and no pair is called ``ok`` with more than 1 px left."""
    b = load_bracket([PIXEL7])
    reg = (
        Pipeline(b, PipelineParams(registration_previews=False))
        .run(until="registration")
        .registration
    )
    left = {(q.dark, q.bright): q.residual.median for q in reg.pairs}
    assert all(q.residual.median <= 1.0 for q in reg.pairs if q.ok)
    assert reg.local is not None
    for f in reg.local.frames:
        if f.kept:
            assert f.after < f.before
            left[tuple(sorted((f.frame, f.against)))] = f.after
    assert np.median(list(left.values())) <= 0.3, left
