"""The inspector draws a large bracket's preview from a binned draft first, then the full one."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import viser

from hdrcore.merge.fusion import METHOD as FUSION
from hdrview import view as view_module
from hdrview.app import InspectorApp
from hdrview.session import Controls, Session
from hdrview.view import ClientView

from ._brackets import write_png_bracket


@pytest.fixture
def large(tmp_path: Path) -> Iterator[ClientView]:
    """A view whose drafts are 96 px long: the 240x360 bracket counts as large."""
    root = tmp_path / "root"
    write_png_bracket(root / "bracket", shape=(240, 360))
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    inspector = InspectorApp(server, root=root, demo_dir=None)
    try:
        view = inspector.headless_view()
        view.draft_max_side = 96
        yield view
    finally:
        inspector.stop()
        server.stop()


def _errors(view: ClientView) -> list[str]:
    return [f"{t}: {b}" for level, t, b in view.notifications if level == "error"]


def test_draft_first_then_the_full_result(large: ClientView, monkeypatch) -> None:
    monkeypatch.setattr(view_module, "DRAFT_WORTH_SECONDS", 0.0)  # however quick the re-merge
    shown: list[tuple[str, tuple[int, ...]]] = []
    panel = large.result_panel
    original = panel.show_draft

    def spy(draft):
        original(draft)
        shown.append((panel.image.label, np.asarray(draft.preview.image).shape))

    monkeypatch.setattr(panel, "show_draft", spy)
    assert large.request_path("bracket")
    assert large.wait_idle(120)
    assert not _errors(large)
    # the load drew a draft binned 4x4 (360 / 96 -> 4), then the full result replaced it
    assert shown == [("tonemapped (draft)", (60, 90, 3))]
    assert large.last_draft_seconds is not None
    assert panel.image.label == "tonemapped"
    assert "Draft" not in panel.summary.content

    large.last_draft_seconds = None
    large.set_control("saturation", 240.0)
    assert large.wait_idle(120)
    assert len(shown) == 2 and large.last_draft_seconds is not None
    assert panel.image.label == "tonemapped"

    # the exposure re-runs the preview only: no draft
    large.last_draft_seconds = None
    large.set_control("tonemap_exposure", 1.0)
    assert large.wait_idle(120)
    assert len(shown) == 2 and large.last_draft_seconds is None
    assert not _errors(large)


def test_no_draft_when_the_full_re_merge_is_quick(large: ClientView, monkeypatch) -> None:
    """A draft delays the full result by its own cost: it is drawn only when the last full
    re-merge (registration drawn -> result drawn) took DRAFT_WORTH_SECONDS or longer."""
    assert large.request_path("bracket")
    assert large.wait_idle(120)
    assert large.last_draft_seconds is not None  # a new bracket: its re-merge not timed yet
    quick = large.last_merge_seconds
    assert quick is not None and 0.0 < quick < view_module.DRAFT_WORTH_SECONDS
    large.last_draft_seconds = None
    large.set_control("saturation", 240.0)
    assert large.wait_idle(120)
    assert large.last_draft_seconds is None and large.last_shown_seconds is not None
    assert large.result_panel.image.label == "tonemapped"
    # a slower re-merge than the threshold: the next step draws its draft first
    monkeypatch.setattr(view_module, "DRAFT_WORTH_SECONDS", 0.0)
    large.set_control("saturation", 235.0)
    assert large.wait_idle(120)
    assert large.last_draft_seconds is not None
    assert not _errors(large)


def test_draft_wanted(tmp_path: Path) -> None:
    s = Session()
    assert not s.draft_wanted(Controls())  # nothing loaded
    s.load(write_png_bracket(tmp_path / "b", shape=(96, 144)))
    assert not s.draft_wanted(Controls())  # 144 px: no larger than a draft
    assert s.draft_wanted(Controls(), max_side=64)  # no full run yet
    s.run(Controls())
    assert not s.draft_wanted(Controls(), max_side=64)  # the full run is current
    assert not s.draft_wanted(Controls(tonemap_exposure=1.0, tonemap="reinhard"), max_side=64)
    assert s.draft_wanted(Controls(saturation=240.0), max_side=64)
    # the draft takes the last full run's motion: what only the registration reads (threshold
    # t, local refinement) changes nothing in it, unless the kind of motion changes too
    assert s.pipeline is not None and s.pipeline.last_result is not None
    assert s.pipeline.last_result.registration is not None
    assert not s.draft_wanted(Controls(threshold=0.2), max_side=64)
    assert not s.draft_wanted(Controls(local="off"), max_side=64)
    assert s.draft_wanted(Controls(threshold=0.2, align="shift"), max_side=64)
    assert s.draft_wanted(Controls(threshold=0.2, noise_floor=9.0), max_side=64)


def test_no_draft_of_an_exposure_fusion_for_a_step_it_does_not_read(tmp_path: Path) -> None:
    """Locally tone-mapped frames are previewed by their exposure fusion, which reads the
    frames and their motion only: a saturation or noise-floor step leaves the picture as it is
    and draws no draft of it, nor does a threshold step (the draft would take the last full
    run's motion); a change of the motion model does."""
    s = Session()
    s.load(write_png_bracket(tmp_path / "b", shape=(96, 144)))
    s.run(Controls())
    assert s.pipeline is not None and s.pipeline.last_result is not None
    last = s.pipeline.last_result
    assert last.preview is not None and last.preview.method != FUSION
    assert s.draft_wanted(Controls(saturation=240.0), max_side=64)
    s.pipeline.last_result = dataclasses.replace(
        last, preview=dataclasses.replace(last.preview, method=FUSION)
    )
    assert not s.draft_wanted(Controls(saturation=240.0), max_side=64)
    assert not s.draft_wanted(Controls(noise_floor=9.0, deghost=True), max_side=64)
    # the draft would fuse the frames with the last full run's motion: the same picture
    assert not s.draft_wanted(Controls(threshold=0.2), max_side=64)
    assert s.draft_wanted(Controls(saturation=240.0, align="shift"), max_side=64)


def test_a_failed_draft_does_not_stop_the_full_run(large: ClientView, monkeypatch) -> None:
    def boom(self, *args, **kwargs):
        raise RuntimeError("draft broken")

    monkeypatch.setattr(Session, "run_draft", boom)
    assert large.request_path("bracket")
    assert large.wait_idle(120)
    assert not _errors(large)
    assert large.last_draft_seconds is None
    assert large.result_panel.image.label == "tonemapped"
    assert large.session.result is not None and large.session.result.preview is not None
