"""Result panel: the tonemapped preview with an exposure control and an operator choice, and the
merge's diagnostic layers: provenance (which frame each pixel came from), clipping and ghosts.
Everything drawn comes from the pipeline's preview and :class:`hdrcore.merge.MergeResult`.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import viser

from hdrcore.errors import InputError
from hdrcore.io import encode_png, write_exr

from ._access import merge_of, preview_of
from ._draw import DISPLAY_WIDTH, display_step, enlarge, labels_to_rgb, unit_to_display

__all__ = ["ResultPanel", "LAYERS", "FRAME_COLOURS", "exr_bytes", "preview_png_bytes"]

LAYERS = ("tonemapped", "provenance", "clipping", "ghosts", "deghosted")

_MASK_LAYERS = {  # layer -> (MergeResult attribute, colour, what it shows)
    "clipping": ("clipped", (255, 0, 0), "clipped in every frame (value is a lower bound)"),
    "ghosts": ("ghost", (255, 0, 255), "ghosts: aligned frames disagree beyond their noise"),
    "deghosted": ("deghosted", (0, 200, 255),
                  "deghosted: filled from one frame (the best exposed in its ghost region)"),
}
FRAME_COLOURS = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
                 (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207))


def _dim(preview: np.ndarray) -> np.ndarray:
    """The preview in grey at half brightness, as a backdrop for a mask."""
    grey = preview.astype(np.float32).mean(axis=2, keepdims=True) * 0.5
    return np.repeat(grey, 3, axis=2)


def _paint(backdrop: np.ndarray, mask: np.ndarray, colour: tuple[int, int, int]) -> np.ndarray:
    out = backdrop.copy()
    out[mask] = colour
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def _fit(a: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    return a[: shape[0], : shape[1]]


class ResultPanel:
    """The preview or one diagnostic layer, with its legend."""

    def __init__(self, gui: viser.GuiApi) -> None:
        self._gui = gui
        self.summary = gui.add_markdown("No bracket loaded.")
        self.image = gui.add_image(np.zeros((4, 4, 3), np.uint8), label="result", format="jpeg",
                                   visible=False)
        self._images: dict[str, np.ndarray] = {}

    def show(self, bracket: Any, result: Any, view: dict) -> None:
        merged = merge_of(result)
        preview = preview_of(result)
        if bracket is None or (merged is None and preview is None):
            self.summary.content = (
                "No bracket loaded." if bracket is None else
                "_Waiting for the merge and tonemap stages (hdrcore.pipeline)._")
            self.image.visible = False
            self._images = {}
            return
        layer = view.get("layer", LAYERS[0])
        shown = unit_to_display(np.asarray(preview)) if preview is not None else None
        images: dict[str, np.ndarray] = {}
        if shown is not None:
            images["preview"] = shown
        lines = []
        if merged is not None:
            s = merged.summary() if hasattr(merged, "summary") else {}
            lines.append(
                f"Merge **{merged.status}**: {merged.message}. Weighting {merged.weighting}; "
                f"clipped {s.get('clipped_fraction', 0):.2%}, under the noise floor "
                f"{s.get('underexposed_fraction', 0):.2%}, ghosts {s.get('ghost_fraction', 0):.2%}"
                " of the pixels."
                + (f" Deghosted {s['deghosted_fraction']:.2%}."
                   if s.get("deghosted_fraction") is not None else "")
            )
        if layer == "deghosted" and merged is not None and getattr(
                merged, "deghosted", None) is None:
            lines.append("_Layer deghosted: tick Deghost (Parameters) to fill each ghost region "
                         "from one frame._")
        elif layer != "tonemapped" and merged is not None:
            step = display_step(merged.shape, DISPLAY_WIDTH)
            backdrop = _dim(shown) if shown is not None else None
            if layer == "provenance":
                from hdrcore.merge import dominant_frame  # lazy: colour is slow to import

                dom = dominant_frame(merged.shares[:, ::step, ::step])
                layer_img = labels_to_rgb(dom, FRAME_COLOURS, width=10**9)
                legend = " · ".join(
                    f"<span style='color:rgb{FRAME_COLOURS[k % 10]}'>■</span> frame {k}"
                    for k in range(merged.n_frames))
                lines.append("Provenance: the frame with the largest weight at each pixel. "
                             + legend)
            else:
                attr, colour, what = _MASK_LAYERS[layer]
                mask = getattr(merged, attr)
                small = np.asarray(mask[::step, ::step], bool)
                if backdrop is None:
                    backdrop = np.full((*small.shape, 3), 40.0, np.float32)
                small = _fit(small, backdrop.shape)
                backdrop = _fit(backdrop, small.shape)
                layer_img = _paint(backdrop, small, colour)
                lines.append(f"<span style='color:rgb{colour}'>■</span> {what}: "
                             f"{np.count_nonzero(mask) / max(mask.size, 1):.2%} of the pixels")
            images[layer] = layer_img
            shown = layer_img
        elif layer != "tonemapped":
            lines.append(f"_Layer {layer} needs the merge result._")
        self.summary.content = "\n\n".join(lines) if lines else "Tonemapped preview."
        if shown is not None:
            self.image.image = enlarge(shown)
            self.image.label = f"{layer}"
            self.image.visible = True
        self._images = images

    def bundle_files(self) -> list[tuple[str, bytes]]:
        return [(f"result-{name}.png", encode_png(img)) for name, img in self._images.items()]


def exr_bytes(result: Any, work_dir: str | Path | None = None) -> bytes:
    """The merged radiance as OpenEXR (half float) bytes (written through a temporary file in
    ``work_dir``, the inspector's own temporary folder, removed when it stops)."""
    merged = merge_of(result)
    radiance = getattr(result, "radiance", None)  # the pipeline's colour-converted radiance
    if radiance is None and merged is not None:
        radiance = merged.radiance
    if radiance is None:
        raise InputError("the merged HDR is not available yet")
    times = getattr(result, "exposure_times", None) or getattr(merged, "exposure_times", None)
    with tempfile.TemporaryDirectory(prefix="exr-", dir=work_dir) as tmp:
        path = Path(tmp) / "merged.exr"
        write_exr(path, radiance, exposure_times=times)
        return path.read_bytes()


def preview_png_bytes(result: Any) -> bytes:
    """The tonemapped preview as 8-bit PNG bytes."""
    preview = preview_of(result)
    if preview is None:
        raise InputError("the preview is not available yet")
    arr = np.asarray(preview)
    if arr.dtype != np.uint8:
        arr = np.clip(arr.astype(np.float32) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return encode_png(arr)
