"""Exposure ratios from registered pixels (hdrcore.exposure.registered) and the simulator's
area rendering they are measured on."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.errors import ParameterError
from hdrcore.exposure import bracket_exposures
from hdrcore.exposure.registered import (
    METHOD,
    bracket_exposures_from_pixels,
    cfa_planes,
    exposure_ratio_registered,
)
from hdrcore.synthetic import SCENES, simulate_bracket

TIMES = (1.0, 4.0, 16.0, 64.0)


@pytest.fixture(scope="module")
def handheld12():
    return [
        simulate_bracket(
            scene=s,
            shape=(320, 480),
            exposure_times=TIMES,
            bits=12,
            noise_sigma=1.0,
            seed=3,
            max_shift=15,
            max_rotation_deg=1.0,
        )
        for s in SCENES
    ]


def test_handheld_ratios_with_true_motion_reach_a_hundredth_of_a_percent(handheld12) -> None:
    errs = []
    for b in handheld12:
        mats = [b.pair_matrix(k, k + 1) for k in range(len(TIMES) - 1)]
        r = bracket_exposures_from_pixels(b.frames, b.max_level, mats)
        assert r.method == METHOD and r.ok, r.message
        errs += [abs(p.ratio / 4 - 1) for p in r.pairs]
        for p in r.pairs:
            assert p.std_error > 0 and np.isfinite(p.std_error)
            assert len(p.equations) == p.inlier_mask.size == p.residuals.size
            assert p.overlap_restricted and 0 < p.common_fraction <= 1
    # Measured: median 0.003 %, worst 0.03 % (the histogram estimate of the same stacks: 2 %).
    assert np.median(errs) < 1e-4, errs
    assert max(errs) < 1e-3, errs
    hist = bracket_exposures(handheld12[0].frames, 4095)
    assert max(abs(p.ratio / 4 - 1) for p in hist.pairs) > 5 * max(errs)


def test_both_sampling_directions_are_needed(handheld12) -> None:
    """Interpolating only one frame biases the ratio; the two directions cancel."""
    b = handheld12[0]
    mat = b.pair_matrix(2, 3)
    r = exposure_ratio_registered(b.frames[2], b.frames[3], 4095, mat)
    spread = float(r.message.split("differ by ")[1].split("%")[0]) / 100
    assert spread > 20 * abs(r.ratio / 4 - 1)


def test_identical_frames_give_one() -> None:
    b = simulate_bracket(scene="patches", shape=(200, 300), exposure_times=(1.0,), bits=12)
    f = b.frames[0]
    r = exposure_ratio_registered(f, f, 4095, np.eye(2, 3))
    assert r.ratio == pytest.approx(1.0, abs=1e-12) and r.ok


def test_no_overlap_gives_a_status_and_a_message() -> None:
    b = simulate_bracket(
        scene="window",
        shape=(200, 300),
        exposure_times=(1.0, 4096.0),
        bits=8,
        noise_sigma=1.0,
        seed=1,
    )
    r = exposure_ratio_registered(b.frames[0], b.frames[1], 255, np.eye(2, 3))
    assert r.status == "no-overlap" and not r.ok
    assert "too few registered pixels" in r.message and not np.isfinite(r.ratio)


def test_black_or_saturated_frame_gives_a_no_signal_pair() -> None:
    # Never an exception (issue 12): the pair says which frame is black or saturated.
    b = simulate_bracket(scene="window", shape=(100, 150), exposure_times=(1.0, 4.0), bits=8)
    black = np.zeros_like(b.frames[0])
    r = bracket_exposures_from_pixels([black, b.frames[1]], 255, [np.eye(2, 3)])
    p = r.pairs[0]
    assert p.status == "no-signal" and np.isnan(p.ratio) and not r.ok
    assert "frames 0 and 1: the darker frame is entirely black" in p.message
    white = np.full_like(b.frames[0], 255)
    r = bracket_exposures_from_pixels([b.frames[0], white], 255, [np.eye(2, 3)])
    assert r.pairs[0].status == "no-signal"
    assert "the brighter frame is entirely saturated" in r.pairs[0].message
    p = exposure_ratio_registered(
        b.frames[0], white, 255, np.eye(2, 3), dark_index=4, bright_index=5
    )
    assert p.status == "no-signal" and "frames 4 and 5" in p.message
    with pytest.raises(ParameterError, match="one matrix per consecutive pair"):
        bracket_exposures_from_pixels(b.frames, 255, [])
    with pytest.raises(ParameterError, match="invertible"):
        exposure_ratio_registered(b.frames[0], b.frames[1], 255, np.zeros((2, 3)))


def test_no_signal_fallback_pair_is_kept_unchanged() -> None:
    # A pair whose histogram estimate says "no-signal" (a black or saturated frame) keeps that
    # result; the other pairs are measured from their pixels.
    b = simulate_bracket(
        scene="window",
        shape=(100, 150),
        exposure_times=(1.0, 4.0, 16.0),
        bits=12,
        noise_sigma=1.0,
        seed=2,
    )
    frames = [np.zeros_like(b.frames[0]), b.frames[1], b.frames[2]]
    fallback = bracket_exposures(frames, b.max_level)
    assert fallback.pairs[0].status == "no-signal"
    mats = [np.eye(2, 3)] * 2
    r = bracket_exposures_from_pixels(frames, b.max_level, mats, fallback=fallback)
    assert r.pairs[0] is fallback.pairs[0]
    assert r.pairs[1].method == METHOD and r.pairs[1].ok, r.pairs[1].message
    assert not r.extra_pairs  # the pair 0-2 has a black frame: not measured


def test_moving_object_tiles_are_rejected(handheld12) -> None:
    b = handheld12[1]
    mat = b.pair_matrix(1, 2)
    bright = b.frames[2].copy()
    # Something moved in the bright frame: 1/16 of the frame 30 % brighter.
    patch = (slice(120, 200), slice(180, 300))
    bright[patch] = np.minimum(bright[patch].astype(np.int64) * 13 // 10, 4095)
    clean = exposure_ratio_registered(b.frames[1], b.frames[2], 4095, mat)
    moved = exposure_ratio_registered(b.frames[1], bright, 4095, mat)
    assert abs(clean.ratio / 4 - 1) < 5e-4
    assert abs(moved.ratio / clean.ratio - 1) < 1e-3, (moved.ratio, clean.ratio)
    assert moved.n_inliers < clean.n_inliers
    assert moved.initial_ratio > 1.03 * moved.ratio  # k0, before the outlier test: 4.145


def test_masked_pixels_are_left_out(handheld12) -> None:
    b = handheld12[2]
    mat = b.pair_matrix(0, 1)
    bright = b.frames[1].copy()
    bright[100:200, 100:250] = (0, 0, 255)  # a marker of no data
    mask = np.ones(bright.shape[:2], bool)
    mask[95:205, 95:255] = False
    masked = exposure_ratio_registered(b.frames[0], bright, 4095, mat, mask_bright=mask)
    assert abs(masked.ratio / 4 - 1) < 5e-4, masked.message
    with pytest.raises(ParameterError, match="mask"):
        exposure_ratio_registered(b.frames[0], bright, 4095, mat, mask_bright=mask[:10])


def test_unregistered_pair_takes_the_histogram_estimate(handheld12) -> None:
    b = handheld12[0]
    mats = [b.pair_matrix(k, k + 1) for k in range(len(TIMES) - 1)]
    hist = bracket_exposures(b.frames, 4095)
    r = bracket_exposures_from_pixels(
        b.frames, 4095, mats, registered=[True, False, True], fallback=hist
    )
    assert r.pairs[1].ratio == hist.pairs[1].ratio
    assert "not registered" in r.pairs[1].message
    assert r.pairs[0].method == METHOD and r.pairs[2].method == METHOD
    assert all(e.dark != 1 or e.bright != 3 for e in r.extra_pairs)  # spans pair 1-2: left out
    alone = bracket_exposures_from_pixels(b.frames, 4095, mats, registered=[True, False, True])
    assert alone.pairs[1].status == "unregistered" and not alone.ok


def test_cfa_planes_follow_the_pattern() -> None:
    raw = np.arange(4 * 6, dtype=np.uint16).reshape(4, 6) + 100
    planes, (scale, offsets), groups = cfa_planes(
        raw, np.array([[0, 1], [3, 2]]), "RGBG", (100, 100, 100, 100), 1000
    )
    assert planes.shape == (2, 3, 4) and scale == 2.0
    assert groups == (0, 1, 1, 2)
    np.testing.assert_array_equal(planes[..., 0], raw[0::2, 0::2] - 100)
    np.testing.assert_array_equal(planes[..., 3], raw[1::2, 1::2] - 100)
    np.testing.assert_array_equal(offsets, [[0, 0], [1, 0], [0, 1], [1, 1]])


def test_cfa_geometry_maps_each_site_through_the_full_frame_motion() -> None:
    """A shifted mosaic: the site planes, each with its own offset, give the ratio."""
    b = simulate_bracket(
        scene="landscape",
        shape=(400, 600),
        exposure_times=(1.0, 4.0),
        bits=12,
        noise_sigma=1.0,
        seed=5,
        motion=[(0, 0, 0), (3.0, -2.0, 0.4)],
        reference=0,
    )
    mosaics = []
    for f in b.frames:
        m = np.empty(f.shape[:2], np.uint16)
        m[0::2, 0::2] = f[0::2, 0::2, 0]
        m[0::2, 1::2] = f[0::2, 1::2, 1]
        m[1::2, 0::2] = f[1::2, 0::2, 1]
        m[1::2, 1::2] = f[1::2, 1::2, 2]
        mosaics.append(m)
    pl = [cfa_planes(m, np.array([[0, 1], [3, 2]]), "RGBG", (0, 0, 0, 0), 4095) for m in mosaics]
    r = exposure_ratio_registered(
        pl[0][0], pl[1][0], 4095, b.pair_matrix(0, 1), geometry=pl[0][1], channel_groups=pl[0][2]
    )
    assert len(r.channel_ratios) == 3
    assert abs(r.ratio / 4 - 1) < 1e-3, r.message
    wrong = exposure_ratio_registered(
        pl[0][0], pl[1][0], 4095, b.pair_matrix(0, 1), channel_groups=pl[0][2]
    )  # offsets ignored
    assert abs(wrong.ratio / 4 - 1) > abs(r.ratio / 4 - 1)


def test_area_rendering_keeps_the_brightness_of_moved_frames() -> None:
    """The simulator's moved frames are the same scene at another exposure (area rendering);
    the earlier log-cubic rendering changed their brightness."""
    kw = dict(
        scene="patches",
        shape=(300, 450),
        exposure_times=(1.0, 1.0),
        bits=16,
        noise_sigma=0.0,
        motion=[(0, 0, 0), (7.5, 0.0, 0.0)],
        reference=0,
        seed=2,
        keep_linear=True,
        key=1e-5,
    )  # nothing clips
    # Measured: area 2e-7, log-cubic +0.9 % on this scene (+0.5 % on "window").
    for rendering, bound in (("area", 1e-5), ("log-cubic", None)):
        b = simulate_bracket(rendering=rendering, **kw)
        a, m = b.linear_frames
        # Frame 1 moved 7.5 px right: its column x sees the scene at x + 7.5.
        ref = 0.5 * (a[:, 7:-9] + a[:, 8:-8])
        diff = float(m[:, :-16].mean() / ref.mean() - 1)
        if bound is not None:
            assert abs(diff) < bound, diff
        else:
            assert abs(diff) > 2e-3, diff
    with pytest.raises(ParameterError, match="rendering"):
        simulate_bracket(rendering="nearest", **kw)


def test_still_brackets_are_the_radiance_grid_itself() -> None:
    rad = np.full((40, 60, 3), 0.1, np.float32)
    rad[10:20, 10:20] = 5.0
    b = simulate_bracket(
        rad, exposure_times=(1.0, 2.0), bits=16, noise_sigma=0.0, key=0.1, keep_linear=True
    )
    np.testing.assert_allclose(b.linear_frames[0], np.clip(rad * 0.1, 0, 1), rtol=1e-6)


@pytest.mark.parametrize(("bits", "median_bound"), [(8, 1e-3), (14, 1e-4)])
def test_handheld_ratios_at_8_and_14_bits(bits: int, median_bound: float) -> None:
    errs = []
    for scene in ("window", "night"):
        b = simulate_bracket(
            scene=scene,
            shape=(320, 480),
            exposure_times=TIMES,
            bits=bits,
            noise_sigma=1.0,
            seed=4,
            max_shift=15,
            max_rotation_deg=1.0,
        )
        mats = [b.pair_matrix(k, k + 1) for k in range(len(TIMES) - 1)]
        r = bracket_exposures_from_pixels(b.frames, b.max_level, mats)
        assert all(p.ok for p in r.pairs), r.message
        errs += [abs(p.ratio / 4 - 1) for p in r.pairs]
    # Issue 3's targets: median <= 0.1 % at 8 bits, <= 0.01 % at 12 (and 14) bits.
    assert np.median(errs) < median_bound, errs
    assert max(errs) < 0.01


def _render_through(
    big: np.ndarray, h: np.ndarray, shape: tuple[int, int], margin: int
) -> np.ndarray:
    """The scene ``big`` (H + 2 margin, W + 2 margin, C) seen by a frame whose pixel ``p``
    looks at ``h p`` (3x3); quadratic spline, so the moved frame keeps the scene's detail."""
    from scipy import ndimage

    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float64)
    zw = h[2, 0] * xx + h[2, 1] * yy + h[2, 2]
    xs = (h[0, 0] * xx + h[0, 1] * yy + h[0, 2]) / zw + margin
    ys = (h[1, 0] * xx + h[1, 1] * yy + h[1, 2]) / zw + margin
    return np.stack(
        [
            ndimage.map_coordinates(big[..., c], [ys, xs], order=2, mode="nearest", prefilter=False)
            for c in range(big.shape[2])
        ],
        axis=-1,
    )


