"""Merge speed and memory against OpenCV's MergeDebevec (and MergeMertens) in one run.

    python bench/bench_merge.py            # 3 frames x 24 MP (6000 x 4000) x 3 channels
    python bench/bench_merge.py --mp 6     # smaller
    python bench/bench_merge.py --no-old   # skip today's pipeline path (float32 + shear warp)
    python bench/bench_merge.py --handheld-only  # the 24 MP DNG hand-held merge step only
    python bench/bench_merge.py --handheld-only --retain-memory  # both without first-touch costs
    python bench/bench_merge.py --kernel --mp 6  # the merge kernel alone, 6 input kinds, CPU s

Frames come from ``hdrcore.synthetic.simulate_bracket`` at 750 x 500 and are upsampled by
pixel repetition (generation time excluded). OpenCV needs 8-bit frames, so MergeDebevec always
merges the 8-bit gamma frames (ours: the same frames with the inverse-gamma LUT and hat weights);
the RAW-like rows merge 12-bit linear levels (and float32 linear frames, the pipeline's input) of
the same size. Every row of ours is the merge's one implementation, its compiled kernel (the
numpy engine was removed; ``--kernel``'s table is the before/after of a kernel change). Peak
memory is the rise of the process's peak resident set during the call
(``/proc/self/clear_refs`` resets the peak), which sees OpenCV's C++ allocations too.
Timings on a shared machine are pessimistic; the ratio is what the target is about.

Run it from the repository root with ``PYTHONPATH=.`` (an editable install elsewhere may
otherwise provide ``hdrcore``; the first line prints which one ran).

The "+ warp" rows give ``merge(..., transforms=...)`` a small rotation and shift for 2 of the 3
frames: the kernel resamples them itself (Keys cubic from the levels), so the row is the
whole warp + merge step. The "old path" row is what the pipeline did before: every frame to
float32 linear, the two moved frames warped with ``hdrcore.registration.warp_to_reference``
(clipped samples as NaN), then the merge with masks.

The last table is the target of issue 6 on ``bench_pipeline``'s 24 MP 12-bit DNG hand-held
bracket (built once under ``bench/out/``): the pipeline's merge step (``Pipeline._merge``: warp
+ merge + colour) and OpenCV's MergeDebevec on the same frames, alternating in one process;
the line "hand-held merge step / MergeDebevec" is the ratio the target (<= 0.30) is about.
"""

from __future__ import annotations

import argparse
import gc
import os
import subprocess
import sys
import tempfile
import time
import tracemalloc

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from hdrcore.merge import merge, warm_up  # noqa: E402
from hdrcore.registration import invert, warp_to_reference  # noqa: E402
from hdrcore.synthetic import rigid_matrix, simulate_bracket  # noqa: E402

TIMES = (1.0, 4.0, 16.0)


def _rss_kb(field: str) -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(field):
                return int(line.split()[1])
    return 0


def _reset_peak() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def measure(fn, *, trace: bool) -> tuple[float, float, float, float | None]:
    """(wall s, cpu s, peak RSS rise MB, tracemalloc peak MB)."""
    gc.collect()
    can_reset = _reset_peak()
    base = _rss_kb("VmRSS:")
    if trace:
        tracemalloc.start()
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    traced = None
    if trace:
        traced = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
    peak = (_rss_kb("VmHWM:") - base) / 1024 if can_reset else float("nan")
    del out
    return wall, cpu, peak, traced


def upsample(frames, factor: int):
    return [np.ascontiguousarray(np.repeat(np.repeat(f, factor, 0), factor, 1)) for f in frames]


def accuracy_table() -> list[tuple[str, float]]:
    """Median relative radiance error where some frame was well exposed (small brackets)."""
    rows = []
    for bits, response in ((12, "linear"), (12, "gamma"), (8, "gamma")):
        sb = simulate_bracket(
            shape=(256, 384),
            exposure_times=TIMES,
            bits=bits,
            response=response,
            noise_sigma=1.0,
            keep_linear=True,
            seed=1,
        )
        kw = {"max_level": sb.max_level}
        if response == "gamma":
            kw = {"response": np.tile(np.linspace(0, 1, sb.max_level + 1) ** 2.2, (3, 1))}
        res = merge(sb.frames, sb.exposure_times, **kw)
        well = np.zeros(sb.radiance.shape[:2], bool)
        for lf in sb.linear_frames:
            well |= ((lf > 0.05) & (lf < 0.9)).all(axis=2)
        err = np.abs(res.radiance / sb.key - sb.radiance) / sb.radiance
        rows.append((f"{bits}-bit {response} ({res.weighting})", float(np.median(err[well]))))
    return rows


