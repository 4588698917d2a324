"""The local operator (Durand & Dorsey on a bilateral grid, hdrcore.tonemap_local) and
``tonemap(..., "auto")``: detail in the window and the room, no halo at a strong edge, colour
kept, crops that render as the image around them, and the choice ``auto`` makes."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore import tonemap_spec as spec
from hdrcore.errors import ParameterError
from hdrcore.tonemap import AUTO_LOCAL_STOPS, TONEMAP_OPERATORS, tonemap
from hdrcore.tonemap_local import LocalToneParams, tonemap_durand

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


def test_deterministic_and_the_compiled_pass_matches_the_spec():
    rad, _ = _room_and_window(11.0, seed=3)
    rad[0, 0] = (np.nan, np.inf, -1.0)
    a = tonemap(rad, "durand", exposure=0.5)
    b = tonemap(rad, "durand", exposure=0.5, workers=1)
    ref, st = spec.durand_8bit(rad, a.scale)
    np.testing.assert_array_equal(a.image, b.image)
    assert np.abs(a.image.astype(int) - ref.astype(int)).max() <= 1
    assert (a.image != ref).mean() < 0.01
    assert (a.image[0, 0] == ref[0, 0]).all() and (a.image[0, 0] == 0).all()
    # the spec builds its state from the float32 exposed values, the kernel from rad * scale
    assert st.c == pytest.approx(a.state.c, rel=1e-8)


def test_the_grid_read_kernel_matches_its_spec_to_the_bit():
    """:func:`_slice` (compiled) against ``tonemap_spec.slice_grid``: whole images at an
    offset (float32 out, a crop's read) and a subsample's pixels (float64 out, the state's
    statistics), levels and positions outside the grid included."""
    from hdrcore.tonemap_local import _read_grid

    rng = np.random.default_rng(5)
    grid = rng.normal(0.0, 3.0, (9, 7, 11)).astype(np.float32)
    lg = rng.uniform(-20.0, 12.0, (23, 31)).astype(np.float32)
    lg[0, :4] = (-1e3, 1e3, 0.0, -6.5)
    for ys, xs, dtype in (
        (13.25 + np.arange(23), -3.5 + np.arange(31), np.float32),
        (np.arange(2, 23 * 4, 4), np.arange(1, 31 * 3, 3), np.float64),
    ):
        got = _read_grid(lg, ys, xs, 1 / 6.5, -10.0, 1 / 1.5, grid, dtype, workers=2)
        ref = spec.slice_grid(lg, ys, xs, 1 / 6.5, -10.0, 1 / 1.5, grid)
        assert got.dtype == dtype
        np.testing.assert_array_equal(got, ref.astype(dtype))


def test_engine_numpy_is_a_deprecated_alias_of_the_kernel():
    rad, _ = _room_and_window(11.0, shape=(60, 90), seed=2)
    a = tonemap(rad, "durand")
    with pytest.warns(DeprecationWarning, match="engine='numpy'"):
        b = tonemap(rad, "durand", engine="numpy")
    np.testing.assert_array_equal(a.image, b.image)
    x = rad * np.float32(a.scale)
    y, _ = tonemap_durand(x, LUMA)
    with pytest.warns(DeprecationWarning, match="engine='numpy'"):
        y2, _ = tonemap_durand(x, LUMA, engine="numpy")
    np.testing.assert_array_equal(y, y2)
    with pytest.raises(ParameterError, match="tonemap engine"):
        tonemap_durand(x, LUMA, engine="gpu")


def test_a_crop_renders_as_the_image_around_it():
    """The inspector's loupe: a crop of the full-resolution map, given the preview's state and
    its offset, renders exactly as the preview made at full resolution; a preview made at a
    quarter of the size hands its state to full-resolution crops (``pixel_size``). The float
    spec (``tonemap_spec.durand_8bit``) keeps the same property."""
    rad, _ = _room_and_window(11.0, shape=(240, 360))
    full = tonemap(rad, "auto")
    crop = np.ascontiguousarray(rad[70:170, 100:300])
    again = tonemap(
        crop,
        full.method,
        exposure=float(np.log2(full.scale)),
        auto_exposure=False,
        state=full.state,
        offset=(70, 100),
    )
    np.testing.assert_array_equal(again.image, full.image[70:170, 100:300])
    ref_full, st = spec.durand_8bit(rad, full.scale)
    ref_crop, _ = spec.durand_8bit(crop, full.scale, state=st, offset=(70, 100))
    np.testing.assert_array_equal(ref_crop, ref_full[70:170, 100:300])
    # a preview at half size: its state serves the full-resolution crop
    small = rad.reshape(120, 2, 180, 2, 3).mean(axis=(1, 3))
    prev = tonemap(small, "durand", pixel_size=2)
    loupe = tonemap(
        crop,
        "durand",
        exposure=float(np.log2(prev.scale)),
        auto_exposure=False,
        state=prev.state,
        offset=(70, 100),
        pixel_size=1,
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
