"""Ghost detection (issue 16): how much of a static bracket is flagged, and how much of a moving
object is found, by the merge's per-pixel test (before) and its consistency regions (after).

Tables:

1. The real brackets of ../shared/data as they are (nothing in them moves; the phone brackets
   are hand-held, so parallax of near objects is real disagreement): per bracket, the % of the
   image flagged as ghost and filled by ``deghost`` with each test, the merge's seconds, the
   ghost test's seconds, and the largest change ``deghost`` makes to the merged radiance.
2. The same brackets with a moving object pasted in (re-exposed through each frame's exposure
   time and the bracket's recovered response, anti-aliased, 1 level of noise, JPEG brackets
   JPEG-encoded again at quality 92): a textured ellipse cut from the scene's own radiance map,
   4x brighter or 4x darker than where it walks, moving across the frame one step per frame.
   The ghost is where the merged radiance differs from the merge of the same frames without
   the object (same response, times, registration; the frames JPEG-encoded alike) by more than
   10 % (and, second column, 30 %) in some channel, inside the object's footprint and not
   clipped in every frame: what a viewer would see. Detection is the % of it flagged; false
   the % flagged more than 8 px away from every position of the object. ``recorded`` is the
   wider area where two frames that recorded the pixel in range disagree about the object,
   visible in the merge or not (a sample near the floor with 5 % of the weight).

3. ``--speed``: CPU seconds (``time.process_time``: all threads; best and median of
   ``--repeats``) of the ghost test (:func:`hdrcore.merge.consistency.consistency_regions`) on
   simulated 8-bit gamma brackets, a hand-held 3-frame one of ``--speed-mp`` megapixels and a
   40-frame 1 MP one (more frames than the kernel's tuple slots: it goes through in groups),
   and of the draft's binning (:func:`hdrcore.draft.bin_levels`, the 3 frames binned 6 x 6, in
   levels and through the response). Needs no data.

The merge's inputs are taken from the pipeline as it runs (every stage before the merge sees
the object too, except the noise floor, kept at the static bracket's: a bright object in the
darkest memorial scans moves the measured film-base pedestal from 21.1 to 12.1 levels, and the
pedestal's own disagreement between scans then floods every test), then the merge is run with
each test.

    python bench/bench_ghost.py [--quick] [--sets memorial,frobisher,pixel7,xperia] [--skip-static]
    python bench/bench_ghost.py --speed [--speed-mp 24] [--repeats 5]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import hdrcore.pipeline as pipeline_module  # noqa: E402
from hdrcore.io import load_bracket  # noqa: E402
from hdrcore.io.bracket import Bracket  # noqa: E402
from hdrcore.merge import merge  # noqa: E402
from hdrcore.pipeline import Pipeline, PipelineParams  # noqa: E402

DATA = (ROOT / ".." / "shared" / "data").resolve()

REAL = {
    "memorial": (
        "memorial-debevec",
        "exposure_times.txt",
        dict(exclude_colour=(0, 0, 255), align="none"),
    ),
    "frobisher": ("frobisher-colour-hdri", None, {}),
    "pixel7": ("handheld-pixel7-lab", None, dict(registration_max_pixels=3_000_000)),
    "xperia": (
        "handheld-xperia-library",
        "iso100_equivalent_times.txt",
        dict(registration_max_pixels=3_000_000),
    ),
}
TRIPOD = ("memorial", "frobisher")


def load(name: str) -> tuple[Bracket, dict]:
    folder, times_name, kw = REAL[name]
    d = DATA / folder
    files = sorted(p for p in d.iterdir() if p.suffix.lower() in (".jpg", ".png"))
    b = load_bracket(files, exposure_times=None if times_name is None else d / times_name)
    return b, kw


@contextlib.contextmanager
def captured_merge():
    """The keyword arguments of the pipeline's call to ``merge`` (frames and times included)."""
    seen: dict = {}
    original = pipeline_module.merge

    def spy(frames, times, **kw):
        seen.clear()
        seen.update(kw, frames=list(frames), exposure_times=tuple(times))
        return original(frames, times, **kw)

    pipeline_module.merge = spy
    try:
        yield seen
    finally:
        pipeline_module.merge = original


