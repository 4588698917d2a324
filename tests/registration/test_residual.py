"""Residual motion of aligned pairs (hdrcore.registration.residual) against known synthetic motion.

Pairs are rendered here from the project's procedural scenes: each frame integrates the
continuous scene (the radiance grid's bilinear interpolant) over its pixels, like the
simulator's "area" rendering, at positions moved by a known 3x3 map, then exposed (linear
response, Gaussian noise of 1 level, quantised). The truth of a tile is the known map's
displacement at its centre.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import ndimage

from hdrcore.errors import ParameterError
from hdrcore.registration import residual, spec
from hdrcore.registration.residual import (
    RESIDUAL_STATUSES,
    ResidualMotion,
    region_name,
    residual_motion,
)
from hdrcore.synthetic import make_scene

from ._pairs import render_frames

SHAPE = (384, 576)
MARGIN = 40
CENTRE = np.array([(SHAPE[1] - 1) / 2.0, (SHAPE[0] - 1) / 2.0])


def _scene(name: str = "window", seed: int = 0) -> np.ndarray:
    big = make_scene(name, (SHAPE[0] + 2 * MARGIN, SHAPE[1] + 2 * MARGIN), seed)
    return big[..., 1].astype(np.float64)


def _render(big: np.ndarray, h: np.ndarray) -> np.ndarray:
    """The scene seen by a frame whose pixel ``p`` looks at ``h p`` (3x3, frame coordinates)."""
    yy, xx = np.mgrid[0 : SHAPE[0], 0 : SHAPE[1]].astype(np.float64)
    zw = h[2, 0] * xx + h[2, 1] * yy + h[2, 2]
    xs = (h[0, 0] * xx + h[0, 1] * yy + h[0, 2]) / zw + MARGIN
    ys = (h[1, 0] * xx + h[1, 1] * yy + h[1, 2]) / zw + MARGIN
    return ndimage.map_coordinates(big, [ys, xs], order=2, mode="nearest", prefilter=False)


def _expose(radiance: np.ndarray, time: float, key: float, bits: int, rng) -> np.ndarray:
    ml = (1 << bits) - 1
    y = np.clip(radiance * time * key, 0, 1) * ml + rng.standard_normal(radiance.shape)
    return (np.clip(np.rint(y), 0, ml) / ml).astype(np.float32)


def _pair(h, *, ratio=4.0, bits=12, scene="window", seed=0, patch=None):
    """``(dark, bright, saturation, noise_floor)``: the bright frame's pixel ``p`` sees the dark
    frame's ``h p`` (``h`` is the pair matrix, bright -> dark). ``patch``: ``(slices, h2)``, a
    region of the bright frame that moves by ``h2`` instead (a second plane)."""
    big = _scene(scene, seed)
    dark = _render(big, np.eye(3))
    bright = _render(big, h)
    if patch is not None:
        region, h2 = patch
        bright[region] = _render(big, h2)[region]
    key = 0.18 / float(np.median(dark)) / np.sqrt(ratio)
    rng = np.random.default_rng(seed + 1)
    ml = (1 << bits) - 1
    return (
        _expose(dark, 1.0, key, bits, rng),
        _expose(bright, ratio, key, bits, rng),
        0.98,
        3.0 / ml,
    )


def _similarity(scale=1.0, angle_deg=0.0, shift=(0.0, 0.0)) -> np.ndarray:
    """3x3: rotation and scaling about the image centre, then ``shift``."""
    t = np.radians(angle_deg)
    a = scale * np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    h = np.eye(3)
    h[:2, :2] = a
    h[:2, 2] = CENTRE - a @ CENTRE + np.asarray(shift)
    return h


def _truth(h: np.ndarray, centres: np.ndarray) -> np.ndarray:
    x, y = centres[:, 0], centres[:, 1]
    zw = h[2, 0] * x + h[2, 1] * y + h[2, 2]
    return np.stack(
        [
            (h[0, 0] * x + h[0, 1] * y + h[0, 2]) / zw - x,
            (h[1, 0] * x + h[1, 1] * y + h[1, 2]) / zw - y,
        ],
        axis=1,
    )


def _measure(h, **kw) -> tuple[ResidualMotion, np.ndarray]:
    pair_kw = {k: kw.pop(k) for k in ("ratio", "bits", "scene", "seed", "patch") if k in kw}
    dark, bright, sat, nf = _pair(h, **pair_kw)
    res = residual_motion(
        dark, bright, pair_kw.get("ratio", 4.0), saturation=sat, noise_floor=nf, **kw
    )
    return res, _truth(h, res.centres)


def test_known_subpixel_shift_is_recovered_to_five_hundredths():
    h = _similarity(shift=(0.3, -0.7))
    res, truth = _measure(h)
    v = res.valid
    assert res.n_valid >= 20
    err = np.median(res.shifts[v] - truth[v], axis=0)
    assert np.all(np.abs(err) <= 0.05), err
    assert abs(res.pattern.shift_x - 0.3) <= 0.05 and abs(res.pattern.shift_y + 0.7) <= 0.05
    assert abs(res.median - np.hypot(0.3, 0.7)) <= 0.05
    assert res.status == "misaligned" and res.kind == "shift"
    assert res.describe().startswith("a shift of 0.8 px is left")


@pytest.mark.parametrize("shift", [(2.3, -1.6), (-0.5, 0.25)])
def test_larger_and_negative_shifts(shift):
    res, truth = _measure(_similarity(shift=shift))
    v = res.valid
    assert np.all(np.abs(np.median(res.shifts[v] - truth[v], axis=0)) <= 0.05)


def test_zoom_pattern_is_recovered_and_named():
    h = _similarity(scale=1.004)
    res, truth = _measure(h)
    p = res.pattern
    assert abs(p.zoom - 0.004) <= 0.0002, p.zoom  # 0.02 % of the radius: 0.07 px at the corners
    pred = p.predict(res.centres[:, 0], res.centres[:, 1], res.shape)
    rms = float(np.sqrt(np.mean(np.sum((pred - truth) ** 2, axis=1))))
    assert rms <= 0.05, rms
    assert abs(p.rotation_deg) < 0.005 and p.shift_px < 0.05
    assert res.kind == "zoom"
    assert res.describe().startswith("a zoom of +0.40 % is left (1.4 px at the corners)")
    assert "no scale" in res.describe()


def test_rotation_pattern_is_named():
    res, _ = _measure(_similarity(angle_deg=0.15))
    assert abs(res.pattern.rotation_deg - 0.15) <= 0.01
    assert res.kind == "rotation" and "rotation of +0.15" in res.describe()


def test_true_homography_given_as_matrix_leaves_nothing():
    h = _similarity(scale=0.997, angle_deg=0.4, shift=(6.2, -3.7))
    h[2, :2] = (1.5e-5, -1e-5)  # a small perspective
    dark, bright, sat, nf = _pair(h)
    res = residual_motion(dark, bright, 4.0, h, saturation=sat, noise_floor=nf)
    assert res.status == "aligned", res.message
    assert res.median <= 0.05 and res.pattern.shift_px <= 0.05
    assert res.describe().endswith("aligned")
    # the same motion without its perspective: the tilt is what is left
    affine = h[:2] / h[2, 2]
    res2 = residual_motion(dark, bright, 4.0, affine, saturation=sat, noise_floor=nf)
    assert res2.status == "misaligned" and res2.kind in ("perspective", "zoom", "shift")
    # no matrix at all: the whole motion is left
    res3 = residual_motion(dark, bright, 4.0, saturation=sat, noise_floor=nf)
    assert res3.median > 5


def test_two_planes_local_residual_is_located():
    h = _similarity(shift=(1.2, 0.4))
    lower_left = (slice(200, 384), slice(0, 260))
    h2 = _similarity(shift=(4.2, 0.4))  # 3 px more parallax in the lower left
    res, truth = _measure(h, patch=(lower_left, h2))
    h_only = _similarity(shift=(1.2, 0.4))
    # given the dominant plane's motion, only the lower left is left
    dark, bright, sat, nf = _pair(h, patch=(lower_left, h2))
    aligned = residual_motion(dark, bright, 4.0, h_only, saturation=sat, noise_floor=nf)
    assert aligned.status == "misaligned" and aligned.kind == "local", aligned.message
    assert aligned.worst_region == "lower left"
    assert aligned.describe().startswith("3.0 px of residual motion at the lower left")
    assert aligned.describe().endswith("parallax, a moving object or flare")
    assert aligned.median < 0.1  # the dominant plane is aligned
    # tiles wholly inside the patch measure its motion
    x, y = res.centres[:, 0], res.centres[:, 1]
    inside = res.valid & (x < 260 - 40) & (y > 200 + 40)
    assert inside.sum() >= 3
    assert np.all(np.abs(res.shifts[inside, 0] - 4.2) <= 0.1)


@pytest.mark.parametrize("ratio", [4.0, 8.0, 16.0])
def test_exposure_gap_8bit_with_noise(ratio):
    shift = (0.4, -0.25)
    res, truth = _measure(_similarity(shift=shift), bits=8, ratio=ratio)
    v = res.valid
    assert res.n_valid >= 10, res.message
    err = np.median(res.shifts[v] - truth[v], axis=0)
    assert np.all(np.abs(err) <= 0.08), err
    dark, bright, sat, nf = _pair(_similarity(shift=shift), bits=8, ratio=ratio)
    done = residual_motion(
        dark, bright, ratio, _similarity(shift=shift), saturation=sat, noise_floor=nf
    )
    assert done.status == "aligned", done.message
    assert done.median <= (0.1 if ratio < 16 else 0.15)  # the noise of 8-bit frames x16


def test_flat_pair_is_unmeasured_never_aligned():
    rng = np.random.default_rng(3)
    flat = np.full(SHAPE, 0.2, np.float32)
    dark = (flat / 4 + rng.standard_normal(SHAPE).astype(np.float32) / 4095).astype(np.float32)
    bright = (flat + rng.standard_normal(SHAPE).astype(np.float32) / 4095).astype(np.float32)
    res = residual_motion(dark, bright, 4.0, saturation=0.98, noise_floor=3 / 4095)
    assert res.status == "unmeasured" and not res.aligned
    assert res.n_valid == 0 and np.isnan(res.median) and res.pattern is None
    assert "cannot be measured" in res.describe()
    # all saturated: nothing in the range both frames share
    sat = np.ones(SHAPE, np.float32)
    res2 = residual_motion(sat, sat, 4.0, saturation=0.98, noise_floor=3 / 4095)
    assert res2.status == "unmeasured" and "no tile is textured" in res2.message


def test_tiles_outside_the_shared_range_are_skipped_the_rest_still_measured():
    # the left third of the bright frame saturated: those tiles cannot count, so they are not
    # measured at all (NaN shift, confidence 0); the others still recover the shift
    h = _similarity(shift=(0.3, -0.7))
    dark, bright, sat, nf = _pair(h)
    bright[:, : SHAPE[1] // 3] = 1.0
    res = residual_motion(dark, bright, 4.0, saturation=sat, noise_floor=nf)
    skipped = res.in_range < 0.5
    assert skipped.sum() >= 4 and (~skipped).sum() >= 10
    assert np.all(np.isnan(res.shifts[skipped])) and np.all(res.confidence[skipped] == 0)
    assert not res.valid[skipped].any() and res.n_valid >= 10
    truth = _truth(h, res.centres)
    v = res.valid
    assert np.all(np.abs(np.median(res.shifts[v] - truth[v], axis=0)) <= 0.05)
    json.dumps(res.to_json())


def test_compiled_phase_plane_fit_matches_its_spec():
    rng = np.random.default_rng(5)
    t, n = 64, 12
    plane = residual._PhasePlane(t)
    fy = np.fft.fftfreq(t)[:, None]
    fx = np.fft.rfftfreq(t)[None]
    d = rng.uniform(-3, 3, (n, 2))
    noise = rng.normal(size=(n, t, t // 2 + 1)) + 1j * rng.normal(size=(n, t, t // 2 + 1))
    cross = (
        np.abs(rng.normal(size=(n, t, t // 2 + 1)))
        * np.exp(-2j * np.pi * (d[:, 0, None, None] * fx + d[:, 1, None, None] * fy))
        + 0.3 * noise
    ).astype(np.complex64)
    start = np.round(d)
    got, cov = plane.fit(cross, start, 2, 2)
    ref, cov_ref = spec.plane_fit(plane, cross, start, 2)
    np.testing.assert_allclose(got, ref, atol=1e-7)
    np.testing.assert_allclose(cov, cov_ref, rtol=1e-5)
    assert np.abs(got - d).max() < 0.1  # and it finds the planted shifts


def test_json_and_statuses():
    res, _ = _measure(_similarity(shift=(0.3, -0.7)))
    doc = json.loads(json.dumps(res.to_json()))
    assert doc["status"] in RESIDUAL_STATUSES and doc["message"] == res.describe()
    assert len(doc["shifts"]) == len(doc["centres"]) == doc["tiles"]
    assert doc["valid_tiles"] == res.n_valid
    assert doc["pattern"]["terms"] in (2, 4, 6, 8)


def test_integer_levels_through_lut_match_float_frames():
    dark, bright, sat, nf = _pair(_similarity(shift=(0.3, -0.7)))
    lut = np.arange(4096, dtype=np.float32) / 4095
    a = np.rint(dark * 4095).astype(np.uint16)
    b = np.rint(bright * 4095).astype(np.uint16)
    r1 = residual_motion(dark, bright, 4.0, saturation=sat, noise_floor=nf)
    r2 = residual_motion(a, b, 4.0, saturation=sat, noise_floor=nf, lut=lut)
    np.testing.assert_allclose(r2.shifts, r1.shifts, atol=1e-4)
    np.testing.assert_array_equal(r2.valid, r1.valid)


def _run_on_specs(monkeypatch) -> None:
    """Put the numpy specs (hdrcore.registration.spec) in the place of the residual's kernels."""
    for name, f in spec.RESIDUAL_KERNELS.items():
        monkeypatch.setattr(residual, name, f)
    monkeypatch.setattr(residual._PhasePlane, "fit", spec.plane_fit)


