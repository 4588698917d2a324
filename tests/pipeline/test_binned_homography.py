"""Registration on binned frames (``registration_max_pixels``) scales every form of the motion
back to full resolution: the 2x3 matrix and the 3x3 homography (found by mypy, issue 17: a
homography pair has no 2x3 matrix, and ``align="homography"`` stopped with "a motion matrix
must be 2x3 or 3x3 (found shape ())"; an affine pair kept its binned homography, which the
residual check and the local refinement read)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hdrcore.io import load_bracket
from hdrcore.pipeline import Pipeline, PipelineParams
from hdrcore.registration import corner_error
from hdrcore.registration.transform import homogeneous

DEMO = Path(__file__).resolve().parents[2] / "assets" / "demo"


@pytest.fixture(scope="module")
def demo():
    return load_bracket([DEMO]), json.loads((DEMO / "truth.json").read_text())


@pytest.mark.parametrize("align", ["similarity", "homography"])
def test_binned_registration_scales_the_homography_back(demo, align: str) -> None:
    b, truth = demo
    r = Pipeline(b, PipelineParams(align=align, local="off", registration_max_pixels=100_000)).run(
        until="registration"
    )
    reg = r.registration
    assert reg is not None
    for k, p in enumerate(reg.pairs):
        assert "binned 2x2" in p.message and p.usable, (k, p.status, p.message)
        assert p.homography is not None and p.homography.shape == (3, 3)
        err = corner_error(p.homography, np.array(truth["pairs"][k]["matrix"]), b.shape)
        assert float(np.max(err)) < 0.3, (k, err)
        if align == "similarity":
            np.testing.assert_allclose(p.homography, homogeneous(p.matrix), atol=1e-9)
        else:
            assert p.matrix is None
    assert len(reg.to_reference_homography) == len(b)
