"""BTF panel: brightness transfer function of the chosen pair with its linear fits (eq. 4)."""

from __future__ import annotations

from typing import Any

import viser

__all__ = ["BtfPanel"]


class BtfPanel:
    def __init__(self, gui: viser.GuiApi) -> None:
        self._gui = gui
        self.summary = gui.add_markdown("No bracket loaded.")
        self.plot = None

    def show(self, bracket: Any, result: Any, view: dict) -> None:
        if bracket is None:
            self.summary.content = "No bracket loaded."
            return
        if result is None:
            self.summary.content = "_Waiting for the exposure-ratio stage (hdrcore.pipeline)._"
            return

    def bundle_files(self) -> list[tuple[str, bytes]]:
        return []