def warp_accuracy_table() -> list[tuple[str, float, float]]:
    """Hand-held brackets merged with their TRUE motion: median relative radiance error (well
    exposed, 16 px from the border; resampled levels through a LUT are interpolated, then read
    linearly between the LUT's entries) and the ratio of the sharpness (mean gradient magnitude
    of log luminance) to the same scene shot on a tripod."""
    rows = []
    for bits, response in ((12, "linear"), (12, "gamma"), (8, "gamma")):
        sb = simulate_bracket(
            shape=(256, 384),
            exposure_times=TIMES,
            bits=bits,
            response=response,
            noise_sigma=1.0,
            keep_linear=True,
            seed=3,
            max_shift=6.0,
            max_rotation_deg=1.5,
        )
        tf = [invert(t) for t in sb.to_reference]
        kw = {"max_level": sb.max_level}
        if response == "gamma":
            kw = {"response": np.tile(np.linspace(0, 1, sb.max_level + 1) ** 2.2, (3, 1))}
        well = np.zeros(sb.radiance.shape[:2], bool)
        for lf in sb.linear_frames:
            well |= ((lf > 0.05) & (lf < 0.9)).all(axis=2)
        well[:16] = well[-16:] = False
        well[:, :16] = well[:, -16:] = False
        tripod = simulate_bracket(
            sb.radiance,
            exposure_times=TIMES,
            bits=bits,
            response=response,
            noise_sigma=1.0,
            key=sb.key,
            seed=3,
        )
        sharp_ref = _sharpness(merge(tripod.frames, TIMES, **kw).radiance, well)
        res = merge(sb.frames, sb.exposure_times, transforms=tf, **kw)
        err = np.abs(res.radiance / sb.key - sb.radiance) / sb.radiance
        rows.append(
            (
                f"{bits}-bit {response}",
                float(np.median(err[well])),
                _sharpness(res.radiance, well) / sharp_ref,
            )
        )
        blind = merge(sb.frames, sb.exposure_times, **kw)
        err = np.abs(blind.radiance / sb.key - sb.radiance) / sb.radiance
        rows.append(
            (
                f"{bits}-bit {response}, motion ignored",
                float(np.median(err[well])),
                _sharpness(blind.radiance, well) / sharp_ref,
            )
        )
    return rows


def deghost_table() -> list[tuple[str, float, float, float]]:
    """An object that moved: a 32 x 32 square 3x brighter than the scene in one frame only, on
    a tripod and on a hand-held bracket (merged with its true motion). Median relative
    radiance error over the object, to the nearer of the scene behind it and the object as its
    frame saw it (deghosting may keep either; the weighted average matches neither): the
    weighted average against ``deghost=True``; and the share of the image replaced."""
    rows = []
    sq = (slice(60, 92), slice(120, 152))
    for label, motion in (
        ("tripod", {}),
        ("hand-held", {"max_shift": 6.0, "max_rotation_deg": 1.5}),
    ):
        sb = simulate_bracket(
            shape=(256, 384),
            exposure_times=TIMES,
            bits=12,
            response="linear",
            noise_sigma=1.0,
            keep_linear=True,
            seed=5,
            **motion,
        )
        tf = [invert(t) for t in sb.to_reference] if motion else None
        for k in range(len(TIMES)):
            frames = [f.copy() for f in sb.frames]
            frames[k][sq] = np.minimum(frames[k][sq].astype(np.int64) * 3, sb.max_level).astype(
                frames[k].dtype
            )
            # where the object lands on the output grid (frame k's pixels mapped back)
            where = np.zeros(sb.radiance.shape[:2], bool)
            if tf is None or tf[k] is None:
                where[sq] = True
            else:
                yy, xx = np.mgrid[0 : where.shape[0], 0 : where.shape[1]].astype(float)
                fx = tf[k][0, 0] * xx + tf[k][0, 1] * yy + tf[k][0, 2]
                fy = tf[k][1, 0] * xx + tf[k][1, 1] * yy + tf[k][1, 2]
                where = (
                    (fy >= sq[0].start + 2)
                    & (fy < sq[0].stop - 2)
                    & (fx >= sq[1].start + 2)
                    & (fx < sq[1].stop - 2)
                )
            errs = []
            # deghosting may keep the object (the frame it chose saw it) or the scene behind:
            # the error is to the nearer of the two (the weighted average matches neither)
            scene = sb.radiance * sb.key
            seen = merge(
                [frames[k]],
                [sb.exposure_times[k]],
                max_level=sb.max_level,
                transforms=None if tf is None else [tf[k]],
            ).radiance
            for dg in (False, True):
                res = merge(
                    frames, sb.exposure_times, max_level=sb.max_level, transforms=tf, deghost=dg
                )
                with np.errstate(divide="ignore", invalid="ignore"):
                    err = np.fmin(np.abs(res.radiance / scene - 1), np.abs(res.radiance / seen - 1))
                errs.append(float(np.median(err[where])))
            rows.append(
                (f"{label}, object in frame {k}", errs[0], errs[1], float(res.deghosted.mean()))
            )
    return rows


