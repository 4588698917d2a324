"""Masks panel: for both frames of the chosen pair, which pixels' levels became inlier equations
of system S0 (Cerman & Hlavac 2006, eq. 4), which were 3V outliers, which are saturated (at or
above ``Z``) and which lie under the noise floor, each in its own colour.

The classes of each level come from the exposure result
(:meth:`hdrcore.exposure.ExposureRatioResult.level_classes`: its equations' levels, directions,
channels and inlier flags, its ``saturation`` and ``noise_floor``); this module only looks each
pixel's level up in that table.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import viser

from hdrcore.io import Bracket, encode_png

from ._draw import DISPLAY_WIDTH, enlarge, labels_to_rgb, shrink

if TYPE_CHECKING:
    from hdrcore.pipeline import PipelineResult

__all__ = ["MasksPanel", "PALETTE", "pixel_classes"]

# colour of each class of hdrcore.exposure.result.LEVEL_CLASSES, by code
PALETTE = ((110, 110, 110), (46, 160, 67), (255, 127, 14), (31, 119, 180), (214, 39, 40))
# Severity of each class (the table's codes in order): breaks a tie between channels
_PRIORITY = np.array([1, 0, 2, 3, 4])  # inlier < not used < outlier < under < saturated


def pixel_classes(levels: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Class per pixel of ``(h, w, C)`` levels: saturated when any channel is (the merge drops
    the pixel's frame there), else the class most of its channels are in, a tie going to the
    more severe class. (The most severe channel alone painted the Xperia's first pair all
    outlier, 0.0 % inliers, beside 430 of 1285 equations kept: its blue channel's levels are
    mostly 3V outliers, red and green mostly inliers.)"""
    from hdrcore.exposure.result import SATURATED

    n = table.shape[1]
    lv = np.minimum(levels, n - 1)
    nch = lv.shape[2]
    per = [table[min(c, table.shape[0] - 1)][lv[..., c]] for c in range(nch)]
    n_cls = len(_PRIORITY)
    # score: votes x (classes + 1) + severity, so the most votes win and severity breaks ties
    best = np.full(lv.shape[:2], -1, np.int32)
    out = np.zeros(lv.shape[:2], np.int8)
    for cls in range(n_cls):
        votes = sum((ch == cls).astype(np.int32) for ch in per)
        score = np.where(votes > 0, votes * (n_cls + 1) + int(_PRIORITY[cls]), -1)
        better = score > best
        best = np.where(better, score, best)
        out[better] = cls
    clipped = np.zeros(lv.shape[:2], bool)
    for ch in per:
        clipped |= ch == SATURATED
    out[clipped] = SATURATED
    return out


def equation_counts(pair: Any, channels: int) -> str:
    """The pair's equations kept by the 3V rule, in all and per channel (the BTF tab's and
    the Diagnostics tab's count of the same estimate)."""
    inl = np.asarray(pair.inlier_mask, bool)
    ch = np.asarray(pair.equations.channel).astype(np.int64)
    names = ("R", "G", "B") if channels == 3 else tuple(f"channel {c}" for c in range(channels))
    per = ", ".join(
        f"{names[c]} {int(np.count_nonzero(inl[ch == c]))}/{int(np.count_nonzero(ch == c))}"
        for c in range(channels)
        if np.any(ch == c)
    )
    return f"{pair.n_inliers} of {pair.n_equations} equations kept by the 3V rule ({per})"


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
        # what is on the page: (bracket, pair index, the pair's ratio result), held so that
        # identity says "the same" (the full result after the quick one shares its ratios)
        self._drawn: tuple[Any, int, Any] | None = None

    def _small_levels(self, bracket: Bracket, k: int) -> np.ndarray:
        if self._bracket_id != id(bracket):
            self._small = {}
            self._bracket_id = id(bracket)
        if k not in self._small:
            self._small[k] = shrink(bracket.frames[k].levels, DISPLAY_WIDTH)
        return self._small[k]

    def show(
        self, bracket: Bracket | None, result: PipelineResult | None, view: dict[str, Any]
    ) -> None:
        # the histogram estimate (eq. 4's equations), even when the ratios the merge used were
        # measured again after registration
        exposure = None if result is None else result.exposures_histogram
        if bracket is None or exposure is None:
            self.summary.content = (
                "No bracket loaded."
                if bracket is None
                else "_Waiting for the exposure-ratio stage (hdrcore.pipeline)._"
            )
            self.dark.visible = self.bright.visible = False
            self._images = {}
            self._drawn = None
            return
        from hdrcore.exposure.result import LEVEL_CLASSES as CLASSES

        k = min(int(view.get("pair", 0)), len(exposure.pairs) - 1)
        pair = exposure.pairs[k]
        drawn = self._drawn
        if drawn is not None and drawn[0] is bracket and drawn[1] == k and drawn[2] is pair:
            return  # on the page already (0.02 s at 24 MP)
        rows = []
        images = {}
        sides: tuple[tuple[Literal["dark", "bright"], viser.GuiImageHandle, int], ...] = (
            ("dark", self.dark, pair.dark),
            ("bright", self.bright, pair.bright),
        )
        for which, handle, frame in sides:
            classes = pixel_classes(self._small_levels(bracket, frame), pair.level_classes(which))
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
        table = ["| frame | " + " | ".join(CLASSES) + " |", "|---" + "|:---:" * len(CLASSES) + "|"]
        for which, frame, counts in rows:
            table.append(f"| {which} {frame} | " + " | ".join(f"{v:.1%}" for v in counts) + " |")
        self.summary.content = (
            f"**Pair {pair.dark}→{pair.bright}**: Z = {pair.saturation:g}, noise floor = "
            f"{pair.noise_floor:g}; the histogram estimate (the BTF tab's): "
            f"{equation_counts(pair, len(pair.channel_ratios) or 1)}. A pixel shows the class "
            "most of its channels are in (saturated if any is).\n\n"
            + legend
            + "\n\n"
            + "\n".join(table)
        )
        self._images = images
        self._drawn = (bracket, k, pair)

    def bundle_files(self) -> list[tuple[str, bytes]]:
        return [(f"{name}.png", encode_png(img)) for name, img in self._images.items()]
