"""Masks panel: which pixels of the pair's frames are inlier equations, outliers, saturated
(above Z) or under the noise floor, each in its own colour."""

from __future__ import annotations

from typing import Any

import viser

__all__ = ["MasksPanel"]


class MasksPanel:
    def __init__(self, gui: viser.GuiApi) -> None:
        self._gui = gui
        self.summary = gui.add_markdown("No bracket loaded.")

    def show(self, bracket: Any, result: Any, view: dict) -> None:
        if bracket is None:
            self.summary.content = "No bracket loaded."
            return
        if result is None:
            self.summary.content = "_Waiting for the exposure-ratio stage (hdrcore.pipeline)._"

    def bundle_files(self) -> list[tuple[str, bytes]]:
        return []