def test_the_specs_give_the_same_residual_motion(monkeypatch):
    h = _similarity(scale=1.002, shift=(0.6, 0.2))
    dark, bright, sat, nf = _pair(h)
    kw = dict(saturation=sat, noise_floor=nf, max_pixels=60_000)  # level 1: reduce + warp
    compiled = residual_motion(dark, bright, 4.0, h, **kw)
    _run_on_specs(monkeypatch)
    reference = residual_motion(dark, bright, 4.0, h, **kw)
    assert compiled.level == reference.level == 1
    np.testing.assert_array_equal(compiled.valid, reference.valid)
    np.testing.assert_allclose(reference.shifts, compiled.shifts, atol=1e-3)
    assert reference.status == compiled.status == "aligned"


def test_each_residual_kernel_matches_its_spec():
    """Block means (float and through a table), the Keys warp (NaN outside), the structure
    image (clipped, saturated and NaN pixels included), the tiles and the non-finite fill."""
    rng = np.random.default_rng(11)
    img = rng.uniform(0.001, 1.2, (70, 90)).astype(np.float32)
    img[5:9, 10:14] = 1.5  # saturated
    img[30, 40] = np.nan
    levels = rng.integers(0, 4096, (70, 90)).astype(np.uint16)
    lut = (np.arange(4096, dtype=np.float32) / 4095) ** 2
    for f in (1, 2, 3):
        for sat in (np.inf, 0.9):
            np.testing.assert_array_equal(
                residual._reduce(img, f, None, 2, sat), spec.reduce(img, f, None, sat=sat)
            )
            got = residual._reduce(levels, f, lut, 2, sat)
            np.testing.assert_array_equal(got, spec.reduce(levels, f, lut, sat=sat))
    # a block holding one saturated pixel is saturated as a whole
    assert residual._reduce(img, 2, None, 2, 1.0)[2, 5] == 2.0  # rows 4-5: one clipped
    clean = np.nan_to_num(img, nan=0.5)
    m = np.array([[1.01, 0.02, -1.7], [-0.015, 0.99, 2.3], [1e-5, -2e-5, 1.0]])
    got = residual._warp(clean, m, (60, 80), 2)
    ref = spec.warp(clean, m, (60, 80))
    np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
    assert np.isnan(got).any() and np.isfinite(got).any()
    np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-6, equal_nan=True)
    g, inside = residual._structure(img, 0.01, 1.0, 2)
    g_ref, inside_ref = spec.structure(img, 0.01, 1.0)
    np.testing.assert_array_equal(inside, inside_ref)
    np.testing.assert_array_equal(np.isnan(g), np.isnan(g_ref))
    np.testing.assert_allclose(g, g_ref, rtol=1e-5, atol=1e-6, equal_nan=True)
    assert (g[4:10, 9:15] == 0).all() and np.nanmax(g) > 0
    win = np.outer(np.hanning(16), np.hanning(16)).astype(np.float32)
    oy, ox = rng.integers(-3, 60, 9), rng.integers(-3, 80, 9)
    d = rng.uniform(-4, 4, (9, 2))
    np.testing.assert_allclose(
        residual._tiles(clean, oy, ox, d, win, 2), spec.tiles(clean, oy, ox, d, win, 2), atol=1e-5
    )
    # whole-pixel offsets (the kernel copies those tiles' pixels), some past the edges
    d_int = np.round(d)
    d_int[:3] = 0.0
    np.testing.assert_allclose(
        residual._tiles(clean, oy, ox, d_int, win, 2),
        spec.tiles(clean, oy, ox, d_int, win, 2),
        atol=1e-5,
    )
    # ... and what the interpolating path gives a hair (2**-40 px) away: the copy reads the
    # right pixels (a copy shifted by a pixel would be off by far more than the tolerance)
    eps = np.array([[np.ldexp(1.0, -40), 0.0]])
    whole = residual._tiles(clean, oy[:1], ox[:1], np.zeros((1, 2)), win, 1)
    near = residual._tiles(clean, oy[:1], ox[:1], eps, win, 1)  # the interpolating path
    np.testing.assert_allclose(whole, near, atol=1e-6)
    np.testing.assert_allclose(residual._nan_to_mean(img), spec.nan_to_mean(img), rtol=1e-6)
    assert np.isfinite(residual._nan_to_mean(img)).all()