def _sharpness(radiance: np.ndarray, region: np.ndarray) -> float:
    lum = np.log(np.maximum(radiance.mean(axis=2), 1e-6))
    gy, gx = np.gradient(lum)
    return float(np.mean(np.hypot(gx, gy)[region]))


def old_path(frames, max_level: int, to_reference, saturation: float):
    """Today's pipeline: float32 linear frames, shear warp of the moved frames, then merge."""
    floats, masks = [], []
    for f, m in zip(frames, to_reference, strict=True):
        lin = np.multiply(f, np.float32(1.0 / max_level), dtype=np.float32)
        if m is None:
            floats.append(lin)
            masks.append(None)
            continue
        lin[f >= saturation] = np.nan
        wr = warp_to_reference(lin, m, fill=0.0)
        img = wr.image
        np.nan_to_num(img, copy=False, nan=1.0)
        floats.append(img)
        masks.append(wr.mask)
        del lin
    return merge(floats, TIMES, masks=masks, saturation_level=saturation / max_level)


def compile_times() -> tuple[float, float]:
    """(cold, cached) seconds of :func:`hdrcore.merge.warm_up` in fresh processes: cold with an
    empty numba cache directory (everything compiled), cached with the default cache (loaded)."""
    code = "import time; from hdrcore.merge import warm_up; print(warm_up())"
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, NUMBA_CACHE_DIR=tmp)
        cold = float(
            subprocess.run(
                [sys.executable, "-c", code], env=env, check=True, capture_output=True, text=True
            ).stdout.split()[-1]
        )
    cached = float(
        subprocess.run(
            [sys.executable, "-c", code], check=True, capture_output=True, text=True
        ).stdout.split()[-1]
    )
    return cold, cached


