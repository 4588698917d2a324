"""Registration panel: the chosen pair before and after alignment (red = bright frame, cyan = the
dark frame times the exposure ratio, grey where they agree), the eq. 7 normalised difference whose
mean square is the eq. 6 cost (Cerman & Hlavac 2006), the motion (dx, dy, angle) and the cost per
iteration. Everything drawn comes from :class:`hdrcore.registration.PairRegistration`.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Any

import numpy as np
import plotly.graph_objects as go
import viser

from hdrcore.errors import InputError
from hdrcore.io import Bracket, Frame, encode_png

from ._draw import EMPTY_PLOT, enlarge, fmt, pct, scalar_to_rgb, unit_to_display

if TYPE_CHECKING:  # the library's stages are imported on first use, not with the page
    from hdrcore.pipeline import PipelineResult
    from hdrcore.registration import BracketRegistration, PairRegistration
    from hdrcore.registration.residual import ResidualMotion

__all__ = [
    "RegistrationPanel",
    "OVERLAYS",
    "SHOWS",
    "cost_figure",
    "motion_summary",
    "overlay_crop",
]

OVERLAYS = ("red/cyan", "difference (eq. 7)")
SHOWS = ("after alignment", "before alignment", "blink before / after")
ZOOMS = ("fit", "100 %", "200 %", "400 %")
BOX = (880, 560)  # (width, height) of the overlay on screen
BLINK_SECONDS = 0.7
ARROW_GAIN = 10.0  # an arrow is this many times longer than the residual it shows


def _registration(result: PipelineResult) -> BracketRegistration:
    if result.registration is None:
        raise InputError("alignment is off: there is no registration to draw")
    return result.registration


def pair_residual(bracket: Bracket, result: PipelineResult, k: int) -> ResidualMotion:
    """The model-independent residual motion of pair ``k`` after alignment
    (:func:`hdrcore.registration.residual.residual_motion`): the registration's own if it
    measured one, else measured here from the frames (green channel)."""
    pair = _registration(result).pairs[k]
    if pair.residual is not None:
        return pair.residual
    from hdrcore.registration.residual import residual_motion

    dark_f, bright_f = bracket.frames[pair.dark], bracket.frames[pair.bright]
    lut = result.lut
    scale = float(dark_f.max_level)
    if lut is None:
        table = np.arange(int(dark_f.max_level) + 1, dtype=np.float32) / scale
    else:
        arr = np.asarray(lut, np.float32)
        table = arr[1] if arr.ndim == 2 else arr
    top = float(table[min(int(result.saturation), len(table) - 1)])
    floor = float(table[min(int(result.noise_floor), len(table) - 1)])
    return residual_motion(
        dark_f.levels[..., 1],
        bright_f.levels[..., 1],
        float(pair.ratio),
        np.asarray(pair.homography),
        saturation=top,
        noise_floor=floor,
        lut=table,
    )


def draw_arrows(
    image: np.ndarray, residual: ResidualMotion, step: float, x0: int = 0, y0: int = 0
) -> np.ndarray:
    """Arrows of the residual field on a display image (``step`` image pixels per display pixel,
    ``(x0, y0)`` the image pixel at its corner): green under 0.3 px, yellow under 1 px, red
    above; grey crosses where no tile could be measured."""
    from PIL import Image, ImageDraw

    im = Image.fromarray(image)
    d = ImageDraw.Draw(im)
    mags = np.hypot(residual.shifts[:, 0], residual.shifts[:, 1])
    for (cx, cy), (dx, dy), ok, m in zip(
        residual.centres, residual.shifts, residual.valid, mags, strict=True
    ):
        px, py = (cx - x0) / step, (cy - y0) / step
        if not (0 <= px < image.shape[1] and 0 <= py < image.shape[0]):
            continue
        if not ok:
            d.line([(px - 3, py - 3), (px + 3, py + 3)], fill=(150, 150, 150))
            d.line([(px - 3, py + 3), (px + 3, py - 3)], fill=(150, 150, 150))
            continue
        colour = (40, 200, 40) if m < 0.3 else (240, 200, 0) if m < 1.0 else (230, 30, 30)
        ex, ey = px + dx * ARROW_GAIN, py + dy * ARROW_GAIN
        d.line([(px, py), (ex, ey)], fill=colour, width=2)
        d.ellipse([px - 2, py - 2, px + 2, py + 2], fill=colour)
    return np.asarray(im)


def _linear_green(
    frame: Frame, lut: np.ndarray | None, rows: slice = slice(None), cols: slice = slice(None)
) -> np.ndarray:
    """The frame's green channel as linear values in [0, 1] (RAW: levels / max level), of the
    ``rows`` and ``cols`` asked for only (a crop never linearises a whole 24 MP frame)."""
    g = frame.levels[rows, cols, 1] if frame.levels.ndim == 3 else frame.levels[rows, cols]
    if lut is None:
        return g.astype(np.float32) / float(frame.max_level)
    table = np.asarray(lut)[1 if np.asarray(lut).ndim == 2 else 0]
    return np.asarray(table, np.float32)[g]


def local_fields(reg: BracketRegistration) -> tuple[Any, ...]:
    """The registration's local-refinement fields per frame (all None without any)."""
    local = reg.local
    return tuple(local.fields) if local is not None else (None,) * (len(reg.pairs) + 1)


