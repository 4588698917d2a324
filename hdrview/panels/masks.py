"""Masks panel: for both frames of the chosen pair, which pixels' levels became inlier equations
of system S0 (Cerman & Hlavac 2006, eq. 4), which were 3V outliers, which are saturated (at or
above ``Z``) and which lie under the noise floor, each in its own colour.

The classes come from the exposure result's own equations (their level, direction, channel and
inlier flag) and its ``saturation`` and ``noise_floor``; this module only looks each pixel's level
up in that table. (A per-level class table on the result object would remove even that lookup.)
"""

from __future__ import annotations

from typing import Any

import numpy as np
import viser

from hdrcore.io import encode_png

from ._access import histogram_exposure_of
from ._draw import DISPLAY_WIDTH, enlarge, labels_to_rgb, shrink

__all__ = ["MasksPanel", "CLASSES", "PALETTE", "level_classes", "pixel_classes"]

FORWARD, INVERSE = 0, 1  # hdrcore.exposure.result direction codes
# Class codes, in increasing priority when channels disagree.
UNUSED, INLIER, OUTLIER, UNDER, SATURATED = 0, 1, 2, 3, 4
CLASSES = ("not used", "inlier", "outlier (3V)", "under noise floor", "saturated (≥ Z)")
PALETTE = ((110, 110, 110), (46, 160, 67), (255, 127, 14), (31, 119, 180), (214, 39, 40))
_PRIORITY = np.array([1, 0, 2, 3, 4])  # inlier < not used < outlier < under < saturated
_BY_PRIORITY = np.argsort(_PRIORITY)


def level_classes(pair: Any, which: str) -> np.ndarray:
    """``(C, max_level + 1)`` class of every level of the dark or bright frame of ``pair``."""
    direction = FORWARD if which == "dark" else INVERSE
    eq = pair.equations
    n_ch = len(pair.btfs) if pair.btfs else int(np.max(eq.channel, initial=0)) + 1
    n = int(pair.max_level) + 1
    levels = np.arange(n)
    table = np.full((n_ch, n), UNUSED, np.int8)
    sel = np.asarray(eq.direction) == direction
    idx = np.clip(np.floor(np.asarray(eq.level)[sel]).astype(np.int64), 0, n - 1)
    ch = np.asarray(eq.channel)[sel].astype(np.int64)
    inl = np.asarray(pair.inlier_mask, bool)[sel]
    table[ch, idx] = np.where(inl, INLIER, OUTLIER)
    # A level at or above Z is clipped and one at or below the floor is noise, whatever
    # equation ends there (an interpolated level can reach the top bin).
    table[:, levels <= pair.noise_floor] = UNDER
    table[:, levels >= pair.saturation] = SATURATED
    return table


def pixel_classes(levels: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Class per pixel of ``(h, w, C)`` levels: the highest-priority class of its channels."""
    n = table.shape[1]
    lv = np.minimum(levels, n - 1)
    per_channel = np.stack(
        [_PRIORITY[table[min(c, table.shape[0] - 1)][lv[..., c]]] for c in range(lv.shape[2])],
        axis=-1,
    )
    return _BY_PRIORITY[per_channel.max(axis=-1)].astype(np.int8)


class MasksPanel:
    """Legend with class fractions and one class image per frame of the pair."""

    def __init__(self, gui: viser.GuiApi) -> None:
        self._gui = gui
        self.summary = gui.add_markdown("No bracket loaded.")
        blank = np.zeros((4, 4, 3), np.uint8)
        self.dark = gui.add_image(blank, label="dark frame", format="png", visible=False)
        self.bright = gui.add_image(blank, label="bright frame", format="png", visible=False)
        self._small: dict[int, np.ndarray] = {}
        self._bracket_id: int | None = None
        self._images: dict[str, np.ndarray] = {}

    def _small_levels(self, bracket: Any, k: int) -> np.ndarray:
        if self._bracket_id != id(bracket):
            self._small = {}
            self._bracket_id = id(bracket)
        if k not in self._small:
            self._small[k] = shrink(bracket.frames[k].levels, DISPLAY_WIDTH)
        return self._small[k]

    def show(self, bracket: Any, result: Any, view: dict) -> None:
        exposure = histogram_exposure_of(result)
        if bracket is None or exposure is None:
            self.summary.content = ("No bracket loaded." if bracket is None else
                                    "_Waiting for the exposure-ratio stage (hdrcore.pipeline)._")
            self.dark.visible = self.bright.visible = False
            self._images = {}
            return
        k = min(int(view.get("pair", 0)), len(exposure.pairs) - 1)
        pair = exposure.pairs[k]
        rows = []
        images = {}
        for which, handle, frame in (("dark", self.dark, pair.dark),
                                     ("bright", self.bright, pair.bright)):
            classes = pixel_classes(self._small_levels(bracket, frame), level_classes(pair, which))
            rgb = labels_to_rgb(classes, PALETTE)
            images[f"mask-{which}-frame{frame}"] = rgb
            handle.image = enlarge(rgb)
            handle.label = f"{which} frame {frame}: {bracket.frames[frame].name}"
            handle.visible = True
            counts = np.bincount(classes.ravel(), minlength=len(CLASSES)) / classes.size
            rows.append((which, frame, counts))
        legend = " · ".join(
            f"<span style='color:rgb{PALETTE[c]}'>■</span> {name}" for c, name in enumerate(CLASSES)
        )
        table = ["| frame | " + " | ".join(CLASSES) + " |", "|---" * (len(CLASSES) + 1) + "|"]
        for which, frame, counts in rows:
            table.append(f"| {which} {frame} | " + " | ".join(f"{v:.1%}" for v in counts) + " |")
        self.summary.content = (
            f"**Pair {pair.dark}→{pair.bright}**: Z = {pair.saturation:g}, noise floor = "
            f"{pair.noise_floor:g}. A pixel takes the most severe class of its channels.\n\n"
            + legend + "\n\n" + "\n".join(table)
        )
        self._images = images

    def bundle_files(self) -> list[tuple[str, bytes]]:
        return [(f"{name}.png", encode_png(img)) for name, img in self._images.items()]