def handheld_dng(reps: int = 3) -> None:
    """The issue-6 target on ``bench_pipeline``'s 24 MP 12-bit DNG hand-held bracket (two frames
    moved by a shift and a rotation): the merge step -- what ``Pipeline._merge`` runs: warp +
    merge + colour conversion -- against ``cv2.createMergeDebevec().process`` on the same frames
    as 8-bit (as ``bench_pipeline``'s OpenCV child gives them), alternating in this process,
    ``reps`` times each; also the same step without the registration (tripod: no warp)."""
    import cv2

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from bench_pipeline import make_bracket

    from hdrcore.io import load_bracket
    from hdrcore.pipeline import Pipeline, PipelineParams

    d = make_bracket((4000, 6000), 3)
    bracket = load_bracket([d])
    pipe = Pipeline(bracket, PipelineParams(preview_max_side=2048, registration_previews=False))
    res = pipe.run(until="overlap_ratios")
    reg = res.registration
    imgs8 = []
    for f in bracket.frames:
        x = np.minimum(f.levels, f.max_level).astype(np.float32) * (255.0 / f.max_level)
        imgs8.append(np.ascontiguousarray(np.rint(x).astype(np.uint8)[..., ::-1]))
    times32 = np.asarray(res.exposure_times, np.float32)
    moved = [k for k in range(len(bracket)) if reg is not None and k != reg.reference]
    h, w = bracket.shape
    print(
        f"\nhand-held DNG bracket {d.name}: {len(bracket)} frames of {w} x {h}, frames "
        f"{moved} resampled (reference {None if reg is None else reg.reference}); "
        f"load average {os.getloadavg()[0]:.2f}"
    )

    def timed(fn):
        gc.collect()
        t0, c0, s0 = time.perf_counter(), time.process_time(), os.times().system
        out = fn()
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        sys_s = os.times().system - s0
        del out
        return wall, cpu, sys_s

    def ours(registration, reuse=None):
        # with reuse: the previous result's arrays, as Pipeline(reuse_buffers=True) hands over
        return pipe._merge(res.params, res.lut, res.exposure_times, registration, None, reuse=reuse)

    prev = ours(reg)[0]  # kernels compiled or loaded from numba's cache outside the runs
    # OpenCV's way to the same hand-held result: each moved frame resampled (bicubic, as our
    # Keys cubic) onto the reference grid, then MergeDebevec. Our transforms map output pixels
    # into the frame: exactly warpAffine's WARP_INVERSE_MAP convention.
    cv_mats = [
        None if k not in moved else np.asarray(invert(reg.to_reference[k]), np.float64)
        for k in range(len(bracket))
    ]

    def cv_handheld():
        warped = [
            img
            if m is None
            else cv2.warpAffine(
                img,
                m,
                (w, h),
                flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP,
                borderMode=cv2.BORDER_REPLICATE,
            )
            for img, m in zip(imgs8, cv_mats, strict=True)
        ]
        return cv2.createMergeDebevec().process(warped, times32)

    rows: dict[str, list[tuple[float, float, float]]] = {
        "debevec": [],
        "cv-hand-held": [],
        "hand-held": [],
        "reuse": [],
        "tripod": [],
    }
    for _ in range(reps):
        rows["debevec"].append(timed(lambda: cv2.createMergeDebevec().process(imgs8, times32)))
        rows["cv-hand-held"].append(timed(cv_handheld))
        rows["hand-held"].append(timed(lambda: ours(reg)))
        rows["reuse"].append(timed(lambda: ours(reg, reuse=prev)))
        rows["tripod"].append(timed(lambda: ours(None)))
    ref = min(t for t, _, _ in rows["debevec"])
    ref_hh = min(t for t, _, _ in rows["cv-hand-held"])
    print(
        f"{'':48s} {'min wall s':>10s} {'cpu s':>6s} {'sys s':>6s} {'/Debevec':>9s} "
        f"{'per run':>12s}"
    )
    for name, label in (
        ("debevec", "OpenCV MergeDebevec (8-bit)"),
        ("cv-hand-held", "OpenCV warpAffine cubic x2 + MergeDebevec"),
        ("tripod", "ours: merge step (+ colour), frames as given"),
        ("hand-held", "ours: merge step, hand-held (warps 2 frames)"),
        ("reuse", "  the same, merge(..., reuse=previous)"),
    ):
        wall, cpu, sys_s = min(rows[name])
        per = [r[0] / d[0] for r, d in zip(rows[name], rows["debevec"], strict=True)]
        print(
            f"{label:48s} {wall:10.2f} {cpu:6.2f} {sys_s:6.2f} {wall / ref:9.2f} "
            f"{min(per):5.2f}..{max(per):.2f}"
        )
    print(
        f"merge step / MergeDebevec on the same frames: {min(rows['tripod'])[0] / ref:.2f}   "
        f"target <= 0.30"
    )
    print(
        f"hand-held: our warp + merge / OpenCV warpAffine x2 + MergeDebevec: "
        f"{min(rows['hand-held'])[0] / ref_hh:.2f}; / MergeDebevec alone: "
        f"{min(rows['hand-held'])[0] / ref:.2f}"
    )
    print(
        f"(min over {reps} alternating runs; 'per run' pairs each run with the Debevec run "
        "before it. sys s: mostly the first touch of new arrays; on a virtual machine memory "
        "the process has not touched recently is slow to fault in, so the plain rows vary "
        "run to run; reuse= writes into pages already touched)"
    )


