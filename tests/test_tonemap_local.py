"""The local operator (Durand & Dorsey on a bilateral grid, hdrcore.tonemap_local) and
``tonemap(..., "auto")``: detail in the window and the room, no halo at a strong edge, colour
kept, crops that render as the image around them, and the choice ``auto`` makes."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.errors import ParameterError
from hdrcore.tonemap import AUTO_LOCAL_STOPS, TONEMAP_OPERATORS, tonemap
from hdrcore.tonemap_local import LocalToneParams

LUMA = np.array([0.2126, 0.7152, 0.0722])


def _room_and_window(stops: float = 11.0, shape=(240, 360), seed: int = 0) -> np.ndarray:
    """A textured room (radiance ~1, +-0.7 stop of texture) with a window ``stops`` brighter
    in its upper left quarter, itself textured the same way (clouds)."""
    rng = np.random.default_rng(seed)
    h, w = shape
    from scipy import ndimage

    tex = ndimage.gaussian_filter(rng.normal(size=(h, w)), 2.0)
    tex *= 0.7 / tex.std()
    lum = 2.0**tex
    win = np.zeros((h, w), bool)
    win[20:110, 30:170] = True
    lum[win] *= 2.0**stops
    rad = np.stack([lum * 1.0, lum * 0.8, lum * 0.6], axis=-1).astype(np.float32)
    return rad, win


def _luma(img: np.ndarray) -> np.ndarray:
    return img.astype(np.float64) @ LUMA


def test_auto_chooses_the_local_operator_for_high_contrast_scenes_and_says_so():
    high, _ = _room_and_window(11.0)
    low, _ = _room_and_window(3.0)
    a = tonemap(high, "auto")
    b = tonemap(low, "auto")
    assert a.method == "durand" and a.requested == "auto" and a.dynamic_range > AUTO_LOCAL_STOPS
    assert b.method == "reinhard" and b.dynamic_range < AUTO_LOCAL_STOPS
    assert "more than 8" in a.reason and "not more than 8" in b.reason
    doc = a.to_json()
    assert doc["method"] == "durand" and doc["requested"] == "auto"
    assert doc["local"]["compression"] < 1 and doc["dynamic_range_stops"] > 8
    assert b.to_json()["local"] is None
    assert {"auto", "durand", "reinhard"} <= set(TONEMAP_OPERATORS)


def test_window_and_room_both_keep_their_detail():
    rad, win = _room_and_window(11.0)
    room = ~win
    room[:130, :190] = False  # away from the window's edge
    inner = np.zeros_like(win)
    inner[30:100, 40:160] = True
    local = _luma(tonemap(rad, "durand").image)
    glob = _luma(tonemap(rad, "reinhard").image)
    # the global curve: the window is a flat white (its clouds lost)
    assert glob[inner].std() < 3.0
    # the local operator: texture in both, the window brighter than the room
    assert local[inner].std() > 8.0 and local[room].std() > 8.0
    assert local[inner].mean() > local[room].mean() + 40
    assert 40 < local[room].mean() < 200 and local[inner].mean() < 250


def test_no_halo_at_a_strong_edge():
    """A flat wall next to a flat window 8 stops brighter: each side stays flat right up to
    the edge (a halo would brighten the wall or darken the window near it)."""
    rad = np.ones((120, 240, 3), np.float32)
    rad[:, 120:] *= 2.0**8
    y = _luma(tonemap(rad, "durand").image)
    wall, window = y[:, :120], y[:, 120:]
    assert np.ptp(wall) <= 2 and np.ptp(window) <= 2
    assert window.mean() > wall.mean() + 60


def test_colour_is_kept():
    rad, _ = _room_and_window(11.0)
    img = tonemap(rad, "durand").image.astype(int)
    mid = img[200:230, 250:350].reshape(-1, 3).mean(axis=0)
    assert mid[0] > mid[1] > mid[2]  # the scene's warm (1, 0.8, 0.6) colour, not grey
    full = tonemap(rad, "durand", local_params=LocalToneParams(saturation=1.0)).image
    grey = tonemap(rad, "durand", local_params=LocalToneParams(saturation=1e-6)).image
    spread = full.astype(int)[200:230, 250:350].std(axis=-1).mean()
    assert grey.astype(int)[200:230, 250:350].std(axis=-1).mean() < 1 < spread


def test_deterministic_and_the_compiled_pass_matches_the_numpy_reference():
    pytest.importorskip("numba")
    rad, _ = _room_and_window(11.0, seed=3)
    rad[0, 0] = (np.nan, np.inf, -1.0)
    a = tonemap(rad, "durand", exposure=0.5, engine="numba")
    b = tonemap(rad, "durand", exposure=0.5, engine="numba")
    ref = tonemap(rad, "durand", exposure=0.5, engine="numpy")
    np.testing.assert_array_equal(a.image, b.image)
    assert np.abs(a.image.astype(int) - ref.image.astype(int)).max() <= 1
    assert (a.image[0, 0] == ref.image[0, 0]).all()


@pytest.mark.parametrize("engine", ["numba", "numpy"])
def test_a_crop_renders_as_the_image_around_it(engine):
    """The inspector's loupe: a crop of the full-resolution map, given the preview's state and
    its offset, renders exactly as the preview made at full resolution; a preview made at a
    quarter of the size hands its state to full-resolution crops (``pixel_size``)."""
    if engine == "numba":
        pytest.importorskip("numba")
    rad, _ = _room_and_window(11.0, shape=(240, 360))
    full = tonemap(rad, "auto", engine=engine)
    crop = np.ascontiguousarray(rad[70:170, 100:300])
    again = tonemap(
        crop,
        full.method,
        exposure=float(np.log2(full.scale)),
        auto_exposure=False,
        state=full.state,
        offset=(70, 100),
        engine=engine,
    )
    np.testing.assert_array_equal(again.image, full.image[70:170, 100:300])
    # a preview at half size: its state serves the full-resolution crop
    small = rad.reshape(120, 2, 180, 2, 3).mean(axis=(1, 3))
    prev = tonemap(small, "durand", pixel_size=2, engine=engine)
    loupe = tonemap(
        crop,
        "durand",
        exposure=float(np.log2(prev.scale)),
        auto_exposure=False,
        state=prev.state,
        offset=(70, 100),
        pixel_size=1,
        engine=engine,
    )
    down = _luma(loupe.image).reshape(50, 2, 100, 2).mean(axis=(1, 3))
    assert np.abs(down - _luma(prev.image[35:85, 50:150])).mean() < 3.0


def test_bad_parameters_are_refused():
    with pytest.raises(ParameterError, match="cells must be >= 2"):
        LocalToneParams(cells=1)
    with pytest.raises(ParameterError, match="saturation must be positive"):
        LocalToneParams(saturation=0)
    with pytest.raises(ParameterError, match="pixel_size"):
        tonemap(np.ones((8, 8, 3), np.float32), "durand", pixel_size=0)
    with pytest.raises(ParameterError, match="whole image"):
        TONEMAP_OPERATORS["auto"](np.ones((4, 3), np.float32))


def test_real_window_bracket_gets_the_local_operator(frobisher_dir):
    """frobisher (a room and its window, 3 frames 3 stops apart): 'auto' picks the local
    operator; the clouds (the window's brightest tenth) keep several times the local contrast
    the global curve leaves them."""
    from hdrcore.io import load_bracket
    from hdrcore.pipeline import Pipeline

    r = Pipeline(load_bracket([frobisher_dir])).run(until="merge")
    rad = r.radiance
    auto = tonemap(rad, "auto")
    assert auto.method == "durand" and auto.dynamic_range > 9
    scene = rad.astype(np.float64) @ LUMA
    top = scene >= np.percentile(scene, 90)

    def detail(img):
        y = _luma(img)
        g = np.zeros_like(y)
        g[:, :-1] += np.abs(np.diff(y, axis=1))
        return g[top].mean()

    assert detail(auto.image) > 2.5 * detail(tonemap(rad, "reinhard").image)