def test_pyramid_level_on_large_frames_reports_full_resolution_pixels():
    h = _similarity(shift=(1.6, -2.4))
    res, truth = _measure(h, max_pixels=60_000)
    assert res.level == 1 and res.tile == 32
    v = res.valid  # 0.04 analysed px on level 1
    assert np.all(np.abs(np.median(res.shifts[v] - truth[v], axis=0)) <= 0.08)
    assert res.centres[:, 0].max() < SHAPE[1] and res.centres[:, 1].max() < SHAPE[0]


def test_region_names():
    assert region_name(10, 370, SHAPE) == "lower left"
    assert region_name(560, 5, SHAPE) == "upper right"
    assert region_name(288, 192, SHAPE) == "centre"
    assert region_name(288, 380, SHAPE) == "bottom"


@pytest.mark.parametrize(
    "args, kwargs, match",
    [
        ((np.zeros((100, 100)), np.zeros((100, 90))), {}, "same size"),
        ((np.zeros((100, 100, 3)), np.zeros((100, 100, 3))), {}, "single-channel"),
        ((np.zeros((100, 100)), np.zeros((100, 100)), 0.0), {}, "exposure ratio"),
        ((np.zeros((100, 100)), np.zeros((100, 100))), {"noise_floor": 2.0}, "noise_floor"),
        ((np.zeros((40, 100)), np.zeros((40, 100))), {}, "too small"),
        ((np.zeros((100, 100)), np.zeros((100, 100))), {"lut": np.arange(4.0)}, "integer"),
        (
            (np.full((100, 100), 9, np.uint8), np.zeros((100, 100), np.uint8)),
            {"lut": np.arange(4.0)},
            "beyond the end of the lut",
        ),
        ((np.zeros((100, 100)), np.zeros((100, 100)), 1.0, np.zeros((3, 3))), {}, "invertible"),
        ((np.zeros((100, 100)), np.zeros((100, 100))), {"tile": 8}, "tile size"),
    ],
)
def test_bad_input_says_what_is_wrong(args, kwargs, match):
    with pytest.raises(ParameterError, match=match):
        residual_motion(*args, **kwargs)