def test_a_pair_related_by_a_homography_is_measured_through_it() -> None:
    """A perspective pair (corners moved by up to ~6 px beyond a similarity): the ratio read
    through the homography is within 0.05 % of the truth; the same pair through the affine
    map nearest to it at the centre is worse; an affine pair gives the same ratio as 2x3 or 3x3."""
    from hdrcore.pipeline import _affine_near
    from hdrcore.synthetic import make_scene

    shape, margin, ratio, ml = (240, 360), 30, 4.0, 4095
    big = make_scene("window", (shape[0] + 2 * margin, shape[1] + 2 * margin), 7)
    h = np.array([[1.004, 0.003, 2.3], [-0.002, 0.998, -1.7], [2.5e-5, -1.8e-5, 1.0]])
    dark = _render_through(big, np.eye(3), shape, margin)
    bright = _render_through(big, h, shape, margin)  # bright pixel p sees dark pixel h p
    rng = np.random.default_rng(0)
    key = 0.18 / float(np.median(dark)) / 2.0

    def expose(r: np.ndarray, t: float) -> np.ndarray:
        y = np.clip(r * t * key, 0, 1) * ml + rng.standard_normal(r.shape)
        return np.clip(np.rint(y), 0, ml).astype(np.uint16)

    d, b = expose(dark, 1.0), expose(bright, ratio)
    through = exposure_ratio_registered(d, b, ml, h)
    assert abs(through.ratio / ratio - 1) < 5e-4, through.message
    near = _affine_near(h, shape)  # what the pipeline used for such pairs before
    affine = exposure_ratio_registered(d, b, ml, near)
    assert abs(affine.ratio / ratio - 1) > abs(through.ratio / ratio - 1)
    r23 = exposure_ratio_registered(d, b, ml, near)
    r33 = exposure_ratio_registered(d, b, ml, np.vstack([near, [0.0, 0.0, 1.0]]))
    assert r23.ratio == r33.ratio


