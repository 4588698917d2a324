"""Response panel: the camera response the merge used, per channel, with its fit residuals; when
``--response auto`` chose it, every candidate's score and, if the recovered curve was degenerate,
that curve beside its fallback; below them each frame's white balance against the reference
(:mod:`hdrview.panels.white_balance`). Everything drawn comes from the pipeline's
:class:`hdrcore.response.ResponseCurve` and its :class:`hdrcore.response.select.ResponseSelection`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import plotly.graph_objects as go
import viser

from hdrcore.io import Bracket

from ._draw import EMPTY_PLOT, fmt, md_table
from .white_balance import WhiteBalancePanel

if TYPE_CHECKING:  # the library's stages are imported on first use, not with the page
    from hdrcore.pipeline import PipelineResult
    from hdrcore.response import ResponseCurve

__all__ = ["ResponsePanel", "curves_figure", "residuals_figure", "candidates_table"]

CHANNEL_COLOURS = ("#d62728", "#2ca02c", "#1f77b4")
CHANNEL_NAMES = ("R", "G", "B")


def _layout(title: str, x: str, y: str, **extra: Any) -> dict:
    return {
        "title": {"text": title, "font": {"size": 14}},
        "xaxis": {"title": {"text": x}},
        "yaxis": {"title": {"text": y}, **extra},
        "margin": {"l": 60, "r": 10, "t": 40, "b": 45},
        "template": "plotly_white",
        "legend": {"orientation": "h", "y": -0.2},
    }


def curves_figure(curve: ResponseCurve) -> go.Figure:
    """``g`` (linear exposure) against the level, per channel; the degenerate recovered curve
    dashed beside its fallback; the other candidates thin and grey."""
    g = np.asarray(curve.g, np.float64)
    levels = np.arange(g.shape[-1])
    data: list[dict] = []
    sel = curve.selection
    if sel is not None:
        for name, other in sel.curves.items():
            if name == sel.chosen:
                continue
            arr = np.asarray(other, np.float64)
            recovered = sel.fallback and name == sel.recovered
            data.append(
                {
                    "type": "scatter",
                    "mode": "lines",
                    "x": levels,
                    "y": arr[min(1, len(arr) - 1)],
                    "name": f"{name} (degenerate, not used)" if recovered else name,
                    "line": {
                        "color": "#ff7f0e" if recovered else "#bbbbbb",
                        "width": 2 if recovered else 1,
                        "dash": "dash" if recovered else "dot",
                    },
                }
            )
    for c in range(g.shape[0]):
        data.append(
            {
                "type": "scatter",
                "mode": "lines",
                "x": levels,
                "y": g[c],
                "name": f"{curve.method} {CHANNEL_NAMES[c % 3]}",
                "line": {"color": CHANNEL_COLOURS[c % 3], "width": 2},
            }
        )
    return go.Figure(
        {
            "data": data,
            "layout": _layout(
                "Camera response: light (linear) for each level", "level", "relative exposure g"
            ),
        },
        _validate=False,
    )


def residuals_figure(curve: ResponseCurve) -> go.Figure | None:
    """The fit's weighted mean residual of ``ln g`` per level (how well the curve explains the
    bracket's own correspondences there)."""
    sel = curve.selection
    series = []
    if sel is not None and sel.residuals:
        for name, res in sel.residuals.items():
            if name == sel.chosen or (sel.fallback and name == sel.recovered):
                series.append((name, np.asarray(res, np.float64)))
    elif curve.residuals is not None:
        series.append((curve.method, np.asarray(curve.residuals, np.float64)))
    if not series:
        return None
    data = []
    for name, res in series:
        res2 = res if res.ndim == 2 else res[None]
        for c in range(res2.shape[0]):
            data.append(
                {
                    "type": "scatter",
                    "mode": "lines",
                    "x": np.arange(res2.shape[1]),
                    "y": res2[c],
                    "name": f"{name} {CHANNEL_NAMES[c % 3]}",
                    "line": {
                        "color": CHANNEL_COLOURS[c % 3],
                        "dash": "solid" if name == series[0][0] else "dash",
                    },
                }
            )
    return go.Figure(
        {
            "data": data,
            "layout": _layout(
                "Fit residual per level (0: the curve explains the frames there)",
                "level",
                "mean residual of ln g",
            ),
        },
        _validate=False,
    )


def candidates_table(sel: Any) -> str:
    rows = []
    for c in sel.candidates:
        rows.append(
            [
                ("**" + c.name + "**") if c.name == sel.chosen else c.name,
                fmt(c.score, 4),
                fmt(c.colour, 3),
                c.n_pairs,
                c.excluded or ("degenerate" if c.degenerate else ""),
            ]
        )
    return md_table(
        [
            "candidate",
            "held-back residual",
            "colour difference between frames",
            "pairs",
            "left out because",
        ],
        rows,
    )


class ResponsePanel:
    """Summary, curves, residuals and the auto-selection's candidates."""

    def __init__(self, gui: viser.GuiApi) -> None:
        self.summary = gui.add_markdown("No bracket loaded.")
        empty = EMPTY_PLOT
        self.curves = gui.add_plotly(empty, aspect=0.55, visible=False)  # height / width
        self.residuals = gui.add_plotly(empty, aspect=0.45, visible=False)
        self.table = gui.add_markdown("")
        self.white_balance = WhiteBalancePanel(gui)
        self._figures: dict[str, go.Figure] = {}

    def show(
        self, bracket: Bracket | None, result: PipelineResult | None, view: dict[str, Any]
    ) -> None:
        self._figures = {}
        self.white_balance.show(bracket, result)
        if self.white_balance.figure is not None:
            self._figures["white-balance"] = self.white_balance.figure
        if bracket is None or result is None:
            self.summary.content = (
                "No bracket loaded." if bracket is None else "_Waiting for the response stage._"
            )
            self.curves.visible = self.residuals.visible = False
            self.table.content = ""
            return
        curve = result.response
        if curve is None or bracket.is_linear:
            self.summary.content = (
                "RAW frames are linear: the levels are light already, no response curve is needed."
            )
            self.curves.visible = self.residuals.visible = False
            self.table.content = ""
            return
        sel = curve.selection
        lines = [
            f"Response **{curve.method}**, status **{curve.status}**"
            + (f": {fmt(curve.message)}" if curve.message else ".")
        ]
        if sel is not None and sel.message and sel.message not in (curve.message or ""):
            lines.append(fmt(sel.message))
            if sel.fallback:
                lines.append(
                    f"The recovered curve ({sel.recovered}) was degenerate and is drawn "
                    "dashed in orange; the merge uses the fallback."
                )
        self.summary.content = "\n\n".join(lines)
        fig = curves_figure(curve)
        self.curves.figure = fig
        self.curves.visible = True
        self._figures["response-curves"] = fig
        res = residuals_figure(curve)
        if res is not None:
            self.residuals.figure = res
            self.residuals.visible = True
            self._figures["response-residuals"] = res
        else:
            self.residuals.visible = False
        self.table.content = "" if sel is None else candidates_table(sel)

    def bundle_files(self) -> list[tuple[str, bytes]]:
        return [
            (f"{name}.plotly.json", fig.to_json().encode()) for name, fig in self._figures.items()
        ]
