"""The ``hdrview`` browser inspector: open a bracket, see every intermediate result, tune it live.

Layout: a wide panel docked on the left holds the tabs that draw the pipeline's result objects
(frames, brightness transfer functions, masks, registration, result, diagnostics); the control
panel on the right holds loading, parameters, view choices and exports.

Every change of a control records the new value and asks the background worker to bring the page
up to date ("reconcile"): load the wanted bracket if it is not the loaded one, re-run the pipeline
(which re-runs only the stages the change touches) and redraw. Requests that arrive while a job
runs replace each other, so only the latest is served; viser's callbacks return at once and other
clients are never blocked. Any error reaches the user as a notification; the server keeps running.
"""

from __future__ import annotations

import argparse
import io
import json
import logging
import shutil
import sys
import threading
import time
import traceback
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import viser

from hdrcore.errors import HdrError, InputError

from . import security
from .guard import ConnectionGuard, install_guard
from .panels import btf as btf_panel
from .panels import diagnostics as diagnostics_panel
from .panels import masks as masks_panel
from .panels import registration as registration_panel
from .panels import result as result_panel
from .panels.frames import FramesPanel
from .session import Controls, Session, pipeline_available
from .uploads import (
    UploadLimits,
    UploadStore,
    install_upload_limits,
    make_work_dir,
    remove_stale_work_dirs,
)
from .worker import JobContext, LatestWorker

__all__ = ["InspectorApp", "main", "build_parser", "DEMO_DIR"]

log = logging.getLogger(__name__)

DEMO_DIR = Path(__file__).resolve().parents[1] / "assets" / "demo"
PANEL_WIDTH = 900


