"""Result panel: the tonemapped preview with an exposure control and an operator choice, and the
merge's diagnostic layers: provenance (which frame each pixel came from), clipping and ghosts.
Everything drawn comes from the pipeline's preview and :class:`hdrcore.merge.MergeResult`.
"""

from __future__ import annotations

import html
import tempfile
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import viser

from hdrcore.errors import InputError
from hdrcore.export import write_result
from hdrcore.io import Bracket, encode_png

from ._draw import DISPLAY_WIDTH, display_step, enlarge, labels_to_rgb, unit_to_display

if TYPE_CHECKING:  # the pipeline is imported on first use (slow: numba), not with the page
    from hdrcore.pipeline import PipelineResult

__all__ = [
    "ResultPanel",
    "LAYERS",
    "ZOOMS",
    "FRAME_COLOURS",
    "exr_bytes",
    "preview_png_bytes",
    "loupe",
    "fit_to_box",
]

LAYERS = ("tonemapped", "provenance", "clipping", "ghosts", "deghosted")
ZOOMS = ("fit", "100 %", "200 %", "400 %")
BOX = (880, 620)  # (width, height) of the image area: a portrait frame fits without scrolling

_MASK_LAYERS = {  # layer -> (MergeResult attribute, colour, what it shows)
    "clipping": ("clipped", (255, 0, 0), "clipped in every frame (value is a lower bound)"),
    "ghosts": ("ghost", (255, 0, 255), "ghosts: aligned frames disagree beyond their noise"),
    "deghosted": (
        "deghosted",
        (0, 200, 255),
        "deghosted: filled from one frame (the best exposed in its ghost region)",
    ),
}
WEIGHTING_WORDS = {  # a merge weighting in a photographer's words, the paper's on hover
    "hat": ("each frame counted by how well exposed the pixel is", "Debevec & Malik's hat"),
    "gaussian": (
        "each frame counted by how near mid-grey the pixel is",
        "Robertson et al.'s Gaussian weight",
    ),
    "noise-aware": (
        "each frame counted by its noise (longer exposures count more)",
        "inverse-variance weight dt^2 / var, Granados et al. 2010",
    ),
    "hat-noise-aware": (
        "each frame counted by its noise and by how well exposed the pixel is",
        "Debevec & Malik's hat times the inverse variance dt^2 / var",
    ),
    "uniform": ("every frame counted alike", "uniform weight"),
}


def weighting_words(name: str) -> str:
    """The merge's weighting in words (a sentence's start), the paper's term and the name in a
    tooltip; an unknown weighting by its name."""
    words, paper = WEIGHTING_WORDS.get(name, (f"weighting {name}", f"weighting {name}"))
    title = html.escape(f"{paper} ({name})", quote=True)
    return f'<abbr title="{title}">{html.escape(words[:1].upper() + words[1:])}</abbr>'


FRAME_COLOURS = (
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
)


def _dim(preview: np.ndarray) -> np.ndarray:
    """The preview in grey at half brightness, as a backdrop for a mask."""
    grey = preview.astype(np.float32).mean(axis=2, keepdims=True) * 0.5
    return np.repeat(grey, 3, axis=2)


def _paint(backdrop: np.ndarray, mask: np.ndarray, colour: tuple[int, int, int]) -> np.ndarray:
    out = backdrop.copy()
    out[mask] = colour
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def _fit_width(preview: np.ndarray, width: int = BOX[0]) -> np.ndarray:
    """The preview resampled (Lanczos, not strided: no aliasing) to the image area's width."""
    from PIL import Image

    img = unit_to_display(preview, width=10**9)
    if img.shape[1] <= width:
        return img
    h = max(1, round(img.shape[0] * width / img.shape[1]))
    return np.asarray(Image.fromarray(img).resize((width, h), Image.Resampling.LANCZOS))


def fit_to_box(image: np.ndarray, box: tuple[int, int] = BOX) -> np.ndarray:
    """The whole image within ``box`` (width, height): a portrait frame is resampled (Lanczos,
    not strided: no aliasing) to the box's height and set on a neutral grey, so it never needs
    scrolling. (A stride of whole pixels showed the 512x768 memorial at 384 px of the 620.)"""
    from PIL import Image

    h, w = image.shape[:2]
    bw, bh = box
    if h <= bh or w >= h:
        return image
    sw = max(1, round(w * bh / h))
    small = np.asarray(
        Image.fromarray(np.ascontiguousarray(image)).resize((sw, bh), Image.Resampling.LANCZOS)
    )
    out = np.full((bh, max(sw, min(bw, w)), 3), 96, np.uint8)
    x0 = (out.shape[1] - sw) // 2
    out[:, x0 : x0 + sw] = small
    return out


