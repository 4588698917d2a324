"""One page of the inspector: its own bracket, parameters, pipeline, uploads and notifications.

viser gives every browser client its own GUI handles (``client.gui``); a :class:`ClientView` is
built on them when a page connects and closed when it leaves, so two pages (two tabs, two
people) never see each other's sliders, path text, toasts or uploads. What they share sits
underneath in the :class:`~hdrview.app.InspectorApp`: the path resolver, the upload limits and
the decoded brackets (:class:`~hdrview.cache.BracketCache`).

Layout: a wide panel docked on the left holds the tabs that draw the pipeline's result objects
(frames, brightness transfer functions, masks, registration, result, diagnostics); the control
panel on the right holds loading, parameters, view choices and exports.

Every change of a control records the new value and asks the page's background worker to bring
the page up to date ("reconcile"): load the wanted bracket if it is not the loaded one, re-run
the pipeline (which re-runs only the stages the change touches) and redraw. Requests that arrive
while a job runs replace each other, so only the latest is served; viser's callbacks return at
once. Any error reaches the user as a notification; the server keeps running.

The controls show the values the pipeline used: a control the user has not moved follows the
pipeline's own choice for the loaded bracket (the measured noise floor, the saturation level in
the frames' levels), marked "default"; "Reset to defaults" forgets every change.
"""

from __future__ import annotations

import io
import json
import logging
import math
import sys
import threading
import time
import traceback
import warnings
import zipfile
from collections.abc import Callable, Sequence
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Protocol, TypeVar

import plotly.graph_objects as go
import viser
from viser._messages import GuiSliderMark  # viser has no public setter of a slider's marks

from hdrcore.errors import HdrError, InputError
from hdrcore.io import Bracket
from hdrcore.status import Severity

from . import security
from .panels import btf as btf_panel
from .panels import diagnostics as diagnostics_panel
from .panels import masks as masks_panel
from .panels import registration as registration_panel
from .panels import response as response_panel
from .panels import result as result_panel
from .panels._draw import EMPTY_PLOT, esc
from .panels.frames import FramesPanel
from .session import Controls, Session, pipeline_available
from .uploads import UploadStore, install_upload_limits
from .worker import JobContext, LatestWorker

if TYPE_CHECKING:
    from viser._gui_handles import _GuiInputHandle  # inputs and progress bars

    from hdrcore.pipeline import PipelineResult

    from .app import InspectorApp

T = TypeVar("T")


class _Panel(Protocol):
    def show(
        self, bracket: Bracket | None, result: PipelineResult | None, view: dict[str, Any]
    ) -> None: ...


__all__ = ["ClientView", "PANEL_WIDTH", "DEFAULT_MARK"]

log = logging.getLogger(__name__)

PANEL_WIDTH = 900  # the strip between the panels holds the notifications
DEFAULT_MARK = " · default"
PLOTLY_DELAY = 1.0
"""Seconds between a page's frames drawn and plotly.js sent: long enough for the browser to
build the page and draw the frames before it spends about a second evaluating the script
(the first-page row of ``bench/bench_hdrview.py``). The panels without plots are drawn
meanwhile; only the plots wait."""
PLOTLY_GAP = 0.3
"""Seconds between a first page's status line (with the result) and plotly.js: messages that
arrive together are handled before the browser draws, so the script would hold up the line."""
WEBGL_TOAST = "webgl-software-rendering"  # viser's own notification id (BrowserWarning.tsx)
INTERIM_WORTH_SECONDS = 1.0
"""The interim picture (the new levels merged on the last registration) is drawn before a
re-registration only when the bracket's last registration took at least this long: it delays
the result by a re-merge. Measured with the rule off (`bench/bench_hdrview.py --steps all`):
the tripod frobisher registers in 0.2 s and its re-registered steps' result came 0.46-0.53 s
after the change instead of 0.36-0.43 s, the interim at 0.19 s; the real phone brackets
register in 8-11 s (the interim at 1.8-3.5 s)."""

DRAFT_WORTH_SECONDS = 2.0
"""A draft is drawn before the full re-merge only when the last full re-merge of the bracket
(its stages after the registration, to the result drawn) took at least this long. A draft
costs 0.5-0.7 s at 24 MP; under 2 s (the inspector's target for the full result) the full
result comes about as soon, and the draft would only delay it. Measured when the rule came in:
the 24 MP bench bracket's re-merge took 1.5-1.8 s after a saturation step (the draft drawn at
0.8-0.9 s, the full result at 2.6-2.8 s; without the draft 1.75-2.0 s); the real Xperia (full
result 5.9-7.2 s after a step) draws a draft on every step as before."""


def _term(word: str, paper: str) -> str:
    """A word a photographer knows, with the paper's term on hover."""
    return f"<abbr title='{paper}'>{word}</abbr>"


#: "What am I looking at", one short note per tab.
NOTES = {
    "Frames": "The frames as loaded, darkest first, with what the camera recorded. A capture "
    "warning means the bracket itself has a problem (settings changed, frames out "
    "of order).",
    "BTF": "How much brighter the brighter frame of a pair is. Each dot compares the same "
    "brightness level in the two frames' histograms; a straight line through the dots "
    "is the " + _term("exposure ratio", "k of eq. 4, fitted iteratively") + ". Dots "
    "far off the line are "
    + _term("ignored", "outliers beyond 3 standard deviations (3V)")
    + ". Below: the same comparison level by "
    "level, with the clipping level Z and the noise floor.",
    "Masks": "Which pixels of the chosen pair were used: well exposed in both frames (green), "
    "too dark or clipped in one of them. Only these count for the ratio and the "
    "alignment.",
    "Registration": "How the hand-held frames were lined up. The overlay shows the two frames "
    "in red and cyan: grey where they agree, coloured fringes where they do "
    "not. The "
    + _term("difference", "normalised difference of eq. 7")
    + " view shows what is left after alignment.",
    "Response": "How the camera turned light into levels (JPEG, PNG and TIFF frames): the curve "
    "the merge uses per channel, how well it explains the frames level by level, "
    "and, when chosen automatically, the candidates it beat.",
    "Result": "The merged HDR image shown on a normal screen. Zoom to 100 % to check edges and "
    "text; the other layers show which frame each pixel came from, what is clipped "
    "everywhere and where something moved.",
    "Diagnostics": "What went right and wrong, worst first, with one row per pair of frames.",
}


#: Every icon of the page's buttons. viser reads an icon's SVG from its zip of 4,285 icons the
#: first time it is used, parsing the zip's whole directory each time (30 ms an icon on this
#: machine, 80 ms beside the start-up decode): :func:`prepare_first_page` reads them at start.
BUTTON_ICONS: tuple[viser.IconName, ...] = (
    viser.Icon.FOLDER_OPEN,
    viser.Icon.UPLOAD,
    viser.Icon.TRASH,
    viser.Icon.PHOTO,
    viser.Icon.REFRESH,
    viser.Icon.DOWNLOAD,
)


