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
import tempfile
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
    ) -> None:
        self.server = server
        self.guard: ConnectionGuard | None = None  # set by create_app
        self.url = f"http://127.0.0.1:{server.get_port()}/"
        self.root = Path(root).resolve()
        self.demo_dir = None if demo_dir is None else Path(demo_dir)
        self.session = Session()
        self.controls = Controls()
        self.notifications: list[tuple[str, str, str]] = []  # (level, title, body), newest last
        self.draw_count = 0
        self.last_job_seconds: float | None = None
        self.last_ratios_seconds: float | None = None  # job start -> BTF plot and masks drawn
        self.last_registration_seconds: float | None = None  # job start -> overlays drawn
        self._lock = threading.RLock()
        self._syncing = False
        self._wanted: tuple[tuple[str, ...], str] | None = None  # (paths, label)
        self._loaded: tuple[tuple[str, ...], str] | None = None
        self._drawn_bracket: object | None = None
        self._pairs_bracket: Any = None
        self._drawn_result: Any = None  # the result every panel shows (last full draw)
        self._upload_dir = Path(tempfile.mkdtemp(prefix="hdrview-upload-"))
        self._upload_set = 0
        self.pair = 0
        self.progress_text = ""
        self.worker = LatestWorker(on_progress=self._on_progress, on_busy=self._on_busy)
        self._build_gui()
        server.on_client_connect(self._on_connect)

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
                hint="one image per upload (two or more make a bracket) or a .zip of a bracket",
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

    def request_paths(self, paths: Sequence[str | Path], label: str = "") -> int:
        """Load these paths (already checked) and bring the page up to date."""
        key = tuple(str(p) for p in paths)
        with self._lock:
            self._wanted = (key, label or ", ".join(Path(p).name for p in key))
        return self._submit("load")

    def request_path(self, text: str, client: viser.ClientHandle | None = None) -> bool:
        """The path field: check every path against ``--root`` and existence, then load."""
        try:
            parts = security.split_path_field(text)
            if not parts:
                raise InputError("type a file or folder path first")
            paths = [security.resolve_under_root(p, self.root) for p in parts]
            for p in paths:
                if not p.exists():
                    raise InputError("file or folder not found", path=p)
        except HdrError as exc:
            self.notify("Cannot load", str(exc), client=client, level="error")
            return False
        label = paths[0].name if len(paths) == 1 else f"{len(paths)} files"
        self.request_paths(paths, label)
        return True

    def request_demo(self, client: viser.ClientHandle | None = None) -> bool:
        if self.demo_dir is None or not self.demo_dir.is_dir():
            self.notify(
                "No demo bracket", f"the demo bracket is not installed at {self.demo_dir}",
                client=client, level="warning",
            )
            return False
        self.request_paths([self.demo_dir], "demo")
        return True

    def handle_upload(
        self, name: str, content: bytes, client: viser.ClientHandle | None = None
    ) -> bool:
        """An uploaded image joins the upload set (two or more load); a .zip loads at once."""
        try:
            kind = security.sniff_upload(name, content)
            if kind is None:
                raise InputError(
                    "uploaded file is not an image", path=security.safe_upload_name(name),
                    expected="PNG, JPEG, TIFF, a camera RAW file or a .zip of them",
                )
            if kind == "zip":
                self._upload_set += 1
                dest = self._upload_dir / f"set{self._upload_set}"
                dest.mkdir(parents=True)
                images = security.extract_zip_images(content, dest)
                if len(images) < 2:
                    raise InputError(
                        "the archive holds fewer than two images", path=name,
                        found=f"{len(images)} image(s)",
                    )
                self.request_paths([dest], security.safe_upload_name(name))
                return True
            dest = self._upload_dir / f"set{self._upload_set}"
            dest.mkdir(parents=True, exist_ok=True)
            (dest / security.safe_upload_name(name)).write_bytes(content)
            frames = sorted(p for p in dest.iterdir() if security.is_image_name(p.name))
            if len(frames) < 2:
                self.notify("Frame uploaded", f"{name}: upload one more frame to make a bracket",
                            client=client)
                return True
            self.request_paths(frames, f"{len(frames)} uploaded frames")
            return True
        except HdrError as exc:
            self.notify("Upload refused", str(exc), client=client, level="error")
            return False
        except Exception as exc:  # noqa: BLE001 -- any failure becomes a notification
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
        self.worker.stop()
        shutil.rmtree(self._upload_dir, ignore_errors=True)

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
            ctx.progress(0.02, f"loading {wanted[1]}")
            try:
                self.session.load(list(wanted[0]), source=wanted[1])
            except BaseException:
                with self._lock:
                    if self._wanted == wanted:  # do not retry a failed load on the next change
                        self._wanted = self._loaded
                raise
            self._loaded = wanted
            self._sync_widgets_to_bracket()
            self.notify("Loaded", f"{wanted[1]}: {len(self.session.bracket)} frames")
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
        data = result_panel.exr_bytes(self._require_result())
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


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="hdrview",
        description="Browser inspector for exposure brackets: ratios from histograms, masks, "
        "registration and the merged result, with live parameters.",
    )
    p.add_argument("files", nargs="*", metavar="FILE|DIR",
                   help="frames of one bracket or a folder (default: the demo bracket)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=int, default=8080, help="port (default 8080; 0 picks one)")
    p.add_argument("--root", default=".",
                   help="the page may only open paths under this folder (default: current folder)")
    p.add_argument("--allow-origin", action="append", default=[], metavar="URL",
                   help="also accept pages from this origin (e.g. https://proxy.example:443); "
                        "by default only the inspector's own address may use it")
    p.add_argument("--no-token", action="store_true",
                   help="do not require the access token printed at start (any local program "
                        "and any page of an allowed origin can then use the inspector)")
    p.add_argument("--debug", action="store_true", help="debug logging")
    return p


def create_app(
    files: Sequence[str] = (), *, host: str = "127.0.0.1", port: int = 8080, root: str = ".",
    verbose: bool = True, demo_dir: Path | None = DEMO_DIR, token: bool = True,
    allow_origins: Sequence[str] = (),
) -> InspectorApp:
    """Start the server and the app; load ``files`` or the demo bracket.

    Only the inspector's own address (and ``allow_origins``) may use it, and with ``token`` only
    a client that brings the access token (:mod:`hdrview.guard`); ``app.url`` is the address to
    open.
    """
    holder: list[viser.ViserServer] = []
    guard = ConnectionGuard(lambda: holder[0].get_port() if holder else port, bind_host=host,
                            allow_origins=allow_origins, token="" if token else None)
    with install_guard(guard):
        server = viser.ViserServer(host=host, port=port, label="hdrview", verbose=verbose)
    holder.append(server)
    app = InspectorApp(server, root=root, demo_dir=demo_dir)
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

        retain_freed_memory()
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
    try:
        app = create_app(args.files, host=args.host, port=args.port, root=str(root),
                         token=not args.no_token, allow_origins=args.allow_origin)
    except ValueError as exc:
        print(f"hdrview: {exc}", file=sys.stderr)
        return 2
    if args.host not in ("127.0.0.1", "localhost", "::1"):
        log.warning("listening on %s: anyone who can reach this address can read files under %s",
                    args.host, root.resolve())
    print(f"hdrview: open {app.url}", file=sys.stderr, flush=True)
    try:
        app.server.sleep_forever()
    except KeyboardInterrupt:
        pass
    finally:
        app.stop()
        app.server.stop()
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
