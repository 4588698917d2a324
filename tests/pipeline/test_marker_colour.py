"""A pure colour painted at the same pixels of every frame (Debevec's memorial scans mark their
border areas (0, 0, 255)) is found and left out by default, as --exclude-colour would."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hdrcore.pipeline import Pipeline, PipelineParams
from hdrcore.synthetic import simulate_bracket


@pytest.fixture(scope="module")
def brackets(tmp_path_factory: pytest.TempPathFactory):
    from hdrcore.io import load_bracket
    from hdrcore.synthetic import write_bracket

    sim = simulate_bracket(
        scene="window",
        shape=(96, 144),
        exposure_times=(1 / 64, 1 / 16, 1 / 4),
        bits=8,
        response="gamma",
        noise_sigma=1.0,
        seed=6,
    )
    plain = tmp_path_factory.mktemp("plain")
    write_bracket(plain, sim, fmt="png")
    for f in sim.frames:  # a painted border strip and a few painted dots, in every frame
        f[:, :6] = (0, 0, 255)
        f[40:43, 70:73] = (0, 0, 255)
    marked = tmp_path_factory.mktemp("marked")
    write_bracket(marked, sim, fmt="png")
    return load_bracket([plain]), load_bracket([marked])


def test_a_painted_colour_is_found_and_left_out(brackets) -> None:
    plain, marked = brackets
    assert Pipeline(plain).marker_colour() is None
    pipe = Pipeline(marked)
    res = pipe.run(PipelineParams(align="none"))
    assert res.marker_colour == (0, 0, 255) and tuple(res.params.exclude_colour) == (0, 0, 255)
    assert any(v.code == "marker-colour-excluded" for v in res.verdicts)
    explicit = Pipeline(marked).run(PipelineParams(align="none", exclude_colour=(0, 0, 255)))
    assert explicit.exposures.ratios == pytest.approx(res.exposures.ratios)
    np.testing.assert_array_equal(explicit.radiance, res.radiance)
    # a re-run from the result's own parameters keeps saying why
    again = pipe.run(res.params.replace(tonemap_exposure=0.5))
    assert again.marker_colour == (0, 0, 255)
    assert any(v.code == "marker-colour-excluded" for v in again.verdicts)


def test_an_excluded_colour_that_some_frames_lack_is_a_warning(brackets) -> None:
    """``exclude_colour`` matching no pixel of a frame (a JPEG moved its marks' colour) leaves
    that frame's marks in the picture: a warning names the frames; matching nowhere says nothing
    was left out; matching everywhere says nothing."""
    plain, marked = brackets
    res = Pipeline(marked).run(PipelineParams(align="none", exclude_colour=(0, 0, 255)))
    assert res.excluded_pixels is not None and all(n > 0 for n in res.excluded_pixels)
    assert not any(v.code == "excluded-colour-unmatched" for v in res.verdicts)
    nowhere = Pipeline(plain).run(PipelineParams(align="none", exclude_colour=(1, 2, 3)))
    assert nowhere.excluded_pixels == (0, 0, 0)
    (v,) = [v for v in nowhere.verdicts if v.code == "excluded-colour-unmatched"]
    assert v.severity == "warning" and "matches no pixel of any frame" in v.message
    # the middle frame's marks moved off the colour (as JPEG moves them)
    frames = list(marked.frames)
    lv = frames[1].levels.copy()
    lv[(lv[..., 0] == 0) & (lv[..., 1] == 0) & (lv[..., 2] == 255)] = (1, 1, 245)
    frames[1] = replace(frames[1], levels=lv)
    moved = replace(marked, frames=tuple(frames))
    some = Pipeline(moved).run(PipelineParams(align="none", exclude_colour=(0, 0, 255)))
    assert some.excluded_pixels is not None and some.excluded_pixels[1] == 0
    (v,) = [v for v in some.verdicts if v.code == "excluded-colour-unmatched"]
    assert v.frames == (1,) and "frame 1 (" in v.message
    assert Pipeline(plain).run(PipelineParams(align="none")).excluded_pixels is None
