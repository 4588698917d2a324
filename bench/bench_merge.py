"""Merge speed and memory against OpenCV's MergeDebevec (and MergeMertens) in one run.

    python bench/bench_merge.py            # 3 frames x 24 MP (6000 x 4000) x 3 channels
    python bench/bench_merge.py --mp 6     # smaller

Frames come from ``hdrcore.synthetic.simulate_bracket`` at 750 x 500 and are upsampled by
pixel repetition (generation time excluded). OpenCV needs 8-bit frames, so the head-to-head rows
use the same 8-bit gamma frames (ours with the inverse-gamma LUT and hat weights); the RAW-like
rows merge 12-bit linear levels and float32 linear frames. Peak memory is the rise of the
process's peak resident set during the call (``/proc/self/clear_refs`` resets the peak), which
sees OpenCV's C++ allocations too; tracemalloc's peak of numpy allocations is shown for ours.
Timings on a shared machine are pessimistic; the ratio is what the target is about.
"""

from __future__ import annotations

import argparse
import gc
import os
import time
import tracemalloc

import numpy as np

from hdrcore.merge import merge
from hdrcore.synthetic import simulate_bracket

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
            shape=(256, 384), exposure_times=TIMES, bits=bits, response=response,
            noise_sigma=1.0, keep_linear=True, seed=1,
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mp", type=float, default=24.0, help="megapixels per frame (default 24)")
    ap.add_argument("--no-mertens", action="store_true", help="skip MergeMertens")
    args = ap.parse_args()
    import cv2

    factor = max(1, int(round(np.sqrt(args.mp * 1e6 / (750 * 500)))))
    small = (500, 750)
    g8 = simulate_bracket(shape=small, exposure_times=TIMES, bits=8, response="gamma", seed=0)
    r12 = simulate_bracket(shape=small, exposure_times=TIMES, bits=12, response="linear", seed=0)
    fr8 = [f.astype(np.uint8) for f in upsample(g8.frames, factor)]
    fr12 = upsample(r12.frames, factor)
    h, w = fr8[0].shape[:2]
    lut = np.tile(np.linspace(0.0, 1.0, 256) ** 2.2, (3, 1))
    times32 = np.asarray(TIMES, np.float32)
    print(f"3 frames of {w} x {h} ({h * w / 1e6:.1f} MP) x 3 channels; cpu count "
          f"{os.cpu_count()}, load average {os.getloadavg()[0]:.2f}")

    rows = []
    wall, cpu, peak, _ = measure(
        lambda: cv2.createMergeDebevec().process(fr8, times32), trace=False
    )
    debevec = wall
    rows.append(("OpenCV MergeDebevec (8-bit)", wall, cpu, peak, None))
    if not args.no_mertens:
        rows.append(("OpenCV MergeMertens (8-bit)",
                     *measure(lambda: cv2.createMergeMertens().process(fr8), trace=False)))
    for workers in (1, 2):
        rows.append((f"ours 8-bit + LUT, hat, {workers} thread(s)", *measure(
            lambda workers=workers: merge(fr8, TIMES, response=lut, workers=workers),
            trace=True)))
    for workers in (1, 2):
        rows.append((f"ours 12-bit linear, noise-aware, {workers} thread(s)", *measure(
            lambda workers=workers: merge(fr12, TIMES, max_level=4095, workers=workers),
            trace=True)))
    fr32 = [f.astype(np.float32) * np.float32(1 / 4095) for f in fr12]
    rows.append(("ours float32 linear, noise-aware, 2 threads", *measure(
        lambda: merge(fr32, TIMES, workers=2), trace=True)))
    # Debevec again at the end: the machine is shared, so bracket our rows with two references.
    wall2, cpu2, peak2, _ = measure(
        lambda: cv2.createMergeDebevec().process(fr8, times32), trace=False
    )
    rows.append(("OpenCV MergeDebevec (8-bit), again", wall2, cpu2, peak2, None))
    ref = min(debevec, wall2)

    print()
    print(f"{'method':52s} {'wall s':>8s} {'cpu s':>8s} {'/Debevec':>9s} "
          f"{'peak RSS+ MB':>13s} {'tracemalloc MB':>15s}")
    for name, wall, cpu, peak, traced in rows:
        tr = f"{traced:15.0f}" if traced is not None else f"{'-':>15s}"
        print(f"{name:52s} {wall:8.2f} {cpu:8.2f} {wall / ref:9.2f} {peak:13.0f} {tr}")
    print(f"(ratio against the faster of the two MergeDebevec runs, {ref:.2f} s)")

    print()
    print(f"{'accuracy (median relative radiance error, well exposed)':60s}")
    for name, err in accuracy_table():
        print(f"  {name:40s} {100 * err:6.3f} %")


if __name__ == "__main__":
    main()
