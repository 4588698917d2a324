"""Frames panel: the loaded bracket, darkest first, with its metadata and capture warnings."""

from __future__ import annotations

from typing import Any

import numpy as np
import viser

from hdrcore.io import Bracket

from ._draw import fmt, levels_to_display, md_table

__all__ = ["FramesPanel", "frames_table", "warnings_markdown", "contact_sheet"]

THUMB_WIDTH = 280
COLUMNS = 3
HIST_HEIGHT = 48
_HIST_COLOURS = ((214, 39, 40), (44, 160, 44), (31, 119, 180))


def _histogram_strip(levels: np.ndarray, max_level: int, width: int) -> np.ndarray:
    """Per-channel histograms of the frame's levels (log counts), ``width`` pixels wide, each
    channel a translucent area in its colour."""
    strip = np.full((HIST_HEIGHT, width, 3), 250.0, np.float32)
    sub = levels[::4, ::4]
    bins = min(width, int(max_level) + 1)
    rows = np.arange(HIST_HEIGHT)[:, None]
    for c in range(min(3, sub.shape[-1] if sub.ndim == 3 else 1)):
        ch = sub[..., c] if sub.ndim == 3 else sub
        idx = (ch.astype(np.int64) * bins) // (int(max_level) + 1)
        counts = np.bincount(idx.ravel(), minlength=bins)[:bins].astype(np.float64)
        heights = np.log1p(counts) / max(np.log1p(counts.max()), 1e-9) * (HIST_HEIGHT - 2)
        heights = heights[(np.arange(width) * bins) // width]  # one column per pixel
        filled = rows >= (HIST_HEIGHT - 1 - heights)[None, :]
        strip[filled] = strip[filled] * 0.6 + np.array(_HIST_COLOURS[c], np.float32) * 0.4
    return strip.astype(np.uint8)


def _seconds(t: Any) -> str:
    """An exposure time as a camera shows it: ``1/15 s`` for a time whose inverse is a whole
    number (within 1 %: a times file's 0.06666666667), else decimal seconds (``0.3 s``)."""
    v = float(t)
    if v <= 0:
        return f"{v:g} s"
    inv = 1.0 / v
    if v < 0.4 and abs(inv - round(inv)) <= 0.01 * inv:
        return f"1/{round(inv)} s"
    return f"{v:.3g} s"


def contact_sheet(bracket: Bracket, columns: int = COLUMNS, width: int = THUMB_WIDTH) -> np.ndarray:
    """The frames as a grid of thumbnails, each with its name, time and a histogram below."""
    from PIL import Image, ImageDraw

    cells = []
    for k, f in enumerate(bracket.frames):
        img = levels_to_display(f.levels, f.max_level, linear=f.is_linear, width=width)
        if img.shape[0] > img.shape[1]:  # portrait: no taller than a 3:2 landscape cell
            step = int(np.ceil(img.shape[0] / (width * 2 // 3)))
            img = img[::step, ::step]
        t = f.meta.exposure_time
        label = f"{k}: {f.name}" + ("" if t is None else f"  {_seconds(t)}")
        text = Image.new("RGB", (width, 18), (255, 255, 255))
        ImageDraw.Draw(text).text((2, 3), label[:44], fill=(20, 20, 20))
        pic = np.full((img.shape[0], width, 3), 255, np.uint8)
        x0 = (width - img.shape[1]) // 2
        pic[:, x0 : x0 + img.shape[1]] = img
        cells.append(
            np.concatenate(
                [np.asarray(text), pic, _histogram_strip(f.levels, f.max_level, width)], axis=0
            )
        )
    ch = max(c.shape[0] for c in cells)
    pad = 6
    rows = (len(cells) + columns - 1) // columns
    sheet = np.full((rows * (ch + pad), columns * (width + pad), 3), 255, np.uint8)
    for k, cell in enumerate(cells):
        r, c = divmod(k, columns)
        sheet[
            r * (ch + pad) : r * (ch + pad) + cell.shape[0],
            c * (width + pad) : c * (width + pad) + width,
        ] = cell
    return sheet


def _colour_space(m: Any) -> str:
    """The RGB space a frame's levels are in, as the file says (RAW: the camera's own)."""
    if m.is_linear:
        return "camera RGB"
    if m.colour_space is not None:
        return str(m.colour_space)
    src = m.colour_space_source
    return f"sRGB (assumed; {src} not known)" if src else "sRGB (assumed)"


def frames_table(bracket: Bracket) -> str:
    rows = []
    for k, f in enumerate(bracket.frames):
        m = f.meta
        t = m.exposure_time
        rows.append(
            [
                k,
                f.name,
                m.format,
                m.bit_depth,
                m.max_level,
                "—" if t is None else _seconds(t),
                m.exposure_time_source,
                None if m.f_number is None else f"f/{float(m.f_number):g}",
                m.iso,
                m.camera,
                _colour_space(m),
            ]
        )
    header = [
        "#",
        "file",
        "format",
        "bits",
        "max level",
        "exposure",
        "source",
        "aperture",
        "ISO",
        "camera",
        "colours",
    ]
    h, w = bracket.shape
    lin = "linear (RAW)" if bracket.is_linear else "non-linear (needs a response)"
    return (
        f"**{len(bracket)} frames**, {w}×{h}, {lin}, ordered by {bracket.order_source}\n\n"
        + md_table(header, rows)
    )


def warnings_markdown(bracket: Bracket) -> str:
    if not bracket.warnings:
        return "No capture warnings."
    lines = ["**Capture warnings**", ""]
    for w in bracket.warnings:
        frames = f" (frames {', '.join(str(k) for k in w.frames)})" if w.frames else ""
        lines.append(f"- `{w.code}`{frames}: {fmt(w.message)}")
    return "\n".join(lines)


class FramesPanel:
    """Metadata table, capture warnings and the frames as a grid of thumbnails with their
    histograms (one image: a 12-frame bracket fits one screen)."""

    def __init__(self, gui: viser.GuiApi, container: Any) -> None:
        self._gui = gui
        self._container = container
        self.table = gui.add_markdown("No bracket loaded.")
        self.warnings = gui.add_markdown("")
        self.sheet = gui.add_image(
            np.zeros((4, 4, 3), np.uint8),
            label="frames, darkest first: thumbnail and histogram of the levels (log counts)",
            format="jpeg",
            visible=False,
        )

    def show(self, bracket: Bracket | None) -> None:
        if bracket is None:
            self.table.content = "No bracket loaded."
            self.warnings.content = ""
            self.sheet.visible = False
            return
        self.table.content = frames_table(bracket)
        self.warnings.content = warnings_markdown(bracket)
        self.sheet.image = contact_sheet(bracket)
        self.sheet.visible = True
