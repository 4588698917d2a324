"""A pure colour painted at the same pixels of every frame (Debevec's memorial scans mark their
border areas (0, 0, 255)) is found and left out by default, as --exclude-colour would."""

from __future__ import annotations

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