def kernel_table(mp: float, reps: int) -> None:
    """The merge kernel alone on the input kinds it has paths for (one worker, ``ghost_test=
    "pixels"``: no region test), min and median CPU seconds over ``reps`` runs taken in turn:
    the before/after table of a kernel change (run both trees in turn; the machine's load
    moves wall times far more than CPU times)."""
    factor = max(1, int(round(np.sqrt(mp * 1e6 / (750 * 500)))))
    s12 = simulate_bracket(
        shape=(500, 750), exposure_times=TIMES, bits=12, response="linear", noise_sigma=1.0, seed=1
    )
    s8 = simulate_bracket(
        shape=(500, 750), exposure_times=TIMES, bits=8, response="gamma", noise_sigma=1.0, seed=1
    )
    f12 = upsample(s12.frames, factor)
    f8 = upsample(s8.frames, factor)
    ff = [np.asarray(f, np.float32) / np.float32(4095) for f in f12]
    lut = np.tile(np.linspace(0, 1, 256) ** 2.2, (3, 1))
    h, w = f12[0].shape[:2]

    def rot(deg: float, dx: float, dy: float) -> np.ndarray:
        c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
        cx, cy = w / 2, h / 2
        return np.array([[c, -s, cx - c * cx + s * cy + dx], [s, c, cy - s * cx - c * cy + dy]])

    tf = [rot(0.3, 2.5, -1.5), None, rot(-0.2, -3.25, 2.0)]
    kw = {"workers": 1, "ghost_test": "pixels", "engine": "numba"}
    cases = {
        "12-bit linear, noise-aware": lambda: merge(f12, TIMES, max_level=4095, **kw),
        "8-bit LUT, hat (level tables)": lambda: merge(f8, TIMES, response=lut, **kw),
        "float32, noise-aware": lambda: merge(ff, TIMES, **kw),
        "float32, hat": lambda: merge(ff, TIMES, weighting="hat", **kw),
        "12-bit, 2 of 3 resampled (cubic)": lambda: merge(
            f12, TIMES, max_level=4095, transforms=tf, **kw
        ),
        "8-bit LUT hat, 2 of 3 resampled": lambda: merge(
            f8, TIMES, response=lut, transforms=tf, **kw
        ),
    }
    for fn in cases.values():
        fn()  # compiled or loaded outside the runs
    cpu: dict[str, list[float]] = {name: [] for name in cases}
    for _ in range(reps):
        for name, fn in cases.items():
            c0 = time.process_time()
            out = fn()
            cpu[name].append(time.process_time() - c0)
            del out
    import hdrcore

    print(
        f"hdrcore from {os.path.dirname(hdrcore.__file__)}; 3 frames of {w} x {h}, "
        f"{reps} runs, load average {os.getloadavg()[0]:.2f}"
    )
    print(f"{'merge kernel, workers=1':36s} {'min cpu s':>10s} {'median':>8s}")
    for name, v in cpu.items():
        print(f"{name:36s} {min(v):10.3f} {float(np.median(v)):8.3f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mp", type=float, default=24.0, help="megapixels per frame (default 24)")
    ap.add_argument(
        "--handheld-only",
        action="store_true",
        help="only the 24 MP DNG hand-held merge step against MergeDebevec",
    )
    ap.add_argument("--mertens", action="store_true", help="also time MergeMertens")
    ap.add_argument("--no-old", action="store_true", help="skip today's pipeline path row")
    ap.add_argument(
        "--retain-memory",
        action="store_true",
        help="glibc keeps freed memory, as the hdrcore program does "
        "(hdrcore._memory); both contenders then reuse touched pages",
    )
    ap.add_argument(
        "--kernel",
        action="store_true",
        help="only the merge kernel's CPU time on 6 input kinds (before/after)",
    )
    ap.add_argument("--reps", type=int, default=5, help="runs per row of --kernel")
    args = ap.parse_args()
    if args.kernel:
        kernel_table(args.mp, args.reps)
        return
    import cv2

    if args.retain_memory:
        from hdrcore._memory import retain_freed_memory

        print(f"# allocator: freed memory kept and reused: {retain_freed_memory()}")
    if args.handheld_only:
        warm_up()
        handheld_dng()
        return
    t_compile = compile_times()
    warm_up()  # compile/load outside the timed rows
    factor = max(1, int(round(np.sqrt(args.mp * 1e6 / (750 * 500)))))
    small = (500, 750)
    g8 = simulate_bracket(shape=small, exposure_times=TIMES, bits=8, response="gamma", seed=0)
    r12 = simulate_bracket(shape=small, exposure_times=TIMES, bits=12, response="linear", seed=0)
    fr8 = [f.astype(np.uint8) for f in upsample(g8.frames, factor)]
    fr12 = upsample(r12.frames, factor)
    h, w = fr8[0].shape[:2]
    lut = np.tile(np.linspace(0.0, 1.0, 256) ** 2.2, (3, 1))
    times32 = np.asarray(TIMES, np.float32)
    load0 = os.getloadavg()
    import hdrcore

    print(f"hdrcore from {os.path.dirname(hdrcore.__file__)}")
    print(
        f"3 frames of {w} x {h} ({h * w / 1e6:.1f} MP) x 3 channels; cpu count "
        f"{os.cpu_count()}, load average {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}"
    )

    def debevec():
        return measure(lambda: cv2.createMergeDebevec().process(fr8, times32), trace=False)

    rows = [("OpenCV MergeDebevec (8-bit)", *debevec())]
    if args.mertens:
        rows.append(
            (
                "OpenCV MergeMertens (8-bit)",
                *measure(lambda: cv2.createMergeMertens().process(fr8), trace=False),
            )
        )
    cases = [
        ("12-bit linear, noise-aware", fr12, {"max_level": 4095}),
        ("8-bit + LUT, hat", fr8, {"response": lut}),
    ]
    for label, frames, kw in cases:
        rows.append(
            (
                f"ours {label}",
                *measure(lambda frames=frames, kw=kw: merge(frames, TIMES, **kw), trace=False),
            )
        )
    # a small hand-held motion for frames 0 and 2 (frame 1 is the reference)
    to_ref = [rigid_matrix(3.3, -2.7, 0.4, (h, w)), None, rigid_matrix(-4.1, 1.9, -0.3, (h, w))]
    tf = [None if m is None else invert(m) for m in to_ref]
    for label, frames, kw in cases:
        rows.append(
            (
                f"ours {label} + warp 2 frames",
                *measure(
                    lambda frames=frames, kw=kw: merge(frames, TIMES, transforms=tf, **kw),
                    trace=False,
                ),
            )
        )
        rows.append(
            (
                f"ours {label} + warp 2 bilinear",
                *measure(
                    lambda frames=frames, kw=kw: merge(
                        frames, TIMES, transforms=tf, resample="bilinear", **kw
                    ),
                    trace=False,
                ),
            )
        )
    if not args.no_old:
        rows.append(
            (
                "old path: float32 + shear warp 2 + merge (12-bit)",
                *measure(lambda: old_path(fr12, 4095, to_ref, 0.98 * 4095), trace=False),
            )
        )
    fr32 = [f.astype(np.float32) * np.float32(1 / 4095) for f in fr12]
    rows.append(
        (
            "ours float32 linear, noise-aware",
            *measure(lambda: merge(fr32, TIMES), trace=False),
        )
    )
    fr32.clear()
    # Debevec again at the end: the machine is shared, so bracket our rows with two references.
    rows.append(("OpenCV MergeDebevec (8-bit), again", *debevec()))
    ref = min(rows[0][1], rows[-1][1])
    load1 = os.getloadavg()

    print()
    print(f"{'method':54s} {'wall s':>7s} {'cpu s':>7s} {'/Debevec':>9s} {'peak RSS+ MB':>13s}")
    for name, wall, cpu, peak, _ in rows:
        print(f"{name:54s} {wall:7.2f} {cpu:7.2f} {wall / ref:9.2f} {peak:13.0f}")
    print(
        f"(ratio against the faster of the two MergeDebevec runs, {ref:.2f} s; "
        f"load average at the end {load1[0]:.2f})"
    )
    print(
        f"numba compilation of the kernels (warm_up): cold cache {t_compile[0]:.1f} s, "
        f"cached {t_compile[1]:.2f} s"
    )

    print()
    print(f"{'accuracy (median relative radiance error, well exposed)':60s}")
    for name, err in accuracy_table():
        print(f"  {name:40s} {100 * err:6.3f} %")
    print()
    print("hand-held brackets (shift <= 6 px, rotation <= 1.5 deg) merged with the TRUE motion")
    print(f"  {'case':40s} {'median err':>10s} {'sharpness / tripod':>19s}")
    for name, err, sharp in warp_accuracy_table():
        print(f"  {name:40s} {100 * err:8.3f} % {sharp:19.3f}")
    print()
    print(
        "an object in one frame only (32 x 32, 3x the scene): median error over it, to the "
        "nearer of scene and object"
    )
    print(f"  {'case':40s} {'average':>9s} {'deghost':>9s} {'replaced':>9s}")
    for name, plain, fixed, frac in deghost_table():
        print(f"  {name:40s} {100 * plain:7.2f} % {100 * fixed:7.3f} % {100 * frac:7.2f} %")
    handheld_dng()


if __name__ == "__main__":
    main()
