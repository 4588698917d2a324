"""Cached stages re-run when what they read changes (issue 17, point 1): on a bracket without
exposure times the response reads the exposure method (its rough ratios come from the
histograms), so switching the method must give what a fresh run gives, not a curve kept from
the other method."""

from __future__ import annotations

import numpy as np
from PIL import Image

from hdrcore.io import load_bracket
from hdrcore.pipeline import Pipeline, PipelineParams
from hdrcore.synthetic import simulate_bracket, write_bracket


def test_switching_the_exposure_method_equals_a_fresh_run(tmp_path) -> None:
    sim = simulate_bracket(
        scene="window",
        shape=(96, 144),
        exposure_times=(1.0, 4.0, 16.0),
        bits=8,
        response="srgb",
        noise_sigma=1.0,
        seed=3,
    )
    out = write_bracket(tmp_path / "png", sim, fmt="png")
    (tmp_path / "png" / "exposure_times.txt").unlink(missing_ok=True)
    for f in out.frames:  # re-saved without their metadata: no exposure times anywhere
        Image.fromarray(np.asarray(Image.open(f))).save(f)
    bracket = load_bracket(list(out.frames))
    assert not all(e is not None for e in bracket.exif_exposures())  # no times: the case
    a = PipelineParams(response="debevec-histogram", exposure_method="Cerman 2006 refined")
    b = a.replace(exposure_method="Cerman 2006")
    pl = Pipeline(bracket, a)
    pl.run(a, until="ratios")
    switched = pl.run(b, until="ratios")
    assert "response" in switched.stages_run
    fresh = Pipeline(load_bracket(list(out.frames)), b).run(b, until="ratios")
    assert np.allclose(switched.lut, fresh.lut)
    assert np.allclose(
        [q.ratio for q in switched.exposures.pairs],
        [q.ratio for q in fresh.exposures.pairs],
        rtol=0,
        atol=1e-9,
    )
