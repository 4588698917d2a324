"""White balance of each frame of a JPEG/PNG/TIFF bracket against the reference frame (issue 15).

Phones (and cameras in auto white balance) may re-balance each shot, so one frame renders the
same surface bluer or redder than the others. The pipeline measures every frame's red/green and
blue/green gain against the reference frame (:mod:`hdrcore.merge.white_balance`, chained through
consecutive frames) and divides the gains out of the merge when a frame differs by more than the
threshold and its uncertainty (unless the *White balance* switch is off). This panel shows what
was measured and done: a plot of the gains with their uncertainty and the threshold, a table and
one sentence per frame in a photographer's words. Nothing is estimated here: everything comes
from ``result.colour["check"]["white_balance"]`` (:meth:`FrameBalance.to_json`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import plotly.graph_objects as go
import viser

from ._draw import EMPTY_PLOT, md_table

if TYPE_CHECKING:
    from hdrcore.io import Bracket
    from hdrcore.pipeline import PipelineResult

__all__ = [
    "WhiteBalancePanel",
    "balance_of",
    "frame_label",
    "frame_rows",
    "gains_figure",
    "verdict",
    "white_balance_markdown",
]

#: Below this relative difference (1 %) a frame is said to have the reference's balance.
SAME = 0.01
#: What the ± means. The gains are measured through the response curve, whose own error is not
#: in it: the Xperia bracket's darkest frame reads B/G +14.5 % through the curve the command
#: line fits and +8.2 % through the inspector's (other estimated times), each ± 0.7 %.
ERROR_NOTE = (
    "_±: one standard error over the image's regions. It leaves out the response curve's own "
    "error, which can move a dark frame's gains by several per cent._"
)


def balance_of(result: PipelineResult | None) -> dict[str, Any] | None:
    """The run's white balance measurement (:meth:`FrameBalance.to_json`), or ``None`` (RAW
    input, or the merge stage not run)."""
    if result is None:
        return None
    check = (result.colour or {}).get("check") or {}
    wb = check.get("white_balance")
    return wb if isinstance(wb, dict) and wb.get("gains") else None


def _time_text(t: float | None) -> str:
    if t is None or not math.isfinite(t) or t <= 0:
        return ""
    if t >= 1.0:
        return f"{t:g} s"
    inv = 1.0 / t
    return f"1/{inv:.0f} s" if abs(inv - round(inv)) < 0.05 * inv else f"{t:.3g} s"


def frame_label(bracket: Bracket | None, k: int) -> str:
    """``frame k (1/15 s, ISO 250)`` from the bracket's metadata (``frame k`` without it)."""
    if bracket is None or not 0 <= k < len(bracket.frames):
        return f"frame {k}"
    f = bracket.frames[k]
    parts = [_time_text(f.exposure_time)]
    iso = getattr(f.meta, "iso", None)
    if iso:
        parts.append(f"ISO {iso}")
    inner = ", ".join(p for p in parts if p)
    return f"frame {k} ({inner})" if inner else f"frame {k}"


def _pct(gain: float | None) -> float | None:
    return None if gain is None or not math.isfinite(gain) else 100.0 * (gain - 1.0)


def _se_pct(se: float | None) -> float | None:
    """A standard error in ln units as a percentage of the gain."""
    return None if se is None or not math.isfinite(se) else 100.0 * math.expm1(se)


def _state(wb: dict[str, Any], k: int) -> str:
    """What was done with frame ``k``'s balance, in a few words."""
    if k == wb["reference"]:
        return "reference"
    if k in wb.get("unmeasured", ()):
        return "not measured"
    if wb.get("applied"):
        # FrameBalance.correction(): every measured frame is divided out once one differs
        return "differs: corrected" if k in wb.get("differs", ()) else "corrected"
    if k in wb.get("differs", ()):
        return "differs: measured only (switch off)"
    return "within the threshold, not corrected"


def verdict(wb: dict[str, Any], k: int, label: str) -> str:
    """One sentence on frame ``k``'s balance: ``frame 0 (1/15 s) is 14.5 % bluer and 3.8 %
    less red than the reference; corrected``."""
    ref = wb["reference"]
    if k == ref:
        return f"{label} is the reference: the other frames' colours are matched to it."
    if k in wb.get("unmeasured", ()):
        return (
            f"{label}: white balance not measured (too few pixels well exposed in it and its "
            "neighbour, or a difference that changes with the level: the response's, not a "
            "balance); left as it is."
        )
    r, _, b = wb["gains"][k]
    words = []
    for gain, more, less in ((b, "bluer", "yellower (less blue)"), (r, "redder", "less red")):
        p = _pct(gain)
        if p is not None and abs(p) >= 100 * SAME:
            words.append(f"{abs(p):.1f} % {more if p > 0 else less}")
    if not words:
        body = f"{label} has the reference's white balance (within {100 * SAME:.0f} %)"
    else:
        body = f"{label} is " + " and ".join(words) + " than the reference"
    state = _state(wb, k)
    tail = {
        "differs: corrected": "corrected (divided out of the merge)",
        "corrected": "corrected with the others (divided out of the merge)",
        "differs: measured only (switch off)": "not corrected: the White balance switch is off",
        "within the threshold, not corrected": (
            f"within the {100 * wb.get('threshold', 0.03):.0f} % threshold, not corrected"
            if words
            else "not corrected"
        ),
    }[state]
    return f"{body}; {tail}."