def pipeline_inputs(b: Bracket, kw: dict):
    """The pipeline's result (until the merge) and the merge's inputs it used."""
    kw = dict(kw)
    kw.setdefault("registration_previews", False)
    with captured_merge() as seen:
        r = Pipeline(b, PipelineParams(**kw)).run(until="merge")
    inputs = dict(seen)
    for k in ("reuse", "deghost", "ghost_test"):
        inputs.pop(k, None)
    return r, inputs


def run_merge(inputs: dict, test: str, deghost: bool):
    kw = dict(inputs)
    frames, times = kw.pop("frames"), kw.pop("exposure_times")
    t0 = time.perf_counter()
    m = merge(frames, times, ghost_test=test, deghost=deghost, **kw)
    return m, time.perf_counter() - t0


# --------------------------------------------------------------------------------------------
# Moving objects pasted into real frames


def _inverse_response(lut: np.ndarray):
    """Per channel: linear value -> level (``lut`` made strictly increasing, interpolated)."""
    g = np.maximum.accumulate(np.asarray(lut, np.float64), axis=1)
    g = g + np.arange(g.shape[1]) * 1e-12
    levels = np.arange(g.shape[1], dtype=np.float64)
    return lambda ch, x: np.interp(x, g[ch], levels)


def _ellipse_alpha(
    shape: tuple[int, int],
    cy: float,
    cx: float,
    ry: float,
    rx: float,
    ys: np.ndarray,
    xs: np.ndarray,
) -> np.ndarray:
    """Anti-aliased ellipse coverage at output coordinates ``ys, xs``."""
    r = np.sqrt(((ys - cy) / ry) ** 2 + ((xs - cx) / rx) ** 2)
    edge = 1.5 / min(ry, rx)
    return np.clip((1.0 - r) / edge + 0.5, 0.0, 1.0)


def moving_object_bracket(
    b: Bracket,
    inputs: dict,
    radiance: np.ndarray,
    *,
    contrast: float,
    seed: int = 0,
    jpeg_quality: int | None = 92,
):
    """``b`` with a textured ellipse walking across it (see the module docstring):
    ``(bracket, the frames without the object encoded alike, coverage per frame (N, H, W) on
    the output grid)``."""
    from scipy import ndimage

    rng = np.random.default_rng(seed)
    n = len(b)
    h, w = b.shape
    lut = inputs.get("response")
    m = b.max_level
    if lut is None:
        lut = np.tile(np.arange(m + 1) / m, (3, 1))
    g = np.asarray(lut, np.float64)
    inv = _inverse_response(g)
    times = np.asarray(inputs["exposure_times"], np.float64)
    tfs = inputs.get("transforms") or [None] * n
    ry, rx = 0.16 * h, 0.06 * w
    cy = 0.55 * h
    travel = 0.45 * w
    x_start = 0.25 * w
    step = travel / max(n - 1, 1)
    # the object's texture: the scene's radiance a third of the frame away, scaled to
    # ``contrast`` times the radiance of the background along its path
    lum = radiance.mean(axis=2)
    band = lum[int(cy - ry) : int(cy + ry), int(x_start - rx) : int(x_start + travel + rx)]
    bg = float(np.exp(np.mean(np.log(np.maximum(band, 1e-12)))))
    sy0 = int((cy - ry + h / 3) % (h - 2 * ry))
    sx0 = int(rng.integers(0, max(1, w - int(2 * rx) - 1)))
    tex = radiance[sy0 : sy0 + int(2 * ry) + 2, sx0 : sx0 + int(2 * rx) + 2].astype(np.float64)
    tex_l = float(np.exp(np.mean(np.log(np.maximum(tex.mean(axis=2), 1e-12)))))
    tex = tex * (contrast * bg / tex_l)
    frames = []
    still = []
    cover = np.zeros((n, h, w), np.float32)
    for k, f in enumerate(b.frames):
        cx = x_start + k * step
        lv = f.levels.astype(np.float64)
        # output-grid bounding box of the object, then each frame pixel mapped back to it
        t = tfs[k]
        fwd = np.eye(3)
        if t is not None:
            a = np.asarray(t, np.float64)  # output -> frame: 2x3 affine or 3x3
            fwd[: a.shape[0]] = a
            fwd /= fwd[2, 2]
        back = np.linalg.inv(fwd)  # frame -> output
        box = np.array(
            [
                [cx - rx - 3, cy - ry - 3, 1],
                [cx + rx + 3, cy - ry - 3, 1],
                [cx - rx - 3, cy + ry + 3, 1],
                [cx + rx + 3, cy + ry + 3, 1],
            ]
        ).T
        fb = fwd @ box
        fb = fb[:2] / fb[2]
        y0, y1 = max(0, int(fb[1].min()) - 2), min(h, int(fb[1].max()) + 3)
        x0, x1 = max(0, int(fb[0].min()) - 2), min(w, int(fb[0].max()) + 3)
        fy, fx = np.mgrid[y0:y1, x0:x1].astype(np.float64)
        ow = back[2, 0] * fx + back[2, 1] * fy + back[2, 2]
        oy = (back[1, 0] * fx + back[1, 1] * fy + back[1, 2]) / ow
        ox = (back[0, 0] * fx + back[0, 1] * fy + back[0, 2]) / ow
        alpha = _ellipse_alpha((h, w), cy, cx, ry, rx, oy, ox)
        ty = np.clip(oy - (cy - ry), 0, tex.shape[0] - 1)
        tx = np.clip(ox - (cx - rx), 0, tex.shape[1] - 1)
        patch = lv[y0:y1, x0:x1]
        for ch in range(3):
            obj = ndimage.map_coordinates(tex[..., ch], [ty, tx], order=1) * times[k]
            back_lin = np.interp(patch[..., ch], np.arange(g.shape[1]), g[ch])
            x = alpha * obj + (1.0 - alpha) * back_lin
            new = inv(ch, x) + rng.normal(0.0, 1.0, x.shape) * (alpha > 0)
            patch[..., ch] = np.where(alpha > 0, np.clip(np.rint(new), 0, m), patch[..., ch])
        lv[y0:y1, x0:x1] = patch

        def encoded(levels: np.ndarray, f=f) -> np.ndarray:
            if jpeg_quality is None or f.meta.format != "jpeg" or m != 255:
                return levels.astype(np.uint16)
            from PIL import Image

            buf = io.BytesIO()
            Image.fromarray(levels.astype(np.uint8)).save(buf, "JPEG", quality=jpeg_quality)
            return np.asarray(Image.open(io.BytesIO(buf.getvalue()))).astype(np.uint16)

        frames.append(replace(f, levels=encoded(lv)))
        still.append(encoded(f.levels))
        gy, gx = np.mgrid[0:h, 0:w]
        cover[k] = _ellipse_alpha((h, w), cy, cx, ry, rx, gy.astype(float), gx.astype(float))
    return replace(b, frames=tuple(frames)), still, cover