ICONS_READ = threading.Event()
"""Set once :func:`prepare_page_extras` has read :data:`BUTTON_ICONS`: a page built before
that gets its buttons' icons when its first job ends (:meth:`ClientView._apply_icons`)."""


def prepare_first_page() -> None:
    """Make what building a page waits for the first time: :func:`prepare_page_controls`,
    then :func:`prepare_page_extras`."""
    prepare_page_controls()
    prepare_page_extras()


def prepare_page_controls() -> None:
    """The dropdowns' registries (:func:`_registry_names`: ``hdrcore.pipeline`` and its
    modules, 0.4-0.7 s of imports), which building a page needs. The inspector's start-up
    thread makes them first, while the browser evaluates the page's script
    (:meth:`hdrview.app.InspectorApp.warm_up`); without them the first page's controls were
    built in 0.4-1.3 s instead of 0.05 s, after the browser had connected."""
    _registry_names()


def prepare_page_extras() -> None:
    """What a page shows after its frames: plotly's figure classes (0.1 s; the panels' plots
    start empty without them, :data:`~hdrview.panels._draw.EMPTY_PLOT`) and the buttons'
    icons (:data:`BUTTON_ICONS`, 0.15 s). The start-up thread makes them after the decode: a
    page built before has its buttons without icons until its first job ends. Measured
    (``bench_hdrview.py``'s first page, 2026-12-07): see the README."""
    try:
        go.Figure().to_json()
        from viser._icons import svg_from_icon  # private: a later viser may move it

        for icon in BUTTON_ICONS:
            svg_from_icon(icon)
    except ImportError:
        pass
    finally:  # also after a failure: no page waits for them
        ICONS_READ.set()


@cache
def _registry_names() -> dict[str, tuple[str, ...]]:
    """The choices of each dropdown, from the library's registries (imported once: the
    inspector imports them on a thread of its own at start, while the browser loads the page,
    :meth:`hdrview.app.InspectorApp.warm_up`)."""
    from hdrcore.exposure import EXPOSURE_METHODS
    from hdrcore.pipeline import ALIGN_CHOICES, LOCAL_CHOICES
    from hdrcore.response import RESPONSE_METHODS, SPECIAL_RESPONSES
    from hdrcore.tonemap import TONEMAP_OPERATORS

    return {
        "align": tuple(ALIGN_CHOICES),
        "local": tuple(LOCAL_CHOICES),
        "response": ("auto", *SPECIAL_RESPONSES, *RESPONSE_METHODS),
        "tonemap": tuple(TONEMAP_OPERATORS),
        "exposure_method": tuple(EXPOSURE_METHODS),
        "times": ("estimated", "exif"),
    }


def _option(name: str, default: Any) -> str:
    return f"{name}{DEFAULT_MARK}" if name == default else name


def _unmark(text: str) -> str:
    return text.split(DEFAULT_MARK)[0]


#: Characters the number box beside a slider shows whole (viser's box is 3 rem wide: "464.56"
#: fits, the demo's 12-bit Z "3723.83" and a 16-bit frame's "63568.9" were cut off).
BOX_CHARACTERS = 6


def _box_decimals(x: float) -> int:
    """Decimals of a level shown beside its slider: two, fewer when the integer part leaves no
    room in :data:`BOX_CHARACTERS` (3723.83 -> one, 63568.95 -> none)."""
    whole = len(str(int(abs(x))))
    return max(0, min(2, BOX_CHARACTERS - whole - 1))


def _decimals(x: float) -> int:
    """Decimal places ``x`` needs to be shown exactly, up to 6 (12 -> 0, 247.35 -> 2)."""
    digits = 0
    while digits < 6 and float(x) != round(float(x), digits):
        digits += 1
    return digits


def _assign(handle: _GuiInputHandle[T], value: T) -> None:
    """``handle.value = value`` (viser defines the setter apart from its getter, which mypy
    reads as a read-only property)."""
    handle.value = value  # type: ignore[misc]  # viser's value setter, see above


_COLOURS: dict[Severity, Literal["red", "yellow", "blue"]] = {
    "error": "red",
    "warning": "yellow",
    "info": "blue",
}


class _Aside:
    """``fn()`` on a thread of its own, started at once; :meth:`join` waits for it and raises
    what ``fn`` raised (once; ``raise_error=False``: logged, the joining thread's own error
    goes first)."""

    def __init__(self, fn: Callable[[], None]) -> None:
        self._error: BaseException | None = None

        def run() -> None:
            try:
                fn()
            except BaseException as exc:  # noqa: BLE001 -- handed to the joining thread
                self._error = exc

        self._thread = threading.Thread(target=run, name="hdrview-draw-aside", daemon=True)
        self._thread.start()

    def join(self, raise_error: bool = True) -> None:
        self._thread.join()
        error, self._error = self._error, None
        if error is not None:
            if raise_error:
                raise error
            log.warning("a drawing beside the pipeline failed", exc_info=error)


def _provisional(what: str, run: Callable[[], PipelineResult]) -> PipelineResult | None:
    """``run()``, a picture shown before the full run's (a draft, the interim); a failure is
    logged and gives ``None``: it never stands in the full run's way (a newer request's
    ``Cancelled`` goes through)."""
    from hdrcore.pipeline import Cancelled

    try:
        return run()
    except Cancelled:
        raise
    except Exception:
        log.warning("the %s failed; the full run goes on", what, exc_info=True)
        return None


