"""Tonemapped previews (issue 16, part 2): which operator ``"auto"`` picks, how long it takes and
how much of the scene it keeps readable, beside OpenCV's operators and exposure fusion.

Per bracket of ../shared/data (merged by the pipeline, reduced to the preview's 2048 px): the
scene's dynamic range (stops between the 1st and 99th percentiles of luminance), the operator
``"auto"`` chose, and for each operator:

* ``in range``: of the pixels whose scene luminance lies between its 1st and 99th percentiles,
  the % whose output luma (sRGB, 0-255) lies within 5-95 % of the display range (13-242):
  pixels outside are crushed or clipped, their detail gone;
* ``detail hi`` / ``detail lo``: the mean absolute difference of output luma between
  neighbouring pixels (levels) over the brightest / darkest tenth of the scene (its
  luminance deciles): the local contrast left in the window and in the shadows;
* ``ms``: time of the operator on the preview (ours: including the statistics).

OpenCV's operators get the same preview-size radiance map (BGR, gamma 2.2 as their
documentation's examples); ``cv2-mertens`` fuses the frames themselves (as loaded: hand-held
frames are not registered for it). A last table times the preview of a 22-megapixel map:
reduction to 2048 px and each operator.

    python bench/bench_tonemap.py [--sets frobisher,memorial,pixel7,xperia]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hdrcore.io import load_bracket  # noqa: E402
from hdrcore.pipeline import Pipeline, PipelineParams  # noqa: E402
from hdrcore.resample import downsample_area, downsample_factor  # noqa: E402
from hdrcore.tonemap import AUTO_LOCAL_STOPS, tonemap  # noqa: E402

DATA = (ROOT / ".." / "shared" / "data").resolve()
PREVIEW = 2048

REAL = {
    "frobisher": ("frobisher-colour-hdri", None, {}),
    "memorial": (
        "memorial-debevec",
        "exposure_times.txt",
        dict(exclude_colour=(0, 0, 255), align="none"),
    ),
    "pixel7": ("handheld-pixel7-lab", None, dict(registration_max_pixels=3_000_000)),
    "xperia": (
        "handheld-xperia-library",
        "iso100_equivalent_times.txt",
        dict(registration_max_pixels=3_000_000),
    ),
}
LUMA = np.array([0.2126, 0.7152, 0.0722])


def merged(name: str):
    folder, times_name, kw = REAL[name]
    d = DATA / folder
    files = sorted(p for p in d.iterdir() if p.suffix.lower() in (".jpg", ".png"))
    b = load_bracket(files, exposure_times=None if times_name is None else d / times_name)
    r = Pipeline(b, PipelineParams(registration_previews=False, **kw)).run(until="merge")
    return b, r.radiance


def measures(image: np.ndarray, scene_lum: np.ndarray) -> tuple[float, float, float]:
    """``(in range %, detail hi, detail lo)`` of an 8-bit sRGB image (see the docstring)."""
    luma = image.astype(np.float64) @ LUMA
    ok = np.isfinite(scene_lum) & (scene_lum > 0)
    lg = np.log2(np.where(ok, scene_lum, 1.0))
    p1, p10, p90, p99 = np.percentile(lg[ok], [1, 10, 90, 99])
    mid = ok & (lg >= p1) & (lg <= p99)
    inside = (luma >= 0.05 * 255) & (luma <= 0.95 * 255)
    grad = np.zeros_like(luma)
    grad[:, :-1] += np.abs(np.diff(luma, axis=1))
    grad[:-1, :] += np.abs(np.diff(luma, axis=0))
    grad /= 2
    hi = ok & (lg >= p90)
    lo = ok & (lg <= p10)
    return (100.0 * float(inside[mid].mean()), float(grad[hi].mean()), float(grad[lo].mean()))


def opencv_operators():
    try:
        import cv2
    except ImportError:
        return {}
    return {
        "cv2-drago": lambda bgr: cv2.createTonemapDrago(2.2, 1.0, 0.85).process(bgr),
        "cv2-reinhard": lambda bgr: cv2.createTonemapReinhard(2.2, 0.0, 0.0, 0.0).process(bgr),
        "cv2-mantiuk": lambda bgr: cv2.createTonemapMantiuk(2.2, 0.85, 1.2).process(bgr),
    }


def mertens(b, factor: int) -> np.ndarray | None:
    try:
        import cv2
    except ImportError:
        return None
    frames = []
    for f in b.frames:
        lv = f.levels.astype(np.float32) / float(f.max_level)
        small = downsample_area(lv, factor) if factor > 1 else lv
        frames.append(np.clip(np.rint(small[..., ::-1] * 255), 0, 255).astype(np.uint8))
    fused = cv2.createMergeMertens().process(frames)
    return np.clip(np.rint(fused[..., ::-1] * 255), 0, 255).astype(np.uint8)


def bracket_table(names: list[str]) -> None:
    print(f"\n## Previews at {PREVIEW} px: 'auto' is 'durand' above {AUTO_LOCAL_STOPS:g} stops")
    print(
        f"{'bracket':<10} {'stops':>5} {'auto':>8} | {'operator':<13} {'in range %':>10} "
        f"{'detail hi':>9} {'detail lo':>9} {'ms':>7}"
    )
    cv = opencv_operators()
    for name in names:
        if not (DATA / REAL[name][0]).is_dir():
            continue
        b, rad = merged(name)
        factor = downsample_factor(rad.shape[:2], PREVIEW)
        small = downsample_area(rad, factor) if factor > 1 else rad
        small = np.ascontiguousarray(small, dtype=np.float32)
        scene = small.astype(np.float64) @ LUMA
        auto = tonemap(small, "auto", pixel_size=factor)
        rows = []
        for method in ("reinhard", "durand", "auto"):
            tonemap(small[:64, :64], method)  # compiled kernels loaded
            t0 = time.perf_counter()
            res = tonemap(small, method, pixel_size=factor)
            rows.append(
                (
                    method if method != "auto" else f"auto={res.method}",
                    res.image,
                    time.perf_counter() - t0,
                )
            )
        bgr = np.ascontiguousarray(np.nan_to_num(small[..., ::-1], nan=0.0, posinf=0.0))
        for label, op in cv.items():
            t0 = time.perf_counter()
            out = op(bgr)
            dt = time.perf_counter() - t0
            rows.append(
                (
                    label,
                    np.clip(np.rint(np.nan_to_num(out[..., ::-1]) * 255), 0, 255).astype(np.uint8),
                    dt,
                )
            )
        t0 = time.perf_counter()
        fused = mertens(b, factor)
        if fused is not None:
            rows.append(("cv2-mertens", fused, time.perf_counter() - t0))
        for i, (label, image, dt) in enumerate(rows):
            inr, hi, lo = measures(image, scene)
            head = (
                f"{name:<10} {auto.dynamic_range:>5.1f} {auto.method:>8}"
                if i == 0
                else f"{'':<10} {'':>5} {'':>8}"
            )
            print(f"{head} | {label:<13} {inr:>10.1f} {hi:>9.2f} {lo:>9.2f} {1e3 * dt:>7.1f}")


def timing_table() -> None:
    """The preview of a 22-megapixel map (the frobisher map repeated 9 x 9)."""
    if not (DATA / REAL["frobisher"][0]).is_dir():
        return
    _, rad = merged("frobisher")
    big = np.ascontiguousarray(np.repeat(np.repeat(rad, 9, axis=0), 9, axis=1))
    factor = downsample_factor(big.shape[:2], PREVIEW)
    downsample_area(big[:512, :512], factor)
    t0 = time.perf_counter()
    small = downsample_area(big, factor)
    t_down = time.perf_counter() - t0
    print(
        f"\n## Preview of a {big.shape[1]}x{big.shape[0]} map "
        f"({big.shape[0] * big.shape[1] / 1e6:.1f} MP): reduction to "
        f"{small.shape[1]}x{small.shape[0]} {1e3 * t_down:.0f} ms"
    )
    print(f"{'operator':<10} {'ms':>7}")
    for method in ("reinhard", "durand", "auto"):
        best = min(_timed(small, method, factor) for _ in range(3))
        print(f"{method:<10} {1e3 * best:>7.1f}")


def _timed(small: np.ndarray, method: str, factor: int) -> float:
    t0 = time.perf_counter()
    tonemap(small, method, pixel_size=factor)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default=None, help="comma-separated subset of " + ",".join(REAL))
    args = ap.parse_args()
    if not DATA.is_dir():
        print(f"{DATA} not found: nothing to measure")
        return
    names = [s for s in args.sets.split(",") if s in REAL] if args.sets else list(REAL)
    bracket_table(names)
    timing_table()


if __name__ == "__main__":
    main()
