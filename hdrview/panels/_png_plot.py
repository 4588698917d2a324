"""Render the inspector's plotly figures to PNG with Pillow, for the diagnostics bundle.

plotly's own image export needs kaleido and a browser; a bug report should not. This draws what
the panels use: scatter traces as markers and/or lines, linear or log axes, a title, axis titles
and a legend. It is a picture for a bug report, not a plotting library.
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from PIL import Image, ImageColor, ImageDraw, ImageFont

__all__ = ["figure_to_png"]

_PALETTE = ["#636efa", "#ef553b", "#00cc96", "#ab63fa", "#ffa15a", "#19d3f3", "#ff6692"]


def _colour(value: Any, index: int) -> tuple[int, int, int]:
    if isinstance(value, str):
        try:
            rgb = ImageColor.getrgb(value.replace(" ", ""))
            return int(rgb[0]), int(rgb[1]), int(rgb[2])
        except ValueError:
            pass
    return ImageColor.getrgb(_PALETTE[index % len(_PALETTE)])[:3]


def _values(v: Any) -> np.ndarray | None:
    if v is None:
        return None
    try:
        arr = np.asarray(v, dtype=float).ravel()
    except (TypeError, ValueError):
        return None
    return arr if arr.size else None


def _ticks(lo: float, hi: float, n: int = 5) -> list[float]:
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return [lo]
    step = 10 ** math.floor(math.log10((hi - lo) / n))
    for m in (1, 2, 5, 10):
        if (hi - lo) / (step * m) <= n:
            step *= m
            break
    start = math.ceil(lo / step) * step
    return [start + k * step for k in range(int((hi - start) / step) + 1)]


def _axis(fig: Any, name: str) -> tuple[bool, str, Sequence[float] | None]:
    ax = getattr(fig.layout, name, None)
    log = bool(ax is not None and getattr(ax, "type", None) == "log")
    title = ""
    if ax is not None and ax.title is not None and ax.title.text:
        title = str(ax.title.text)
    rng = None if ax is None or ax.range is None else tuple(ax.range)
    return log, title, rng


def figure_to_png(fig: Any, width: int = 960, height: int = 600) -> bytes:
    """PNG bytes of a plotly figure's scatter traces."""
    font = ImageFont.load_default()
    img = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(img)
    left, right, top, bottom = 80, width - 200, 40, height - 60
    xlog, xtitle, xr = _axis(fig, "xaxis")
    ylog, ytitle, yr = _axis(fig, "yaxis")

    traces = []
    for i, tr in enumerate(fig.data):
        x, y = _values(getattr(tr, "x", None)), _values(getattr(tr, "y", None))
        if y is None:
            continue
        if x is None:
            x = np.arange(y.size, dtype=float)
        n = min(x.size, y.size)
        x, y = x[:n], y[:n]
        if xlog:
            x = np.where(x > 0, np.log10(np.where(x > 0, x, 1)), np.nan)
        if ylog:
            y = np.where(y > 0, np.log10(np.where(y > 0, y, 1)), np.nan)
        mode = str(getattr(tr, "mode", None) or "markers")
        marker = getattr(tr, "marker", None)
        line = getattr(tr, "line", None)
        colour = None
        if marker is not None and isinstance(marker.color, str):
            colour = marker.color
        elif line is not None and isinstance(line.color, str):
            colour = line.color
        symbol = str(getattr(marker, "symbol", "") or "") if marker is not None else ""
        traces.append((x, y, mode, _colour(colour, i), str(tr.name or f"trace {i}"), symbol))

    allx = np.concatenate([t[0] for t in traces]) if traces else np.array([0.0, 1.0])
    ally = np.concatenate([t[1] for t in traces]) if traces else np.array([0.0, 1.0])
    allx, ally = allx[np.isfinite(allx)], ally[np.isfinite(ally)]
    x0, x1 = xr if xr else (allx.min(), allx.max()) if allx.size else (0.0, 1.0)
    y0, y1 = yr if yr else (ally.min(), ally.max()) if ally.size else (0.0, 1.0)
    if x1 <= x0:
        x1 = x0 + 1.0
    if y1 <= y0:
        y1 = y0 + 1.0

    def px(xv: np.ndarray) -> np.ndarray:
        return left + (xv - x0) / (x1 - x0) * (right - left)

    def py(yv: np.ndarray) -> np.ndarray:
        return bottom - (yv - y0) / (y1 - y0) * (bottom - top)

    draw.rectangle([left, top, right, bottom], outline="black")
    for t in _ticks(x0, x1):
        xp = float(px(np.array(t)))
        draw.line([xp, bottom, xp, bottom + 4], fill="black")
        label = f"{10**t:.3g}" if xlog else f"{t:.3g}"
        draw.text((xp - 12, bottom + 6), label, fill="black", font=font)
    for t in _ticks(y0, y1):
        yp = float(py(np.array(t)))
        draw.line([left - 4, yp, left, yp], fill="black")
        label = f"{10**t:.3g}" if ylog else f"{t:.3g}"
        draw.text((left - 60, yp - 5), label, fill="black", font=font)
    title = ""
    if fig.layout.title is not None and fig.layout.title.text:
        title = str(fig.layout.title.text)
    title = title.replace("\u2192", "->").replace("\u2014", "-")
    draw.text((left, 12), title[:140], fill="black", font=font)
    draw.text(((left + right) // 2 - 40, height - 30), xtitle[:60], fill="black", font=font)
    draw.text((6, top - 20), ytitle[:60], fill="black", font=font)

    for k, (x, y, mode, col, name, symbol) in enumerate(traces):
        ok = np.isfinite(x) & np.isfinite(y) & (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
        xs, ys = px(x), py(y)
        if "lines" in mode:
            pts = [(float(a), float(b)) for a, b, o in zip(xs, ys, ok, strict=True) if o]
            if len(pts) >= 2:
                draw.line(pts, fill=col, width=2)
        if "markers" in mode:
            step = max(1, int(ok.sum() // 20000))
            for a, b in zip(xs[ok][::step], ys[ok][::step], strict=True):
                if symbol.startswith("x"):
                    draw.line([a - 2, b - 2, a + 2, b + 2], fill=col)
                    draw.line([a - 2, b + 2, a + 2, b - 2], fill=col)
                else:
                    draw.ellipse([a - 1.5, b - 1.5, a + 1.5, b + 1.5], fill=col)
        ly = top + 14 * k
        draw.rectangle([right + 10, ly + 2, right + 20, ly + 10], fill=col)
        draw.text((right + 26, ly), name[:28], fill="black", font=font)

    buf = io.BytesIO()
    img.save(buf, format="PNG")
    return buf.getvalue()