def _sample_green(frame: Frame, lut: np.ndarray | None, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The frame's linear green read bilinearly at ``(x, y)`` (0 outside), as
    ``map_coordinates(order=1, mode="constant")`` reads the linearised plane: the four
    neighbours of each point are linearised, not the frame (a fitted overlay of a 24 MP frame
    reads 0.7 M points)."""
    levels = frame.levels[..., 1] if frame.levels.ndim == 3 else frame.levels
    h, w = levels.shape
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    inside = (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
    x0 = np.clip(np.floor(x), 0, max(w - 2, 0)).astype(np.intp)
    y0 = np.clip(np.floor(y), 0, max(h - 2, 0)).astype(np.intp)
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    fx = np.clip(x - x0, 0.0, 1.0).astype(np.float32)
    fy = np.clip(y - y0, 0.0, 1.0).astype(np.float32)
    if lut is None:
        table = np.arange(frame.max_level + 1, dtype=np.float32) / float(frame.max_level)
    else:
        table = np.asarray(np.asarray(lut)[1 if np.asarray(lut).ndim == 2 else 0], np.float32)
    top = table[levels[y0, x0]] * (1 - fx) + table[levels[y0, x1]] * fx
    bottom = table[levels[y1, x0]] * (1 - fx) + table[levels[y1, x1]] * fx
    return np.where(inside, top * (1 - fy) + bottom * fy, 0.0).astype(np.float32)


def local_summary(reg: BracketRegistration, k: int) -> str:
    """One line on the local refinement of pair ``k``'s frames (empty when none ran)."""
    local = reg.local
    if local is None:
        return ""
    pair = reg.pairs[k]
    for fr in local.frames:
        if {fr.frame, fr.against} == {pair.dark, pair.bright}:
            state = "kept" if fr.kept else "not kept"
            return (
                f"Local refinement of frame {fr.frame} against {fr.against} ({state}): {fr.message}"
            )
    return ""


def overlay_crop(
    bracket: Bracket,
    result: PipelineResult,
    k: int,
    *,
    aligned: bool,
    zoom: float = 1.0,
    cx: float = 0.5,
    cy: float = 0.5,
    box: tuple[int, int] = BOX,
) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """Red/cyan overlay of pair ``k`` at full resolution: red the bright frame, cyan the dark
    frame times the ratio, grey where they agree; a crop of ``box / zoom`` dark-frame pixels
    centred at ``(cx, cy)``, the bright frame resampled through the pair's homography
    (``aligned``) or as shot; with local refinement both frames are read through their motion
    and field on the reference grid, as the merge reads them. Returns the image (pixels
    repeated for zoom > 1) and the crop."""
    reg = _registration(result)
    pair = reg.pairs[k]
    dark_f, bright_f = bracket.frames[pair.dark], bracket.frames[pair.bright]
    lut = result.lut
    h, w = dark_f.levels.shape[:2]
    if zoom <= 0:  # fit: the whole frame, every n-th pixel
        step = int(np.ceil(max(w / box[0], h / box[1])))
        x0, y0, cw, ch = 0, 0, w, h
    else:
        step = 1
        cw, ch = max(1, min(w, int(box[0] / zoom))), max(1, min(h, int(box[1] / zoom)))
        x0 = min(max(0, int(round(cx * w - cw / 2))), w - cw)
        y0 = min(max(0, int(round(cy * h - ch / 2))), h - ch)
    ys, xs = np.mgrid[y0 : y0 + ch : step, x0 : x0 + cw : step].astype(np.float64)
    dark = _linear_green(dark_f, lut, slice(y0, y0 + ch, step), slice(x0, x0 + cw, step)) * float(
        pair.ratio
    )
    fields = local_fields(reg)
    if aligned and (fields[pair.dark] is not None or fields[pair.bright] is not None):
        # local refinement: both frames read on the reference grid through their motion and
        # field, as the merge reads them (the crop is then in reference pixels)
        from hdrcore.registration.field import map_points

        chain = reg.to_reference_homography
        dx_, dy_ = map_points(
            np.linalg.inv(np.asarray(chain[pair.dark], np.float64)), fields[pair.dark], xs, ys
        )
        dark = _sample_green(dark_f, lut, dx_, dy_) * float(pair.ratio)
        bx, by = map_points(
            np.linalg.inv(np.asarray(chain[pair.bright], np.float64)), fields[pair.bright], xs, ys
        )
    elif aligned:
        inv = np.linalg.inv(np.asarray(pair.homography, np.float64))
        den = inv[2, 0] * xs + inv[2, 1] * ys + inv[2, 2]
        bx = (inv[0, 0] * xs + inv[0, 1] * ys + inv[0, 2]) / den
        by = (inv[1, 0] * xs + inv[1, 1] * ys + inv[1, 2]) / den
    else:
        bx, by = xs, ys
    bright = _sample_green(bright_f, lut, bx, by)
    scale = float(np.percentile(np.concatenate([bright.ravel(), dark.ravel()]), 99.0)) or 1.0
    rgb = np.stack([bright, dark, dark], axis=-1) / scale
    img = (np.clip(rgb, 0.0, 1.0) ** (1 / 2.2) * 255.0 + 0.5).astype(np.uint8)
    kz = int(round(zoom)) if zoom > 1 else 1
    if kz > 1:
        img = np.repeat(np.repeat(img, kz, axis=0), kz, axis=1)
    return np.ascontiguousarray(img), (x0, y0, x0 + cw, y0 + ch)


def _size_name(level: int) -> str:
    return "full size" if level <= 0 else f"1/{1 << level} size"


def cost_figure(pair: PairRegistration) -> go.Figure:
    """The eq. 6 cost per iteration, one line per pyramid level: each level has its own scale
    (a finer one keeps more detail in the differences), which drawn as one line read as the
    search getting worse (the Xperia's pair 0-1: 0.00033 at 1/32 size -> 0.0025 at full size,
    falling within every size)."""
    costs = [float(c) for c in pair.cost_history]
    levels = [int(lv) for lv in pair.level_history]
    if len(levels) != len(costs):  # no level per iteration: one line
        levels = [0] * len(costs)
    data = []
    start = 0
    for i in range(1, len(costs) + 1):
        if i < len(costs) and levels[i] == levels[start]:
            continue
        name = _size_name(levels[start])
        data.append(
            {
                "type": "scatter",
                "mode": "lines+markers",
                "x": list(range(start, i)),
                "y": costs[start:i],
                "name": name,
                "text": [f"{name} (pyramid level {levels[start]})"] * (i - start),
            }
        )
        start = i
    layout = {
        "title": {
            "text": f"Cost per iteration ({pair.method}), one line per image size "
            "(each size has its own scale: compare within a line)",
            "font": {"size": 14},
        },
        "xaxis": {"title": {"text": "iteration"}},
        "yaxis": {"title": {"text": "cost"}, "type": "log", "dtick": 1, "exponentformat": "power"},
        "margin": {"l": 55, "r": 10, "t": 40, "b": 45},
        "legend": {"orientation": "h", "y": -0.2},
        "template": "plotly_white",
    }
    return go.Figure({"data": data, "layout": layout}, _validate=False)


def motion_summary(pair: PairRegistration) -> str:
    return (
        f"**Pair {pair.dark}→{pair.bright}** ({pair.model}, {pair.method}): status "
        f"**{pair.status}**: {fmt(pair.message)}\n\n"
        f"dx = {fmt(pair.dx, 4)} px, dy = {fmt(pair.dy, 4)} px, angle = "
        f"{fmt(pair.angle_deg, 4)}°; eq. 6 cost {fmt(pair.cost_before, 4)} → "
        f"{fmt(pair.cost_after, 4)}; ratio used {fmt(pair.ratio, 6)}; overlap {pct(pair.overlap)},"
        f" well exposed {pct(pair.valid_fraction)}; {pair.iterations} iterations; eq. 5 peak NCC "
        f"{fmt(pair.peak_ncc, 3)}, PSR {fmt(pair.peak_psr, 3)}; {1000 * pair.seconds:.0f} ms"
    )


class RegistrationPanel:
    """Motion summary, before/after images and the cost history of the chosen pair."""

    def __init__(self, gui: viser.GuiApi) -> None:
        self._gui = gui
        self.summary = gui.add_markdown("No bracket loaded.")
        self.show_dropdown = gui.add_dropdown(
            "Show",
            SHOWS,
            hint="blink: the image switches between before and after, so a "
            "shift of one pixel shows as movement",
        )
        self.zoom = gui.add_dropdown(
            "Zoom ", ZOOMS, hint="the overlay at full resolution; fit: the whole frame"
        )
        self.centre_x = gui.add_slider("Centre x (%) ", 0.0, 100.0, 1.0, 50.0, visible=False)
        self.centre_y = gui.add_slider("Centre y (%) ", 0.0, 100.0, 1.0, 50.0, visible=False)
        self.arrows = gui.add_checkbox(
            "Residual arrows",
            True,
            hint="what is left after alignment, tile by tile, measured "
            "independently of the motion model (phase correlation)",
        )
        self.residual_md = gui.add_markdown("")
        self._residuals: dict[tuple[int, int], ResidualMotion | None] = {}
        blank = np.zeros((4, 4, 3), np.uint8)
        self.full = gui.add_image(blank, label="overlay", format="png", visible=False)
        self.before = gui.add_image(blank, label="before alignment", format="png", visible=False)
        self.after = gui.add_image(blank, label="after alignment", format="png", visible=False)
        self._last: tuple[Bracket | None, PipelineResult | None, dict[str, Any]] | None = None
        self._drawn: tuple[Any, ...] | None = None  # the key (_key) of what is drawn
        self._frames: dict[bool, np.ndarray] = {}
        self._lock = threading.Lock()
        self._blink_stop = threading.Event()
        self._blink_thread: threading.Thread | None = None
        for handle in (self.show_dropdown, self.zoom, self.centre_x, self.centre_y, self.arrows):
            handle.on_update(lambda _e: self._redraw())
        self.costs = gui.add_plotly(EMPTY_PLOT, aspect=0.45, visible=False)  # height / width
        self._images: dict[str, np.ndarray] = {}
        self._figure: go.Figure | None = None

    def _hide(self, text: str) -> None:
        self.summary.content = text
        self.before.visible = self.after.visible = self.costs.visible = False
        self.full.visible = False
        self._images = {}
        self._figure = None

    def _redraw(self) -> None:
        last = self._last
        if last is not None:
            self.show(*last)

    def close(self) -> None:
        self._blink_stop.set()

    def _blink(self) -> None:
        """Switch the overlay between before and after until another choice is made."""
        aligned = True
        while not self._blink_stop.wait(BLINK_SECONDS):
            frames = self._frames
            if not frames:
                continue
            aligned = not aligned
            try:
                self.full.image = frames[aligned]
                self.full.label = (
                    "after alignment" if aligned else "before alignment"
                ) + " (blinking)"
            except Exception:  # noqa: BLE001 -- the page went away
                return

    def _set_blink(self, on: bool) -> None:
        if on and (self._blink_thread is None or not self._blink_thread.is_alive()):
            self._blink_stop.clear()
            self._blink_thread = threading.Thread(
                target=self._blink, daemon=True, name="hdrview-blink"
            )
            self._blink_thread.start()
        elif not on:
            self._blink_stop.set()

    def _show_full(self, bracket: Bracket, result: PipelineResult, k: int) -> str:
        """The full-resolution overlay (or a fit of the whole frame); returns its label."""
        zoom_text = self.zoom.value
        zoom = 0.0 if zoom_text == "fit" else float(zoom_text.split()[0]) / 100.0
        self.centre_x.visible = self.centre_y.visible = zoom > 0
        cx, cy = self.centre_x.value / 100.0, self.centre_y.value / 100.0
        show = self.show_dropdown.value
        frames = {}
        crop = (0, 0, 0, 0)
        for aligned in (True, False):
            if show.startswith("blink") or show.startswith("after") == aligned:
                frames[aligned], crop = overlay_crop(
                    bracket, result, k, aligned=aligned, zoom=zoom, cx=cx, cy=cy
                )
        residual = None
        if self.arrows.value and True in frames:
            key = (id(result), k)
            residual = self._residuals.get(key)
            if residual is None:
                try:
                    residual = pair_residual(bracket, result, k)
                except Exception:  # noqa: BLE001 -- the arrows are extra; the overlay stays
                    residual = None
                self._residuals = {key: residual}  # only the shown pair's is kept
            if residual is not None:
                h, w = bracket.frames[0].levels.shape[:2]
                step = w / frames[True].shape[1] if zoom == 0 else 1.0 / zoom
                frames[True] = draw_arrows(frames[True], residual, step, crop[0], crop[1])
        loc = local_summary(_registration(result), k)
        said = (
            ""
            if residual is None
            else (
                f"Residual after the motion model: **{residual.status}**: {residual.message} "
                f"(arrows x{ARROW_GAIN:g}: green < 0.3 px, yellow < 1 px, red above; grey x: no "
                "texture)"
            )
        )
        self.residual_md.content = "\n\n".join(t for t in (said, loc) if t)
        self._frames = frames if show.startswith("blink") else {}
        first = frames[True] if True in frames else frames[False]
        self.full.image = first
        self._set_blink(show.startswith("blink"))
        where = (
            "whole frame"
            if zoom == 0
            else (f"{zoom_text}: pixels {crop[0]}-{crop[2]} x {crop[1]}-{crop[3]}")
        )
        return (
            f"{show} — red: bright frame, cyan: dark frame x ratio, grey where they agree ({where})"
        )

    def _key(
        self, bracket: Bracket | None, result: PipelineResult | None, view: dict[str, Any]
    ) -> tuple[Any, ...] | None:
        """What the drawn panel shows: the bracket and registration (by identity), the
        response's table the overlays scale by, the pair, the overlay and this panel's own
        choices. ``None`` when there is no registration to draw."""
        reg = None if result is None else result.registration
        if bracket is None or result is None or reg is None:
            return None
        lut = result.lut
        return (
            bracket,
            reg,
            None if lut is None else hash(np.ascontiguousarray(lut).tobytes()),
            int(view.get("pair", 0)),
            view.get("overlay"),
            self.show_dropdown.value,
            self.zoom.value,
            self.centre_x.value,
            self.centre_y.value,
            self.arrows.value,
        )

    def show(
        self, bracket: Bracket | None, result: PipelineResult | None, view: dict[str, Any]
    ) -> None:
        with self._lock:
            self._last = (bracket, result, view)
            key = self._key(bracket, result, view)
            drawn = self._drawn
            if (
                key is not None
                and drawn is not None
                and len(key) == len(drawn)
                and key[0] is drawn[0]
                and key[1] is drawn[1]
                and key[2:] == drawn[2:]
            ):
                # a slider step that kept the registration: the same overlays (drawing them
                # again cost about 0.1 s a step at 24 MP, before the merge could start)
                return
            self._show(bracket, result, view)
            self._drawn = key

    def _show(
        self, bracket: Bracket | None, result: PipelineResult | None, view: dict[str, Any]
    ) -> None:
        if bracket is None:
            self._hide("No bracket loaded.")
            return
        reg = None if result is None else result.registration
        if result is None or reg is None:
            self._hide(
                "_Waiting for the registration stage (hdrcore.pipeline)._"
                if result is None
                else "Registration is off (alignment: none)."
            )
            return
        k = min(int(view.get("pair", 0)), len(reg.pairs) - 1)
        pair = reg.pairs[k]
        self.summary.content = motion_summary(pair)
        prev = pair.preview
        mode = view.get("overlay", OVERLAYS[0])
        if not mode.startswith("difference") and bracket is not None and k < len(reg.pairs):
            # Full resolution from the frames themselves: zoom, before/after and blink.
            self.before.visible = self.after.visible = False
            self.full.label = self._show_full(bracket, result, k)
            self.full.visible = True
            self._images = {
                f"registration-pair{k}-{'after' if a else 'before'}": img
                for a, img in self._frames.items()
            } or {f"registration-pair{k}-overlay": self.full.image}
        elif prev is None:
            self._set_blink(False)
            self.full.visible = False
            self.before.visible = self.after.visible = False
            self.summary.content += "\n\n_No preview images were kept for this pair._"
        else:
            self._set_blink(False)
            self.full.visible = False
            if mode.startswith("difference"):
                before = scalar_to_rgb(prev.difference_before, vmin=-1.0, vmax=1.0)
                after = scalar_to_rgb(prev.difference_after, vmin=-1.0, vmax=1.0)
                what = "eq. 7 normalised difference (−1 purple … +1 yellow, grey: not used)"
            else:
                before = unit_to_display(prev.overlay_before)
                after = unit_to_display(prev.overlay_after)
                what = "red: bright frame, cyan: dark frame × ratio"
            self.before.image, self.after.image = enlarge(before), enlarge(after)
            self.before.label = f"before alignment — {what}"
            self.after.label = f"after alignment — {what}"
            self.before.visible = self.after.visible = True
            self._images = {
                f"registration-pair{k}-before": before,
                f"registration-pair{k}-after": after,
            }
        if pair.cost_history:
            self._figure = cost_figure(pair)
            self.costs.figure = self._figure
            self.costs.visible = True
        else:
            self.costs.visible = False

    def bundle_files(self) -> list[tuple[str, bytes]]:
        files = [(f"{name}.png", encode_png(img)) for name, img in self._images.items()]
        if self._figure is not None:
            from ._png_plot import figure_to_png

            files.append(("registration-costs.plotly.json", self._figure.to_json().encode()))
            files.append(("registration-costs.png", figure_to_png(self._figure)))
        return files