def visible_ghost(
    inputs: dict, still: list[np.ndarray], cover: np.ndarray, moved, change: float
) -> np.ndarray:
    """Pixels where the merge ``moved`` of the bracket with the object differs from the merge of
    ``still`` (the frames without it, same inputs otherwise) by more than ``change`` in some
    channel, inside the object's footprint and not clipped in every frame."""
    kw = dict(inputs)
    kw.pop("frames")
    times = kw.pop("exposure_times")
    ref = merge(still, times, ghost_test="pixels", **kw)
    diff = np.abs(moved.radiance - ref.radiance) / np.maximum(np.abs(ref.radiance), 1e-12)
    return (diff > change).any(axis=-1) & (cover > 0).any(axis=0) & ~moved.clipped


def moving_area(inputs: dict, cover: np.ndarray) -> np.ndarray:
    """Output pixels where two frames that recorded the pixel in range (every channel above
    the floor and below the saturation level, nearest source pixel) disagree about the
    object."""
    frames = inputs["frames"]
    n = len(frames)
    h, w = frames[0].shape[:2]
    sat = np.asarray(inputs.get("saturation_level"), np.float64).ravel()
    floor = float(inputs.get("noise_floor") or 0.0)
    tfs = inputs.get("transforms") or [None] * n
    masks = inputs.get("masks") or [None] * n
    gy, gx = np.mgrid[0:h, 0:w].astype(np.float64)
    seen_in = np.zeros((h, w), bool)
    seen_out = np.zeros((h, w), bool)
    moving = np.zeros((h, w), bool)
    for k in range(n):
        t = tfs[k]
        if t is None:
            v = frames[k]
        else:
            t = np.asarray(t, np.float64)
            tw = (t[2, 0] * gx + t[2, 1] * gy + t[2, 2]) if t.shape[0] == 3 else 1.0
            sx = np.clip(np.floor((t[0, 0] * gx + t[0, 1] * gy + t[0, 2]) / tw + 0.5), 0, w - 1)
            sy = np.clip(np.floor((t[1, 0] * gx + t[1, 1] * gy + t[1, 2]) / tw + 0.5), 0, h - 1)
            v = frames[k][sy.astype(int), sx.astype(int)]
        ok = np.all((v < sat) & (v > floor), axis=-1)
        if masks[k] is not None:
            ok &= masks[k]
        inside = cover[k] > 0.5
        seen_in |= ok & inside
        seen_out |= ok & ~inside
    moving = seen_in & seen_out
    return moving


