"""The declared stage graph (hdrcore.stage_graph, hdrcore.pipeline.GRAPH): keys from the
declaration, content tokens never id(), undeclared reads raise, the graph is checked."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hdrcore.pipeline import GRAPH, STAGES, Pipeline, PipelineParams
from hdrcore.response import ResponseCurve
from hdrcore.stage_graph import Stage, StageCache, StageGraph, UndeclaredDependency, token
from hdrcore.synthetic import simulate_bracket, write_bracket


@dataclasses.dataclass(frozen=True)
class _Params:
    a: int = 1
    b: int = 2
    c: float = 0.5


def test_tokens_follow_content_not_identity() -> None:
    x = np.arange(12.0).reshape(3, 4)
    assert token(x) == token(x.copy())
    y = x.copy()
    y[2, 3] += 1e-12
    assert token(x) != token(y)
    assert token(x) != token(x.astype(np.float32))
    assert token(x) != token(x.reshape(4, 3))
    g = np.tile(np.linspace(0.0, 1.0, 256) ** 2.2, (3, 1))
    a, b = ResponseCurve(g, "gamma"), ResponseCurve(g.copy(), "gamma")
    assert a is not b and token(a) == token(b)
    g2 = g.copy()
    g2[1, 100] *= 0.999
    assert token(ResponseCurve(g2, "gamma")) != token(a)
    assert token((1, 0.1, "x", None)) == token((1, 0.1, "x", None))
    assert token(0.1) != token(float(np.nextafter(0.1, 1.0)))
    assert token(float("nan")) == token(float("nan"))  # a NaN parameter still hits the cache
    with pytest.raises(TypeError, match="cannot derive a cache token"):
        token(lambda: None)


def _toy_graph(read_c: bool = False) -> StageGraph:
    def first(ctx, p, up):
        ctx["calls"].append("first")
        return p.a * 10

    def second(ctx, p, up):
        ctx["calls"].append("second")
        return up.first + p.b + (p.c if read_c else 0)

    return StageGraph(
        [Stage("first", first, ("a",)), Stage("second", second, ("b",), ("first",))],
        [f.name for f in dataclasses.fields(_Params)],
    )


def test_keys_come_from_the_declaration() -> None:
    ctx: dict = {"calls": []}
    cache = StageCache(_toy_graph(), ctx)
    assert cache.run(_Params()).get("second") == 12
    assert cache.run(_Params(c=9.0)).get("second") == 12  # c is read by no stage
    assert ctx["calls"] == ["first", "second"]
    ran: list[str] = []
    assert cache.run(_Params(b=5), ran).get("second") == 15
    assert ran == ["second"]
    ran = []
    assert cache.run(_Params(a=2, b=5), ran).get("second") == 25
    assert ran == ["first", "second"]


def test_a_stage_keeps_its_recent_values() -> None:
    """``keep``: going back to one of a stage's last ``keep`` keys takes its value again (its
    downstream keyed as before); older keys, and stages keeping one value, compute again."""
    calls: list[str] = []

    def first(ctx, p, up):
        calls.append(f"first{p.a}")
        return p.a * 10

    def second(ctx, p, up):
        calls.append(f"second{up.first // 10}{p.b}")
        return up.first + p.b

    graph = StageGraph(
        [Stage("first", first, ("a",), keep=3), Stage("second", second, ("b",), ("first",))],
        [f.name for f in dataclasses.fields(_Params)],
    )
    cache = StageCache(graph, {})
    for a in (1, 2, 3):
        assert cache.run(_Params(a=a)).get("second") == 10 * a + 2
    calls.clear()
    ran: list[str] = []
    assert cache.run(_Params(a=1), ran).get("second") == 12  # a=1 is one of the last three
    assert ran == ["second"] and calls == ["second12"]
    assert cache.run(_Params(a=3), ran).get("second") == 32
    assert calls == ["second12", "second32"]  # a=3 was kept in turn when a=1 came back
    assert cache.run(_Params(a=4)).get("second") == 42
    calls.clear()
    assert cache.run(_Params(a=2)).get("second") == 22  # kept: 4 (current), 3, 1
    assert calls == ["first2", "second22"]
    assert [e.key[1] for e in cache.recent["first"]] == [(("a", token(4)),), (("a", token(3)),)]
    cache.clear()
    assert not cache.recent and not cache.entries


def test_an_undeclared_read_raises() -> None:
    cache = StageCache(_toy_graph(read_c=True), {"calls": []})
    with pytest.raises(UndeclaredDependency, match="'second' read the parameter 'c'"):
        cache.run(_Params()).get("second")
    assert "second" not in cache.entries  # nothing stored from a failed stage

    def sneaky(ctx, p, up):
        return up.first

    cache = StageCache(
        StageGraph([Stage("first", lambda ctx, p, up: 1), Stage("other", sneaky)], ["a"]), {}
    )
    with pytest.raises(UndeclaredDependency, match="'other' read the stage 'first'"):
        cache.run(_Params()).get("other")


def test_the_graph_is_checked() -> None:
    def f(ctx, p, up):
        return None

    with pytest.raises(ValueError, match="unknown stage 'nope'"):
        StageGraph([Stage("x", f, (), ("nope",))], ["a"])
    with pytest.raises(ValueError, match="stage cycle"):
        StageGraph([Stage("x", f, (), ("y",)), Stage("y", f, (), ("x",))], ["a"])
    with pytest.raises(ValueError, match="unknown parameters"):
        StageGraph([Stage("x", f, ("zeta",))], ["a"])
    with pytest.raises(ValueError, match="declared twice"):
        StageGraph([Stage("x", f), Stage("x", f)], ["a"])


def test_the_pipeline_graph() -> None:
    reported = [name for name in GRAPH.order if not GRAPH.stages[name].internal]
    assert reported == [s for s in STAGES if s in reported] and set(reported) == set(STAGES)
    fields = {f.name for f in dataclasses.fields(PipelineParams)}
    # The preview reads the tonemap fields and whatever its merge read; the merge never reads
    # the tonemap fields (moving the exposure slider re-renders the preview only).
    assert {"tonemap", "tonemap_exposure", "preview_max_side", "deghost"} <= GRAPH.fields_read(
        "preview", _NoTimes(False)
    )
    assert not {"tonemap", "tonemap_exposure", "preview_max_side"} & GRAPH.fields_read(
        "merge", _NoTimes(True)
    )
    # The response reads the exposure method only for frames without times.
    assert "exposure_method" not in GRAPH.stages["response"].fields(_NoTimes(False))
    assert "exposure_method" in GRAPH.stages["response"].fields(_NoTimes(True))
    assert GRAPH.fields_read("preview", _NoTimes(True)) <= fields


class _NoTimes:
    def __init__(self, no_times: bool) -> None:
        self.no_times = no_times


@pytest.fixture(scope="module")
def small_bracket(tmp_path_factory: pytest.TempPathFactory):
    from hdrcore.io import load_bracket

    sim = simulate_bracket(
        scene="window",
        shape=(48, 64),
        exposure_times=(1 / 16, 1 / 4, 1.0),
        bits=8,
        response="gamma",
        noise_sigma=1.0,
        seed=2,
    )
    out = tmp_path_factory.mktemp("graph")
    write_bracket(out, sim, fmt="png")
    return load_bracket([out])


def test_a_stage_missing_a_field_in_its_declaration_fails_at_once(
    small_bracket, monkeypatch
) -> None:
    """By construction: drop ``preview_max_side`` from the preview's declaration and the run
    stops with the stage and the field named, instead of keeping a stale preview."""
    st = GRAPH.stages["preview"]
    monkeypatch.setitem(
        GRAPH.stages,
        "preview",
        dataclasses.replace(st, params=tuple(f for f in st.params if f != "preview_max_side")),
    )
    with pytest.raises(
        UndeclaredDependency, match="'preview' read the parameter 'preview_max_side'"
    ):
        Pipeline(small_bracket).run(PipelineParams(align="none"))


def test_a_curve_parameter_is_keyed_by_its_content(small_bracket) -> None:
    """The issue's ``id()`` key: an equal curve in a new object re-uses the cache, a changed
    curve re-runs the response and everything after it."""
    m = small_bracket.max_level
    g = np.tile(np.linspace(0.0, 1.0, m + 1) ** 2.2, (3, 1))
    pipe = Pipeline(small_bracket)
    p = PipelineParams(align="none", response=ResponseCurve(g, "gamma"))
    pipe.run(p)
    again = pipe.run(p.replace(response=ResponseCurve(g.copy(), "gamma")))
    assert again.stages_run == ()
    g2 = np.tile(np.linspace(0.0, 1.0, m + 1) ** 2.0, (3, 1))
    changed = pipe.run(p.replace(response=ResponseCurve(g2, "gamma 2")))
    assert changed.stages_run[:2] == ("response", "ratios")
    assert np.array_equal(changed.lut, ResponseCurve(g2, "gamma 2").to_lut(m))


def test_a_switched_off_stage_reads_nothing_downstream(small_bracket) -> None:
    """With alignment off the registration is ``None`` whatever its parameters: moving the
    threshold re-runs it (it reads the threshold) but nothing after it, as before the graph."""
    pipe = Pipeline(small_bracket)
    p = PipelineParams(align="none")
    pipe.run(p)
    moved = pipe.run(p.replace(threshold=0.2))
    assert moved.stages_run == ("registration",)
    aligned = PipelineParams(align="shift")
    pipe.run(aligned)
    # aligned, what reads the registration runs again (the merge only if a frame is read
    # elsewhere or the times moved: it reads the registration through _Reading)
    assert "overlap_ratios" in pipe.run(aligned.replace(threshold=0.2)).stages_run


def test_internal_steps_are_not_reported(small_bracket) -> None:
    seen: list[str] = []
    res = Pipeline(small_bracket, progress=lambda s, f, m: seen.append(s)).run(
        PipelineParams(align="none")
    )
    internal = {n for n, st in GRAPH.stages.items() if st.internal}
    assert not internal & set(seen) and not internal & set(res.stages_run)
    assert not internal & set(res.timings)
    assert set(res.stages_run) <= set(STAGES)