def layer_loupe(
    merged: Any, layer: str, crop: np.ndarray, rect: tuple[int, int, int, int]
) -> np.ndarray:
    """A layer over a :func:`loupe` crop of the rectangle ``rect`` (``x0, y0, x1, y1`` in image
    pixels): a mask layer painted on the dimmed crop, the provenance as its frame colours; the
    full-resolution values, each pixel repeated as the crop repeats it."""
    x0, y0, x1, y1 = rect
    k = max(1, crop.shape[0] // max(1, y1 - y0))
    if layer == "provenance":
        from hdrcore.merge import dominant_frame  # lazy: colour is slow to import

        dom = dominant_frame(merged.shares[:, y0:y1, x0:x1])
        img = labels_to_rgb(dom, FRAME_COLOURS, width=10**9)
    else:
        attr, colour, _ = _MASK_LAYERS[layer]
        mask = np.asarray(getattr(merged, attr)[y0:y1, x0:x1], bool)
        backdrop = _dim(crop[::k, ::k])
        img = _paint(backdrop, mask, colour)
    if k > 1:
        img = np.repeat(np.repeat(img, k, axis=0), k, axis=1)
    return np.ascontiguousarray(img[: crop.shape[0], : crop.shape[1]])


def loupe(
    result: PipelineResult, zoom: float, cx: float, cy: float, box: tuple[int, int] = BOX
) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """A crop of the full-resolution radiance map at ``zoom`` screen pixels per image pixel
    (1 = 100 %), centred at ``(cx, cy)`` (fractions of the width and height), tonemapped with
    the preview's own operator and scale (so it matches the preview), pixels repeated for zooms
    above 100 %. Returns the image and the crop ``(x0, y0, x1, y1)`` in image pixels."""
    from hdrcore.tonemap import tonemap

    radiance, preview = result.radiance, result.preview
    if radiance is None or preview is None:
        raise InputError("the merged radiance map is not available yet")
    h, w = radiance.shape[:2]
    cw = max(1, min(w, int(box[0] / zoom)))
    ch = max(1, min(h, int(box[1] / zoom)))
    x0 = int(round(cx * w - cw / 2))
    y0 = int(round(cy * h - ch / 2))
    x0 = min(max(0, x0), w - cw)
    y0 = min(max(0, y0), h - ch)
    crop = np.ascontiguousarray(radiance[y0 : y0 + ch, x0 : x0 + cw])
    from hdrcore.tonemap import TONEMAP_OPERATORS

    method = preview.method if preview.method in TONEMAP_OPERATORS else "reinhard"
    extra: dict[str, Any] = {}
    if preview.state is not None:  # a local operator: the preview's own state
        extra = {"state": preview.state, "offset": (float(y0), float(x0))}
    tm = tonemap(
        crop,
        method,
        exposure=float(np.log2(preview.scale)),
        auto_exposure=False,
        white=preview.white,
        **extra,
    )
    img = tm.image
    k = int(round(zoom))
    if k > 1:
        img = np.repeat(np.repeat(img, k, axis=0), k, axis=1)
    return np.ascontiguousarray(img), (x0, y0, x0 + cw, y0 + ch)


class ResultPanel:
    """The preview or one diagnostic layer, with its legend."""

    def __init__(self, gui: viser.GuiApi) -> None:
        self._gui = gui
        self.summary = gui.add_markdown("No bracket loaded.")
        self.zoom = gui.add_dropdown(
            "Zoom",
            ZOOMS,
            hint="fit: the whole picture; 100 %: one screen pixel per image pixel "
            "of the full-resolution result (a loupe)",
        )
        self.centre_x = gui.add_slider("Centre x (%)", 0.0, 100.0, 1.0, 50.0, visible=False)
        self.centre_y = gui.add_slider("Centre y (%)", 0.0, 100.0, 1.0, 50.0, visible=False)
        self.image = gui.add_image(
            np.zeros((4, 4, 3), np.uint8), label="result", format="jpeg", visible=False
        )
        self._images: dict[str, np.ndarray] = {}
        self._last: tuple[Bracket | None, PipelineResult | None, dict[str, Any]] | None = None
        self._lock = threading.Lock()
        for handle in (self.zoom, self.centre_x, self.centre_y):
            handle.on_update(lambda _e: self._redraw())

    def _redraw(self) -> None:
        last = self._last
        if last is not None:
            self.show(*last)

    def show(
        self, bracket: Bracket | None, result: PipelineResult | None, view: dict[str, Any]
    ) -> None:
        with self._lock:
            self._show(bracket, result, view)

    def _show(
        self, bracket: Bracket | None, result: PipelineResult | None, view: dict[str, Any]
    ) -> None:
        self._last = (bracket, result, view)
        merged = None if result is None else result.merge
        preview = None if result is None or result.preview is None else result.preview.image
        if bracket is None or result is None or (merged is None and preview is None):
            self.summary.content = (
                "No bracket loaded."
                if bracket is None
                else "_Waiting for the merge and tonemap stages (hdrcore.pipeline)._"
            )
            self.image.visible = False
            self._images = {}
            return
        layer = view.get("layer", LAYERS[0])
        shown = _fit_width(np.asarray(preview)) if preview is not None else None
        images: dict[str, np.ndarray] = {}
        if shown is not None:
            images["preview"] = shown
        lines = []
        if merged is not None:
            # the fractions alone, not the whole summary (its provenance reads every share:
            # 0.05 s at 24 MP before the result was drawn)
            ghosts = (
                " of the pixels; the ghost test is running."
                if getattr(merged, "ghost_test_pending", False)
                else f", ghosts {merged.ghost_fraction:.2%} of the pixels."
            )
            deghosted = merged.deghosted_fraction
            lines.append(
                f"Merge **{merged.status}**: {merged.message}. "
                f"{weighting_words(merged.weighting)}; "
                f"clipped {merged.clipped_fraction:.2%}, under the noise floor "
                f"{merged.underexposed_fraction:.2%}{ghosts}"
                + (f" Deghosted {deghosted:.2%}." if deghosted is not None else "")
            )
        if getattr(result, "colour_pending", None) is not None:
            lines.append(
                "_The colour checks (the merge against each frame's own colour) are being "
                "measured; their verdicts follow._"
            )
        if layer == "deghosted" and merged is not None and merged.deghosted is None:
            lines.append(
                "_Layer deghosted: tick Deghost (Parameters) to fill each ghost region "
                "from one frame._"
            )
        elif layer != "tonemapped" and merged is not None:
            step = display_step(merged.shape, DISPLAY_WIDTH)
            backdrop = _dim(shown) if shown is not None else None
            if layer == "provenance":
                from hdrcore.merge import dominant_frame  # lazy: colour is slow to import

                dom = dominant_frame(merged.shares[:, ::step, ::step])
                layer_img = labels_to_rgb(dom, FRAME_COLOURS, width=10**9)
                legend = " · ".join(
                    f"<span style='color:rgb{FRAME_COLOURS[k % 10]}'>■</span> frame {k}"
                    for k in range(merged.n_frames)
                )
                lines.append(
                    "Provenance: the frame with the largest weight at each pixel. " + legend
                )
            else:
                attr, colour, what = _MASK_LAYERS[layer]
                mask = getattr(merged, attr)
                if backdrop is None:
                    small = np.asarray(mask[::step, ::step], bool)
                    backdrop = np.full((*small.shape, 3), 40.0, np.float32)
                else:  # the mask sampled on the backdrop's own grid (nearest pixel)
                    mh, mw = mask.shape[:2]
                    ys = (np.arange(backdrop.shape[0]) * mh) // backdrop.shape[0]
                    xs = (np.arange(backdrop.shape[1]) * mw) // backdrop.shape[1]
                    small = np.asarray(mask, bool)[ys[:, None], xs[None, :]]
                layer_img = _paint(backdrop, small, colour)
                lines.append(
                    f"<span style='color:rgb{colour}'>■</span> {what}: "
                    f"{np.count_nonzero(mask) / max(mask.size, 1):.2%} of the pixels"
                )
            images[layer] = layer_img
            shown = layer_img
        elif layer != "tonemapped":
            lines.append(f"_Layer {layer} needs the merge result._")
        zoom = self.zoom.value
        self.centre_x.visible = self.centre_y.visible = zoom != "fit"
        radiance = result.radiance
        zoomable = layer == "tonemapped" or (merged is not None and layer in images)
        if zoom != "fit" and zoomable and radiance is not None:
            factor = float(zoom.split()[0]) / 100.0
            crop, (x0, y0, x1, y1) = loupe(
                result, factor, self.centre_x.value / 100.0, self.centre_y.value / 100.0
            )
            if layer != "tonemapped" and merged is not None:
                # the layer at full resolution over the loupe (it zoomed the tonemapped layer
                # whatever layer was chosen, and said so in small print)
                crop = layer_loupe(merged, layer, crop, (x0, y0, x1, y1))
            images["loupe"] = crop
            self.image.image = crop
            self.image.label = (
                f"{layer}, {zoom} of the full-resolution result: pixels {x0}-{x1} x "
                f"{y0}-{y1} of {radiance.shape[1]}x{radiance.shape[0]}"
            )
            self.image.visible = True
        elif shown is not None:
            self.image.image = fit_to_box(enlarge(shown))
            self.image.label = f"{layer}"
            self.image.visible = True
        self.summary.content = "\n\n".join(lines) if lines else "Tonemapped preview."
        self._images = images

    def show_draft(self, draft: PipelineResult) -> None:
        """The preview of a draft (:func:`hdrcore.draft.run_draft`, the bracket binned) while
        the full-resolution merge runs; the next :meth:`show` replaces it."""
        f = draft.preview_factor
        self._show_provisional(
            draft,
            "tonemapped (draft)",
            f"_Draft: the bracket binned {f}x{f}, merged with the same parameters; the "
            "full-resolution merge follows._",
        )

    def show_interim(self, interim: PipelineResult) -> None:
        """The full-resolution preview of a run that held the last registration
        (:meth:`hdrview.session.Session.interim_params`) while the frames are registered again
        for the new levels; the next :meth:`show` replaces it."""
        self._show_provisional(
            interim,
            "tonemapped (last motion)",
            "_Merged at full resolution with the new levels on the last registration; the "
            "frames are being registered again for them (such a step moves the motion by "
            "hundredths of a pixel) and the result follows._",
        )

    def _show_provisional(self, result: PipelineResult, label: str, summary: str) -> None:
        """A picture shown until the next :meth:`show` (no layers, nothing to export)."""
        if result.preview is None:
            return
        preview = result.preview.image
        with self._lock:
            self.image.image = fit_to_box(enlarge(_fit_width(np.asarray(preview))))
            self.image.label = label
            self.image.visible = True
            self.summary.content = summary
            self._images = {}

    def bundle_files(self) -> list[tuple[str, bytes]]:
        return [(f"result-{name}.png", encode_png(img)) for name, img in self._images.items()]


def _crop_of(result: PipelineResult, crop: bool) -> tuple[int, int, int, int] | None:
    """The rectangle every frame covers (``hdrcore merge --crop common``), or None."""
    if not crop:
        return None
    from hdrcore.export import common_crop

    rect = common_crop(result)
    if rect[2] <= rect[0] or rect[3] <= rect[1]:
        raise InputError("no part of the image is covered by every frame: nothing to crop to")
    return rect


def exr_bytes(
    result: PipelineResult, work_dir: str | Path | None = None, *, crop: bool = False
) -> bytes:
    """The merged radiance as OpenEXR (half float) bytes, as ``hdrcore merge`` writes it
    (:func:`hdrcore.export.write_result`: the same attributes), through a temporary file in
    ``work_dir``, the inspector's own temporary folder, removed when it stops. ``crop``: only
    the rectangle every frame covers, as ``hdrcore merge --crop common``."""
    if result.radiance is None:
        raise InputError("the merged HDR is not available yet")
    rect = _crop_of(result, crop)
    with tempfile.TemporaryDirectory(prefix="exr-", dir=work_dir) as tmp:
        path = write_result(Path(tmp) / "merged.exr", result, crop=rect)
        return path.read_bytes()


def preview_png_bytes(result: PipelineResult, *, crop: bool = False) -> bytes:
    """The tonemapped preview as 8-bit PNG bytes (``crop``: as :func:`exr_bytes`)."""
    if result.preview is None:
        raise InputError("the preview is not available yet")
    arr = np.asarray(result.preview.image)
    rect = _crop_of(result, crop)
    if rect is not None:
        from hdrcore.export import crop_preview

        arr = crop_preview(arr, rect, result.preview_factor)
    if arr.dtype != np.uint8:
        arr = np.clip(arr.astype(np.float32) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return encode_png(arr)