def test_structure_fixed_to_the_sensor_is_left_out():
    """Dust on the sensor (a strong multiplicative stain at the same pixels in both frames)
    shows the alignment itself once the bright frame is warped: those tiles are left out."""
    h = _similarity(shift=(6.0, -4.0))
    dark, bright, sat, nf = _pair(h)
    rng = np.random.default_rng(5)
    z = ndimage.gaussian_filter(rng.standard_normal((192, 288)), 2.0)
    stain = np.exp(0.6 * z / z.std() - 0.6).astype(np.float32)
    for frame in (dark, bright):
        frame[:192, :288] *= stain
    res = residual_motion(dark, bright, 4.0, h, saturation=sat, noise_floor=nf)
    assert res.sensor.sum() >= 3
    x, y = res.centres[res.sensor, 0], res.centres[res.sensor, 1]
    assert np.all(x < 288) and np.all(y < 192)
    assert not np.any(res.valid & res.sensor)
    assert res.status == "aligned", res.message
    assert "follow the sensor" in res.describe()


def test_register_pair_with_check_residual_is_ok_only_when_aligned():
    # a zoom of 0.6 % (1.7 px at the corners): the euclidean model cannot hold it and its pair
    # is 'weak', the residual saying what is left; the similarity's pair is 'ok'
    from hdrcore.registration import register_pair

    h = _similarity(scale=1.006, shift=(2.0, -1.0))
    dark, bright, sat, nf = _pair(h)
    kw = dict(saturation=sat, noise_floor=nf, previews=False, check_residual=True)
    eu = register_pair(dark, bright, 4.0, model="euclidean", **kw)
    assert eu.status == "weak" and eu.usable and eu.residual is not None
    assert eu.residual.kind == "zoom" and "zoom" in eu.message
    sim = register_pair(dark, bright, 4.0, model="similarity", **kw)
    assert sim.ok and sim.residual is not None and sim.residual.aligned
    assert sim.residual.median < 0.3
    # without the check the euclidean pair says 'ok' (the search's own status)
    assert register_pair(
        dark, bright, 4.0, model="euclidean", saturation=sat, noise_floor=nf, previews=False
    ).ok