def _tile_sums_reference(grid, other, use_g, use_o, has_mask, lut, mat, lo, hi, tiles, tile):
    """The tile sums' definition, pixel by pixel in Python: a pixel enters when its 3x3
    neighbourhood in the grid and that of its nearest pixel in ``other`` lie strictly between
    ``lo`` and ``hi`` (and both are usable under ``has_mask``)."""
    h, w, nc = grid.shape
    ho, wo = other.shape[:2]
    out = np.zeros((len(tiles), nc, 3))

    def in_range(a, y, x, c):
        v = a[y - 1 : y + 2, x - 1 : x + 2, c]
        return not bool(np.any((v <= lo) | (v >= hi)))

    for t, (y0, x0) in enumerate(tiles):
        for y in range(max(y0, 1), min(y0 + tile, h - 1)):
            for x in range(max(x0, 1), min(x0 + tile, w - 1)):
                for c in range(nc):
                    m = mat[c]
                    zw = m[2, 0] * x + m[2, 1] * y + m[2, 2]
                    if not zw > 0.0:
                        continue
                    xs = (m[0, 0] * x + m[0, 1] * y + m[0, 2]) / zw
                    ys = (m[1, 0] * x + m[1, 1] * y + m[1, 2]) / zw
                    if not (xs >= 1.0 and ys >= 1.0 and int(xs) < wo - 2 and int(ys) < ho - 2):
                        continue
                    ix, iy = int(xs), int(ys)
                    fx, fy = xs - ix, ys - iy
                    rx = ix + 1 if fx >= 0.5 else ix
                    ry = iy + 1 if fy >= 0.5 else iy
                    if has_mask and (use_g[y, x] == 0 or use_o[ry, rx] == 0):
                        continue
                    if not (in_range(grid, y, x, c) and in_range(other, ry, rx, c)):
                        continue
                    t00, t01 = lut[c, other[iy, ix, c]], lut[c, other[iy, ix + 1, c]]
                    t10, t11 = lut[c, other[iy + 1, ix, c]], lut[c, other[iy + 1, ix + 1, c]]
                    top = t00 + (t01 - t00) * fx
                    bottom = t10 + (t11 - t10) * fx
                    out[t, c, 0] += lut[c, grid[y, x, c]]
                    out[t, c, 1] += top + (bottom - top) * fy
                    out[t, c, 2] += 1.0
    return out


