"""Cached runs equal fresh runs (issue 17, point 1, the must-show property test).

A hypothesis state machine changes the pipeline's parameters at random (one of 20 fields at a
time, from a few values each, so sequences come back to earlier settings and hit the cache) and
runs up to a random stage. After every run, the cached pipeline's result must equal a fresh
pipeline's on the same parameters, every array and number of every stage result (timings left
out), and an error must be the same error. It runs on a tiny simulated hand-held bracket, the
same kind of bracket without exposure times (where the response reads the exposure method), and
a tiny real one (frobisher, every 6th pixel; skipped without ../shared).
"""

from __future__ import annotations

import os
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, rule, run_state_machine_as_test

from hdrcore import stage_graph
from hdrcore.errors import HdrError
from hdrcore.io import Bracket, load_bracket
from hdrcore.pipeline import Pipeline, PipelineParams
from hdrcore.stage_graph import token
from hdrcore.synthetic import simulate_bracket, write_bracket

from ..conftest import shared_dir
from ._compare import differences

#: One field changed at a time, among a few values each (8-bit brackets).
CHANGES = (
    [("saturation", v) for v in (None, 200.0, 240.0)]
    + [("noise_floor", v) for v in (None, 3.0, 8.0)]
    + [("threshold", v) for v in (0.1, 0.2)]
    + [("align", v) for v in ("auto", "none", "shift", "similarity")]
    + [("local", v) for v in ("auto", "off")]
    + [("reference", v) for v in (None, 0)]
    + [("response", v) for v in ("auto", "srgb", "debevec-histogram")]
    + [("times", v) for v in ("estimated", "exif")]
    + [("exposure_method", v) for v in ("Cerman 2006 refined", "Cerman 2006")]
    + [("refine_ratios", v) for v in ("pixels", "histograms", "none")]
    + [("ratio_fallback_stops", v) for v in (0.0, 0.3)]
    + [("exclude_colour", v) for v in (None, (0, 0, 255))]
    + [("registration_max_pixels", v) for v in (None, 2000)]
    + [("working_space", v) for v in ("sRGB", "Rec.2020")]
    + [("deghost", v) for v in (False, True)]
    + [("colour_anchor", v) for v in (True, False)]
    + [("tonemap", v) for v in ("auto", "reinhard")]
    + [("tonemap_exposure", v) for v in (0.0, 1.0)]
    + [("preview_max_side", v) for v in (2048, 40)]
    + [
        ("workers", v)
        for v in (None, 1, 3)  # no key holds it: results must not depend on it
    ]
)

UNTIL = ("ratios", "registration", "overlap_ratios", "preview", "preview")

#: Steps that re-used at least one cached stage, over all the machines of this module: a cache
#: that never hits would pass the comparison for nothing.
REUSED = {"steps": 0, "reused": 0, "errors": 0, "recalled": 0}


@pytest.fixture(autouse=True)
def _count_recalls(monkeypatch: pytest.MonkeyPatch) -> None:
    """Counts the values a stage took again from its recent ones (``Stage.keep``), so a test
    can check the comparison covered them."""
    recall = stage_graph.StageCache.recall

    def counted(self, name, key):
        entry = recall(self, name, key)
        REUSED["recalled"] += entry is not None
        return entry

    monkeypatch.setattr(stage_graph.StageCache, "recall", counted)


def _outcome(pipe: Pipeline, params: PipelineParams, until: str):
    try:
        return pipe.run(params, until=until), None
    except HdrError as exc:  # the same error from the cached and the fresh pipeline
        return None, f"{type(exc).__name__}: {exc}"


class CachedEqualsFresh(RuleBasedStateMachine):
    bracket: Bracket
    fresh: dict  # fresh results by (until, parameters' token): one fresh run per setting

    def __init__(self) -> None:
        super().__init__()
        self.pipe = Pipeline(self.bracket)
        self.params = PipelineParams()

    @rule(change=st.sampled_from(CHANGES))
    def change(self, change) -> None:
        name, value = change
        self.params = replace(self.params, **{name: value})

    @rule(until=st.sampled_from(UNTIL))
    def run(self, until: str) -> None:
        cached, error = _outcome(self.pipe, self.params, until)
        key = (until, token(self.params))
        if key not in self.fresh:
            self.fresh[key] = _outcome(Pipeline(self.bracket), self.params, until)
        fresh, fresh_error = self.fresh[key]
        assert error == fresh_error, (self.params, error, fresh_error)
        if cached is None:
            REUSED["errors"] += 1
            return
        diff = differences(cached, fresh)
        assert not diff, (self.params, until, cached.stages_run, diff)
        REUSED["steps"] += 1
        REUSED["reused"] += int(len(cached.stages_run) < len(fresh.stages_run))


