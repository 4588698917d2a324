"""Registration panel: overlays before and after alignment, the eq. 6 difference map, motion."""

from __future__ import annotations

from typing import Any

import viser

__all__ = ["RegistrationPanel", "OVERLAYS"]

OVERLAYS = ("red/cyan", "checkerboard", "difference")


class RegistrationPanel:
    def __init__(self, gui: viser.GuiApi) -> None:
        self._gui = gui
        self.summary = gui.add_markdown("No bracket loaded.")

    def show(self, bracket: Any, result: Any, view: dict) -> None:
        if bracket is None:
            self.summary.content = "No bracket loaded."
            return
        if result is None:
            self.summary.content = "_Waiting for the registration stage (hdrcore.pipeline)._"

    def bundle_files(self) -> list[tuple[str, bytes]]:
        return []
