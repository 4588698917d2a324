"""Frames panel: the loaded bracket, darkest first, with its metadata and capture warnings."""

from __future__ import annotations

from typing import Any

import numpy as np
import viser

from hdrcore.io import Bracket

from ._draw import fmt, levels_to_display, md_table

__all__ = ["FramesPanel", "frames_table", "warnings_markdown"]

THUMB_WIDTH = 300


def frames_table(bracket: Bracket) -> str:
    rows = []
    for k, f in enumerate(bracket.frames):
        m = f.meta
        t = m.exposure_time
        rows.append([
            k,
            f.name,
            m.format,
            m.bit_depth,
            m.max_level,
            "—" if t is None else f"{t} s",
            m.exposure_time_source,
            None if m.f_number is None else f"f/{float(m.f_number):g}",
            m.iso,
            m.camera,
        ])
    header = ["#", "file", "format", "bits", "max level", "exposure", "source", "aperture",
              "ISO", "camera"]
    h, w = bracket.shape
    lin = "linear (RAW)" if bracket.is_linear else "non-linear (needs a response)"
    return (f"**{len(bracket)} frames**, {w}×{h}, {lin}, ordered by {bracket.order_source}\n\n"
            + md_table(header, rows))


def warnings_markdown(bracket: Bracket) -> str:
    if not bracket.warnings:
        return "No capture warnings."
    lines = ["**Capture warnings**", ""]
    for w in bracket.warnings:
        frames = f" (frames {', '.join(str(k) for k in w.frames)})" if w.frames else ""
        lines.append(f"- `{w.code}`{frames}: {fmt(w.message)}")
    return "\n".join(lines)


class FramesPanel:
    """Metadata table, capture warnings and one thumbnail per frame."""

    def __init__(self, gui: viser.GuiApi, container: Any) -> None:
        self._gui = gui
        self._container = container
        self.table = gui.add_markdown("No bracket loaded.")
        self.warnings = gui.add_markdown("")
        self._thumbs: list[Any] = []

    def show(self, bracket: Bracket | None) -> None:
        for h in self._thumbs:
            h.remove()
        self._thumbs = []
        if bracket is None:
            self.table.content = "No bracket loaded."
            self.warnings.content = ""
            return
        self.table.content = frames_table(bracket)
        self.warnings.content = warnings_markdown(bracket)
        for k, f in enumerate(bracket.frames):
            img = levels_to_display(f.levels, f.max_level, linear=f.is_linear, width=THUMB_WIDTH)
            t = f.meta.exposure_time
            label = f"frame {k}: {f.name}" + ("" if t is None else f" ({t} s)")
            with self._container:
                self._thumbs.append(self._gui.add_image(np.ascontiguousarray(img), label=label))
