"""Result panel: the tonemapped preview and its diagnostic layers (provenance, clipping, ghosts)."""

from __future__ import annotations

from typing import Any

import viser

from hdrcore.errors import InputError

__all__ = ["ResultPanel", "LAYERS", "exr_bytes", "preview_png_bytes"]

LAYERS = ("tonemapped", "provenance", "clipping", "ghosts")


class ResultPanel:
    def __init__(self, gui: viser.GuiApi) -> None:
        self._gui = gui
        self.summary = gui.add_markdown("No bracket loaded.")

    def show(self, bracket: Any, result: Any, view: dict) -> None:
        if bracket is None:
            self.summary.content = "No bracket loaded."
            return
        if result is None:
            self.summary.content = "_Waiting for the merge and tonemap stages (hdrcore.pipeline)._"

    def bundle_files(self) -> list[tuple[str, bytes]]:
        return []


def exr_bytes(result: Any) -> bytes:
    raise InputError("the merged HDR is not available yet")


def preview_png_bytes(result: Any) -> bytes:
    raise InputError("the preview is not available yet")