class ClientView:
    """All state of one page; methods are safe to call from any thread."""

    def __init__(
        self, app: InspectorApp, gui: viser.GuiApi, client: viser.ClientHandle | None = None
    ) -> None:
        self.app = app
        self.gui = gui
        self.client = client
        self.session = Session(workers=app.workers)
        self.controls = Controls()
        self.notifications: list[tuple[str, str, str]] = []  # (level, title, body), newest last
        # the error toast on the page (errors stay until closed): a new error replaces it, so
        # failed attempts do not pile up red toasts beside the panel
        self._error_toast: Any = None
        self.draw_count = 0
        self.last_job_seconds: float | None = None
        self.last_ratios_seconds: float | None = None  # job start -> BTF plot and masks drawn
        self.last_registration_seconds: float | None = None  # job start -> overlays drawn
        # the same spans in CPU seconds of the whole process (every thread): a shared machine's
        # load stretches wall times, not these
        self.last_ratios_cpu: float | None = None
        self.last_registration_cpu: float | None = None
        self.last_job_cpu: float | None = None
        self.ready_seconds: float | None = None  # view created -> first result drawn
        self.drafts = True  # a large bracket's preview drawn from a binned draft first
        self.draft_max_side: int | None = None  # the draft's longer side (None: hdrcore's)
        self.last_draft_seconds: float | None = None  # job start -> draft preview drawn
        self.last_draft_cpu: float | None = None
        # job start -> the interim picture drawn (full resolution, the last motion held)
        self.last_interim_seconds: float | None = None
        # the bracket's last registration stage, seconds (INTERIM_WORTH_SECONDS)
        self.registration_stage_seconds: float | None = None
        # job start -> the full-resolution result drawn (before its ghost test)
        self.last_shown_seconds: float | None = None
        self.last_shown_cpu: float | None = None
        # the last full re-merge of this bracket: registration drawn -> result drawn
        self.last_merge_seconds: float | None = None
        self._t_created = time.perf_counter()
        self._lock = threading.RLock()
        self._syncing = False
        # (frame files, times list or None, label): checked by the app's resolver
        self._wanted: tuple[tuple[str, ...], str | None, str] | None = None
        self._loaded: tuple[tuple[str, ...], str | None, str] | None = None
        self._drawn_bracket: Bracket | None = None
        self._pairs_bracket: Bracket | None = None
        self._drawn_result: PipelineResult | None = None  # what every panel shows (last draw)
        self._closed = False
        self.pair = 0
        self.progress_text = ""
        self.uploads = UploadStore(app.work_dir / f"page{app.next_page_number()}", app.limits)
        app.resolver.allow_folder(self.uploads.dir)
        self.worker = LatestWorker(on_progress=self._on_progress, on_busy=self._on_busy)
        # viser sends plotly.js (4.8 MB) with a page's first plot, and the browser evaluates it
        # before it handles anything queued after it: about 0.5-1 s of this machine's Chromium
        # between the panels arriving and the frames showing. The plots are empty until a
        # result exists, so the script is sent just before the first one is drawn instead.
        self._plotly_sent = False
        self._plotly_due: float | None = None  # when the frames' page may take the script
        gui._setup_plotly_js = True  # viser's once-per-page flag
        self._pending_icons: list[tuple[Any, viser.IconName]] = []
        self._build_gui()
        install_upload_limits(
            gui, app.server, self.upload_button, self.uploads.refuse_transfer, self._upload_refused
        )
        if client is not None:
            self._hide_webgl_toast()

    # -- GUI construction ------------------------------------------------------------------

    def _iconed(self, add: Callable[..., T], label: str, icon: viser.IconName, **kw: Any) -> T:
        """A button made by ``add`` with ``icon``, or without it until the icons are read (a
        page built before :func:`prepare_page_extras` is done: :meth:`_apply_icons`)."""
        ready = ICONS_READ.is_set() or self.client is None
        handle = add(label, icon=icon if ready else None, **kw)
        if not ready:
            self._pending_icons.append((handle, icon))
        return handle

    def _apply_icons(self) -> None:
        """The icons of buttons made before they were read."""
        with self._lock:
            pending, self._pending_icons = self._pending_icons, []
        for handle, icon in pending:
            handle.icon = icon

    def _build_gui(self) -> None:
        gui = self.gui
        names = _registry_names()
        defaults = self.app.defaults
        gui.configure_theme(show_share_button=False, control_width="large", show_logo=False)
        gui.set_panel_label("hdrview")

        with gui.add_folder("Bracket"):
            self.path_text = gui.add_text(
                "Path", "", hint=f"files or a folder under {self.app.root}; separate files with ;"
            )
            self.load_button = self._iconed(gui.add_button, "Load", viser.Icon.FOLDER_OPEN)
            self.upload_button = self._iconed(
                gui.add_upload_button,
                "Upload frame or .zip",
                viser.Icon.UPLOAD,
                hint="one image per upload (two or more make a bracket) or a .zip of a bracket; "
                + self.uploads.limits.describe(),
            )
            self.new_set_button = self._iconed(
                gui.add_button,
                "New upload set",
                viser.Icon.TRASH,
                hint="the next uploaded frame starts a new bracket",
            )
            self.demo_button = self._iconed(gui.add_button, "Demo bracket", viser.Icon.PHOTO)
            self.status = gui.add_markdown("No bracket loaded.")
            self.progress = gui.add_progress_bar(0.0, visible=False, animated=True)
            self.progress_md = gui.add_markdown("", visible=False)

        with gui.add_folder("Parameters"):
            self.saturation_slider = gui.add_slider(  # float values: Z is 0.97 x max level
                "Saturation Z",
                0.0,
                255.0,
                1.0,
                250.0,
                hint="levels at or above Z count as clipped (the paper's eq. 4); in the frames' "
                "own levels; follows the pipeline's choice until moved",
            )
            self.noise_slider = gui.add_slider(
                "Noise floor",
                0.0,
                64.0,
                0.1,
                2.0,
                hint="levels at or below this are noise and not used (native levels); the "
                "default is 3 sigma of the noise measured in the frames",
            )
            self.threshold_slider = gui.add_slider(
                "Threshold t",
                0.0,
                1.0,
                0.01,
                defaults.threshold,
                hint="registration: the brightness below which differences stop being "
                "normalised (the paper's eq. 7), as a fraction of Z",
            )
            self.alignment_dropdown = gui.add_dropdown(
                "Alignment",
                tuple(_option(n, defaults.align) for n in names["align"]),
                initial_value=_option(defaults.align, defaults.align),
                hint="motion model between hand-held frames",
            )
            self.local_dropdown = gui.add_dropdown(
                "Local refinement",
                tuple(_option(n, defaults.local) for n in names["local"]),
                initial_value=_option(defaults.local, defaults.local),
                hint="after the motion model, a smooth displacement field per frame for "
                "parallax (auto: the frames left misaligned; kept where it lowers the "
                "measured residual)",
            )
            self.reference_dropdown = gui.add_dropdown("Reference", ("middle",))
            self.response_dropdown = gui.add_dropdown(
                "Response",
                tuple(_option(n, defaults.response) for n in names["response"]),
                initial_value=_option(str(defaults.response), defaults.response),
                hint="camera response (how levels map to light) for JPEG/PNG/TIFF brackets",
            )
            self.times_dropdown = gui.add_dropdown(
                "Exposure times",
                tuple(_option(n, defaults.times) for n in names["times"]),
                initial_value=_option(defaults.times, defaults.times),
                hint="estimated: measured from the pictures (the paper's method); exif: as "
                "recorded by the camera",
            )
            self.exposure_method_dropdown = gui.add_dropdown(
                "Ratio method",
                tuple(_option(n, defaults.exposure_method) for n in names["exposure_method"]),
                initial_value=_option(defaults.exposure_method, defaults.exposure_method),
                hint="how the exposure ratio of a pair is measured from its histograms",
            )
            self.deghost_checkbox = gui.add_checkbox(
                "Deghost",
                defaults.deghost,
                hint="fill each region where something moved from one frame",
            )
            self.white_balance_checkbox = gui.add_checkbox(
                "White balance",
                defaults.white_balance,
                hint="JPEG/PNG/TIFF: divide out a frame's white balance where it differs from "
                "the reference frame's by more than 3 % (measured and reported either way)",
            )
            self.reset_button = self._iconed(
                gui.add_button, "Reset to defaults", viser.Icon.REFRESH
            )

        with gui.add_folder("View"):
            self.pair_dropdown = gui.add_dropdown("Pair", ("—",))
            self.tonemap_dropdown = gui.add_dropdown(
                "Operator",
                tuple(_option(n, defaults.tonemap) for n in names["tonemap"]),
                initial_value=_option(defaults.tonemap, defaults.tonemap),
                hint="how the HDR result is shown on a normal screen",
            )
            self.exposure_slider = gui.add_slider(
                "Exposure (EV)", -8.0, 8.0, 0.25, defaults.tonemap_exposure
            )
            self.layer_dropdown = gui.add_dropdown("Layer", result_panel.LAYERS)
            self.overlay_dropdown = gui.add_dropdown("Overlay", registration_panel.OVERLAYS)

        with gui.add_folder("Export"):
            self.crop_checkbox = gui.add_checkbox(
                "Crop to common area",
                False,
                hint="export only the largest rectangle every frame covers (hand-held "
                "brackets: the border strips have fewer exposures)",
            )
            self.export_exr_button = self._iconed(gui.add_button, "HDR (.exr)", viser.Icon.DOWNLOAD)
            self.export_png_button = self._iconed(
                gui.add_button, "Preview (.png)", viser.Icon.DOWNLOAD
            )
            self.export_bundle_button = self._iconed(
                gui.add_button, "Diagnostics bundle (.zip)", viser.Icon.DOWNLOAD
            )

        self.panel = gui.add_panel()

        def in_tab(name: str, build: Callable[[viser.GuiTabHandle], T]) -> T:
            tab = self.panel.add_tab(name)
            with tab:
                gui.add_markdown(f"_{NOTES[name]}_")
                return build(tab)

        self.frames_panel = in_tab("Frames", lambda tab: FramesPanel(gui, tab))
        self.btf_panel = in_tab("BTF", lambda tab: btf_panel.BtfPanel(gui))
        self.masks_panel = in_tab("Masks", lambda tab: masks_panel.MasksPanel(gui))
        self.registration_panel = in_tab(
            "Registration", lambda tab: registration_panel.RegistrationPanel(gui)
        )
        self.response_panel = in_tab("Response", lambda tab: response_panel.ResponsePanel(gui))
        self.result_panel = in_tab("Result", lambda tab: result_panel.ResultPanel(gui))
        self.diagnostics_panel = in_tab(
            "Diagnostics", lambda tab: diagnostics_panel.DiagnosticsPanel(gui)
        )
        self.panel.dock_left()
        self.panel.set_width(PANEL_WIDTH)
        self._wire()

    def _wire(self) -> None:
        def load(e: viser.GuiEvent) -> None:
            self.request_path(self.path_text.value, e.client)

        def demo(e: viser.GuiEvent) -> None:
            self.request_demo(e.client)

        def reset(e: viser.GuiEvent) -> None:
            self.reset_controls()

        def upload(e: viser.GuiEvent) -> None:
            self.handle_upload(
                self.upload_button.value.name, self.upload_button.value.content, e.client
            )

        self.load_button.on_click(load)
        self.demo_button.on_click(demo)
        self.new_set_button.on_click(lambda e: self.new_upload_set(e.client))
        self.reset_button.on_click(reset)
        self.upload_button.on_upload(upload)

        def control(handle: Any, name: str, cast: Any) -> None:
            def cb(event: viser.GuiEvent) -> None:
                if self._syncing:
                    return
                value = cast(handle.value)
                lo, hi = getattr(handle, "min", None), getattr(handle, "max", None)
                if lo is not None and hi is not None and not lo <= value <= hi:
                    # a value typed into the box beyond the slider's range (-3, 999 for an
                    # 8-bit Z): the box keeps it only until it loses focus, then shows the
                    # end of the range, which is what runs (it ran -3 with an error first)
                    value = cast(min(max(value, lo), hi))
                    self._syncing = True
                    try:
                        _assign(handle, value)
                    finally:
                        self._syncing = False
                self.set_control(name, value, client=event.client)

            handle.on_update(cb)

        control(self.saturation_slider, "saturation", float)
        control(self.noise_slider, "noise_floor", float)
        control(self.threshold_slider, "threshold", float)
        control(self.alignment_dropdown, "align", _unmark)
        control(self.local_dropdown, "local", _unmark)
        control(self.exposure_slider, "tonemap_exposure", float)
        control(self.reference_dropdown, "reference", self._reference_value)
        control(self.response_dropdown, "response", _unmark)
        control(self.times_dropdown, "times", _unmark)
        control(self.exposure_method_dropdown, "exposure_method", _unmark)
        control(self.tonemap_dropdown, "tonemap", _unmark)
        control(self.deghost_checkbox, "deghost", bool)
        control(self.white_balance_checkbox, "white_balance", bool)

        def view_changed(_: viser.GuiEvent) -> None:
            if not self._syncing:
                self.set_view(pair=self._pair_value(self.pair_dropdown.value))

        self.pair_dropdown.on_update(view_changed)
        self.layer_dropdown.on_update(view_changed)
        self.overlay_dropdown.on_update(view_changed)

        self.export_exr_button.on_click(lambda e: self._guarded(self.export_exr, e.client))
        self.export_png_button.on_click(lambda e: self._guarded(self.export_png, e.client))
        self.export_bundle_button.on_click(lambda e: self._guarded(self.export_bundle, e.client))

    def _send_plotly(self) -> None:
        """plotly.js to the page, once, before any plot has a figure (see ``__init__``).
        Under the view's lock, so a figure drawn by another thread is queued after it. A
        result drawn right after the frames waits until :data:`PLOTLY_DELAY` after them, so
        the browser shows the frames before it evaluates the script."""
        due = self._plotly_due
        if not self._plotly_sent and due is not None:
            wait = due - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
        with self._lock:
            if self._plotly_sent:
                return
            self.gui._setup_plotly_js = False
            # viser's own path: the first add_plotly of a page sends the script (the element
            # is an empty, hidden plot at the end of the page)
            self.gui.add_plotly(EMPTY_PLOT, visible=False)
            self._plotly_sent = True

    def _frames_drawn(self, delay: float = PLOTLY_DELAY) -> None:
        """The frames are drawn: plotly.js may go ``delay`` s from now, with the first whole
        result (:meth:`_send_plotly`), after its status line and pictures."""
        if self._plotly_sent or self.client is None or self._plotly_due is not None:
            return
        self._plotly_due = time.perf_counter() + delay

    def _hide_webgl_toast(self) -> None:
        """viser warns about software WebGL, which this page does not use (no 3-D scene)."""
        from viser import _messages

        def hide() -> None:
            for delay in (0.3, 1.0, 2.5, 5.0):
                time.sleep(delay)
                if self._closed or self.client is None:
                    return
                try:
                    self.client._websock_connection.queue_message(
                        _messages.RemoveNotificationMessage(uuid=WEBGL_TOAST)
                    )
                except Exception:  # noqa: BLE001 -- the page went away
                    return

        threading.Thread(target=hide, name="hdrview-hide-toast", daemon=True).start()

    @staticmethod
    def _reference_value(value: str) -> int | None:
        return None if value == "middle" else int(value.split()[-1])

    @staticmethod
    def _pair_value(value: str) -> int:
        try:
            return int(value.split(":")[0].split()[-1])
        except (ValueError, IndexError):
            return 0

    # -- notifications ---------------------------------------------------------------------

    def notify(
        self,
        title: str,
        body: str,
        *,
        client: viser.ClientHandle | None = None,
        level: Severity = "info",
    ) -> None:
        """Show a notification on this page and keep it in ``notifications``."""
        self.notifications.append((level, title, body))
        color = _COLOURS[level]
        stream = log.warning if level != "info" else log.info
        stream("%s: %s", title, body)
        target = client or self.client
        if target is None:
            return
        try:
            if level == "error" and self._error_toast is not None:
                old, self._error_toast = self._error_toast, None
                try:
                    with warnings.catch_warnings():  # (viser warns when it was closed already)
                        warnings.simplefilter("ignore")
                        old.remove()
                except Exception:  # noqa: BLE001 -- the page went away
                    log.debug("removing the last error toast failed", exc_info=True)
            toast = target.add_notification(
                title,
                body,
                color=color,
                auto_close_seconds=None if level == "error" else 8.0,
            )
            if level == "error":
                self._error_toast = toast
        except Exception:  # a page that went away
            log.debug("notification to a closed client failed", exc_info=True)

    def _report_error(self, exc: BaseException, client: viser.ClientHandle | None = None) -> None:
        if isinstance(exc, HdrError):
            self.notify("Cannot do that", str(exc), client=client, level="error")
        else:
            traceback.print_exception(type(exc), exc, exc.__traceback__, file=sys.stderr)
            self.notify(
                "Internal error",
                f"{type(exc).__name__}: {exc} (details on the server's stderr)",
                client=client,
                level="error",
            )

    def _guarded(
        self, fn: Callable[[viser.ClientHandle | None], object], client: viser.ClientHandle | None
    ) -> None:
        try:
            fn(client)
        except Exception as exc:  # noqa: BLE001 -- shown to the user
            self._report_error(exc, client)

    # -- requests (called from viser's callback threads or tests) ---------------------------

    def request_paths(
        self, paths: Sequence[str | Path], label: str = "", client: viser.ClientHandle | None = None
    ) -> bool:
        """Check ``paths`` (files or one folder) with the resolver, then load them."""
        try:
            inputs = self.app.resolver.bracket_inputs(list(paths))
        except HdrError as exc:
            self.notify("Cannot load", str(exc), client=client, level="error")
            return False
        key = tuple(str(p) for p in inputs.files)
        times = None if inputs.times is None else str(inputs.times)
        with self._lock:
            wanted = (key, times, label or ", ".join(Path(p).name for p in paths))
            if wanted != self._wanted:
                # The levels of another bracket: Z, the floor and the reference start from the
                # pipeline's choice again (the other choices are the user's and stay).
                self.controls = self.controls.replace(
                    saturation=None, noise_floor=None, reference=None
                )
            self._wanted = wanted
        self._submit("load")
        return True

    def request_path(self, text: str, client: viser.ClientHandle | None = None) -> bool:
        """The path field: files or a folder, each checked by the resolver, then loaded."""
        parts = security.split_path_field(text)
        if not parts:
            self.notify(
                "Cannot load", "type a file or folder path first", client=client, level="error"
            )
            return False
        self.uploads.close_set()
        name = Path(parts[0]).name or parts[0]
        label = name if len(parts) == 1 else f"{len(parts)} files"
        return self.request_paths(parts, label, client)

    def request_demo(self, client: viser.ClientHandle | None = None) -> bool:
        demo = self.app.demo_dir
        if demo is None or not demo.is_dir():
            self.notify(
                "No demo bracket",
                f"the demo bracket is not installed at {demo}",
                client=client,
                level="warning",
            )
            return False
        self.uploads.close_set()
        return self.request_paths([demo], "demo", client)

    def new_upload_set(self, client: viser.ClientHandle | None = None) -> None:
        self.uploads.close_set()
        self.notify("New upload set", "the next uploaded frame starts a new bracket", client=client)

    def _upload_refused(self, client: viser.ClientHandle | None, reason: str) -> None:
        self.uploads.close_set()
        self.notify("Upload refused", reason, client=client, level="error")

    def handle_upload(
        self, name: str, content: bytes, client: viser.ClientHandle | None = None
    ) -> bool:
        """An uploaded image joins the open upload set (two or more load); a .zip loads at once.

        Any refusal closes the set, so the next upload starts afresh (a bad file never keeps
        later uploads from loading)."""
        try:
            if security.sniff_upload(name, content) == "zip":
                dest = self.uploads.add_zip(name, content)
                return self.request_paths([dest], security.safe_upload_name(name), client)
            frames = self.uploads.add_frame(name, content)
            if len(frames) < 2:
                self.notify(
                    "Frame uploaded",
                    f"{name}: upload one more frame to make a bracket",
                    client=client,
                )
                return True
            return self.request_paths(frames, f"{len(frames)} uploaded frames", client)
        except HdrError as exc:
            self._upload_refused(client, str(exc))
            return False
        except Exception as exc:  # noqa: BLE001 -- any failure becomes a notification
            self.uploads.close_set()
            self._report_error(exc, client)
            return False

    def set_control(self, name: str, value: Any, client: viser.ClientHandle | None = None) -> int:
        """Record a parameter change and ask for a re-run (latest request wins)."""
        with self._lock:
            self.controls = self.controls.replace(**{name: value})
        return self._submit(f"control {name}")

    def reset_controls(self) -> int:
        """Forget every parameter change: the pipeline's defaults again, widgets included."""
        with self._lock:
            self.controls = Controls()
        self._syncing = True
        try:
            d = self.app.defaults
            _assign(self.threshold_slider, d.threshold)
            _assign(self.exposure_slider, d.tonemap_exposure)
            _assign(self.deghost_checkbox, d.deghost)
            _assign(self.white_balance_checkbox, d.white_balance)
            _assign(self.reference_dropdown, "middle")
            for handle, default in (
                (self.alignment_dropdown, d.align),
                (self.local_dropdown, d.local),
                (self.response_dropdown, d.response),
                (self.times_dropdown, d.times),
                (self.exposure_method_dropdown, d.exposure_method),
                (self.tonemap_dropdown, d.tonemap),
            ):
                _assign(handle, _option(str(default), default))
        finally:
            self._syncing = False
        return self._submit("reset")

    def set_view(self, pair: int | None = None) -> int:
        """A view choice changed (pair, layer, overlay): redraw, nothing to compute."""
        if pair is not None:
            self.pair = pair
        return self._submit("view")

    def wait_idle(self, timeout: float = 60.0) -> bool:
        return self.worker.wait_idle(timeout)

    def close(self) -> None:
        """The page left: stop its worker, drop its uploads and its GUI."""
        self._closed = True
        self.worker.stop()
        self.registration_panel.close()
        self.uploads.remove()

    # -- the job -----------------------------------------------------------------------------

    def _submit(self, label: str) -> int:
        return self.worker.submit(self._job, on_error=self._report_error, label=label)

    def _job(self, ctx: JobContext) -> None:
        """:meth:`_reconcile`, then the icons of buttons built before they were read (a page
        that connected early: :meth:`_iconed`)."""
        try:
            self._reconcile(ctx)
        finally:
            if self._pending_icons:
                self._apply_icons()

    def _on_progress(self, fraction: float, text: str) -> None:
        _assign(self.progress, round(100.0 * fraction, 1))
        if text:
            self.progress_text = text
            note = (
                " (first run of this installation: compiling kernels)"
                if (self.app.first_run and fraction < 0.9)
                else ""
            )
            self.progress_md.content = f"_{esc(text)}{note}_"

    def _on_busy(self, busy: bool) -> None:
        self.progress.visible = busy
        self.progress_md.visible = busy
        if not busy:
            _assign(self.progress, 0.0)
            self.progress_md.content = ""

    def _reconcile(self, ctx: JobContext) -> None:
        t0 = time.perf_counter()
        c0 = time.process_time()
        with self._lock:
            wanted = self._wanted
        if wanted is not None and wanted != self._loaded:
            files, times, label = wanted
            ctx.progress(0.02, f"loading {label}")
            try:
                if self.app.warm_pending(files, times):
                    # The start-up run is still going: show the frames (decoded already, or
                    # soon, in the shared cache) while its stages finish.
                    early = self.app.brackets.get(list(files), times)
                    self.frames_panel.show(early)
                    self._drawn_bracket = early
                    self._frames_drawn()
                    if self._pending_icons and ICONS_READ.is_set():
                        self._apply_icons()  # read meanwhile: at once, after the frames
                    self.status.content = f"**{esc(label)}**: {len(early)} frames; processing..."
                warm = self.app.take_warm(files, times)  # decoded and run at start
                if warm is not None:
                    self.session = warm
                else:
                    self.session.load(
                        list(files), source=label, times=times, loader=self.app.brackets.get
                    )
            except BaseException:
                with self._lock:
                    if self._wanted == wanted:  # do not retry a failed load on the next change
                        self._wanted = self._loaded
                if any(Path(f).is_relative_to(self.uploads.dir) for f in files):
                    self.uploads.close_set()  # the next upload starts a new set
                raise
            self._loaded = wanted
            self.last_merge_seconds = None  # another bracket: its re-merge not timed yet
            self.registration_stage_seconds = None
            self._sync_widgets_to_bracket()
            self.notify("Loaded", f"{label}: {len(self.session.bracket or ())} frames")
            if self._drawn_result is None or self._drawn_result.bracket is not self.session.bracket:
                # the status line names the new bracket at once (it named the previous one,
                # "Everything came from the cache", until the new result was drawn)
                self.status.content = (
                    f"**{esc(label)}**: {len(self.session.bracket or ())} frames; processing..."
                )
        ctx.check()
        result: PipelineResult | None = None
        if self.session.bracket is not None and pipeline_available():

            def progress(stage: str, fraction: float, message: str) -> None:
                # A newer request stops this run at the next stage boundary: the pipeline lets
                # Cancelled through (finished stages stay cached) and the worker drops the job.
                if ctx.superseded:
                    from hdrcore.pipeline import Cancelled

                    raise Cancelled(ctx.label)
                frac, text = _progress_words(stage, fraction, message)
                ctx.progress(0.05 + 0.9 * frac, text)

            # Ratios first (a re-fit from cached histograms), drawn at once so the BTF plot and
            # the masks follow a slider quickly; then the later stages unless superseded.
            quick = self.session.run(self.controls, progress=progress, until="ratios")
            ctx.check()
            self._sync_widgets_to_result(quick)
            self._draw(quick, stages=("btf", "masks"))
            self.last_ratios_seconds = time.perf_counter() - t0
            self.last_ratios_cpu = time.process_time() - c0
            ctx.check()
            if (
                self.drafts
                and (
                    self.last_merge_seconds is None
                    or self.last_merge_seconds >= DRAFT_WORTH_SECONDS
                )
                and self.session.draft_wanted(self.controls, self.draft_max_side)
            ):
                # A large bracket: the preview of a binned copy (hdrcore.draft) first, so the
                # page follows a slider in a fraction of the full re-merge's time.
                draft = _provisional(
                    "draft preview",
                    lambda: self.session.run_draft(
                        quick, progress=progress, max_side=self.draft_max_side
                    ),
                )
                ctx.check()
                if draft is not None:
                    self.result_panel.show_draft(draft)
                    self.last_draft_seconds = time.perf_counter() - t0
                    self.last_draft_cpu = time.process_time() - c0
            ctx.check()
            took = self.registration_stage_seconds
            if took is None and self.session.pipeline is not None:
                # the registration on the page came from the cache (the start-up run's): what
                # computing it took
                took = self.session.pipeline.stage_seconds("registration")
            held = (
                self.session.interim_params(quick)
                if (took or 0.0) >= INTERIM_WORTH_SECONDS
                else None
            )
            if held is not None:
                # The frames are to be registered again (a step across a rung of the
                # registration's level ladder): the full-resolution merge of the new levels
                # on the last motion first, labelled, then the registration and its result.
                interim = _provisional(
                    "interim picture",
                    lambda: self.session.run_interim(held, progress=progress),
                )
                ctx.check()
                if interim is not None:
                    self.result_panel.show_interim(interim)
                    self.last_interim_seconds = time.perf_counter() - t0
            ctx.check()
            registered = self.session.run(self.controls, progress=progress, until="registration")
            if "registration" in registered.stages_run:
                self.registration_stage_seconds = registered.timings.get("registration")
            ctx.check()
            drawn = self._drawn_result
            t_registered = time.perf_counter()

            def overlays_drawn() -> None:
                self.last_registration_seconds = time.perf_counter() - t0
                self.last_registration_cpu = time.process_time() - c0

            aside = None
            if getattr(registered, "registration", None) is not None and not (
                drawn is not None and drawn.registration is registered.registration
            ):
                # A new registration drawn at once (a kept one is on the page already, drawn
                # with the response the full result reads), beside the merge, whose compiled
                # passes leave the GIL to the drawing's numpy and encoding: 24 MP sRGB bench
                # bracket, re-registered slider steps, full result shown (median of 7, two
                # runs) 2.16 -> 2.04-2.08 s. Joined before the result is drawn and before the
                # job ends: no drawing of a superseded job lands after a newer one's.

                def draw_overlays() -> None:
                    self._draw(registered, stages=("registration",))
                    overlays_drawn()

                aside = _Aside(draw_overlays)
            else:
                overlays_drawn()
            try:
                ctx.check()
                # the full-resolution picture first; the region ghost test (no pixel changes
                # without deghost) and the colour checks after it is drawn
                result = self.session.run(self.controls, progress=progress, checks="later")
            except BaseException:
                if aside is not None:
                    aside.join(raise_error=False)
                raise
            if aside is not None:
                aside.join()
            self.app.first_run = False
        ctx.check()
        self._draw(result)
        self.last_shown_seconds = time.perf_counter() - t0
        if result is not None and result.timings.get("merge", 0.0) > 0.0:
            self.last_merge_seconds = time.perf_counter() - t_registered
        self.last_shown_cpu = time.process_time() - c0
        if result is not None and result.checks_pending:
            # a newer request (a slider dragged on) goes first: these measurements change no
            # pixel, and the next run finds them still pending in the cached merge when it
            # keeps it (1.0-1.2 s on the 24 MP sRGB bench bracket)
            ctx.check()
            ctx.progress(
                0.97,
                "ghost test: where the frames disagree"
                if result.merge is not None and result.merge.ghost_test_pending
                else "colour checks",
            )
            done = self.session.finish_checks(result)
            ctx.check()
            self._draw_checks(done)
            result = done
        self.last_job_seconds = time.perf_counter() - t0
        self.last_job_cpu = time.process_time() - c0
        if self.ready_seconds is None and result is not None:
            self.ready_seconds = time.perf_counter() - self._t_created

    def _sync_widgets_to_bracket(self) -> None:
        """New bracket: slider ranges in its native levels, pair and reference choices."""
        b = self.session.bracket
        assert b is not None
        n = len(b)
        self._syncing = True
        try:
            self.saturation_slider.max = b.max_level
            self.noise_slider.max = max(16, b.max_level // 16)
            self.noise_slider.step = 0.1 if b.max_level <= 255 else 1.0
            self._set_pair_options(b)
            self.reference_dropdown.options = ("middle",) + tuple(f"frame {k}" for k in range(n))
            _assign(self.reference_dropdown, "middle")
        finally:
            self._syncing = False

    def _sync_widgets_to_result(self, result: PipelineResult) -> None:
        """Controls the user has not moved show what the pipeline used, marked as default."""
        self._syncing = True
        try:
            for handle, moved, used in (
                (self.saturation_slider, self.controls.saturation, result.saturation),
                (self.noise_slider, self.controls.noise_floor, result.noise_floor),
            ):
                # (``handle.marks = ...`` set a plain attribute the page never saw: viser's
                # marks are its private prop ``_marks``, with no public setter)
                handle._marks = (GuiSliderMark(value=float(used), label="default"),)
                if used > handle.max:  # a noisy bracket's floor (memorial: 21.1 of 8 bits)
                    handle.max = float(math.ceil(2 * used))
                if moved is None and handle.min <= used:
                    # to 0.01 level, as far as the box's six characters go (the status line
                    # says the value exactly): 247.35, 3723.8, 63569
                    shown = round(float(used), _box_decimals(float(used)))
                    # the box beside the slider shows as many decimals as its precision
                    # (viser derives it from the step at creation: 247.35 read "247")
                    handle.precision = max(_decimals(handle.step), _decimals(shown))
                    _assign(handle, shown)
        finally:
            self._syncing = False

    def _set_pair_options(self, b: Bracket) -> None:
        names = [f.name for f in b.frames]
        self.pair_dropdown.options = tuple(
            f"pair {k}: frames {k}-{k + 1} ({names[k]}, {names[k + 1]})" for k in range(len(b) - 1)
        )
        _assign(self.pair_dropdown, self.pair_dropdown.options[0])
        self.pair = 0
        self._pairs_bracket = b

    def _sync_pairs(self, b: Bracket) -> None:
        """The pair dropdown lists the pairs of the frames the result used."""
        if (
            self._pairs_bracket is not None
            and len(self._pairs_bracket) == len(b)
            and all(x is y for x, y in zip(self._pairs_bracket.frames, b.frames, strict=True))
        ):
            self._pairs_bracket = b
            return
        self._syncing = True
        try:
            self._set_pair_options(b)
        finally:
            self._syncing = False

    # -- drawing -----------------------------------------------------------------------------

    def _view_choices(self) -> dict[str, Any]:
        """What the panels show of a result: the pair, the Result layer, the overlay."""
        return {
            "pair": self.pair,
            "layer": self.layer_dropdown.value,
            "overlay": self.overlay_dropdown.value,
        }

    def _draw_checks(self, result: PipelineResult) -> None:
        """The drawn result's ghost test and colour checks done: what reads them drawn again
        (the status line, the Result tab's layers and summary, the verdicts); the same arrays,
        nothing released."""
        bracket = self.session.bracket
        used = result.bracket
        view = self._view_choices()
        self.status.content = self.status_markdown(result)
        self.result_panel.show(used, result, view)
        self.diagnostics_panel.show(bracket, result, view)
        self._drawn_result = result

    def _draw(self, result: PipelineResult | None, stages: tuple[str, ...] | None = None) -> None:
        bracket = self.session.bracket
        if bracket is not self._drawn_bracket:
            self.frames_panel.show(bracket)
            self._drawn_bracket = bracket
            self._frames_drawn()
        # A black or saturated frame is left out by the pipeline: the stage results index the
        # frames it used (result.bracket); the pair choices follow them.
        used = result.bracket if result is not None else bracket
        if used is not None and used is not self._pairs_bracket:
            self._sync_pairs(used)
        view = self._view_choices()
        if stages is None:
            self.status.content = self.status_markdown(result)
            if not self._plotly_sent and self._plotly_due is not None:
                # and the status line drawn before the browser evaluates the script
                self._plotly_due = max(self._plotly_due, time.perf_counter() + PLOTLY_GAP)
        # the panels without plots first; plotly.js (sent once, a moment after the frames)
        # before the first plot has a figure
        wanted = (lambda name: True) if stages is None else (lambda name: name in stages)
        pictures: tuple[tuple[str, _Panel], ...] = (
            ("masks", self.masks_panel),
            ("result", self.result_panel),
        )
        for name, panel in pictures:
            if wanted(name):
                panel.show(used, result, view)
        if wanted("diagnostics"):
            self.diagnostics_panel.show(bracket, result, view)
        if not self._plotly_sent and stages is not None:
            # a first page's early stages: their plots are drawn with the whole result, after
            # the script (the page is not held up for them)
            return
        if result is not None:
            self._send_plotly()
        plots: tuple[tuple[str, _Panel], ...] = (
            ("btf", self.btf_panel),
            ("registration", self.registration_panel),
            ("response", self.response_panel),
        )
        for name, panel in plots:
            if wanted(name):
                panel.show(used, result, view)
        if stages is None:
            self.draw_count += 1
            # No panel shows the previous result any more: the next merge may write into its
            # arrays (at 24 MP that saves faulting in 0.7 GB of fresh memory, 0.5-1 s here).
            previous, self._drawn_result = self._drawn_result, result
            pipeline = self.session.pipeline
            if (
                previous is not None
                and pipeline is not None
                and result is not None
                and previous.merge is not result.merge
            ):
                pipeline.release(previous)

    def status_markdown(self, result: PipelineResult | None) -> str:
        """The loaded bracket and the values the pipeline used (the same the controls show)."""
        b = self.session.bracket
        if b is None:
            return "No bracket loaded."
        lines = [
            f"**{esc(str(self.session.source))}**: {len(b)} frames, {b.shape[1]}×{b.shape[0]}, "
            f"{b.bit_depth}-bit, max level {b.max_level}",
        ]
        if result is None:
            if not pipeline_available():
                lines.append("_The processing pipeline (hdrcore.pipeline) is not installed._")
            return "\n\n".join(lines)
        if result.unused_frames:
            # a frame left out (black, saturated) is said where the bracket is named, not only
            # on the Diagnostics tab
            left = ", ".join(
                f"frame {u.index} ({esc(b.frames[u.index].name)}) {u.status}"
                if u.index < len(b)
                else f"frame {u.index} {u.status}"
                for u in result.unused_frames
            )
            lines[0] += f"; **{len(result.bracket)} used** ({left}: not used)"
        p = result.params
        c = self.controls

        def mark(control: str) -> str:
            # the default chosen again from its dropdown is still the default
            value = getattr(c, control)
            default = getattr(self.app.defaults, control, None)
            return " (default)" if value is None or value == default else ""

        # what was asked for and, when "auto" chose, what it chose ("auto: joint-histogram"),
        # as the dropdown says "auto"
        method = result.response.method if result.response is not None else None
        response = (
            str(p.response)
            if method is None or method == str(p.response)
            else f"{p.response}: {method}"
        )
        lines.append(
            f"Z = {_num(result.saturation)}{mark('saturation')}, "
            f"noise floor = {_num(result.noise_floor)}{mark('noise_floor')}, "
            f"t = {_num(p.threshold)}{mark('threshold')}, alignment = {p.align}"
            f"{mark('align')}, local refinement = {p.local}"
            f"{mark('local')}, response = {response}{mark('response')}, "
            f"times = {esc(diagnostics_panel.times_words(result))}, "
            f"operator = {p.tonemap}{mark('tonemap')}, "
            f"exposure = {_num(p.tonemap_exposure)} EV"
        )
        timings = result.timings
        ran = set(result.stages_run)
        if ran:
            lines.append(
                "Computed: "
                + ", ".join(f"{k} {1000 * float(v):.0f} ms" for k, v in timings.items() if k in ran)
            )
        else:
            lines.append("Everything came from the cache.")
        return "\n\n".join(lines)

    # -- exports -----------------------------------------------------------------------------

    def _require_result(self) -> PipelineResult:
        if self.session.result is None:
            raise InputError("nothing to export yet: load a bracket and wait for the result")
        return self.session.result

    def export_exr(self, client: viser.ClientHandle | None) -> None:
        data = result_panel.exr_bytes(
            self._require_result(), work_dir=self.app.work_dir, crop=self.crop_checkbox.value
        )
        self._send(client, f"{self.export_stem()}.exr", data)

    def export_png(self, client: viser.ClientHandle | None) -> None:
        data = result_panel.preview_png_bytes(self._require_result(), crop=self.crop_checkbox.value)
        self._send(client, f"{self.export_stem()}-preview.png", data)

    def export_bundle(self, client: viser.ClientHandle | None) -> None:
        self._send(client, f"{self.export_stem()}-diagnostics.zip", self.bundle_bytes())

    def export_stem(self) -> str:
        """A file name for exports: the bracket's folder, or its first frame's name."""
        b = self.session.bracket
        if b is None:
            return "bracket"
        first = Path(b.frames[0].path)
        folder = first.parent.name
        stem = folder if folder and not folder.startswith("set") else first.stem
        if self.session.source == "demo":
            stem = "demo"
        return security.safe_upload_name(stem) or "bracket"

    def bundle_bytes(self) -> bytes:
        """The report JSON, the plots (plotly JSON) and the masks/overlays (PNG) in one zip."""
        result = self._require_result()
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
            zf.writestr("report.json", json.dumps(_to_report(result), indent=2, default=str))
            for name, data in diagnostics_panel.bundle_files(
                self.session.bracket,
                result,
                self.btf_panel,
                self.masks_panel,
                self.registration_panel,
                self.response_panel,
                self.result_panel,
            ):
                zf.writestr(name, data)
        return buf.getvalue()

    def _send(self, client: viser.ClientHandle | None, name: str, data: bytes) -> None:
        target = client or self.client
        if target is None:
            raise InputError("no page to send the file to")
        target.send_file_download(name, data, save_immediately=True)
        self.notify("Export", f"{name} ({len(data) / 1e6:.1f} MB) sent", client=target)


def _to_report(result: PipelineResult) -> dict[str, Any]:
    return result.to_report()


def _num(v: float | None) -> str:
    if v is None:
        return "default"
    return f"{float(v):.6g}"


_STAGE_TEXT = {
    "histograms": "histograms of every frame",
    "response": "camera response",
    "ratios": "exposure ratios (histograms)",
    "registration": "registration (hand-held motion)",
    "response_registered": "camera response on the registered frames",
    "overlap_histograms": "histograms of the common field of view",
    "overlap_ratios": "exposure ratios of the registered frames",
    "merge": "merging to a radiance map",
    "preview": "preview",
}


def _progress_words(stage: str, frac: float, message: str) -> tuple[float, str]:
    """Overall fraction and words for the pipeline's ``progress(stage, fraction, message)``."""
    from hdrcore.pipeline import STAGES

    if stage in STAGES:
        overall = (STAGES.index(stage) + max(0.0, min(1.0, frac))) / len(STAGES)
        words = _STAGE_TEXT.get(stage, stage)
        detail = message if message and not message.startswith(stage) else ""
        return overall, words + (f": {detail}" if detail else "")
    return max(0.0, min(1.0, frac)), message or stage