class InspectorApp:
    """All state of one inspector server; methods are safe to call from any thread."""

    def __init__(
        self,
        server: viser.ViserServer,
        *,
        root: str | Path = ".",
        demo_dir: str | Path | None = DEMO_DIR,
        files: Sequence[str | Path] = (),
        limits: UploadLimits | None = None,
    ) -> None:
        """``files``: paths the operator named on the command line (readable even outside
        ``root``); ``limits``: the upload limits (:class:`hdrview.uploads.UploadLimits`)."""
        self.server = server
        self.guard: ConnectionGuard | None = None  # set by create_app
        self.url = f"http://127.0.0.1:{server.get_port()}/"
        self.demo_dir = None if demo_dir is None else Path(demo_dir)
        # One private temporary folder: upload sets and export files; removed by stop().
        self.work_dir = make_work_dir()
        self.uploads = UploadStore(self.work_dir, limits)
        # Every path the inspector reads is checked by this one resolver.
        self.resolver = security.RootResolver(root, folders=[self.uploads.dir], files=files)
        if self.demo_dir is not None and self.demo_dir.is_dir():
            self.resolver.allow_folder(self.demo_dir)
        self.root = self.resolver.root
        self.session = Session()
        self.controls = Controls()
        self.notifications: list[tuple[str, str, str]] = []  # (level, title, body), newest last
        self.draw_count = 0
        self.last_job_seconds: float | None = None
        self.last_ratios_seconds: float | None = None  # job start -> BTF plot and masks drawn
        self.last_registration_seconds: float | None = None  # job start -> overlays drawn
        self._lock = threading.RLock()
        self._syncing = False
        # (frame files, times list or None, label): checked by the resolver
        self._wanted: tuple[tuple[str, ...], str | None, str] | None = None
        self._loaded: tuple[tuple[str, ...], str | None, str] | None = None
        self._drawn_bracket: object | None = None
        self._pairs_bracket: Any = None
        self._drawn_result: Any = None  # the result every panel shows (last full draw)
        self.pair = 0
        self.progress_text = ""
        self.worker = LatestWorker(on_progress=self._on_progress, on_busy=self._on_busy)
        self._build_gui()
        server.on_client_connect(self._on_connect)
        install_upload_limits(server, self.uploads.refuse_transfer, self._upload_refused)

    # -- GUI construction ------------------------------------------------------------------

    def _build_gui(self) -> None:
        gui = self.server.gui
        gui.configure_theme(show_share_button=False, control_width="large", show_logo=False)
        gui.set_panel_label("hdrview")

        with gui.add_folder("Bracket"):
            self.path_text = gui.add_text(
                "Path", "", hint=f"files or a folder under {self.root}; separate files with ;"
            )
            self.load_button = gui.add_button("Load", icon=viser.Icon.FOLDER_OPEN)
            self.upload_button = gui.add_upload_button(
                "Upload frame or .zip", icon=viser.Icon.UPLOAD,
                hint="one image per upload (two or more make a bracket) or a .zip of a bracket; "
                     + (self.uploads.limits.describe()),
            )
            self.new_set_button = gui.add_button(
                "New upload set", icon=viser.Icon.TRASH,
                hint="the next uploaded frame starts a new bracket",
            )
            self.demo_button = gui.add_button("Demo bracket", icon=viser.Icon.PHOTO)
            self.status = gui.add_markdown("No bracket loaded.")
            self.progress = gui.add_progress_bar(0.0, visible=False, animated=True)

        with gui.add_folder("Parameters"):
            self.saturation_slider = gui.add_slider(
                "Saturation Z", 0, 255, 1, 250,
                hint="levels above Z are saturated (eq. 4); in the frames' native levels",
            )
            self.noise_slider = gui.add_slider(
                "Noise floor", 0, 64, 1, 2, hint="levels below this are discarded (native levels)"
            )
            self.threshold_slider = gui.add_slider(
                "Threshold t", 0.0, 1.0, 0.01, 0.1,
                hint="normalisation threshold of eq. 7 (registration)",
            )
            self.alignment_dropdown = gui.add_dropdown(
                "Alignment", ("euclidean", "shift", "none"), initial_value="euclidean"
            )
            self.reference_dropdown = gui.add_dropdown("Reference", ("middle",))
            self.response_dropdown = gui.add_dropdown("Response", ("default",))
            self.deghost_checkbox = gui.add_checkbox(
                "Deghost", False,
                hint="fill each region the ghost layer marks from one frame (moving objects)",
            )

        with gui.add_folder("View"):
            self.pair_dropdown = gui.add_dropdown("Pair", ("—",))
            self.tonemap_dropdown = gui.add_dropdown("Operator", ("default",))
            self.exposure_slider = gui.add_slider("Exposure (EV)", -8.0, 8.0, 0.25, 0.0)
            self.layer_dropdown = gui.add_dropdown("Layer", result_panel.LAYERS)
            self.overlay_dropdown = gui.add_dropdown("Overlay", registration_panel.OVERLAYS)

        with gui.add_folder("Export"):
            self.export_exr_button = gui.add_button("HDR (.exr)", icon=viser.Icon.DOWNLOAD)
            self.export_png_button = gui.add_button("Preview (.png)", icon=viser.Icon.DOWNLOAD)
            self.export_bundle_button = gui.add_button(
                "Diagnostics bundle (.zip)", icon=viser.Icon.DOWNLOAD
            )

        self.panel = gui.add_panel()
        tabs = {}
        for name in ("Frames", "BTF", "Masks", "Registration", "Result", "Diagnostics"):
            tabs[name] = self.panel.add_tab(name)
        with tabs["Frames"]:
            self.frames_panel = FramesPanel(gui, tabs["Frames"])
        with tabs["BTF"]:
            self.btf_panel = btf_panel.BtfPanel(gui)
        with tabs["Masks"]:
            self.masks_panel = masks_panel.MasksPanel(gui)
        with tabs["Registration"]:
            self.registration_panel = registration_panel.RegistrationPanel(gui)
        with tabs["Result"]:
            self.result_panel = result_panel.ResultPanel(gui)
        with tabs["Diagnostics"]:
            self.diagnostics_panel = diagnostics_panel.DiagnosticsPanel(gui)
        self.panel.dock_left()
        self.panel.set_width(PANEL_WIDTH)
        self._wire()

    def _wire(self) -> None:
        self.load_button.on_click(lambda e: self.request_path(self.path_text.value, e.client))
        self.demo_button.on_click(lambda e: self.request_demo(e.client))
        self.new_set_button.on_click(lambda e: self.new_upload_set(e.client))
        self.upload_button.on_upload(
            lambda e: self.handle_upload(self.upload_button.value.name,
                                         self.upload_button.value.content, e.client)
        )

        def control(handle: Any, name: str, cast: Any) -> None:
            def cb(event: viser.GuiEvent) -> None:
                if self._syncing:
                    return
                self.set_control(name, cast(handle.value), client=event.client)

            handle.on_update(cb)

        control(self.saturation_slider, "saturation", float)
        control(self.noise_slider, "noise_floor", float)
        control(self.threshold_slider, "threshold", float)
        control(self.alignment_dropdown, "alignment", str)
        control(self.exposure_slider, "exposure", float)
        control(self.reference_dropdown, "reference", self._reference_value)
        control(self.response_dropdown, "response", self._option_value)
        control(self.tonemap_dropdown, "tonemap", self._option_value)
        control(self.deghost_checkbox, "deghost", bool)

        def view_changed(_: viser.GuiEvent) -> None:
            if not self._syncing:
                self.set_view(pair=self._pair_value(self.pair_dropdown.value))

        self.pair_dropdown.on_update(view_changed)
        self.layer_dropdown.on_update(view_changed)
        self.overlay_dropdown.on_update(view_changed)

        self.export_exr_button.on_click(lambda e: self._guarded(self.export_exr, e.client))
        self.export_png_button.on_click(lambda e: self._guarded(self.export_png, e.client))
        self.export_bundle_button.on_click(lambda e: self._guarded(self.export_bundle, e.client))

    @staticmethod
    def _option_value(value: str) -> str | None:
        return None if value == "default" else value

    @staticmethod
    def _reference_value(value: str) -> int | None:
        return None if value == "middle" else int(value.split()[-1])

    @staticmethod
    def _pair_value(value: str) -> int:
        try:
            return int(value.split(":")[0].split()[-1])
        except (ValueError, IndexError):
            return 0

    def _on_connect(self, client: viser.ClientHandle) -> None:
        # Recent errors (for example from loading before this page opened) are shown again.
        for level, title, body in self.notifications[-3:]:
            if level == "error":
                client.add_notification(title, body, color="red", auto_close_seconds=20)

    # -- notifications ---------------------------------------------------------------------

    def notify(
        self, title: str, body: str, *, client: viser.ClientHandle | None = None,
        level: str = "info",
    ) -> None:
        """Show a notification on ``client`` (or every page) and keep it in ``notifications``."""
        self.notifications.append((level, title, body))
        color = {"error": "red", "warning": "yellow", "info": "blue"}.get(level, "blue")
        stream = log.warning if level != "info" else log.info
        stream("%s: %s", title, body)
        clients = [client] if client is not None else list(self.server.get_clients().values())
        for c in clients:
            try:
                c.add_notification(
                    title, body, color=color,
                    auto_close_seconds=None if level == "error" else 8.0,
                )
            except Exception:  # a page that went away
                log.debug("notification to a closed client failed", exc_info=True)

    def _report_error(self, exc: BaseException, client: viser.ClientHandle | None = None) -> None:
        if isinstance(exc, HdrError):
            self.notify("Cannot do that", str(exc), client=client, level="error")
        else:
            traceback.print_exception(type(exc), exc, exc.__traceback__, file=sys.stderr)
            self.notify(
                "Internal error", f"{type(exc).__name__}: {exc} (details on the server's stderr)",
                client=client, level="error",
            )

    def _guarded(self, fn: Any, client: viser.ClientHandle | None) -> None:
        try:
            fn(client)
        except Exception as exc:  # noqa: BLE001 -- shown to the user
            self._report_error(exc, client)

    # -- requests (called from viser's callback threads or tests) ---------------------------

    def request_paths(self, paths: Sequence[str | Path], label: str = "",
                      client: viser.ClientHandle | None = None) -> bool:
        """Check ``paths`` (files or one folder) with the resolver, then load them."""
        try:
            inputs = self.resolver.bracket_inputs(list(paths))
        except HdrError as exc:
            self.notify("Cannot load", str(exc), client=client, level="error")
            return False
        key = tuple(str(p) for p in inputs.files)
        times = None if inputs.times is None else str(inputs.times)
        with self._lock:
            self._wanted = (key, times, label or ", ".join(Path(p).name for p in paths))
        self._submit("load")
        return True

    def request_path(self, text: str, client: viser.ClientHandle | None = None) -> bool:
        """The path field: files or a folder, each checked by the resolver, then loaded."""
        parts = security.split_path_field(text)
        if not parts:
            self.notify("Cannot load", "type a file or folder path first", client=client,
                        level="error")
            return False
        self.uploads.close_set()
        name = Path(parts[0]).name or parts[0]
        label = name if len(parts) == 1 else f"{len(parts)} files"
        return self.request_paths(parts, label, client)

    def request_demo(self, client: viser.ClientHandle | None = None) -> bool:
        if self.demo_dir is None or not self.demo_dir.is_dir():
            self.notify(
                "No demo bracket", f"the demo bracket is not installed at {self.demo_dir}",
                client=client, level="warning",
            )
            return False
        self.uploads.close_set()
        return self.request_paths([self.demo_dir], "demo", client)

    def new_upload_set(self, client: viser.ClientHandle | None = None) -> None:
        self.uploads.close_set()
        self.notify("New upload set", "the next uploaded frame starts a new bracket",
                    client=client)

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
                self.notify("Frame uploaded", f"{name}: upload one more frame to make a bracket",
                            client=client)
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

    def set_view(self, pair: int | None = None) -> int:
        """A view choice changed (pair, layer, overlay): redraw, nothing to compute."""
        if pair is not None:
            self.pair = pair
        return self._submit("view")

    def wait_idle(self, timeout: float = 60.0) -> bool:
        return self.worker.wait_idle(timeout)

    def stop(self) -> None:
        """Stop the worker and remove the temporary folder (uploads, exports)."""
        self.worker.stop()
        shutil.rmtree(self.work_dir, ignore_errors=True)

    # -- the job -----------------------------------------------------------------------------

    def _submit(self, label: str) -> int:
        return self.worker.submit(self._reconcile, on_error=self._report_error, label=label)

    def _on_progress(self, fraction: float, text: str) -> None:
        self.progress.value = round(100.0 * fraction, 1)
        if text:
            self.progress_text = text

    def _on_busy(self, busy: bool) -> None:
        self.progress.visible = busy
        if not busy:
            self.progress.value = 0.0

    def _reconcile(self, ctx: JobContext) -> None:
        t0 = time.perf_counter()
        with self._lock:
            wanted = self._wanted
        if wanted is not None and wanted != self._loaded:
            files, times, label = wanted
            ctx.progress(0.02, f"loading {label}")
            try:
                self.session.load(list(files), source=label, times=times)
            except BaseException:
                with self._lock:
                    if self._wanted == wanted:  # do not retry a failed load on the next change
                        self._wanted = self._loaded
                if any(Path(f).is_relative_to(self.uploads.dir) for f in files):
                    self.uploads.close_set()  # the next upload starts a new set
                raise
            self._loaded = wanted
            self._sync_widgets_to_bracket()
            self.notify("Loaded", f"{label}: {len(self.session.bracket)} frames")
        ctx.check()
        result = None
        if self.session.bracket is not None and pipeline_available():
            def progress(*args: Any, **kwargs: Any) -> None:
                # A newer request stops this run at the next stage boundary: the pipeline lets
                # Cancelled through (finished stages stay cached) and the worker drops the job.
                if ctx.superseded:
                    from hdrcore.pipeline import Cancelled

                    raise Cancelled(ctx.label)
                frac, text = _progress_args(args, kwargs)
                ctx.progress(0.05 + 0.9 * frac, text)

            # Ratios first (a re-fit from cached histograms), drawn at once so the BTF plot and
            # the masks follow a slider quickly; then the later stages unless superseded.
            quick = self.session.run(self.controls, progress=progress, until="ratios")
            ctx.check()
            self._draw(quick, stages=("btf", "masks"))
            self.last_ratios_seconds = time.perf_counter() - t0
            ctx.check()
            # Then the registration (a threshold-t change lands here first), then the rest.
            registered = self.session.run(self.controls, progress=progress,
                                          until="registration")
            ctx.check()
            if getattr(registered, "registration", None) is not None:
                self._draw(registered, stages=("registration",))
            self.last_registration_seconds = time.perf_counter() - t0
            ctx.check()
            result = self.session.run(self.controls, progress=progress)
        ctx.check()
        self._draw(result)
        self.last_job_seconds = time.perf_counter() - t0

    def _sync_widgets_to_bracket(self) -> None:
        """New bracket: slider ranges in its native levels, pair and reference choices."""
        b = self.session.bracket
        assert b is not None
        n = len(b)
        self._syncing = True
        try:
            self.saturation_slider.max = b.max_level
            self.noise_slider.max = max(16, b.max_level // 16)
            if pipeline_available():
                self._sync_widgets_to_params()
            else:
                self.saturation_slider.value = b.max_level
                self.noise_slider.value = 0
            self._set_pair_options(b)
            self.reference_dropdown.options = ("middle",) + tuple(f"frame {k}" for k in range(n))
            self.reference_dropdown.value = "middle"
        finally:
            self._syncing = False
        with self._lock:
            if pipeline_available():
                # Start from the pipeline's defaults; a control is set once its widget moves.
                self.controls = Controls()
            else:
                self.controls = Controls(
                    saturation=float(self.saturation_slider.value),
                    noise_floor=float(self.noise_slider.value),
                    threshold=float(self.threshold_slider.value),
                    alignment=self.alignment_dropdown.value,
                    exposure=float(self.exposure_slider.value),
                )

    def _set_pair_options(self, b: Any) -> None:
        names = [f.name for f in b.frames]
        self.pair_dropdown.options = tuple(
            f"pair {k}: frames {k}-{k + 1} ({names[k]}, {names[k + 1]})"
            for k in range(len(b) - 1)
        )
        self.pair_dropdown.value = self.pair_dropdown.options[0]
        self.pair = 0
        self._pairs_bracket = b

    def _sync_pairs(self, b: Any) -> None:
        """The pair dropdown lists the pairs of the frames the result used."""
        if self._pairs_bracket is not None and len(self._pairs_bracket) == len(b) and all(
                x is y for x, y in zip(self._pairs_bracket.frames, b.frames, strict=True)):
            self._pairs_bracket = b
            return
        self._syncing = True
        try:
            self._set_pair_options(b)
        finally:
            self._syncing = False

    def _sync_widgets_to_params(self) -> None:
        s = self.session
        for handle, control in (
            (self.saturation_slider, "saturation"),
            (self.noise_slider, "noise_floor"),
            (self.threshold_slider, "threshold"),
            (self.exposure_slider, "exposure"),
        ):
            v = s.param_value(control)
            if isinstance(v, (int, float)) and handle.min <= v <= handle.max:
                handle.value = v

    # -- drawing -----------------------------------------------------------------------------

    def _draw(self, result: Any, stages: tuple[str, ...] | None = None) -> None:
        bracket = self.session.bracket
        if bracket is not self._drawn_bracket:
            self.frames_panel.show(bracket)
            self._drawn_bracket = bracket
        # A black or saturated frame is left out by the pipeline: the stage results index the
        # frames it used (result.bracket); the pair choices follow them.
        used = getattr(result, "bracket", None) or bracket
        if used is not None and used is not self._pairs_bracket:
            self._sync_pairs(used)
        view = {
            "pair": self.pair,
            "layer": self.layer_dropdown.value,
            "overlay": self.overlay_dropdown.value,
        }
        self.status.content = self._status_markdown(result)
        panels = {"btf": self.btf_panel, "masks": self.masks_panel,
                  "registration": self.registration_panel, "result": self.result_panel}
        for name, panel in panels.items():
            if stages is None or name in stages:
                panel.show(used, result, view)
        if stages is None or "diagnostics" in stages:
            self.diagnostics_panel.show(bracket, result, view)
        if stages is None:
            self.draw_count += 1
            # No panel shows the previous result any more: the next merge may write into its
            # arrays (at 24 MP that saves faulting in 0.7 GB of fresh memory, 0.5-1 s here).
            previous, self._drawn_result = self._drawn_result, result
            pipeline = self.session.pipeline
            if (previous is not None and pipeline is not None and hasattr(pipeline, "release")
                    and getattr(previous, "merge", None) is not getattr(result, "merge", None)):
                pipeline.release(previous)

    def _status_markdown(self, result: Any) -> str:
        b = self.session.bracket
        if b is None:
            return "No bracket loaded."
        c = self.controls
        lines = [
            f"**{self.session.source}**: {len(b)} frames, {b.shape[1]}×{b.shape[0]}, "
            f"{b.bit_depth}-bit, max level {b.max_level}",
            f"Z = {_num(c.saturation)}, noise floor = {_num(c.noise_floor)}, "
            f"t = {_num(c.threshold)}, alignment = {c.alignment}, "
            f"exposure = {_num(c.exposure)} EV",
        ]
        if result is None and not pipeline_available():
            lines.append("_The processing pipeline (hdrcore.pipeline) is not installed yet._")
        timings = getattr(result, "timings", None)
        if isinstance(timings, dict) and timings:
            lines.append(
                "Stage times: " + ", ".join(f"{k} {1000 * float(v):.0f} ms"
                                            for k, v in timings.items())
            )
        return "\n\n".join(lines)

    # -- exports -----------------------------------------------------------------------------

    def _require_result(self) -> Any:
        if self.session.result is None:
            raise InputError("nothing to export yet: load a bracket and wait for the result")
        return self.session.result

    def export_exr(self, client: viser.ClientHandle | None) -> None:
        data = result_panel.exr_bytes(self._require_result(), work_dir=self.work_dir)
        self._send(client, f"{_stem(self.session.source)}.exr", data)

    def export_png(self, client: viser.ClientHandle | None) -> None:
        data = result_panel.preview_png_bytes(self._require_result())
        self._send(client, f"{_stem(self.session.source)}-preview.png", data)

    def export_bundle(self, client: viser.ClientHandle | None) -> None:
        self._send(client, f"{_stem(self.session.source)}-diagnostics.zip", self.bundle_bytes())

    def bundle_bytes(self) -> bytes:
        """The report JSON, the plots (plotly JSON) and the masks/overlays (PNG) in one zip."""
        result = self._require_result()
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
            zf.writestr("report.json", json.dumps(_to_report(result), indent=2, default=str))
            for name, data in diagnostics_panel.bundle_files(
                self.session.bracket, result, self.btf_panel, self.masks_panel,
                self.registration_panel, self.result_panel,
            ):
                zf.writestr(name, data)
        return buf.getvalue()

    def _send(self, client: viser.ClientHandle | None, name: str, data: bytes) -> None:
        if client is None:
            raise InputError("no page to send the file to")
        client.send_file_download(name, data, save_immediately=True)
        self.notify("Export", f"{name} ({len(data) / 1e6:.1f} MB) sent", client=client)


def _to_report(result: Any) -> dict:
    to_report = getattr(result, "to_report", None)
    return to_report() if callable(to_report) else {"result": repr(result)}


def _stem(source: str) -> str:
    return security.safe_upload_name(Path(source).stem or "bracket") or "bracket"


def _num(v: float | None) -> str:
    if v is None:
        return "default"
    return f"{v:g}"


def _progress_args(args: tuple, kwargs: dict) -> tuple[float, str]:
    """Fraction and text from a progress call of any of the shapes the pipeline may use."""
    frac = kwargs.get("fraction", kwargs.get("progress"))
    text = kwargs.get("stage", kwargs.get("text", kwargs.get("message", "")))
    for a in args:
        if hasattr(a, "fraction"):
            frac = a.fraction
            text = getattr(a, "stage", getattr(a, "message", text))
        elif isinstance(a, (int, float)) and not isinstance(a, bool) and frac is None:
            frac = float(a)
        elif isinstance(a, str) and not text:
            text = a
    return (float(frac) if frac is not None else 0.0), str(text or "")


# -- command line ------------------------------------------------------------------------------


LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1", "[::1]")


class StartError(Exception):
    """The inspector cannot start as asked (one line for the user, exit 2)."""


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="hdrview",
        description="Browser inspector for exposure brackets: ratios from histograms, masks, "
        "registration and the merged result, with live parameters.",
    )
    p.add_argument("files", nargs="*", metavar="FILE|DIR",
                   help="frames of one bracket or a folder (default: the demo bracket)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default 127.0.0.1: this machine only; any other "
                        "address needs --allow-remote)")
    p.add_argument("--allow-remote", action="store_true",
                   help="allow --host to be an address other machines can reach (prefer SSH "
                        "port forwarding, see the README)")
    p.add_argument("--port", type=int, default=8080,
                   help="port (default 8080; a busy port is an error; 0 picks a free one)")
    p.add_argument("--root", default=".",
                   help="the page may only open paths under this folder (default: current folder)")
    p.add_argument("--allow-origin", action="append", default=[], metavar="URL",
                   help="also accept pages from this origin (e.g. https://proxy.example:443); "
                        "by default only the inspector's own address may use it")
    p.add_argument("--no-token", action="store_true",
                   help="do not require the access token printed at start (any local program "
                        "and any page of an allowed origin can then use the inspector)")
    d = UploadLimits()
    p.add_argument("--max-upload-mb", type=float, default=d.file_bytes / 1e6, metavar="MB",
                   help=f"largest uploaded file (default {d.file_bytes / 1e6:g}; 0: no limit)")
    p.add_argument("--max-upload-total-mb", type=float, default=d.total_bytes / 1e6,
                   metavar="MB", help=f"largest upload set, a zip once extracted (default "
                                      f"{d.total_bytes / 1e6:g}; 0: no limit)")
    p.add_argument("--max-upload-pixels", type=float, default=float(d.frame_pixels),
                   metavar="N", help=f"largest uploaded frame in pixels, read from its header "
                                     f"before decoding (default {d.frame_pixels:.0e}; 0: none)")
    p.add_argument("--debug", action="store_true", help="debug logging")
    return p