# --------------------------------------------------------------------------------------------


def static_table(names: list[str]) -> None:
    print(
        "\n## Static brackets: % of the image flagged (ghost) and filled (deghost); before: "
        "the per-pixel test (ghost_test='pixels'), after: consistency regions (default)"
    )
    print(
        "   'seen' = flagged where filling from one frame moves the merge by > 10 % (the frames "
        "really disagree there, visibly: a moving object or a defect of one frame); 'unseen' = "
        "flagged where it moves it less (false alarms)"
    )
    print(
        f"{'bracket':<10} {'frames':>6} {'size':>10} | {'ghost % before':>14} "
        f"{'after':>7} | {'seen %':>6} {'unseen %':>8} | {'filled % before':>15} {'after':>7} | "
        f"{'merge s':>7} {'test s':>6} | {'deghost changed %':>17}"
    )
    for name in names:
        b, kw = load(name)
        _, inputs = pipeline_inputs(b, kw)
        before, _ = run_merge(inputs, "pixels", False)
        before_d, _ = run_merge(inputs, "pixels", True)
        after, secs = run_merge(inputs, "regions", False)
        after_d, _ = run_merge(inputs, "regions", True)
        changed = np.any(after_d.radiance != after.radiance, axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = np.abs(after_d.radiance - after.radiance) / np.abs(after.radiance)
        seen = after.ghost & np.any(rel > 0.1, axis=-1)
        print(
            f"{name:<10} {len(b):>6} {b.shape[1]:>5}x{b.shape[0]:<4} | "
            f"{100 * before.ghost.mean():>14.2f} {100 * after.ghost.mean():>7.2f} | "
            f"{100 * seen.mean():>6.2f} {100 * (after.ghost & ~seen).mean():>8.2f} | "
            f"{100 * before_d.deghosted.mean():>15.2f} {100 * after_d.deghosted.mean():>7.2f}"
            f" | {secs:>7.2f} {after.timings['ghosts']:>6.2f} | "
            f"{100 * float(changed.mean()):>17.2f}"
        )
        gr = after.ghost_regions
        if gr is not None:
            print(f"{'':<10} {gr.message}")


def moving_table(names: list[str], contrasts: tuple[float, ...]) -> None:
    print(
        "\n## Moving object pasted into the brackets: % of the visible ghost flagged "
        "(merge changed > 10 % / > 30 %), % flagged away from the object"
    )
    print(
        f"{'bracket':<10} {'object':>7} {'ghost px':>8} | {'>10% before':>11} {'after':>6} | "
        f"{'>30% before':>11} {'after':>6} | {'false % before':>14} {'after':>6} | "
        f"{'recorded after':>14} | {'filled %':>8}"
    )
    from scipy import ndimage

    for name in names:
        b, kw = load(name)
        r, inputs0 = pipeline_inputs(b, kw)
        for i, contrast in enumerate(contrasts):
            mb, still, cover = moving_object_bracket(
                b, inputs0, r.radiance, contrast=contrast, seed=i
            )
            # the floor of the static bracket: a bright object in the darkest frames moves the
            # measured film-base pedestal of the memorial scans (21.1 -> 12.1 levels)
            _, inputs = pipeline_inputs(mb, {**kw, "noise_floor": r.noise_floor})
            before, _ = run_merge(inputs, "pixels", False)
            after_d, _ = run_merge(inputs, "regions", True)
            after = after_d.ghost
            vis10 = visible_ghost(inputs, still, cover, before, 0.1)
            vis30 = visible_ghost(inputs, still, cover, before, 0.3)
            recorded = moving_area(inputs, cover)
            away = ~ndimage.binary_dilation((cover > 0.0).any(axis=0), iterations=8)
            print(
                f"{name:<10} {f'x{contrast:g}':>7} {int(vis10.sum()):>8} | "
                f"{100 * before.ghost[vis10].mean():>11.1f} {100 * after[vis10].mean():>6.1f} | "
                f"{100 * before.ghost[vis30].mean():>11.1f} {100 * after[vis30].mean():>6.1f} | "
                f"{100 * before.ghost[away].mean():>14.2f} {100 * after[away].mean():>6.2f} | "
                f"{100 * after[recorded].mean():>14.1f} | "
                f"{100 * after_d.deghosted.mean():>8.2f}"
            )


def _cpu(fn, repeats: int) -> tuple[float, float]:
    """Best and median CPU seconds of ``fn()`` over ``repeats`` calls (after one warm-up)."""
    fn()
    out = []
    for _ in range(repeats):
        c0 = time.process_time()
        fn()
        out.append(time.process_time() - c0)
    return min(out), float(np.median(out))


def speed_table(megapixels: float, repeats: int) -> None:
    from hdrcore.draft import bin_levels
    from hdrcore.merge import NoiseModel
    from hdrcore.merge.consistency import MAX_KERNEL_FRAMES, consistency_regions
    from hdrcore.registration import invert
    from hdrcore.synthetic import simulate_bracket

    lut = np.tile(np.linspace(0.0, 1.0, 256) ** 2.2, (3, 1))
    kw = dict(saturation=[247.0] * 3, floor=5.0, lut=lut, noise=NoiseModel(level_noise=2.0))
    h = int(round(np.sqrt(megapixels * 1e6 * 2 / 3)))
    w = int(round(h * 1.5))
    sb = simulate_bracket(
        scene="window",
        shape=(h, w),
        bits=8,
        response="gamma",
        exposure_times=(1.0, 4.0, 16.0),
        seed=5,
        noise_sigma=1.0,
        max_shift=4.0,
        max_rotation_deg=0.3,
    )
    frames = [f.astype(np.uint8) for f in sb.frames]
    tf = [invert(t) for t in sb.to_reference]
    times = list(sb.exposure_times)
    n_long = 40
    lb = simulate_bracket(
        scene="window",
        shape=(800, 1200),
        bits=8,
        response="gamma",
        exposure_times=tuple(2 ** (k / 6) for k in range(n_long)),
        seed=4,
        noise_sigma=1.0,
    )
    long_frames = [f.astype(np.uint8) for f in lb.frames]
    rows = [
        (
            f"ghost test, {h}x{w}, 3 frames hand-held",
            lambda: consistency_regions(frames, times, transforms=tf, **kw),
        ),
        (
            f"ghost test, 800x1200, {n_long} frames (> {MAX_KERNEL_FRAMES}: frame groups)",
            lambda: consistency_regions(long_frames, list(lb.exposure_times), **kw),
        ),
        (
            f"draft binning 6x6, {h}x{w}, 3 frames, levels",
            lambda: [bin_levels(f, 6, saturation=247, max_level=255) for f in frames],
        ),
        (
            f"draft binning 6x6, {h}x{w}, 3 frames, through the response",
            lambda: [bin_levels(f, 6, saturation=247, max_level=255, lut=lut) for f in frames],
        ),
    ]
    load = os.getloadavg()[0]
    print(f"\n3. Speed: CPU s (all threads), best / median of {repeats}, load {load:.1f}")
    print(f"{'what':<62} {'best':>7} {'median':>7}")
    for name, fn in rows:
        best, med = _cpu(fn, repeats)
        print(f"{name:<62} {best:>7.2f} {med:>7.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tripod brackets only")
    ap.add_argument("--sets", default=None, help="comma-separated subset of " + ",".join(REAL))
    ap.add_argument("--skip-static", action="store_true", help="the moving-object table only")
    ap.add_argument("--speed", action="store_true", help="the speed table only (no data)")
    ap.add_argument("--speed-mp", type=float, default=24.0, help="speed table's frame size, MP")
    ap.add_argument("--repeats", type=int, default=5, help="speed table's runs per row")
    args = ap.parse_args()
    if args.speed:
        speed_table(args.speed_mp, args.repeats)
        return
    if not DATA.is_dir():
        print(f"{DATA} not found: nothing to measure")
        return
    names = list(TRIPOD) if args.quick else list(REAL)
    if args.sets:
        names = [s for s in args.sets.split(",") if s in REAL]
    if not args.skip_static:
        static_table(names)
    moving_table(names, (4.0, 0.25))


if __name__ == "__main__":
    main()
