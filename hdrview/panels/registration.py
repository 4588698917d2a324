"""Registration panel: the chosen pair before and after alignment (red = bright frame, cyan = the
dark frame times the exposure ratio, grey where they agree), the eq. 7 normalised difference whose
mean square is the eq. 6 cost (Cerman & Hlavac 2006), the motion (dx, dy, angle) and the cost per
iteration. Everything drawn comes from :class:`hdrcore.registration.PairRegistration`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import plotly.graph_objects as go
import viser

from hdrcore.io import encode_png

from ._access import registration_of
from ._draw import enlarge, fmt, scalar_to_rgb, unit_to_display

__all__ = ["RegistrationPanel", "OVERLAYS", "cost_figure", "motion_summary"]

OVERLAYS = ("red/cyan", "difference (eq. 7)")


def cost_figure(pair: Any) -> go.Figure:
    it = list(range(len(pair.cost_history)))
    data = [{"type": "scatter", "mode": "lines+markers", "x": it,
             "y": [float(c) for c in pair.cost_history], "name": "eq. 6 cost",
             "text": [f"pyramid level {lv}" for lv in pair.level_history]}]
    layout = {"title": {"text": f"Cost per iteration ({pair.method})", "font": {"size": 14}},
              "xaxis": {"title": {"text": "iteration"}},
              "yaxis": {"title": {"text": "cost"}, "type": "log", "dtick": 1,
                        "exponentformat": "power"},
              "margin": {"l": 55, "r": 10, "t": 40, "b": 45}, "template": "plotly_white"}
    return go.Figure({"data": data, "layout": layout}, _validate=False)


def motion_summary(pair: Any) -> str:
    return (
        f"**Pair {pair.dark}→{pair.bright}** ({pair.model}, {pair.method}): status "
        f"**{pair.status}**: {fmt(pair.message)}\n\n"
        f"dx = {fmt(pair.dx, 4)} px, dy = {fmt(pair.dy, 4)} px, angle = "
        f"{fmt(pair.angle_deg, 4)}°; eq. 6 cost {fmt(pair.cost_before, 4)} → "
        f"{fmt(pair.cost_after, 4)}; ratio used {fmt(pair.ratio, 6)}; overlap {pair.overlap:.1%},"
        f" well exposed {pair.valid_fraction:.1%}; {pair.iterations} iterations; eq. 5 peak NCC "
        f"{fmt(pair.peak_ncc, 3)}, PSR {fmt(pair.peak_psr, 3)}; {1000 * pair.seconds:.0f} ms"
    )


class RegistrationPanel:
    """Motion summary, before/after images and the cost history of the chosen pair."""

    def __init__(self, gui: viser.GuiApi) -> None:
        self._gui = gui
        self.summary = gui.add_markdown("No bracket loaded.")
        blank = np.zeros((4, 4, 3), np.uint8)
        self.before = gui.add_image(blank, label="before alignment", format="png", visible=False)
        self.after = gui.add_image(blank, label="after alignment", format="png", visible=False)
        self.costs = gui.add_plotly(go.Figure(), aspect=0.45, visible=False)  # height / width
        self._images: dict[str, np.ndarray] = {}
        self._figure: go.Figure | None = None

    def _hide(self, text: str) -> None:
        self.summary.content = text
        self.before.visible = self.after.visible = self.costs.visible = False
        self._images = {}
        self._figure = None

    def show(self, bracket: Any, result: Any, view: dict) -> None:
        if bracket is None:
            self._hide("No bracket loaded.")
            return
        reg = registration_of(result)
        if reg is None:
            self._hide("_Waiting for the registration stage (hdrcore.pipeline)._" if result is None
                       else "Registration is off (alignment: none).")
            return
        k = min(int(view.get("pair", 0)), len(reg.pairs) - 1)
        pair = reg.pairs[k]
        self.summary.content = motion_summary(pair)
        prev = pair.preview
        if prev is None:
            self.before.visible = self.after.visible = False
            self.summary.content += "\n\n_No preview images were kept for this pair._"
        else:
            mode = view.get("overlay", OVERLAYS[0])
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
            self._images = {f"registration-pair{k}-before": before,
                            f"registration-pair{k}-after": after}
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
