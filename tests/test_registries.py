"""Adding a method of each kind is one entry in a public registry (ARCHITECTURE.md): each test
registers a toy method, runs it by name through the public function and the pipeline, and
checks that the toy itself did the work (not a default standing in for it)."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.errors import ParameterError
from hdrcore.pipeline import Pipeline, PipelineParams
from hdrcore.synthetic import simulate_bracket


@pytest.fixture(scope="module")
def bracket(tmp_path_factory: pytest.TempPathFactory):
    from hdrcore.io import load_bracket
    from hdrcore.synthetic import write_bracket

    sim = simulate_bracket(
        scene="window",
        shape=(96, 144),
        exposure_times=(1 / 64, 1 / 16, 1 / 4),
        bits=8,
        response="gamma",
        noise_sigma=1.0,
        seed=4,
        max_shift=2,
        max_rotation_deg=0.2,
    )
    out = tmp_path_factory.mktemp("registries")
    write_bracket(out, sim, fmt="png")
    return load_bracket([out])


def test_a_tonemap_operator_is_one_entry(bracket, monkeypatch) -> None:
    from hdrcore import tonemap as tm

    calls = []

    def halves(x: np.ndarray, *, white: float | None = None) -> np.ndarray:
        calls.append(x.shape)
        np.clip(0.5 * x, 0.0, 1.0, out=x)
        return x

    monkeypatch.setitem(tm.TONEMAP_OPERATORS, "halves", halves)
    rad = np.full((8, 8, 3), 0.18, np.float32)
    lin = tm.tonemap(rad, "linear", auto_exposure=False)
    half = tm.tonemap(rad, "halves", auto_exposure=False)
    assert calls and half.method == "halves"
    assert int(half.image[0, 0, 0]) < int(lin.image[0, 0, 0])  # half the light, darker
    calls.clear()
    res = Pipeline(bracket).run(PipelineParams(tonemap="halves"))
    assert calls and res.preview.method == "halves"
    monkeypatch.delitem(tm.TONEMAP_OPERATORS, "halves")
    with pytest.raises(ParameterError, match="halves"):
        tm.tonemap(rad, "halves")


def test_a_response_method_is_one_entry(bracket, monkeypatch) -> None:
    import hdrcore.response as rsp

    calls = []

    def gamma22(frames, exposure_times=None, *, max_level: int = 255, **_: object):
        calls.append(len(frames))
        g = (np.arange(max_level + 1) / max_level) ** 2.2
        return rsp.ResponseCurve(g=np.tile(g, (3, 1)), method="gamma22")

    monkeypatch.setitem(rsp.RESPONSE_METHODS, "gamma22", gamma22)
    frames = [f.levels for f in bracket.frames]
    curve = rsp.recover_response(frames, bracket.exif_exposures(), method="gamma22")
    assert calls == [3] and curve.method == "gamma22"
    calls.clear()
    res = Pipeline(bracket).run(PipelineParams(response="gamma22", align="none"))
    assert calls and res.response.method == "gamma22"
    np.testing.assert_allclose(res.response.g[1], (np.arange(256) / 255.0) ** 2.2)


def test_a_registration_method_is_one_entry(bracket, monkeypatch) -> None:
    import hdrcore.registration as reg
    from hdrcore.registration.fast import register_pair_fast

    calls = []

    def counted(dark, bright, ratio, **options):
        calls.append(options.get("model"))
        return register_pair_fast(dark, bright, ratio, **options)

    monkeypatch.setitem(reg.REGISTRATION_METHODS, "counted", counted)
    res = Pipeline(bracket).run(
        PipelineParams(registration_method="counted", align="similarity", local="off")
    )
    assert calls == ["similarity", "similarity"]  # one search per consecutive pair
    assert [q.method for q in res.registration.pairs] == ["fast", "fast"]
    assert all(q.usable for q in res.registration.pairs)
