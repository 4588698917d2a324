"""What a non-linear merge's colour check measures on the frames alone is kept between the
checks and the slider steps of one bracket (the ``frame_measures`` stage); a draft's merge is
anchored but not measured (``Pipeline(colour_report=False)``). Neither changes a pixel or a
reported figure."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hdrcore.io import load_bracket
from hdrcore.pipeline import Pipeline
from tests.hdrview._brackets import write_png_bracket


def _bracket(tmp_path: Path):
    return load_bracket(write_png_bracket(tmp_path / "b", shape=(120, 180)))


def test_a_step_reads_the_frames_measures_from_the_cache(tmp_path: Path) -> None:
    pl = Pipeline(_bracket(tmp_path))
    first = pl.run()
    assert first.colour["check"]["before"] is not None
    # a step that keeps the registration (its levels snap to a ladder): the frames' measures
    # come from the cache, the merge is new
    for d in (0.5, 1.0, 1.5, 2.0):
        step = first.params.replace(saturation=first.saturation - d)
        kept = pl.run(step)
        if "registration" not in kept.stages_run:
            break
    assert "registration" not in kept.stages_run and "merge" in kept.stages_run
    fresh = Pipeline(_bracket(tmp_path)).run(step)
    # the same report and pixels as a pipeline that measured everything afresh
    assert kept.colour["check"] == fresh.colour["check"]
    assert np.array_equal(kept.radiance, fresh.radiance)


def test_a_merge_not_measured_has_the_same_pixels(tmp_path: Path) -> None:
    measured = Pipeline(_bracket(tmp_path)).run()
    draft = Pipeline(_bracket(tmp_path), colour_report=False).run()
    check = draft.colour["check"]
    assert check["before"] is None and check["after"] is None
    assert "not measured" in check["message"]
    assert check["local_tone_mapping"] == measured.colour["check"]["local_tone_mapping"]
    assert np.array_equal(draft.radiance, measured.radiance)
    assert np.array_equal(draft.preview.image, measured.preview.image)


def test_an_exposure_fusion_preview_is_kept_across_a_step(tmp_path: Path, monkeypatch) -> None:
    """Locally tone-mapped frames (the test forced to say so) are previewed by their exposure
    fusion, a stage of its own keyed on the frames' motion: a step that keeps the registration
    draws it from the cache, the same picture."""
    import dataclasses

    from hdrcore.merge import fusion
    from hdrcore.response import local_tonemap

    real = local_tonemap.local_tone_mapping

    def detected(*args, **kwargs):
        return dataclasses.replace(real(*args, **kwargs), detected=True)

    monkeypatch.setattr(local_tonemap, "local_tone_mapping", detected)
    calls = []
    real_fusion = fusion.exposure_fusion

    def counted(*args, **kwargs):
        calls.append(1)
        return real_fusion(*args, **kwargs)

    monkeypatch.setattr("hdrcore.pipeline.exposure_fusion", counted)
    pl = Pipeline(_bracket(tmp_path))
    first = pl.run()
    assert first.preview is not None and first.preview.method == "exposure-fusion"
    assert len(calls) == 1
    for d in (0.5, 1.0, 1.5, 2.0):
        step = pl.run(first.params.replace(saturation=first.saturation - d))
        if "registration" not in step.stages_run:
            break
    assert "registration" not in step.stages_run and "merge" in step.stages_run
    assert len(calls) == 1  # the fusion from the cache
    assert step.preview is not None
    assert np.array_equal(step.preview.image, first.preview.image)
    # a new motion makes a new fusion
    pl.run(first.params.replace(align="shift"))
    assert len(calls) == 2


def test_the_fusion_reads_the_merge_levels_only_through_the_snapped_registration(
    tmp_path: Path,
) -> None:
    from hdrcore.pipeline import SNAPPED_INPUTS

    pl = Pipeline(_bracket(tmp_path))
    every = pl.fields_read("fusion")
    direct = pl.fields_read("fusion", skip=SNAPPED_INPUTS)
    assert {"saturation", "noise_floor"} <= every  # through the registration's levels
    assert not {"saturation", "noise_floor", "deghost", "white_balance"} & direct
    assert {"preview_max_side", "threshold", "align", "response"} <= direct


def test_colour_checks_made_later_report_the_same(tmp_path: Path) -> None:
    """``checks="later"``: the picture comes back before the colour checks (the anchored
    pixels are the same), which :meth:`Pipeline.finish_checks` makes from the merge's pixels as
    they were before and after the anchoring: the same report, to the figure."""
    now = Pipeline(_bracket(tmp_path)).run()
    pl = Pipeline(_bracket(tmp_path))
    later = pl.run(checks="later")
    assert later.checks_pending and later.colour_pending is not None
    check = later.colour["check"]
    assert check["before"] is None and check["after"] is None
    assert "being measured" in check["message"]
    assert check["anchor"] == now.colour["check"]["anchor"]  # anchored already
    assert np.array_equal(later.radiance, now.radiance)
    assert np.array_equal(later.preview.image, now.preview.image)
    assert "colour-anchored" not in {v.code for v in later.verdicts}
    done = pl.finish_checks(later)
    assert not done.checks_pending and pl.last_result is done
    assert done.colour == now.colour
    assert [v.to_json() for v in done.verdicts] == [v.to_json() for v in now.verdicts]
    assert "colour_checks" in done.timings
    # "before" is the merge as made: what an unanchored merge of the same frames measures
    plain = Pipeline(_bracket(tmp_path)).run(now.params.replace(colour_anchor=False))
    assert plain.colour["check"]["anchor"] is None
    assert done.colour["check"]["before"] == plain.colour["check"]["before"]
    assert done.colour["check"]["after"] != done.colour["check"]["before"]
    # the cached merge serves the next run, measured (either way it is asked)
    for checks in ("later", "now"):
        again = pl.run(checks=checks)
        assert "merge" not in again.stages_run
        assert again.colour == now.colour and again.colour_pending is None


def test_the_checks_read_radiance_samples_as_the_map(tmp_path: Path) -> None:
    from hdrcore.errors import ParameterError
    from hdrcore.merge.colour_check import RadianceSamples, colour_check, frame_colours

    res = Pipeline(_bracket(tmp_path)).run()
    frames = [f.levels for f in res.bracket.frames]
    kw = dict(max_level=255, reference=1)
    full = colour_check(frames, res.radiance, res.lut, **kw)
    sampled = colour_check(frames, RadianceSamples.of(res.radiance, 150_000), res.lut, **kw)
    assert sampled.to_json() == full.to_json()
    assert frame_colours(frames, RadianceSamples.of(res.radiance, 2_000), **kw, max_samples=2_000)
    try:
        colour_check(frames, RadianceSamples.of(res.radiance, 2_000), res.lut, **kw)
    except ParameterError as e:
        assert "another grid" in str(e)
    else:
        raise AssertionError("samples on another grid were read")
