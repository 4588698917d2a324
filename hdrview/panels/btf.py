"""BTF panel: the chosen pair's equations of system S0 (Cerman & Hlavac 2006, eq. 4) drawn as a
scatter of linearised dark vs bright values, inliers and 3V outliers marked differently, with the
initial fit ``k0``, the converged ratio ``k`` and the line the EXIF times imply; below it the
brightness transfer functions ``T`` (Grossberg & Nayar 2002) with the saturation level ``Z`` and
the noise floor. Everything drawn comes from :class:`hdrcore.exposure.ExposureRatioResult`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import plotly.graph_objects as go
import viser

from hdrcore.io import Bracket

from ._draw import EMPTY_PLOT, fmt, pct

if TYPE_CHECKING:  # the library's stages are imported on first use, not with the page
    from hdrcore.exposure import ExposureRatioResult
    from hdrcore.pipeline import PipelineResult

__all__ = ["BtfPanel", "equations_figure", "transfer_figure", "pair_summary"]

MAX_POINTS = 2500  # per trace, so a 14-bit bracket still draws quickly
CHANNEL_COLOURS = ("#d62728", "#2ca02c", "#1f77b4")
CHANNEL_NAMES = ("R", "G", "B")


def _every(n: int, limit: int = MAX_POINTS) -> int:
    return max(1, int(np.ceil(n / limit)))


def _figure(data: list[dict], layout: dict) -> go.Figure:
    # Plain dicts without plotly's validation: ten times faster, and these are fixed shapes.
    base = {
        "margin": {"l": 55, "r": 10, "t": 40, "b": 45},
        "template": "plotly_white",
        "legend": {"orientation": "h", "y": -0.18},
    }
    return go.Figure({"data": data, "layout": {**base, **layout}}, _validate=False)


def equations_figure(
    pair: ExposureRatioResult, exif_ratio: float | None, registered_ratio: float | None = None
) -> go.Figure:
    """Scatter of the equations ``k x = y`` with the initial, converged and EXIF lines (and the
    ratio measured from the registered pixels, when known)."""
    eq = pair.equations
    x = np.asarray(eq.x, np.float64)
    y = np.asarray(eq.y, np.float64)
    inl = np.asarray(pair.inlier_mask, bool)
    ch = np.asarray(eq.channel)
    data: list[dict] = []
    for c in np.unique(ch):
        sel = np.flatnonzero((ch == c) & inl)
        sel = sel[:: _every(sel.size)]
        data.append(
            {
                "type": "scatter",
                "mode": "markers",
                "x": x[sel].astype(np.float32),
                "y": y[sel].astype(np.float32),
                "name": f"inliers {CHANNEL_NAMES[int(c) % 3]}",
                "marker": {"size": 4, "color": CHANNEL_COLOURS[int(c) % 3], "opacity": 0.6},
            }
        )
    out = np.flatnonzero(~inl)
    out = out[:: _every(out.size)]
    if out.size:
        # beneath the inliers, lighter: on a phone's locally tone-mapped pair most equations
        # are outliers, and their crosses hid the inliers the fit used (the Pixel 7)
        data.insert(
            0,
            {
                "type": "scatter",
                "mode": "markers",
                "x": x[out].astype(np.float32),
                "y": y[out].astype(np.float32),
                "name": "outliers (3V)",
                "marker": {"size": 6, "symbol": "x", "color": "#ff7f0e", "opacity": 0.45},
            },
        )
    xmax = float(np.nanmax(x)) if x.size else 1.0
    xs = [0.0, xmax]

    def line(k: float | None, name: str, dash: str, colour: str) -> None:
        if k is None or not np.isfinite(k):
            return
        data.append(
            {
                "type": "scatter",
                "mode": "lines",
                "x": xs,
                "y": [0.0, k * xmax],
                "name": f"{name} {k:.4f}",
                "line": {"dash": dash, "color": colour},
            }
        )

    line(pair.initial_ratio, "initial k0", "dash", "#7f7f7f")
    line(pair.ratio, "converged k", "solid", "#000000")
    line(exif_ratio, "EXIF", "dot", "#9467bd")
    line(registered_ratio, "registered pixels", "dashdot", "#2ca02c")
    title = (
        f"Frames {pair.dark}→{pair.bright}: k = {fmt(pair.ratio, 6)} "
        f"({pair.n_inliers}/{pair.n_equations} inliers, {pair.status})"
    )
    return _figure(
        data,
        {
            "title": {"text": title, "font": {"size": 14}},
            "xaxis": {"title": {"text": "dark frame, linearised"}},
            "yaxis": {"title": {"text": "bright frame, linearised"}},
        },
    )


def transfer_figure(pair: ExposureRatioResult) -> go.Figure:
    """``T(m)`` per channel in levels, with ``Z`` and the noise floor."""
    data: list[dict] = []
    for c, btf in enumerate(pair.btfs):
        fwd = np.asarray(btf.forward, np.float32)
        step = _every(fwd.size)
        m = np.arange(fwd.size, dtype=np.float32)[::step]
        data.append(
            {
                "type": "scatter",
                "mode": "lines",
                "x": m,
                "y": fwd[::step],
                "name": f"T {CHANNEL_NAMES[c % 3]}",
                "line": {"color": CHANNEL_COLOURS[c % 3]},
            }
        )
    top = float(pair.max_level)
    z, floor = float(pair.saturation), float(pair.noise_floor)
    data.append(
        {
            "type": "scatter",
            "mode": "lines",
            "x": [0, top, None, z, z],
            "y": [z, z, None, 0, top],
            "name": f"Z = {z:g}",
            "line": {"color": "#d62728", "dash": "dash", "width": 1},
        }
    )
    data.append(
        {
            "type": "scatter",
            "mode": "lines",
            "x": [0, top, None, floor, floor],
            "y": [floor, floor, None, 0, top],
            "name": f"noise floor = {floor:g}",
            "line": {"color": "#7f7f7f", "dash": "dot", "width": 1},
        }
    )
    return _figure(
        data,
        {
            "title": {"text": "Brightness transfer function T (levels)", "font": {"size": 14}},
            "xaxis": {"title": {"text": "dark level m"}, "range": [0, top]},
            "yaxis": {"title": {"text": "bright level T(m)"}, "range": [0, top]},
        },
    )


def pair_summary(
    pair: ExposureRatioResult, exif_ratio: float | None, mismatch: float | None
) -> str:
    iterates = ", ".join(fmt(v, 6) for v in pair.iterates[:8])
    if len(pair.iterates) > 8:
        iterates += ", …"
    channels = ", ".join(
        f"{CHANNEL_NAMES[c % 3]} {fmt(r, 5)}" for c, r in enumerate(pair.channel_ratios)
    )
    lines = [
        f"**Pair {pair.dark}→{pair.bright}** ({pair.method}): ratio **{fmt(pair.ratio, 6)}** "
        f"± {fmt(pair.std_error, 2)}; status **{pair.status}**: {fmt(pair.message)}",
        f"k0 = {fmt(pair.initial_ratio, 6)}; iterates: {iterates} ({pair.iterations} iterations); "
        f"EXIF ratio {fmt(exif_ratio, 6)}, mismatch {fmt(mismatch, 3)} stops",
        f"Per channel: {channels}"
        + (" — **channels disagree**" if pair.channels_disagree else "")
        + f"; overlap {pct(pair.overlap)}; Z = {pair.saturation:g}, "
        f"noise floor = {pair.noise_floor:g}",
    ]
    return "\n\n".join(lines)


def _used_by_merge(result: PipelineResult, k: int, exif: float | None) -> str:
    """Which ratio of pair ``k`` the merge used: the measured one, or the EXIF ratio where the
    pipeline fell back to it (an unreliable estimate far from the metadata)."""
    from hdrcore.diagnose import exif_pairs

    source = result.times_source or ""
    if source == "exif" or f"{k}-{k + 1}" in exif_pairs(source):
        return (
            f"The merge uses the EXIF ratio ({fmt(exif, 6)}) for this pair: the estimates "
            "are not reliable enough."
        )
    return "The merge uses this estimate."


class BtfPanel:
    """Summary text, the equations scatter and the transfer functions of the chosen pair."""

    def __init__(self, gui: viser.GuiApi) -> None:
        self._gui = gui
        self.summary = gui.add_markdown("No bracket loaded.")
        empty = EMPTY_PLOT
        # viser's aspect is height / width: plots wider than tall, so a tab fits one screen.
        self.scatter = gui.add_plotly(empty, aspect=0.62, visible=False)
        self.transfer = gui.add_plotly(empty, aspect=0.55, visible=False)
        self._figures: dict[str, go.Figure] = {}

    def show(
        self, bracket: Bracket | None, result: PipelineResult | None, view: dict[str, Any]
    ) -> None:
        if bracket is None or result is None:
            self.summary.content = (
                "No bracket loaded."
                if bracket is None
                else "_Waiting for the exposure-ratio stage (hdrcore.pipeline)._"
            )
            self.scatter.visible = self.transfer.visible = False
            self._figures = {}
            return
        # The figures show the paper's estimate from histograms (its equations and transfer
        # functions); a ratio measured again from the registered pixels is shown beside it.
        hist = result.exposures_histogram
        refined = result.exposures if result.exposures is not hist else None
        k = min(int(view.get("pair", 0)), len(hist.pairs) - 1)
        pair = hist.pairs[k]
        exif = hist.exif_ratios[k] if k < len(hist.exif_ratios) else None
        mismatch = hist.mismatch_stops[k] if k < len(hist.mismatch_stops) else None
        text = pair_summary(pair, exif, mismatch)
        reg_ratio = None
        if refined is not None and k < len(refined.pairs):
            rp = refined.pairs[k]
            reg_ratio = rp.ratio
            text += (
                f"\n\n**After registration** ({rp.method}): ratio **{fmt(rp.ratio, 6)}** "
                f"± {fmt(rp.std_error, 2)} ({rp.n_inliers}/{rp.n_equations} inlier equations); "
                f"status **{rp.status}**: {fmt(rp.message)}. " + _used_by_merge(result, k, exif)
            )
        else:
            text += "\n\n" + _used_by_merge(result, k, exif)
        self.summary.content = text
        scatter = equations_figure(pair, exif, reg_ratio)
        transfer = transfer_figure(pair)
        self.scatter.figure = scatter
        self.transfer.figure = transfer
        self.scatter.visible = self.transfer.visible = True
        self._figures = {"btf-equations": scatter, "btf-transfer": transfer}

    def bundle_files(self) -> list[tuple[str, bytes]]:
        from ._png_plot import figure_to_png

        files = []
        for name, fig in self._figures.items():
            files.append((f"{name}.plotly.json", fig.to_json().encode()))
            files.append((f"{name}.png", figure_to_png(fig)))
        return files