def frame_rows(wb: dict[str, Any], bracket: Bracket | None) -> list[list[object]]:
    """Per frame: label, R/G and B/G gain differences (%) with their standard errors, state."""
    rows: list[list[object]] = []
    for k, (g, s) in enumerate(zip(wb["gains"], wb["std_error"], strict=True)):
        cells: list[object] = [frame_label(bracket, k)]
        for c in (0, 2):
            p, e = _pct(g[c]), _se_pct(s[c])
            if p is None:
                cells.append(None)
            elif k == wb["reference"]:
                cells.append("0 (reference)")
            else:
                cells.append(f"{p:+.1f} ± {e:.1f}" if e is not None else f"{p:+.1f}")
        cells.append(_state(wb, k))
        rows.append(cells)
    return rows


def white_balance_markdown(wb: dict[str, Any], bracket: Bracket | None) -> str:
    """The summary, the per-frame table and the per-frame verdicts."""
    ref = wb["reference"]
    n = len(wb["gains"])
    switch = (
        "divided out of the merge"
        if wb.get("applied")
        else (
            "**measured only**: the White balance switch is off"
            if wb.get("differs")
            else "nothing to correct"
        )
    )
    head = (
        f"**White balance per frame** against reference {frame_label(bracket, ref)}: "
        f"{len(wb.get('differs', ()))} of {n - 1} other frames differ by more than "
        f"{100 * wb.get('threshold', 0.03):.0f} % (and three standard errors); {switch}."
    )
    drift = wb.get("drift") or [1.0, 1.0, 1.0]
    extra = ""
    lim = math.log1p(wb.get("threshold", 0.03))
    if any(v is not None and abs(math.log(v)) > lim for v in drift):
        extra = (
            f"\n\nEvery consecutive pair shifts the balance alike (R/G x{drift[0]:.3f}, "
            f"B/G x{drift[2]:.3f} a pair): the response's channels, taken out of the gains "
            "and not corrected."
        )
    table = md_table(
        ["frame", "R/G vs reference (%)", "B/G vs reference (%)", "state"],
        frame_rows(wb, bracket),
    )
    lines = "\n".join(f"- {verdict(wb, k, frame_label(bracket, k))}" for k in range(n))
    return f"{head}{extra}\n\n{table}\n\n{lines}\n\n{ERROR_NOTE}"


def gains_figure(wb: dict[str, Any], bracket: Bracket | None) -> go.Figure:
    """R/G and B/G gain differences (%) per frame with one-standard-error bars and the
    correction threshold."""
    n = len(wb["gains"])
    times = [] if bracket is None else list(bracket.exposure_times)
    x = [
        f"{k}<br>{_time_text(times[k])}" if k < len(times) and times[k] else str(k)
        for k in range(n)
    ]
    thr = 100 * wb.get("threshold", 0.03)
    data: list[dict[str, Any]] = []
    for c, name, colour in ((0, "R/G", "#d62728"), (2, "B/G", "#1f77b4")):
        data.append(
            {
                "type": "scatter",
                "mode": "markers+lines",
                "x": x,
                "y": [_pct(g[c]) for g in wb["gains"]],
                "error_y": {
                    "type": "data",
                    "array": [_se_pct(s[c]) or 0.0 for s in wb["std_error"]],
                    "visible": True,
                },
                "name": name,
                "line": {"color": colour, "width": 1},
                "marker": {"color": colour, "size": 8},
            }
        )
    for y in (thr, -thr):
        data.append(
            {
                "type": "scatter",
                "mode": "lines",
                "x": [x[0], x[-1]],
                "y": [y, y],
                "name": f"±{thr:.0f} % threshold",
                "showlegend": y > 0,
                "line": {"color": "#888888", "dash": "dash", "width": 1},
                "hoverinfo": "skip",
            }
        )
    title = "White balance vs the reference" + (
        " (divided out)" if wb.get("applied") else " (not divided out)"
    )
    return go.Figure(
        {
            "data": data,
            "layout": {
                "title": {"text": title, "font": {"size": 14}},
                "xaxis": {"title": {"text": "frame (exposure)"}, "type": "category"},
                "yaxis": {"title": {"text": "gain difference (%)"}, "zeroline": True},
                "margin": {"l": 60, "r": 10, "t": 40, "b": 45},
                "template": "plotly_white",
                "legend": {"orientation": "h", "y": -0.3},
            },
        },
        _validate=False,
    )


class WhiteBalancePanel:
    """Plot, table and verdicts of the frames' white balance (hidden for RAW input)."""

    def __init__(self, gui: viser.GuiApi) -> None:
        self.plot = gui.add_plotly(EMPTY_PLOT, aspect=0.5, visible=False)  # height / width
        self.text = gui.add_markdown("")
        self.figure: go.Figure | None = None

    def show(self, bracket: Bracket | None, result: PipelineResult | None) -> None:
        wb = balance_of(result)
        self.figure = None
        if wb is None:
            self.plot.visible = False
            self.text.content = (
                ""
                if result is None or bracket is None or bracket.is_linear
                else "_White balance: waiting for the merge stage._"
            )
            return
        self.figure = gains_figure(wb, bracket)
        self.plot.figure = self.figure
        self.plot.visible = True
        self.text.content = white_balance_markdown(wb, bracket)