def test_memo_computes_each_frame_once_and_changes_nothing(monkeypatch):
    """Measured against two versions of the bright frame with one memo, the dark frame's
    structure is computed once, and both results equal fresh measurements."""
    h = _similarity(scale=1.002, shift=(0.6, 0.2))
    dark, bright, sat, nf = _pair(h)
    moved = np.roll(bright, 1, axis=1)
    kw = dict(saturation=sat, noise_floor=nf)
    fresh = [residual_motion(dark, b, 4.0, **kw) for b in (bright, moved)]
    calls = []
    real = residual._structure
    monkeypatch.setattr(
        residual, "_structure", lambda img, *a, **k: calls.append(img.shape) or real(img, *a, **k)
    )
    memo: dict = {}
    memoised = [residual_motion(dark, b, 4.0, memo=memo, **kw) for b in (bright, moved)]
    assert len(calls) == 3  # dark once, each bright frame once
    for a, b in zip(fresh, memoised, strict=True):
        np.testing.assert_array_equal(a.shifts, b.shifts)
        assert a.status == b.status
    assert fresh[0].median != fresh[1].median  # the second frame did move


def test_tile_fractions_compiled_and_summed_area_agree():
    rng = np.random.default_rng(5)
    mask = rng.uniform(size=(130, 171)) < 0.3
    oy, ox = rng.integers(0, 130 - 32, 40), rng.integers(0, 171 - 32, 40)
    truth = np.array([mask[y : y + 32, x : x + 32].mean() for y, x in zip(oy, ox, strict=True)])
    np.testing.assert_array_equal(residual._box_fraction(mask, oy, ox, 32), truth)
    np.testing.assert_array_equal(spec.box_fraction(mask, oy, ox, 32), truth)


