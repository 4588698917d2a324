"""Registration bench: ours (fast, Cerman 2006) beside OpenCV AlignMTB, ECC and SIFT + RANSAC.

Run: ``python bench/bench_registration.py [--brackets 6] [--shape 384 576] [--no-nm] [--no-big]``

1. Synthetic hand-held brackets (``hdrcore.synthetic.simulate_bracket``): 2-stop spacing
   (times 1, 4, 16), per-frame motion up to +-15 px and +-1 degree from the middle frame (so a
   consecutive pair moves up to 30 px and 2 degrees), 8 and 12 bits, Gaussian noise of 1 level.
   Error of a pair: the four image corners mapped by the estimated and the true pair matrix,
   Euclidean distance (pixels).
2. Real tripod bracket ``../shared/data/frobisher-colour-hdri`` (1/8, 1, 8 s): the motion found
   and the eq. 6 residual after alignment (ours vs AlignMTB's shift vs none).
3. Large frames (6 megapixels, simulated as the pipeline bench's bracket): corner error of the
   numpy reference path with the first version's budget (60 000 full-resolution samples) and of
   the default, same pairs.
4. Speed on the two 24-megapixel pairs of the pipeline bench's bracket
   (``bench/bench_pipeline.py``, cached under ``bench/out/``): numpy reference path with the
   first version's budget vs the default, on float32 green frames and on uint16 green views
   with a table, in the same run, best of 3, with the corner error against the simulator's
   truth; AlignMTB and warp timings.

Peers get the best input we can give them: AlignMTB the 8-bit gamma-encoded green channels (it
is exposure invariant by construction); ECC and SIFT the exposure-equalised pair (dark times the
true ratio, both clipped to their common range, log-scaled to 8 bits). ECC starts from the
identity. cv2 is used only here, never in ``hdrcore``.

Numbers measured on a shared 2-core machine while other people use it are pessimistic.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hdrcore.registration import (  # noqa: E402
    _kernels,  # noqa: E402
    corner_error,
    identity,
    register_pair,
    warp,
    warp_to_reference,
)
from hdrcore.registration._problem import cost, prepare, select_samples  # noqa: E402
from hdrcore.registration.transform import compose, invert  # noqa: E402
from hdrcore.synthetic import simulate_bracket  # noqa: E402

DATA = (ROOT / ".." / "shared" / "data").resolve()


def _gamma8(x: np.ndarray) -> np.ndarray:
    return (np.clip(x, 0, 1) ** (1 / 2.2) * 255 + 0.5).astype(np.uint8)


def _equalised8(dark: np.ndarray, bright: np.ndarray, k: float, sat: float, nf: float):
    lo, hi = nf * k, sat
    def tone(v):
        t = (np.log(np.clip(v, lo, hi)) - np.log(lo)) / (np.log(hi) - np.log(lo))
        return (t * 255 + 0.5).astype(np.uint8)
    return tone(dark * k), tone(bright)


def peer_mtb(dark, bright, k, sat, nf):
    mtb = cv2.createAlignMTB()
    sx, sy = mtb.calculateShift(_gamma8(dark), _gamma8(bright))
    # calculateShift(img0, img1): shifting img1 by (sx, sy) aligns it to img0, i.e.
    # bright(x - s) = dark(x): the pair matrix (bright -> dark) is a translation by +s.
    m = identity()
    m[0, 2], m[1, 2] = sx, sy
    return m


def peer_ecc(dark, bright, k, sat, nf):
    d8, b8 = _equalised8(dark, bright, k, sat, nf)
    warp = np.eye(2, 3, dtype=np.float32)
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 200, 1e-6)
    try:
        # template = bright, input = dark: dark(W x) ~ bright(x), W is the pair matrix
        _, warp = cv2.findTransformECC(b8.astype(np.float32), d8.astype(np.float32), warp,
                                       cv2.MOTION_EUCLIDEAN, crit, None, 5)
    except cv2.error:
        return None
    return warp.astype(np.float64)


def peer_sift(dark, bright, k, sat, nf):
    d8, b8 = _equalised8(dark, bright, k, sat, nf)
    sift = cv2.SIFT_create()
    kb, db = sift.detectAndCompute(b8, None)
    kd, dd = sift.detectAndCompute(d8, None)
    if db is None or dd is None or len(kb) < 3 or len(kd) < 3:
        return None
    matches = cv2.BFMatcher().knnMatch(db, dd, k=2)
    good = [m for m, n in (p for p in matches if len(p) == 2) if m.distance < 0.75 * n.distance]
    if len(good) < 3:
        return None
    pb = np.float32([kb[m.queryIdx].pt for m in good])
    pd = np.float32([kd[m.trainIdx].pt for m in good])
    m, _ = cv2.estimateAffinePartial2D(pb, pd, method=cv2.RANSAC, ransacReprojThreshold=1.0)
    return None if m is None else m.astype(np.float64)


def ours(method, **kw):
    def run(dark, bright, k, sat, nf):
        r = register_pair(dark, bright, k, saturation=sat, noise_floor=nf, method=method,
                          previews=False, **kw)
        return r.matrix if r.ok else None
    return run


def synthetic(args) -> None:
    methods = {"ours fast": ours("fast")}
    if not args.no_nm:
        methods["ours Cerman 2006 (NM)"] = ours("Cerman 2006", max_samples=30_000)
    methods.update({"AlignMTB": peer_mtb, "ECC euclidean": peer_ecc, "SIFT+RANSAC": peer_sift})
    shape = tuple(args.shape)
    print(f"\n## Synthetic hand-held brackets {shape[1]}x{shape[0]}, times 1/4/16, "
          f"pair motion up to 30 px / 2 deg, noise 1 level, {args.brackets} brackets per depth")
    for bits in (8, 12):
        errs = {m: [] for m in methods}
        worst = {m: 0.0 for m in methods}
        fails = {m: 0 for m in methods}
        secs = {m: 0.0 for m in methods}
        for seed in range(args.brackets):
            sb = simulate_bracket(shape=shape, exposure_times=(1, 4, 16), bits=bits,
                                  noise_sigma=1.0, max_shift=15, max_rotation_deg=1.0,
                                  seed=100 + seed)
            ml = sb.max_level
            fr = [f[..., 1].astype(np.float32) / ml for f in sb.frames]
            sat, nf = 0.97, max(3.0, 0.02 * ml) / ml  # the project defaults (hdrcore.exposure)
            for i in range(2):
                truth = sb.pair_matrix(i, i + 1)
                for name, fn in methods.items():
                    t0 = time.perf_counter()
                    m = fn(fr[i], fr[i + 1], sb.ratios[i], sat, nf)
                    secs[name] += time.perf_counter() - t0
                    if m is None:
                        fails[name] += 1
                        continue
                    e = corner_error(m, truth, shape)
                    errs[name].append(float(e.mean()))
                    worst[name] = max(worst[name], float(e.max()))
        n = 2 * args.brackets
        print(f"\n### {bits}-bit ({n} pairs)\n")
        print("| method | mean corner error px | median | worst pair (max corner) px | "
              "failed | s/pair |")
        print("|---|---|---|---|---|---|")
        for name in methods:
            e = np.array(errs[name]) if errs[name] else np.array([np.nan])
            print(f"| {name} | {e.mean():.4f} | {np.median(e):.4f} | {worst[name]:.4f} | "
                  f"{fails[name]}/{n} | {secs[name] / n:.3f} |")


def real(args) -> None:
    folder = DATA / "frobisher-colour-hdri"
    if not folder.is_dir():
        print(f"\n## Real: {folder} not available, skipped")
        return
    from PIL import Image

    from hdrcore.exposure import srgb_lut
    from hdrcore.response import recover_response

    names = ["IMG_2600.jpg", "IMG_2601.jpg", "IMG_2602.jpg"]  # 1/8, 1, 8 s
    times = [0.125, 1.0, 8.0]
    raw = [np.asarray(Image.open(folder / n)) for n in names]
    try:
        curve = recover_response(raw, times, max_level=255)
        lut, how = curve.g[1], f"response recovered by hdrcore.response ({curve.method})"
    except Exception as exc:  # the bench still runs if the response stage fails
        lut, how = srgb_lut(255), f"sRGB inverse (response recovery failed: {exc})"
    frames = [lut[f[..., 1]].astype(np.float32) for f in raw]
    sat, nf = float(lut[int(0.97 * 255)]), float(lut[5])
    print(f"\n## Real tripod bracket frobisher-colour-hdri ({how}, EXIF ratio 8)")
    print("\n| pair | ours dx, dy, angle | ours eq. 6 before -> after | AlignMTB shift | "
          "eq. 6 at AlignMTB | ours s | AlignMTB s |")
    print("|---|---|---|---|---|---|---|")
    for i in range(2):
        d, b = frames[i], frames[i + 1]
        k = times[i + 1] / times[i]
        t0 = time.perf_counter()
        r = register_pair(d, b, k, saturation=sat, noise_floor=nf, previews=False)
        t_ours = time.perf_counter() - t0
        t0 = time.perf_counter()
        m_mtb = peer_mtb(d, b, k, sat, nf)
        t_mtb = time.perf_counter() - t0
        data = prepare(d, b, k, saturation=sat, noise_floor=nf, threshold=0.1)
        ev = select_samples(data, 0, 100_000, by_gradient=False, seed=1)
        c_mtb, _ = cost(data, 0, invert(m_mtb), ev)
        print(f"| {i}-{i + 1} ({r.status}) | {r.dx:+.3f}, {r.dy:+.3f}, {r.angle_deg:+.4f} deg | "
              f"{r.cost_before:.5f} -> {r.cost_after:.5f} | {m_mtb[0, 2]:+.0f}, {m_mtb[1, 2]:+.0f}"
              f" | {c_mtb:.5f} | {t_ours:.3f} | {t_mtb:.3f} |")


def real_moved(args) -> None:
    """Real photographs, known motion: frobisher's tripod frames moved by a known rigid motion.

    No real hand-held bracket is available here, so the real content, noise, JPEG artefacts and
    camera response of the frobisher frames are kept and a known shift + rotation is applied to
    the brighter frame of each pair (cubic warp, then a centre crop that removes the borders).
    """
    folder = DATA / "frobisher-colour-hdri"
    if not folder.is_dir():
        print(f"\n## Real + known motion: {folder} not available, skipped")
        return
    from PIL import Image

    from hdrcore.registration import corner_error, rigid_matrix
    from hdrcore.response import recover_response

    names = ["IMG_2600.jpg", "IMG_2601.jpg", "IMG_2602.jpg"]
    times = [0.125, 1.0, 8.0]
    raw = [np.asarray(Image.open(folder / n)) for n in names]
    lut = recover_response(raw, times, max_level=255).g[1]
    frames = [lut[f[..., 1]].astype(np.float32) for f in raw]
    sat, nf = float(lut[int(0.97 * 255)]), float(lut[5])
    h, w = frames[0].shape
    crop = (slice(40, h - 40), slice(40, w - 40))
    shape = (h - 80, w - 80)
    motions = [(7.3, -4.6, 1.2), (-12.8, 9.1, -1.7), (3.4, 15.2, 0.6), (-20.5, -6.7, 1.9)]
    methods = {"ours (fast)": ours("fast"), "AlignMTB": peer_mtb, "ECC euclidean": peer_ecc,
               "SIFT+RANSAC": peer_sift}
    errs: dict[str, list[float]] = {m: [] for m in methods}
    resid: dict[str, list[float]] = {m: [] for m in methods}
    fails = {m: 0 for m in methods}
    for i in range(2):
        k = times[i + 1] / times[i]
        for dx, dy, ang in motions:
            # bright(x) = original_bright(T x): the pair matrix (bright -> dark) is T.
            t_full = rigid_matrix(dx, dy, ang, (h, w))
            moved = warp(frames[i + 1], t_full).image
            d = frames[i][crop]
            b = np.nan_to_num(moved[crop], nan=0.0)
            # Express T in the crop's coordinates: x_full = x_crop + 40.
            shift = np.array([[1, 0, 40], [0, 1, 40]], float)
            back = np.array([[1, 0, -40], [0, 1, -40]], float)
            truth = compose(back, compose(t_full, shift))
            data = prepare(d, b, k, saturation=sat, noise_floor=nf, threshold=0.1)
            ev = select_samples(data, 0, 100_000, by_gradient=False, seed=1)
            for name, fn in methods.items():
                m = fn(d, b, k, sat, nf)
                if m is None:
                    fails[name] += 1
                    continue
                errs[name].append(float(np.mean(corner_error(m, truth, shape))))
                resid[name].append(float(cost(data, 0, invert(m), ev)[0]))
    print("\n## Real content (frobisher JPEGs) + known motion up to 21 px and 1.9 deg, "
          "8 pairs")
    print("\n| method | mean corner error px | worst px | median eq. 6 residual | failed |")
    print("|---|---|---|---|---|")
    for name in methods:
        e = errs[name]
        print(f"| {name} | {np.mean(e) if e else float('nan'):.4f} | "
              f"{np.max(e) if e else float('nan'):.4f} | "
              f"{np.median(resid[name]) if resid[name] else float('nan'):.5f} | "
              f"{fails[name]}/{len(motions) * 2} |")


@contextlib.contextmanager
def numpy_reference():
    """Run the registration on its numpy reference path (the first version's arithmetic)."""
    saved = _kernels.AVAILABLE
    _kernels.AVAILABLE = False
    try:
        yield
    finally:
        _kernels.AVAILABLE = saved


#: The first version's budget: 60 000 full-resolution samples (run on the numpy path).
FIRST_VERSION = {"max_samples": 60_000}


def large_accuracy(args) -> None:
    """Accuracy on large frames, where samples are a subset of the pixels: the numpy reference
    path with the first version's budget (60 000 samples) against the default, same pairs."""
    shape = (2000, 3000)
    times = tuple(2.0 ** (2 * k) / 256 for k in range(3))
    variants = {"numpy reference path, 60k samples (first version's budget)": True,
                "default (compiled)": False}
    errs: dict[str, list[np.ndarray]] = {v: [] for v in variants}
    cpu = {v: 0.0 for v in variants}
    n = 0
    for seed in range(20, 20 + args.large_brackets):
        sb = simulate_bracket(scene="window", shape=shape, exposure_times=times, bits=12,
                              noise_sigma=2.0, shot_noise_full_well=20000, max_shift=15,
                              max_rotation_deg=1.0, key=0.24, seed=seed)
        ml = sb.max_level
        fr = [f[..., 1].astype(np.float32) / ml for f in sb.frames]
        sat, nf = 0.97, max(3.0, 0.02 * ml) / ml
        for i in range(2):
            n += 1
            for name, reference in variants.items():
                kw = FIRST_VERSION if reference else {}
                with numpy_reference() if reference else contextlib.nullcontext():
                    c0 = time.process_time()
                    r = register_pair(fr[i], fr[i + 1], sb.ratios[i], saturation=sat,
                                      noise_floor=nf, previews=False, **kw)
                    cpu[name] += time.process_time() - c0
                errs[name].append(corner_error(r.matrix, sb.pair_matrix(i, i + 1), shape)
                                  if r.ok else np.full(4, np.inf))
    print(f"\n## Large frames: {shape[1]}x{shape[0]} simulated 12-bit brackets (as the pipeline "
          f"bench, motion up to 15 px / 1 deg per frame), {n} pairs")
    print("\n| variant | mean corner error px | worst pair (max corner) px | CPU s/pair |")
    print("|---|---|---|---|")
    for name in variants:
        e = np.array(errs[name])
        print(f"| {name} | {e.mean():.4f} | {e.max():.4f} | {cpu[name] / n:.3f} |")


def big(args) -> None:
    """24-megapixel pairs of the pipeline bench's bracket (bench/bench_pipeline.py), as the
    pipeline registers them (green channel, linear levels): the numpy reference path with the
    first version's budget against the default, in one process."""
    sys.path.insert(0, str(ROOT / "bench"))
    from bench_pipeline import make_bracket

    from hdrcore.io import load_bracket

    d = make_bracket((4000, 6000), 3)
    b = load_bracket([d])
    truth = json.loads((d / "truth.json").read_text())
    ml = b.max_level
    views = [f.levels[..., 1] for f in b.frames]  # strided uint16 channel views
    table = np.arange(ml + 1, dtype=np.float32) * np.float32(1.0 / ml)
    green = [table[v] for v in views]  # what the pipeline passes today (float32)
    sat, nf = 0.97, max(3.0, 0.02 * ml) / ml  # the pipeline's defaults, linear
    ratios = [float(truth["ratios"][k]) for k in range(2)]
    variants = {
        "numpy reference, 60k samples (first version's budget), float32 green": (True, False),
        "default (compiled), float32 green": (False, False),
        "default (compiled), uint16 green view + lut": (False, True),
    }
    print("\n## Speed: 24-megapixel pairs (6000x4000, the pipeline bench's bracket), best of 3, "
          "same run")
    print(f"\nload average before: {os.getloadavg()[0]:.2f} (2 cores)\n")
    print("| variant | pair | best s | best CPU s | iterations | worst corner px |")
    print("|---|---|---|---|---|---|")
    results = {}
    for name, (reference, levels) in variants.items():
        for k in range(2):
            frames = (views[k], views[k + 1]) if levels else (green[k], green[k + 1])
            kw = dict(FIRST_VERSION) if reference else {}
            if levels:
                kw["lut"] = table
            best, best_cpu = np.inf, np.inf
            for _ in range(3):
                with numpy_reference() if reference else contextlib.nullcontext():
                    t0, c0 = time.perf_counter(), time.process_time()
                    r = register_pair(*frames, ratios[k], saturation=sat, noise_floor=nf,
                                      previews=False, **kw)
                    best = min(best, time.perf_counter() - t0)
                    best_cpu = min(best_cpu, time.process_time() - c0)
            err = corner_error(r.matrix, np.array(truth["pairs"][k]["matrix"]), b.shape)
            results[(name, k)] = r
            print(f"| {name} | {k}-{k + 1} | {best:.3f} | {best_cpu:.3f} | {r.iterations} | "
                  f"{err.max():.4f} |")
    r = results[("default (compiled), float32 green", 0)]
    d8, b8 = _gamma8(green[0]), _gamma8(green[1])
    mtb = cv2.createAlignMTB()
    t_mtb = []
    for _ in range(3):
        t0 = time.perf_counter()
        mtb.calculateShift(d8, b8)
        t_mtb.append(time.perf_counter() - t0)
    print(f"\nAlignMTB (integer shift only) on the same pair: best {min(t_mtb):.3f} s")
    t_warp = []
    for _ in range(2):
        t0 = time.perf_counter()
        w = warp_to_reference(green[1], r.matrix)
        t_warp.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    cv2.warpAffine(green[1], np.float32(r.matrix), (6000, 4000), flags=cv2.INTER_CUBIC)
    t_cv = time.perf_counter() - t0
    print(f"\nwarp of one 24 MP channel onto the dark frame (three-shear cubic convolution, "
          f"{w.method}): best {min(t_warp):.3f} s; cv2.warpAffine INTER_CUBIC {t_cv:.3f} s")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--brackets", type=int, default=6)
    p.add_argument("--shape", type=int, nargs=2, default=(384, 576))
    p.add_argument("--no-nm", action="store_true", help="skip the (slow) Nelder-Mead method")
    p.add_argument("--no-big", action="store_true",
                   help="skip the large-frame accuracy and the 24-megapixel timing")
    p.add_argument("--large-brackets", type=int, default=4,
                   help="simulated 6-megapixel brackets for the large-frame accuracy")
    args = p.parse_args()
    print(f"# Registration bench (load average {os.getloadavg()[0]:.2f} on "
          f"{os.cpu_count()} cores; shared machine: timings are pessimistic)")
    synthetic(args)
    real(args)
    real_moved(args)
    if not args.no_big:
        large_accuracy(args)
        big(args)


if __name__ == "__main__":
    main()