def _port_free(host: str, port: int) -> bool:
    import socket

    family = socket.AF_INET6 if ":" in host.strip("[]") else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host.strip("[]"), port))
        except OSError:
            return False
    return True


def create_app(
    files: Sequence[str] = (), *, host: str = "127.0.0.1", port: int = 8080, root: str = ".",
    verbose: bool = True, demo_dir: Path | None = DEMO_DIR, token: bool = True,
    allow_origins: Sequence[str] = (), limits: UploadLimits | None = None,
) -> InspectorApp:
    """Start the server and the app; load ``files`` or the demo bracket.

    Only the inspector's own address (and ``allow_origins``) may use it, and with ``token`` only
    a client that brings the access token (:mod:`hdrview.guard`); ``app.url`` is the address to
    open. A busy ``port`` raises :class:`StartError` (viser itself would move to the next
    port without a word); ``port=0`` takes a free one.
    """
    if port and not _port_free(host, port):
        raise StartError(f"port {port} on {host} is in use (another hdrview?): choose another "
                         f"with --port N, or --port 0 for any free port")
    holder: list[viser.ViserServer] = []
    guard = ConnectionGuard(lambda: holder[0].get_port() if holder else port, bind_host=host,
                            allow_origins=allow_origins, token="" if token else None)
    with install_guard(guard):
        server = viser.ViserServer(host=host, port=port, label="hdrview", verbose=verbose)
    holder.append(server)
    if port and server.get_port() != port:  # taken between the check and the start
        server.stop()
        raise StartError(f"port {port} on {host} is in use: choose another with --port N, "
                         f"or --port 0 for any free port")
    app = InspectorApp(server, root=root, demo_dir=demo_dir, files=files, limits=limits)
    app.guard = guard
    app.url = guard.url("127.0.0.1" if host in ("0.0.0.0", "::", "") else host)
    if files:
        app.request_paths([Path(f) for f in files])
    else:
        app.request_demo()
    return app


