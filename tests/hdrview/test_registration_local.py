"""The registration panel shows the local refinement (issue 14): the 'after' overlay reads the
frames through their motion and field as the merge does, and the panel says per pair what the
refinement did. On a real PipelineResult of a simulated hand-held bracket (local="on")."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hdrcore.io import load_bracket
from hdrcore.pipeline import Pipeline, PipelineParams
from hdrcore.registration.field import DisplacementField
from hdrcore.synthetic import simulate_bracket, write_bracket
from hdrview.panels.registration import local_fields, local_summary, overlay_crop


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    sim = simulate_bracket(
        scene="window",
        shape=(192, 256),
        exposure_times=(1.0, 4.0, 16.0),
        bits=12,
        response="linear",
        noise_sigma=1.0,
        seed=4,
        max_shift=3.0,
        max_rotation_deg=0.3,
        keep_linear=True,
    )
    out = tmp_path_factory.mktemp("local") / "dng"
    write_bracket(out, sim, fmt="dng")
    return Pipeline(load_bracket([out]), PipelineParams(local="on")).run(until="registration")


def test_the_refinement_is_reported_for_every_refined_pair(result) -> None:
    reg = result.registration
    assert reg.local is not None and len(reg.local.frames) == 2
    for k in range(len(reg.pairs)):
        line = local_summary(reg, k)
        assert line.startswith("Local refinement of frame") and "px median" in line
    doc = reg.to_json()["local"]
    assert [f["frame"] for f in doc["frames"]] == [0, 2]


def test_the_overlay_reads_the_frames_through_their_fields(result) -> None:
    reg = result.registration
    shape = result.bracket.shape
    step = reg.local.tile
    gh, gw = DisplacementField.grid(shape, step)
    moved = DisplacementField(step, np.full((gh, gw, 2), 6.0, np.float32))
    fields = list(local_fields(reg))
    plain = replace(
        result, registration=replace(reg, local=replace(reg.local, fields=(None,) * len(fields)))
    )
    fields[2] = moved
    shifted = replace(
        result, registration=replace(reg, local=replace(reg.local, fields=tuple(fields)))
    )
    a, _ = overlay_crop(result.bracket, plain, 1, aligned=True, zoom=0)
    b, _ = overlay_crop(result.bracket, shifted, 1, aligned=True, zoom=0)
    # the bright frame (red) moved by 6 px: the overlay changes, the dark frame (cyan) not
    assert np.abs(a[..., 0].astype(int) - b[..., 0].astype(int)).mean() > 2
    assert np.array_equal(a[..., 1], b[..., 1])
