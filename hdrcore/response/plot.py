"""Response curves drawn into a PNG with Pillow (no plotting library is a dependency).

One panel per colour channel (levels on x, normalised linear exposure ``g`` on y), every curve
in its own colour with a legend; a single curve is drawn in one panel with the channel colours.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from ..errors import ParameterError
from .curve import ResponseCurve

__all__ = ["plot_curves", "render_curves"]

_PALETTE = [
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
]
_CHANNEL_COLOURS = [(200, 30, 30), (20, 140, 20), (30, 60, 220)]


def _font(size: int) -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1
        return ImageFont.load_default()


def _panel(
    draw: ImageDraw.ImageDraw,
    box: tuple[int, int, int, int],
    title: str,
    series: list[tuple[np.ndarray, np.ndarray, tuple[int, int, int], int]],
    max_level: int,
    font,
    small,
    y_max: float = 1.0,
) -> None:
    x0, y0, x1, y1 = box
    left, bottom, top, right = x0 + 48, y1 - 34, y0 + 26, x1 - 22
    draw.text(((x0 + x1) // 2, y0 + 4), title, fill=(0, 0, 0), font=font, anchor="ma")
    for k in range(6):
        f = k / 5
        gx = left + f * (right - left)
        gy = bottom - f * (bottom - top)
        draw.line([(gx, top), (gx, bottom)], fill=(225, 225, 225))
        draw.line([(left, gy), (right, gy)], fill=(225, 225, 225))
        draw.text(
            (gx, bottom + 4), f"{round(f * max_level)}", fill=(60, 60, 60), font=small, anchor="ma"
        )
        draw.text((left - 4, gy), f"{f * y_max:.2g}", fill=(60, 60, 60), font=small, anchor="rm")
    draw.rectangle([left, top, right, bottom], outline=(0, 0, 0))
    draw.text(((left + right) // 2, y1 - 14), "level", fill=(0, 0, 0), font=small, anchor="ma")
    for lv, g, colour, width in series:
        px = left + (lv / max(lv[-1], 1)) * (right - left)
        py = bottom - np.clip(g / y_max, 0, 1) * (bottom - top)
        draw.line(list(zip(px.tolist(), py.tolist(), strict=True)), fill=colour, width=width)


def render_curves(
    curves: Sequence[tuple[ResponseCurve, str]],
    *,
    title: str = "camera response",
    panel_size: tuple[int, int] = (420, 380),
) -> Image.Image:
    """An RGB image of the curves (see module docstring).

    A curve may be any object with ``g`` ``(C, L)``, ``levels``, ``max_level``, ``n_channels``
    and ``channel_names`` (e.g. a peer's unnormalised curve in a benchmark); the y axis extends
    up to 2 to show values above 1.
    """
    if not curves:
        raise ParameterError("nothing to plot", expected="at least one response curve")
    font, small = _font(15), _font(12)
    single = len(curves) == 1
    n_panels = 1 if single else max(c.n_channels for c, _ in curves)
    pw, ph = panel_size
    legend_h = 22 * (len(curves) if not single else curves[0][0].n_channels) + 10
    img = Image.new("RGB", (pw * n_panels, ph + 30 + legend_h), "white")
    draw = ImageDraw.Draw(img)
    draw.text((img.width // 2, 6), title, fill=(0, 0, 0), font=font, anchor="ma")
    legend: list[tuple[str, tuple[int, int, int]]] = []
    top = max(float(np.nanmax(c.g)) for c, _ in curves)
    y_max = 1.0 if top <= 1.0 + 1e-9 else min(2.0, float(np.ceil(top * 5) / 5))
    if single:
        curve, label = curves[0]
        series = []
        for c in range(curve.n_channels):
            colour = _CHANNEL_COLOURS[c] if curve.n_channels == 3 else _PALETTE[c % 10]
            series.append((curve.levels.astype(float), curve.g[c], colour, 2))
            legend.append((f"{label} {curve.channel_names[c]}", colour))
        _panel(draw, (0, 30, pw, 30 + ph), "g(level)", series, curve.max_level, font, small, y_max)
    else:
        for p in range(n_panels):
            series = []
            max_level = 1
            name = f"channel {p}"
            for i, (curve, _label) in enumerate(curves):
                c = min(p, curve.n_channels - 1)
                name = curve.channel_names[c]
                series.append((curve.levels / curve.max_level, curve.g[c], _PALETTE[i % 10], 2))
                max_level = max(max_level, curve.max_level)
            series = [(lv * max_level, g, col, w) for lv, g, col, w in series]
            _panel(
                draw,
                (p * pw, 30, (p + 1) * pw, 30 + ph),
                f"channel {name}",
                series,
                max_level,
                font,
                small,
                y_max,
            )
        legend = [(label, _PALETTE[i % 10]) for i, (_c, label) in enumerate(curves)]
    y = 30 + ph + 6
    for label, colour in legend:
        draw.line([(20, y + 8), (50, y + 8)], fill=colour, width=3)
        draw.text((58, y + 1), label, fill=(0, 0, 0), font=small)
        y += 22
    return img


def plot_curves(
    curves: Sequence[tuple[ResponseCurve, str]],
    path: str | os.PathLike,
    *,
    force: bool = False,
    title: str = "camera response",
    inputs: Sequence[str | os.PathLike] = (),
) -> Path:
    """Render the curves and write a PNG atomically (refuses to overwrite without ``force``)."""
    from ..io.atomic import atomic_write

    img = render_curves(curves, title=title)
    return atomic_write(path, lambda p: img.save(p, format="PNG"), force=force, inputs=inputs)
