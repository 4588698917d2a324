"""Display helpers shared by the panels: 8-bit RGB for ``add_image`` and small markdown tables.

Nothing here estimates anything: it shrinks arrays the core returned to screen size (by striding),
maps them to 8-bit colours for display, and formats numbers.
"""

from __future__ import annotations

import html
from collections.abc import Sequence

import numpy as np

__all__ = [
    "DISPLAY_WIDTH",
    "display_step",
    "shrink",
    "enlarge",
    "levels_to_display",
    "unit_to_display",
    "labels_to_rgb",
    "scalar_to_rgb",
    "md_table",
    "fmt",
]

DISPLAY_WIDTH = 640

# A perceptual-ish sequential palette (viridis key colours) for heat maps.
_VIRIDIS = np.array(
    [
        [68, 1, 84],
        [72, 40, 120],
        [62, 74, 137],
        [49, 104, 142],
        [38, 130, 142],
        [31, 158, 137],
        [53, 183, 121],
        [110, 206, 88],
        [181, 222, 43],
        [253, 231, 37],
    ],
    np.float32,
)


def display_step(shape: Sequence[int], width: int = DISPLAY_WIDTH) -> int:
    """Integer stride that brings an image of ``shape`` to at most ``width`` columns."""
    return max(1, int(np.ceil(int(shape[1]) / width)))


def shrink(image: np.ndarray, width: int = DISPLAY_WIDTH) -> np.ndarray:
    """Every n-th pixel so the image is at most ``width`` wide (display only)."""
    step = display_step(image.shape, width)
    return np.ascontiguousarray(image[::step, ::step])


def enlarge(image: np.ndarray, min_width: int = 480) -> np.ndarray:
    """Repeat pixels so a small image is at least ``min_width`` wide (display only)."""
    w = int(image.shape[1])
    factor = int(np.ceil(min_width / w)) if 0 < w < min_width else 1
    if factor == 1:
        return image
    return np.ascontiguousarray(np.repeat(np.repeat(image, factor, axis=0), factor, axis=1))


def _as_rgb(arr: np.ndarray) -> np.ndarray:
    if arr.ndim == 2:
        arr = np.repeat(arr[..., None], 3, axis=2)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise ValueError(f"expected an (H, W) or (H, W, 3) image, got {arr.shape}")
    return np.ascontiguousarray(arr)


def levels_to_display(
    levels: np.ndarray, max_level: int, *, linear: bool, width: int = DISPLAY_WIDTH
) -> np.ndarray:
    """8-bit RGB thumbnail of integer levels; linear (RAW) levels get a display gamma of 2.2.

    Only for looking at input frames: a 256-entry lookup table, no tone mapping.
    """
    small = shrink(levels, width)
    scale = 255.0 / max(1, int(max_level))
    if linear:
        lut_in = np.arange(int(max_level) + 1, dtype=np.float32) / max(1, int(max_level))
        lut = np.round(255.0 * np.power(lut_in, 1 / 2.2)).astype(np.uint8)
        return _as_rgb(lut[np.minimum(small, max_level)])
    return _as_rgb(np.clip(small.astype(np.float32) * scale + 0.5, 0, 255).astype(np.uint8))


def unit_to_display(image: np.ndarray, width: int = DISPLAY_WIDTH) -> np.ndarray:
    """8-bit RGB of an image with values in [0, 1] (or already uint8)."""
    small = shrink(np.asarray(image), width)
    if small.dtype == np.uint8:
        return _as_rgb(small)
    return _as_rgb(np.clip(small.astype(np.float32) * 255.0 + 0.5, 0, 255).astype(np.uint8))


def labels_to_rgb(
    labels: np.ndarray, palette: Sequence[tuple[int, int, int]], width: int = DISPLAY_WIDTH
) -> np.ndarray:
    """Colour an integer label image with ``palette[label]``."""
    small = shrink(np.asarray(labels), width)
    pal = np.asarray(palette, np.uint8)
    return np.ascontiguousarray(pal[np.clip(small.astype(np.int64), 0, len(pal) - 1)])


def scalar_to_rgb(
    values: np.ndarray,
    *,
    vmin: float | None = None,
    vmax: float | None = None,
    width: int = DISPLAY_WIDTH,
    invalid: tuple[int, int, int] = (128, 128, 128),
) -> np.ndarray:
    """Viridis colours of a scalar map; NaN shown in ``invalid`` grey."""
    small = shrink(np.asarray(values, np.float32), width)
    finite = np.isfinite(small)
    if not finite.any():
        return np.full((*small.shape[:2], 3), invalid, np.uint8)
    lo = float(np.nanmin(small[finite])) if vmin is None else float(vmin)
    hi = float(np.nanmax(small[finite])) if vmax is None else float(vmax)
    span = hi - lo if hi > lo else 1.0
    t = np.clip((np.where(finite, small, lo) - lo) / span, 0, 1) * (len(_VIRIDIS) - 1)
    i0 = np.floor(t).astype(np.int64)
    i1 = np.minimum(i0 + 1, len(_VIRIDIS) - 1)
    f = (t - i0)[..., None]
    rgb = _VIRIDIS[i0] * (1 - f) + _VIRIDIS[i1] * f
    out = np.round(rgb).astype(np.uint8)
    out[~finite] = invalid
    return out


def pct(value: float | None, digits: int = 1) -> str:
    """A fraction as a percentage (``—`` when missing or not finite: a pair never registered
    has no overlap, which read "nan%")."""
    if value is None or not np.isfinite(float(value)):
        return "—"
    return f"{float(value):.{digits}%}"


def fmt(value: object, digits: int = 4) -> str:
    """Short text for a table cell (``—`` for missing)."""
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, (float, np.floating)):
        v = float(value)
        if not np.isfinite(v):
            return "—"
        return f"{v:.{digits}g}"
    return esc(str(value)).replace("|", "\\|").replace("\n", " ")


def esc(text: str) -> str:
    """Text for the page's markdown, which renders raw HTML unsanitised (viser's
    ``rehypeRawDom``): ``&``, ``<`` and ``>`` as entities, which markdown shows as the
    characters. File and folder names reach the page this way; a name holding
    ``<img src=...>`` put 13 images on the page before."""
    return html.escape(text, quote=False)


def md_table(header: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    """A markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in rows:
        lines.append("| " + " | ".join(fmt(c) for c in row) + " |")
    return "\n".join(lines)


class _EmptyPlot:
    """What a panel's plot holds before its first figure: the JSON of an empty plot, without
    plotly (building plotly's ``Figure`` class took 0.1 s of the first page's build, before the
    page showed anything; the plots stay hidden until a figure is drawn)."""

    def to_json(self) -> str:
        return '{"data": [], "layout": {}}'


EMPTY_PLOT = _EmptyPlot()