def main(argv: Sequence[str] | None = None) -> int:
    if argv is None:  # run as the program: large buffers reuse freed memory (hdrcore._memory)
        from hdrcore._memory import retain_freed_memory
        from hdrcore.cli import catch_termination

        retain_freed_memory()
        catch_termination()  # SIGTERM/SIGHUP unwind like Ctrl-C: the temporary folder goes
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.debug else logging.INFO,
        format="hdrview: %(levelname)s: %(message)s",
    )
    root = Path(args.root)
    if not root.is_dir():
        print(f"hdrview: --root {root} is not a folder", file=sys.stderr)
        return 2
    for f in args.files:
        if not Path(f).exists():
            print(f"hdrview: {f}: file or folder not found", file=sys.stderr)
            return 2
    remote = args.host not in LOOPBACK_HOSTS
    if remote and not args.allow_remote:
        print(f"hdrview: --host {args.host} lets other machines reach the inspector and read "
              f"files under {root.resolve()}: add --allow-remote if you mean it (safer: SSH "
              f"port forwarding, see the README)", file=sys.stderr)
        return 2
    for opt in ("max_upload_mb", "max_upload_total_mb", "max_upload_pixels"):
        if not getattr(args, opt) >= 0:
            print(f"hdrview: --{opt.replace('_', '-')} must be 0 or more", file=sys.stderr)
            return 2
    limits = UploadLimits(file_bytes=int(args.max_upload_mb * 1e6),
                          total_bytes=int(args.max_upload_total_mb * 1e6),
                          frame_pixels=int(args.max_upload_pixels))
    for stale in remove_stale_work_dirs():
        log.info("removed %s, left by an inspector that was killed", stale)
    app = None
    try:
        try:
            app = create_app(args.files, host=args.host, port=args.port, root=str(root),
                             token=not args.no_token, allow_origins=args.allow_origin,
                             limits=limits)
        except (StartError, ValueError, HdrError) as exc:
            print(f"hdrview: {exc}", file=sys.stderr)
            return 2
        if remote:
            log.warning("listening on %s: anyone who can reach this address and has the token "
                        "can read files under %s", args.host, root.resolve())
        print(f"hdrview: open {app.url}", file=sys.stderr, flush=True)
        app.server.sleep_forever()
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM/SIGHUP (hdrcore.cli.Terminated)
        signum = getattr(exc, "signum", None)
        return 0 if signum is None else 128 + int(signum)
    finally:
        if app is not None:
            app.stop()
            app.server.stop()
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
