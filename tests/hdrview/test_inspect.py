"""Images you can inspect (issue 16): a 100 % loupe on the full-resolution result that matches the
preview's rendering, and portrait frames that fit the window."""

from __future__ import annotations

import re

import numpy as np

from hdrcore.tonemap import tonemap
from hdrview.panels.result import BOX, fit_to_box, loupe


def test_loupe_is_a_full_resolution_crop_rendered_like_the_preview(app) -> None:
    assert app.request_path("bracket")
    assert app.wait_idle(120)
    result = app.session.result
    rad = result.radiance
    h, w = rad.shape[:2]
    img, (x0, y0, x1, y1) = loupe(result, 1.0, 0.5, 0.5)
    assert img.shape[:2] == (min(h, BOX[1]), min(w, BOX[0])) == (y1 - y0, x1 - x0)
    full = tonemap(
        rad,
        result.preview.method,
        exposure=float(np.log2(result.preview.scale)),
        auto_exposure=False,
        white=result.preview.white,
    ).image
    assert np.abs(img.astype(int) - full[y0:y1, x0:x1].astype(int)).max() <= 1
    # 400 %: a quarter of the pixels each way, each repeated 4 times, clamped inside the image.
    img4, (a0, b0, a1, b1) = loupe(result, 4.0, 1.0, 0.0)
    assert (a1, b0) == (w, 0) and img4.shape[1] == 4 * (a1 - a0)
    assert (
        np.array_equal(img4[::4, ::4], full[b0:b1, a0:a1])
        or np.abs(img4[::4, ::4].astype(int) - full[b0:b1, a0:a1].astype(int)).max() <= 1
    )


def test_the_panel_switches_to_the_loupe(app) -> None:
    assert app.request_path("bracket")
    assert app.wait_idle(120)
    panel = app.result_panel
    panel.zoom.value = "200 %"
    panel._redraw()
    assert "200 % of the full-resolution result" in panel.image.label
    assert panel.centre_x.visible
    panel.zoom.value = "fit"
    panel._redraw()
    assert not panel.centre_x.visible and panel.image.label == "tonemapped"


def test_portrait_fits_the_window() -> None:
    portrait = np.zeros((3000, 2000, 3), np.uint8)
    out = fit_to_box(portrait)
    # the box's whole height (not a whole-pixel stride's 500 of 620), the aspect kept
    assert out.shape[0] == BOX[1] and out.shape[1] >= out.shape[0] * 2000 // 3000
    # resampled, not strided: a one-pixel checkerboard reads mid-grey, not one of its colours
    checker = np.zeros((1240, 800, 3), np.uint8)
    checker[::2, ::2] = checker[1::2, 1::2] = 255
    small = fit_to_box(checker)
    x0 = (small.shape[1] - 400) // 2
    inner = small[10:-10, x0 + 10 : x0 + 390].astype(float)
    assert abs(inner.mean() - 127.5) < 10 and inner.std() < 20
    landscape = np.zeros((400, 600, 3), np.uint8)
    assert fit_to_box(landscape) is landscape


def test_the_loupe_zooms_the_layer_shown(app) -> None:
    """Zoom on the clipping or provenance layer showed the fitted layer and said the loupe
    showed the tonemapped layer: the loupe now draws the layer itself at full resolution."""
    from hdrview.panels.result import _MASK_LAYERS, FRAME_COLOURS

    assert app.request_path("bracket")
    assert app.wait_idle(120)
    panel = app.result_panel
    merged = app.session.result.merge
    panel.zoom.value = "200 %"
    for layer in ("clipping", "provenance"):
        app.layer_dropdown.value = layer
        assert app.wait_idle(60)
        panel._redraw()
        assert panel.image.label.startswith(f"{layer}, 200 % of the full-resolution result")
        crop = panel._images["loupe"]
        found = re.search(r"pixels (\d+)-\d+ x (\d+)-\d+", panel.image.label)
        assert found is not None
        x0, y0 = int(found[1]), int(found[2])
        sub = crop[::2, ::2]
        h, w = sub.shape[:2]
        if layer == "clipping":
            mask = np.asarray(merged.clipped[y0 : y0 + h, x0 : x0 + w], bool)
            painted = np.all(sub == np.array(_MASK_LAYERS["clipping"][1], np.uint8), axis=2)
            assert np.array_equal(painted & mask, mask)
        else:
            colours = {tuple(c) for c in sub.reshape(-1, 3)}
            assert colours <= {tuple(c) for c in FRAME_COLOURS}
