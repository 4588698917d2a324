"""Diagnostics panel: per-pair table for the whole bracket and the plain-language verdicts."""

from __future__ import annotations

from typing import Any

import viser

from .frames import warnings_markdown

__all__ = ["DiagnosticsPanel", "bundle_files"]


class DiagnosticsPanel:
    def __init__(self, gui: viser.GuiApi) -> None:
        self._gui = gui
        self.verdicts = gui.add_markdown("No bracket loaded.")
        self.table = gui.add_markdown("")
        self.warnings = gui.add_markdown("")

    def show(self, bracket: Any, result: Any, view: dict) -> None:
        if bracket is None:
            self.verdicts.content = "No bracket loaded."
            self.table.content = ""
            self.warnings.content = ""
            return
        self.warnings.content = warnings_markdown(bracket)
        if result is None:
            self.verdicts.content = "_Waiting for the pipeline's verdicts (hdrcore.pipeline)._"
            self.table.content = ""


def bundle_files(bracket: Any, result: Any, *panels: Any) -> list[tuple[str, bytes]]:
    files: list[tuple[str, bytes]] = []
    for p in panels:
        files.extend(p.bundle_files())
    return files
