"""One writer for a run's radiance map (issue 17): ``hdrcore merge`` and the inspector's EXR
export write the same pixels with the same attributes (:func:`hdrcore.export.write_result`)."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.cli import main
from hdrcore.errors import OutputError
from hdrcore.export import write_result
from hdrcore.io import load_bracket, read_exr
from hdrcore.pipeline import Pipeline, PipelineParams
from hdrcore.synthetic import simulate_bracket, write_bracket
from hdrview.panels.result import exr_bytes


@pytest.fixture(scope="module")
def bracket_dir(tmp_path_factory):
    sim = simulate_bracket(
        scene="window",
        shape=(64, 96),
        exposure_times=(1.0, 4.0, 16.0),
        bits=8,
        response="srgb",
        noise_sigma=0.5,
        seed=5,
        max_shift=1.5,
        max_rotation_deg=0.2,
    )
    out = tmp_path_factory.mktemp("export") / "jpeg"
    write_bracket(out, sim, fmt="png")
    return out


def _attributes(path) -> tuple[np.ndarray, dict]:
    rgb, attrs = read_exr(path)
    # written by OpenEXR itself, not by us
    keep = {
        k: v
        for k, v in attrs.items()
        if k.startswith("hdrview") or k in ("exposureTimes", "exposureRatios")
    }
    return rgb, keep


def test_cli_and_inspector_write_the_same_file(bracket_dir, tmp_path) -> None:
    cli_out = tmp_path / "cli.exr"
    assert main(["merge", str(bracket_dir), "-o", str(cli_out), "--quiet"]) == 0
    result = Pipeline(load_bracket([bracket_dir]), PipelineParams()).run(until="merge")
    ins_out = tmp_path / "inspector.exr"
    ins_out.write_bytes(exr_bytes(result, work_dir=tmp_path))
    cli_rgb, cli_attrs = _attributes(cli_out)
    ins_rgb, ins_attrs = _attributes(ins_out)
    for key in (
        "exposureTimes",
        "exposureRatios",
        "hdrviewTransforms",
        "hdrviewSources",
        "hdrview",
    ):
        assert key in ins_attrs, key
    assert ins_attrs == cli_attrs
    np.testing.assert_array_equal(ins_rgb, cli_rgb)
    assert ins_attrs["hdrview"]["working_space"] == result.params.working_space
    assert len(ins_attrs["hdrviewTransforms"]) == 3


def test_a_run_without_a_merge_is_refused(bracket_dir, tmp_path) -> None:
    result = Pipeline(load_bracket([bracket_dir]), PipelineParams()).run(until="ratios")
    with pytest.raises(OutputError, match="no merged radiance.*run until 'ratios'"):
        write_result(tmp_path / "x.exr", result)
    assert not (tmp_path / "x.exr").exists()


def test_write_result_is_atomic_and_keeps_existing_files(bracket_dir, tmp_path) -> None:
    result = Pipeline(load_bracket([bracket_dir]), PipelineParams()).run(until="merge")
    out = tmp_path / "out.exr"
    out.write_bytes(b"keep")
    with pytest.raises(OutputError, match="exists"):
        write_result(out, result)
    assert out.read_bytes() == b"keep"
    write_result(out, result, force=True)
    assert out.read_bytes()[:4] == b"\x76\x2f\x31\x01"
    assert [p.name for p in tmp_path.iterdir()] == ["out.exr"]  # no temporary file left
