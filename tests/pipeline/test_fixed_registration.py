"""``Pipeline(registration=...)`` and :func:`scale_registration`: a motion known already (a
draft takes the full-resolution run's) used in place of the registration stage."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hdrcore.draft import draft_bracket
from hdrcore.errors import ParameterError
from hdrcore.pipeline import Pipeline, PipelineParams, scale_registration

from ..test_draft import _bracket

P = PipelineParams(local="off", registration_previews=False, response="srgb")


def test_scaled_registration_goes_back_to_the_same_motion() -> None:
    b = _bracket(bits=8)
    reg = Pipeline(b, P).run(until="registration").registration
    assert reg is not None
    h, w = b.shape
    half = scale_registration(reg, 0.5, (h // 2, w // 2))
    back = scale_registration(half, 2.0, (h, w))
    for q, r in zip(reg.pairs, back.pairs, strict=True):
        np.testing.assert_allclose(r.matrix, q.matrix, atol=1e-9)
    # on the half-size grid a pixel of motion is half a pixel
    for q, r in zip(reg.pairs, half.pairs, strict=True):
        assert r.dx == pytest.approx(q.dx / 2, abs=1e-6)
        assert r.dy == pytest.approx(q.dy / 2, abs=1e-6)


def test_a_given_registration_replaces_the_stage() -> None:
    b = _bracket(bits=8)
    full = Pipeline(b, P).run()
    small = draft_bracket(b, 2, saturation=float(full.saturation))
    given = scale_registration(full.registration, 0.5, small.shape)
    res = Pipeline(small, registration=given).run(P)
    assert res.registration is given
    assert res.radiance is not None and np.isfinite(res.radiance).any()
    # align="none" still means no alignment
    none = Pipeline(small, registration=given).run(P.replace(align="none"))
    assert none.registration is None
    with pytest.raises(ParameterError, match="a pair per neighbouring frames"):
        Pipeline(small, registration=replace(given, pairs=given.pairs[:1]))
