"""A slider step that registers the frames again first draws the full-resolution merge of the
new levels on the last motion (labelled), then the registration's own result."""

from __future__ import annotations

from pathlib import Path

import pytest

from hdrview import view as view_module
from hdrview.view import ClientView

from ._brackets import write_png_bracket


@pytest.fixture
def bracket_root(tmp_path: Path) -> Path:
    """The conftest's root with a smaller bracket (its ladder has both kinds of step)."""
    root = tmp_path / "root"
    write_png_bracket(root / "bracket", shape=(120, 180))
    return root


@pytest.fixture
def view(app: ClientView) -> ClientView:
    return app


def _errors(view: ClientView) -> list[str]:
    return [f"{t}: {b}" for level, t, b in view.notifications if level == "error"]


def _steps(view: ClientView) -> tuple[float, float, float] | None:
    """Saturation levels ``a``, ``b``, ``c`` one level apart: the step ``a -> b`` keeps the
    registration, ``b -> c`` registers again (read from the pipeline's quick runs while the
    view is idle)."""
    first = view.session.result
    assert first is not None and view.session.pipeline is not None
    top = round(first.saturation)

    def inputs(z: float):
        p = first.params.replace(saturation=z)
        return view.session.pipeline.run(p, until="ratios").registration_inputs

    levels = [float(top - d) for d in range(1, 40)]
    read = [inputs(z) for z in levels]
    for i in range(len(levels) - 2):
        if read[i] == read[i + 1] != read[i + 2]:
            return levels[i], levels[i + 1], levels[i + 2]
    return None


def test_a_step_that_registers_again_shows_the_interim_first(view: ClientView, monkeypatch):
    monkeypatch.setattr(view_module, "INTERIM_WORTH_SECONDS", 0.0)  # however quick it registers
    shown: list[tuple[str, str, object]] = []
    panel = view.result_panel
    original = panel.show_interim

    def spy(interim):
        original(interim)
        shown.append((panel.image.label, panel.summary.content, interim))

    monkeypatch.setattr(panel, "show_interim", spy)
    assert view.request_path("bracket")
    assert view.wait_idle(120)
    assert not _errors(view) and not shown
    steps = _steps(view)
    assert steps is not None  # the bracket's ladder has both kinds of step (the premise)
    start, kept, moved = steps
    view.set_control("saturation", start)
    assert view.wait_idle(120)
    shown.clear()

    before = view.session.result
    view.last_interim_seconds = None
    view.set_control("saturation", kept)
    assert view.wait_idle(120)
    assert not shown and view.last_interim_seconds is None
    assert view.session.result.registration is before.registration

    before = view.session.result
    view.set_control("saturation", moved)
    assert view.wait_idle(120)
    assert not _errors(view)
    assert len(shown) == 1 and shown[0][0] == "tonemapped (last motion)"
    assert "registered again" in shown[0][1]
    interim = shown[0][2]
    # the picture was this step's merge on the last registration
    assert interim.registration is before.registration and interim.saturation == moved
    assert view.last_interim_seconds is not None
    assert view.last_interim_seconds <= view.last_shown_seconds
    final = view.session.result
    assert final.saturation == moved and final.registration is not before.registration
    assert final.params.hold_registration is None
    assert panel.image.label == "tonemapped"  # the full result replaced the interim
    assert "last registration" not in panel.summary.content

    # back to the level before: its registration is cached, nothing to wait for
    view.set_control("saturation", kept)
    assert view.wait_idle(120)
    assert len(shown) == 1 and not _errors(view)


def test_a_failed_interim_leaves_the_full_run_alone(view: ClientView, monkeypatch, caplog):
    monkeypatch.setattr(view_module, "INTERIM_WORTH_SECONDS", 0.0)
    assert view.request_path("bracket")
    assert view.wait_idle(120)
    steps = _steps(view)
    assert steps is not None
    start, kept, moved = steps
    view.set_control("saturation", kept)
    assert view.wait_idle(120)

    def broken(*args, **kwargs):
        raise RuntimeError("interim broke")

    monkeypatch.setattr(view.session, "run_interim", broken)
    view.last_interim_seconds = None
    with caplog.at_level("WARNING", logger="hdrview.view"):
        view.set_control("saturation", moved)
        assert view.wait_idle(120)
    assert not _errors(view)
    assert view.last_interim_seconds is None
    assert view.session.result.saturation == moved
    assert view.result_panel.image.label == "tonemapped"
    assert any("interim picture failed" in r.getMessage() for r in caplog.records)


def test_no_interim_when_the_bracket_registers_quickly(view: ClientView, monkeypatch) -> None:
    """The interim delays the result by a re-merge: drawn only when the last registration took
    INTERIM_WORTH_SECONDS or longer."""
    drawn: list[object] = []
    monkeypatch.setattr(view.result_panel, "show_interim", drawn.append)
    assert view.request_path("bracket")
    assert view.wait_idle(120)
    took = view.registration_stage_seconds
    assert took is not None and 0.0 < took < view_module.INTERIM_WORTH_SECONDS
    steps = _steps(view)
    assert steps is not None
    start, kept, moved = steps
    view.set_control("saturation", kept)
    assert view.wait_idle(120)
    view.set_control("saturation", moved)
    assert view.wait_idle(120)
    assert not drawn and view.last_interim_seconds is None
    assert view.session.result.saturation == moved and not _errors(view)
    # a bracket that registers slowly: the next step that registers again draws it (a level
    # further down whose registration inputs are new: none cached)
    first = view.session.result
    seen = {first.registration_inputs}
    for z in (kept, start):
        p = first.params.replace(saturation=z)
        seen.add(view.session.pipeline.run(p, until="ratios").registration_inputs)
    further = None
    for d in range(1, 40):
        z = moved - d
        p = first.params.replace(saturation=z)
        if view.session.pipeline.run(p, until="ratios").registration_inputs not in seen:
            further = z
            break
    assert further is not None
    monkeypatch.setattr(view_module, "INTERIM_WORTH_SECONDS", took / 2)
    # a page whose registration came from the cache (the start-up run's) reads what computing
    # it took from the pipeline
    assert view.session.pipeline.stage_seconds("registration") is not None
    view.registration_stage_seconds = None
    view.set_control("saturation", further)
    assert view.wait_idle(120)
    assert len(drawn) == 1 and view.last_interim_seconds is not None