def test_an_unverifiable_motion_is_not_called_ok():
    """Frames with no measurable structure (noise about a flat level): the residual is
    unmeasured, so a motion of several pixels is 'weak' and says it cannot be verified, while
    a sub-pixel one stays 'ok' (harmless either way)."""
    from hdrcore.registration._problem import UNVERIFIED_PX, _checked, prepare

    rng = np.random.default_rng(0)
    ml = 4095
    dark = (np.clip(np.rint(200 + rng.standard_normal(SHAPE) * 2), 0, ml) / ml).astype(np.float32)
    bright = (np.clip(np.rint(800 + rng.standard_normal(SHAPE) * 2), 0, ml) / ml).astype(np.float32)
    data = prepare(dark, bright, 4.0, saturation=0.98, noise_floor=3 / ml, threshold=0.02)
    far = _similarity(shift=(6.0, -3.0))
    status, message, res = _checked(data, far, "similarity", "converged")
    assert res is not None and res.status == "unmeasured"
    assert status == "weak" and "cannot be verified" in message and "6.7 px" in message
    near = _similarity(shift=(0.5 * UNVERIFIED_PX, 0.0))
    assert _checked(data, near, "similarity", "converged")[0] == "ok"


def test_clipped_blocks_do_not_shift_the_edge_of_a_saturated_window():
    """Two exactly aligned frames 2 stops apart whose window clips in the bright frame (18 %
    of it), measured on level 2: a block holding a clipped pixel is saturated as a whole in
    both frames (the dark one where it leaves the range the pair shares, at ``saturation /
    k``). Block means mixing clipped and valid pixels moved the window's edge: 18 of 32
    tiles valid, 0.26 px median, a tile off by 6.3 px; now 32 tiles, 0.02 px, at most 1.4 px
    (one isolated tile within its own standard error)."""
    frames, _ = render_frames(
        [np.eye(3), np.eye(3)], (1.0, 4.0), bits=12, shape=(768, 1152), scene="window", seed=3
    )
    dark, bright = frames
    assert (bright >= 1.0).mean() > 0.1  # the window clips in the bright frame
    r = residual_motion(dark, bright, 4.0, None, saturation=1.0, noise_floor=0.002, max_pixels=1e5)
    assert r.level == 2
    full = residual_motion(dark, bright, 4.0, None, saturation=1.0, noise_floor=0.002)
    assert r.n_valid >= full.n_valid  # no tile lost to the window's edge
    assert r.aligned and r.median < 0.1, r.describe()
    assert np.nanmax(r.magnitudes) < 2.0