def _run_machine(bracket: Bracket, examples: int, steps: int) -> None:
    CachedEqualsFresh.bracket = bracket
    CachedEqualsFresh.fresh = {}
    run_state_machine_as_test(
        CachedEqualsFresh,
        settings=settings(
            max_examples=int(os.environ.get("HDRCORE_CACHE_EXAMPLES", examples)),
            stateful_step_count=steps,
            deadline=None,
            derandomize=True,
            database=None,
            suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
        ),
    )


@pytest.fixture(scope="module")
def tiny_handheld(tmp_path_factory: pytest.TempPathFactory) -> Bracket:
    sim = simulate_bracket(
        scene="window",
        shape=(48, 64),
        exposure_times=(1 / 16, 1 / 4, 1.0),
        bits=8,
        response="gamma",
        noise_sigma=1.0,
        max_shift=2,
        max_rotation_deg=0.3,
        seed=1,
    )
    out = tmp_path_factory.mktemp("tiny")
    write_bracket(out, sim, fmt="png")
    return load_bracket([out])


@pytest.fixture(scope="module")
def tiny_without_times(tmp_path_factory: pytest.TempPathFactory) -> Bracket:
    """PNG frames without any exposure time: the response reads the exposure method (the case
    of the issue's forgotten key)."""
    from PIL import Image

    sim = simulate_bracket(
        scene="window",
        shape=(48, 64),
        exposure_times=(1.0, 4.0, 16.0),
        bits=8,
        response="srgb",
        noise_sigma=1.0,
        seed=3,
    )
    out = tmp_path_factory.mktemp("no_times")
    written = write_bracket(out, sim, fmt="png")
    (out / "exposure_times.txt").unlink(missing_ok=True)
    for f in written.frames:  # saved again without their metadata
        Image.fromarray(np.asarray(Image.open(f))).save(f)
    bracket = load_bracket(list(written.frames))
    assert not any(e is not None for e in bracket.exif_exposures())
    return bracket


def _every(bracket: Bracket, step: int) -> Bracket:
    return replace(
        bracket,
        frames=tuple(
            replace(f, levels=np.ascontiguousarray(f.levels[::step, ::step]))
            for f in bracket.frames
        ),
    )


def test_cached_runs_equal_fresh_runs_simulated(tiny_handheld: Bracket) -> None:
    REUSED.update(steps=0, reused=0, errors=0, recalled=0)
    _run_machine(tiny_handheld, examples=6, steps=20)
    assert REUSED["steps"] >= 10 and REUSED["reused"] >= 3, REUSED


def test_cached_runs_equal_fresh_runs_without_times(tiny_without_times: Bracket) -> None:
    REUSED.update(steps=0, reused=0, errors=0, recalled=0)
    _run_machine(tiny_without_times, examples=4, steps=20)
    assert REUSED["steps"] >= 8 and REUSED["reused"] >= 3, REUSED


def test_cached_runs_equal_fresh_runs_real() -> None:
    bracket = _every(load_bracket([shared_dir("frobisher-colour-hdri")]), 6)  # 107 x 71
    REUSED.update(steps=0, reused=0, errors=0, recalled=0)
    _run_machine(bracket, examples=6, steps=20)
    assert REUSED["steps"] >= 10 and REUSED["reused"] >= 3, REUSED


def test_values_taken_again_equal_fresh_runs(tiny_handheld: Bracket) -> None:
    """Controls moved and moved back (and a reset): the stages that keep their recent values
    (``Stage.keep``: response, ratios, registration, ...) take them again, and every result
    still equals a fresh pipeline's."""
    pipe = Pipeline(tiny_handheld)
    base = PipelineParams()
    steps = [
        base,
        replace(base, align="similarity"),
        base,
        replace(base, threshold=0.2),
        replace(base, threshold=0.2, response="srgb"),
        replace(base, threshold=0.2),
        base,
        replace(base, align="similarity"),
    ]
    REUSED.update(recalled=0)
    for params in steps:
        cached = pipe.run(params)
        diff = differences(cached, Pipeline(tiny_handheld).run(params))
        assert not diff, (params, cached.stages_run, diff)
    assert REUSED["recalled"] >= 6, REUSED  # registration and more, at each step back


def test_the_comparison_sees_a_stale_cache(tiny_handheld: Bracket, monkeypatch) -> None:
    """The property can fail: a preview keyed without its parameters (a forgotten dependency
    forced in) comes back stale, and the comparison says where."""
    real_key = stage_graph._Run.key

    def forgetful(self, name):
        return ("preview",) if name == "preview" else real_key(self, name)

    monkeypatch.setattr(stage_graph._Run, "key", forgetful)
    pipe = Pipeline(tiny_handheld)
    p = PipelineParams(align="none", response="srgb")
    pipe.run(p)
    q = p.replace(preview_max_side=16)
    stale = pipe.run(q)
    assert "preview" not in stale.stages_run
    monkeypatch.undo()
    diff = differences(stale, Pipeline(tiny_handheld).run(q))
    assert any(d.startswith("result.preview") for d in diff), diff
