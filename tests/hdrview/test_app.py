"""The inspector's logic without a browser: loading, refusals, uploads, controls, exports."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import pytest

from hdrview.app import InspectorApp, build_parser, create_app

from ._brackets import write_png_bracket


def _errors(app: InspectorApp) -> list[str]:
    return [f"{t}: {b}" for level, t, b in app.notifications if level == "error"]


def test_load_folder_draws_frames_and_status(app: InspectorApp) -> None:
    assert app.request_path("bracket")
    assert app.wait_idle(60)
    b = app.session.bracket
    assert b is not None and len(b) == 3
    assert b.exposure_times == (1.0, 4.0, 16.0)  # from the folder's exposure_times.txt
    assert "frame0.png" in app.frames_panel.table.content
    assert "3 frames" in app.status.content
    # A gamma PNG bracket needs a response: its curves per channel and their residuals drawn.
    assert app.response_panel.curves.visible
    assert "Response **" in app.response_panel.summary.content
    sheet = app.frames_panel.sheet
    assert sheet.visible and sheet.image.shape[1] >= 3 * 280  # three thumbnails in a row
    assert app.pair_dropdown.options == (
        "pair 0: frames 0-1 (frame0.png, frame1.png)",
        "pair 1: frames 1-2 (frame1.png, frame2.png)",
    )
    assert app.saturation_slider.max == 255
    assert not _errors(app)


def test_deghost_checkbox_reaches_the_merge(app: InspectorApp) -> None:
    assert app.request_path("bracket")
    assert app.wait_idle(60)
    assert app.session.result.merge.deghosted is None
    app.set_control("deghost", True)
    assert app.wait_idle(60)
    merged = app.session.result.merge
    assert merged.deghosted is not None and merged.deghosted.shape == merged.shape
    assert app.session.params.deghost is True
    assert not _errors(app)


def test_white_balance_checkbox_reaches_the_merge(app: InspectorApp) -> None:
    assert app.request_path("bracket")
    assert app.wait_idle(60)
    assert app.white_balance_checkbox.value is True and app.session.params.white_balance
    app.set_control("white_balance", False)
    assert app.wait_idle(60)
    assert app.session.params.white_balance is False
    app.reset_controls()
    assert app.wait_idle(60)
    assert app.white_balance_checkbox.value is True and app.session.params.white_balance
    assert not _errors(app)


def test_path_outside_root_is_refused(app: InspectorApp, tmp_path: Path) -> None:
    outside = tmp_path / "outside"
    write_png_bracket(outside)
    assert not app.request_path(str(outside))
    assert not app.request_path("../outside")
    assert app.wait_idle(10)
    assert app.session.bracket is None
    errs = _errors(app)
    assert len(errs) == 2 and all("outside the folder" in e for e in errs)


def test_missing_and_unreadable_paths_notify_and_server_survives(
    app: InspectorApp, bracket_root: Path
) -> None:
    assert not app.request_path("nope")
    assert "not found" in _errors(app)[-1]
    (bracket_root / "junk").mkdir()
    (bracket_root / "junk" / "a.png").write_text("not a png")
    (bracket_root / "junk" / "b.png").write_text("not a png either")
    assert app.request_path("junk")  # exists: the failure comes from the loader, in the worker
    assert app.wait_idle(30)
    assert "not a recognised image" in _errors(app)[-1]
    assert app.session.bracket is None
    # A later change does not retry the failed load; a good load still works.
    app.set_control("saturation", 200.0)
    assert app.wait_idle(30)
    assert len([e for e in _errors(app) if "recognised" in e]) == 1
    assert app.request_path("bracket")
    assert app.wait_idle(60)
    assert app.session.bracket is not None


def test_upload_of_a_non_image_is_refused(app: InspectorApp) -> None:
    assert not app.handle_upload("notes.txt", b"these are not pixels")
    assert not app.handle_upload("fake.png", b"\x00\x01 also not pixels")
    errs = _errors(app)
    assert len(errs) == 2 and all("not an image" in e for e in errs)
    assert app.session.bracket is None


def test_upload_frames_one_by_one_then_zip(app: InspectorApp, bracket_root: Path) -> None:
    frames = sorted((bracket_root / "bracket").glob("*.png"))
    assert app.handle_upload(frames[0].name, frames[0].read_bytes())
    assert app.session.bracket is None  # one frame is not a bracket yet
    assert app.handle_upload(frames[1].name, frames[1].read_bytes())
    assert app.wait_idle(60)
    assert app.session.bracket is not None and len(app.session.bracket) == 2

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for p in sorted((bracket_root / "bracket").iterdir()):
            zf.write(p, f"nested/{p.name}")
    assert app.handle_upload("bracket.zip", buf.getvalue())
    assert app.wait_idle(60)
    assert len(app.session.bracket) == 3
    assert app.session.bracket.exposure_times == (1.0, 4.0, 16.0)
    # Nothing was refused; the two PNGs without exposure times may be reported by the pipeline.
    assert not [e for e in _errors(app) if "Upload refused" in e]


def test_zip_with_one_image_is_refused(app: InspectorApp, bracket_root: Path) -> None:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.write(bracket_root / "bracket" / "frame0.png", "frame0.png")
    assert not app.handle_upload("one.zip", buf.getvalue())
    assert "fewer than two images" in _errors(app)[-1]


def test_controls_update_state_and_page(app: InspectorApp) -> None:
    app.request_path("bracket")
    assert app.wait_idle(60)
    draws = app.draw_count
    app.set_control("saturation", 201.0)
    app.set_control("noise_floor", 5.0)
    app.set_control("threshold", 0.25)
    assert app.wait_idle(60)
    assert (app.controls.saturation, app.controls.noise_floor, app.controls.threshold) == (
        201.0,
        5.0,
        0.25,
    )
    assert "Z = 201" in app.status.content
    assert "noise floor = 5" in app.status.content
    assert "t = 0.25" in app.status.content
    assert app.draw_count > draws


def test_controls_follow_a_bracket_with_a_black_frame(
    app: InspectorApp, bracket_root: Path
) -> None:
    """A bracket with an unusable frame is run without it (a pipeline of the other frames):
    every later change reaches the result too, not only the first run (that inner pipeline
    once kept the first job's progress callback, which cancelled each later job)."""
    import numpy as np

    from hdrcore.io import write_png

    paths = write_png_bracket(bracket_root / "black", times=(1.0, 4.0, 16.0, 64.0))
    write_png(paths[0], np.zeros((128, 192, 3), np.uint8), force=True)
    app.request_path("black")
    assert app.wait_idle(120)
    result = app.session.result
    assert result is not None and [u.index for u in result.unused_frames] == [0]
    # the status line says so where it names the bracket (it said "4 frames" only)
    assert "4 frames" in app.status.content and "**3 used** (frame 0 (" in app.status.content
    assert "black: not used)" in app.status.content
    for t in (0.2, 0.3):
        app.set_control("threshold", t)
        assert app.wait_idle(120)
        assert not _errors(app)
        assert app._drawn_result is not None and app._drawn_result.params.threshold == t
        assert f"t = {t:g}" in app.status.content


def test_export_without_result_notifies(app: InspectorApp) -> None:
    app._guarded(app.export_png, None)
    assert "nothing to export" in _errors(app)[-1] or "not available" in _errors(app)[-1]


def test_missing_demo_notifies(app: InspectorApp) -> None:
    assert not app.request_demo()
    assert app.notifications[-1][1] == "No demo bracket"


def test_defaults_bind_localhost() -> None:
    args = build_parser().parse_args([])
    assert args.host == "127.0.0.1"
    assert args.root == "."


def test_create_app_binds_localhost_on_a_free_port_and_warms_up(tmp_path: Path) -> None:
    """The command line's bracket is decoded and processed once at start; the first page
    takes that session over (no second decode, its result at once)."""
    import time

    write_png_bracket(tmp_path / "b")
    app = create_app([str(tmp_path / "b")], port=0, root=str(tmp_path), verbose=False)
    try:
        assert app.server.get_host() == "127.0.0.1"
        assert app.server.get_port() > 0
        deadline = time.time() + 60
        while app.ready_seconds is None and time.time() < deadline:
            time.sleep(0.05)
        assert app.ready_seconds is not None and app.brackets.loads == 1
        view = app.headless_view()
        app._open_default(view)
        assert view.wait_idle(60)
        assert view.session.bracket is not None and view.session.result is not None
        assert app.brackets.loads == 1
        # A second page decodes nothing either: the bracket comes from the shared cache.
        other = app.headless_view()
        app._open_default(other)
        assert other.wait_idle(60)
        assert other.session is not view.session and app.brackets.loads == 1
    finally:
        app.stop()
        app.server.stop()


def test_the_first_page_finds_its_icons_read(
    bracket_root: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """What the start-up thread prepares covers every icon a page shows: once it has run,
    building a page reads nothing from viser's zip of icons (each read parses the zip's whole
    directory)."""
    import types

    import viser
    import viser._icons

    from hdrview.view import prepare_first_page

    viser._icons.svg_from_icon.cache_clear()
    prepare_first_page()

    def no_zip(*args: object, **kwargs: object) -> None:
        raise AssertionError(f"viser's icons read while building a page: {args}")

    monkeypatch.setattr(viser._icons, "zipfile", types.SimpleNamespace(ZipFile=no_zip))
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    inspector = InspectorApp(server, root=bracket_root, demo_dir=None)
    try:
        inspector.headless_view()
    finally:
        inspector.stop()
        server.stop()


@pytest.mark.parametrize("with_default", [True, False])
def test_the_start_up_thread_prepares_the_first_page_before_decoding(
    bracket_root: Path, monkeypatch: pytest.MonkeyPatch, with_default: bool
) -> None:
    """The start-up thread makes what the first page's build waits for first (the controls'
    registries), then decodes the default bracket (beside each other both ended later and the
    page was built behind them), then what the page shows after its frames (plotly, the
    buttons' icons); without a default bracket it still prepares the whole page."""
    import threading

    import viser

    import hdrview.app as app_module
    from hdrview.session import Session

    events: list[str] = []
    prepared = threading.Event()

    def prepare(part: str = "all") -> None:
        events.append(f"prepare {part}")
        if part != "controls":
            prepared.set()

    original_load = Session.load

    def load(self, *args: object, **kwargs: object) -> None:
        events.append("decode")
        original_load(self, *args, **kwargs)

    monkeypatch.setattr(app_module, "_prepare_first_page", prepare)
    monkeypatch.setattr(Session, "load", load)
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    demo = bracket_root / "bracket" if with_default else None
    inspector = InspectorApp(server, root=bracket_root, demo_dir=demo)
    try:
        inspector.warm_up()
        assert prepared.wait(30)
        if with_default:
            assert inspector._warm is not None
            inspector._warm[1].join(120)
            assert events[:3] == ["prepare controls", "decode", "prepare extras"]
        else:
            assert events == ["prepare all"]
    finally:
        inspector.stop()
        server.stop()


def test_the_start_up_run_waits_while_a_page_is_built(app: InspectorApp) -> None:
    """The start-up run's stage boundaries wait while a page's controls are built (and go on
    when it is built, or after the limit)."""
    import threading
    import time

    inspector = app.app
    done = threading.Event()
    with inspector._built:
        inspector._building += 1
    waiter = threading.Thread(
        target=lambda: (inspector._after_pages_built("merge", 0.5, ""), done.set())
    )
    waiter.start()
    assert not done.wait(0.3)  # a page is being built: the run waits
    with inspector._built:
        inspector._building -= 1
        inspector._built.notify_all()
    assert done.wait(5)  # built: it goes on at once
    waiter.join()
    with inspector._built:
        inspector._building += 1
    t0 = time.perf_counter()
    inspector._after_pages_built(limit=0.2)  # a page that never finishes holds it 0.2 s
    assert 0.15 < time.perf_counter() - t0 < 5
    with inspector._built:
        inspector._building -= 1
    t0 = time.perf_counter()
    inspector._after_pages_built()
    assert time.perf_counter() - t0 < 0.1  # nothing being built: no wait


def test_main_refuses_missing_root(capsys: pytest.CaptureFixture[str]) -> None:
    from hdrview.app import main

    assert main(["--root", "/nonexistent/dir"]) == 2
    assert "not a folder" in capsys.readouterr().err


def test_the_result_is_drawn_before_its_ghost_test(app: InspectorApp, monkeypatch) -> None:
    """The full-resolution result is drawn with its ghost test pending, then the status line,
    the Result tab and the verdicts again once it is done."""
    drawn: list[bool] = []
    original = type(app.result_panel).show

    def show(panel, bracket, result, view):
        if result is not None and result.merge is not None:
            drawn.append(result.merge.ghost_test_pending)
        return original(panel, bracket, result, view)

    monkeypatch.setattr(type(app.result_panel), "show", show)
    assert app.request_path("bracket")
    assert app.wait_idle(60)
    assert True in drawn and drawn[-1] is False  # pending first, complete last
    assert drawn.index(True) < len(drawn) - 1
    res = app.session.result
    assert res is not None and not res.merge.ghost_test_pending
    assert app._drawn_result is res
    assert app.last_shown_seconds is not None and app.last_job_seconds is not None
    assert app.last_shown_seconds <= app.last_job_seconds
    assert "ghost test is running" not in app.result_panel.summary.content


def test_the_result_is_drawn_before_its_colour_checks(app: InspectorApp, monkeypatch) -> None:
    """A non-linear bracket's colour checks (which change no pixel) are measured after the
    result is drawn: the Result tab says so, then the verdicts they give are drawn."""
    drawn: list[tuple[bool, bool, bool]] = []
    original = type(app.result_panel).show

    def show(panel, bracket, result, view):
        out = original(panel, bracket, result, view)
        if result is not None and result.merge is not None:
            check = result.colour["check"]
            drawn.append(
                (
                    result.colour_pending is not None,
                    check["before"] is None,
                    "being measured" in panel.summary.content,
                )
            )
        return out

    monkeypatch.setattr(type(app.result_panel), "show", show)
    assert app.request_path("bracket")
    assert app.wait_idle(60)
    assert drawn[0] == (True, True, True) and drawn[-1] == (False, False, False)
    res = app.session.result
    assert res is not None and res.colour_pending is None
    assert "colour-anchored" in {v.code for v in res.verdicts}
    assert "being measured" not in app.result_panel.summary.content


def test_a_newer_request_goes_before_the_checks(app: InspectorApp, monkeypatch) -> None:
    """A slider moved again while a result is drawn: that result's checks (which change no
    pixel) are not made, the newer request runs at once and its own result is finished."""
    from hdrview.session import Session

    assert app.request_path("bracket")
    assert app.wait_idle(60)
    finished: list[float] = []
    original_finish = Session.finish_checks

    def finish(self, result):
        finished.append(result.params.saturation)
        return original_finish(self, result)

    original_draw = type(app)._draw
    moved: list[bool] = []

    def draw(view, result, stages=None):
        original_draw(view, result, stages)
        if stages is None and result is not None and result.checks_pending and not moved:
            moved.append(True)
            view.set_control("saturation", 230.0)  # the next step, while this one is drawn

    monkeypatch.setattr(Session, "finish_checks", finish)
    monkeypatch.setattr(type(app), "_draw", draw)
    app.set_control("saturation", 240.0)
    assert app.wait_idle(60)
    assert moved and finished == [230.0]
    res = app.session.result
    assert res is not None and res.params.saturation == 230.0 and not res.checks_pending


def test_new_overlays_are_drawn_beside_the_merge(app: InspectorApp, monkeypatch) -> None:
    """A step that registers again: its overlays are drawn on a thread of their own while the
    full run goes on (the merge's compiled passes leave the GIL), and always before the result
    is drawn; a failing drawing there reaches the page as the job's error."""
    import threading
    import time

    from hdrview.session import Session

    assert app.request_path("bracket")
    assert app.wait_idle(60)
    events: list[tuple[str, str, float]] = []
    original_draw = type(app)._draw
    original_run = Session.run

    def draw(view, result, stages=None):
        name = "result" if stages is None else "+".join(stages)
        events.append((f"draw {name} start", threading.current_thread().name, time.perf_counter()))
        if stages == ("registration",):
            time.sleep(0.3)  # a slow drawing: the full run must not wait for it
            if fail:
                raise RuntimeError("overlay drawing failed")
        original_draw(view, result, stages)
        events.append((f"draw {name} end", threading.current_thread().name, time.perf_counter()))

    def run(self, params, **kw):
        full = kw.get("until") is None
        if full:
            events.append(("full run start", threading.current_thread().name, time.perf_counter()))
        out = original_run(self, params, **kw)
        if full:
            events.append(("full run end", threading.current_thread().name, time.perf_counter()))
        return out

    monkeypatch.setattr(type(app), "_draw", draw)
    monkeypatch.setattr(Session, "run", run)
    fail = False
    app.set_control("threshold", 0.2)  # the registration's own parameter: registered again
    assert app.wait_idle(60)
    at = {what: (thread, t) for what, thread, t in events}
    assert "draw registration start" in at and "draw result start" in at
    drawer, worker = at["draw registration start"][0], at["full run start"][0]
    assert drawer == "hdrview-draw-aside" and worker != drawer
    # the full run started before the overlays were drawn, and the result came after them
    assert at["full run start"][1] < at["draw registration end"][1]
    assert at["draw registration end"][1] <= at["draw result start"][1]
    assert not [n for n in app.notifications if n[0] == "error"]

    events.clear()
    fail = True
    app.set_control("threshold", 0.3)
    assert app.wait_idle(60)
    errors = [n for n in app.notifications if n[0] == "error"]
    assert errors and "overlay drawing failed" in " ".join(errors[-1][1:])
    assert not any(what == "draw result start" for what, _, _ in events)


def test_buttons_built_before_the_icons_are_read_get_them_when_the_job_ends(monkeypatch) -> None:
    """A page that connects while the start-up thread still reads viser's icons is built at
    once, its buttons without icons; they get their icons when its first job ends."""
    import threading
    from types import SimpleNamespace

    import viser

    from hdrview import view as view_module

    ready = threading.Event()
    monkeypatch.setattr(view_module, "ICONS_READ", ready)
    page = SimpleNamespace(client=object(), _pending_icons=[], _lock=threading.Lock())
    made: list[SimpleNamespace] = []

    def add(label: str, icon=None, **kw) -> SimpleNamespace:
        made.append(SimpleNamespace(label=label, icon=icon, kw=kw))
        return made[-1]

    ClientView = view_module.ClientView
    b = ClientView._iconed(page, add, "Load", viser.Icon.FOLDER_OPEN, hint="h")
    assert b.icon is None and b.kw == {"hint": "h"}
    assert page._pending_icons == [(b, viser.Icon.FOLDER_OPEN)]
    ClientView._apply_icons(page)
    assert b.icon == viser.Icon.FOLDER_OPEN and page._pending_icons == []
    ready.set()  # read: made with the icon at once
    c = ClientView._iconed(page, add, "Demo", viser.Icon.PHOTO)
    assert c.icon == viser.Icon.PHOTO and page._pending_icons == []
    headless = SimpleNamespace(client=None, _pending_icons=[], _lock=threading.Lock())
    ready.clear()  # a view without a page never waits
    d = ClientView._iconed(headless, add, "Reset", viser.Icon.REFRESH)
    assert d.icon == viser.Icon.REFRESH


def test_a_new_error_toast_replaces_the_last_one(app) -> None:
    """Errors stay on the page until closed: five failed loads showed five red toasts beside
    the panel. A new error removes the page's previous error toast (info toasts close
    themselves); every notification is still kept in ``notifications``."""

    class Toast:
        def __init__(self, shown: list) -> None:
            self.shown = shown
            shown.append(self)

        def remove(self) -> None:
            self.shown.remove(self)

    class Page:
        def __init__(self) -> None:
            self.shown: list[Toast] = []

        def add_notification(self, title, body, **kw) -> Toast:
            return Toast(self.shown)

    page = Page()
    for k in range(5):
        app.notify("Cannot load", f"path {k} missing", client=page, level="error")
    app.notify("Loaded", "frobisher: 3 frames", client=page)
    assert len(page.shown) == 2  # the last error and the info toast
    assert sum(1 for lv, _, _ in app.notifications if lv == "error") >= 5


def test_a_value_typed_beyond_a_slider_runs_at_the_end_of_its_range(app: InspectorApp) -> None:
    """-3 typed into the noise floor's box ran -3 (an error toast) and then 0, the box's own
    clamp: the end of the slider's range is what runs, and the box shows it."""
    assert app.request_path("bracket")
    assert app.wait_idle(120)
    app.noise_slider.value = -3.0  # as the page sends a typed value
    assert app.wait_idle(120)
    assert app.controls.noise_floor == app.noise_slider.min == app.noise_slider.value
    top = app.saturation_slider.max
    app.saturation_slider.value = top + 744.0
    assert app.wait_idle(120)
    assert app.controls.saturation == top == app.saturation_slider.value
    assert not _errors(app)


def test_the_status_line_marks_a_default_chosen_again_and_names_auto_s_choice(
    app: InspectorApp,
) -> None:
    """Choosing "auto" again in the operator's dropdown dropped "(default)" from the status
    line; the response reads "auto: <the method it chose>" as its dropdown reads "auto"."""
    assert app.request_path("bracket")
    assert app.wait_idle(120)
    app.set_control("tonemap", "auto")
    assert app.wait_idle(120)
    status = app.status.content
    assert "operator = auto (default)" in status
    method = app.session.result.response.method
    assert f"response = auto: {method} (default)" in status