@pytest.mark.parametrize(
    "case", ["identity", "affine", "perspective", "strong-perspective", "per-channel", "masked"]
)
def test_tile_sums_take_the_pixels_of_their_definition(case: str) -> None:
    """The compiled tile sums (neighbourhood tests made a tile at a time) take exactly the
    pixels of the definition and sum them in its order: equal to the bit, for thresholds on and
    between integer levels, maps that move the nearest pixels off the box of the mapped corners
    (a strong perspective: tested pixel by pixel) and per-channel maps (a mosaic's planes)."""
    from hdrcore.exposure.registered import _tile_sums

    rng = np.random.default_rng(5)
    h, w, nc, tile = 70, 90, 3, 16
    grid = rng.integers(0, 256, (h, w, nc)).astype(np.uint8)
    other = rng.integers(0, 256, (h, w, nc)).astype(np.uint8)
    # smooth regions, so that whole neighbourhoods pass
    grid[10:60, 10:80] = rng.integers(100, 140, (50, 70, nc)).astype(np.uint8)
    other[5:65, 5:85] = rng.integers(95, 165, (60, 80, nc)).astype(np.uint8)
    lut = np.stack([np.linspace(0.0, 1.0 + 0.1 * c, 256) ** 2.2 for c in range(nc)])
    mats = {
        "identity": np.eye(3),
        "affine": np.array([[1.01, 0.02, 1.7], [-0.015, 0.99, -2.4], [0.0, 0.0, 1.0]]),
        "perspective": np.array([[1.0, 0.01, 0.6], [0.0, 1.02, 0.3], [4e-4, -3e-4, 1.0]]),
        "strong-perspective": np.array([[2.5, 0.05, -54.0], [0.1, 2.5, -52.0], [1e-3, 5e-4, 1.0]]),
    }
    mat = np.repeat(mats.get(case, mats["affine"])[None], nc, axis=0)
    if case == "per-channel":
        mat[1, 0, 2] += 0.5
        mat[2, 1, 2] -= 0.5
    has_mask = case == "masked"
    use_g = (rng.random((h, w)) > 0.2).astype(np.uint8) if has_mask else np.ones((1, 1), np.uint8)
    use_o = (rng.random((h, w)) > 0.2).astype(np.uint8) if has_mask else np.ones((1, 1), np.uint8)
    tiles = np.array([(y, x) for y in range(0, h, tile) for x in range(0, w, tile)], np.int64)
    for lo, hi in ((90.0, 170.0), (99.5, 139.5), (-1.0, 300.0), (120.0, 118.0)):
        args = (grid, other, use_g, use_o, has_mask)
        got = _tile_sums(*args, lut, lut, mat, lo, hi, tiles, tile)
        want = _tile_sums_reference(*args, lut, mat, lo, hi, tiles, tile)
        assert np.array_equal(got, want), (case, lo, hi)
        if lo < hi and case != "masked":
            assert want[:, :, 2].sum() > 0
