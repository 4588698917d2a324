"""Local refinement (issue 14) on the real hand-held brackets, beside OpenCV's DIS optical flow.

Run: ``python bench/bench_local.py [--brackets NAME ...]``

For each bracket in ``../shared/data`` (Pixel 7 and Xperia hand-held phone JPEGs): the pipeline's
registration (``--align auto``: similarity, homography where perspective is left; ``--align
similarity`` for the pipeline's default), then for every
frame's pair, the remaining misalignment measured independently of the motion model at full
resolution (:func:`hdrcore.registration.residual.residual_motion` on the green channel, the
frame warped beforehand by a cubic spline: median and 90th percentile of the tile shifts, px)

- after the global motion alone;
- after the global motion and our field (``local="on"``: every frame refined, kept or not);
- after the global motion and OpenCV's DIS optical flow (``cv2.DISOpticalFlow``, preset
  MEDIUM, on the exposure-equalised log images at 8 bits, the frame pair as our refinement
  sees it): a dense local aligner, the peer that refines per pixel.

and the seconds of our refinement per frame (CPU-shared 2-core machine: pessimistic).

``--speed``: the rendered 24-megapixel pair of ``bench_models_real.py --speed`` (cached in
``bench/out``), its true motion as the global one: the refinement's wall and CPU seconds (best
of 3) beside OpenCV's AlignMTB on the same pair in the same run, as a ratio. cv2 is used only
here, never in ``hdrcore``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np
from scipy import ndimage

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hdrcore.io import load_bracket  # noqa: E402
from hdrcore.pipeline import Pipeline, PipelineParams  # noqa: E402
from hdrcore.registration.field import map_points  # noqa: E402
from hdrcore.registration.local import refine_bracket  # noqa: E402
from hdrcore.registration.residual import residual_motion  # noqa: E402

DATA = (ROOT / ".." / "shared" / "data").resolve()


def _warp(img: np.ndarray, m: np.ndarray, field=None, flow=None) -> np.ndarray:
    h, w = img.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    sx, sy = map_points(m, field, xx, yy)
    if flow is not None:
        sx = sx + flow[..., 0]
        sy = sy + flow[..., 1]
    out = ndimage.map_coordinates(img.astype(np.float32), [sy, sx], order=3, mode="nearest")
    out[~((sx >= 0) & (sx <= w - 1) & (sy >= 0) & (sy <= h - 1))] = np.nan
    return out.astype(np.float32)


def _log8(v: np.ndarray, lo: float, hi: float) -> np.ndarray:
    t = (np.log(np.clip(np.nan_to_num(v, nan=lo), lo, hi)) - np.log(lo)) / (np.log(hi) - np.log(lo))
    return np.clip(np.rint(t * 255), 0, 255).astype(np.uint8)


def run(name: str, tile: int | None = None, align: str = "auto") -> None:
    folder = DATA / name
    if not folder.is_dir():
        print(f"\n{name}: not available, skipped")
        return
    b = load_bracket([folder])
    pl = Pipeline(b, PipelineParams(align=align, local="off", registration_previews=False))
    res = pl.run(until="registration")
    reg = res.registration
    ml = b.max_level
    table = (
        np.arange(ml + 1, dtype=np.float32) / ml
        if res.lut is None
        else res.lut[1].astype(np.float32)
    )
    sat = float(np.interp(res.saturation, np.arange(ml + 1), table))
    nf = float(np.interp(res.noise_floor, np.arange(ml + 1), table))
    exposures = np.cumprod([1.0] + [float(q.ratio) for q in reg.pairs])
    green = [f.levels[..., 1] for f in b.frames]
    t0 = time.process_time()
    w0 = time.perf_counter()
    loc = refine_bracket(
        green,
        exposures,
        reg.to_reference_homography,
        reg.reference,
        saturation=sat,
        noise_floor=nf,
        lut=table,
        threshold=pl.params.threshold,
        tile=tile,
    )
    cpu, wall = time.process_time() - t0, time.perf_counter() - w0
    lin = [table[g] for g in green]
    inv = [
        np.linalg.inv(np.asarray(m, float) if np.shape(m) == (3, 3) else np.vstack([m, [0, 0, 1]]))
        for m in reg.to_reference_homography
    ]
    print(
        f"\n### {name}: {b.shape[1]}x{b.shape[0]}, {len(b)} frames, reference {reg.reference}; "
        f"refinement ({loc.tile} px nodes) {wall:.1f} s wall, {cpu:.1f} s CPU for "
        f"{len(loc.frames)} frames"
    )
    print(
        "\n| frame vs | global: median / p90 | + our field | + DIS flow | field kept | "
        "field median / max px |"
    )
    print("|---|---|---|---|---|---|")
    fields_used = {}
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    # outwards from the reference, as the refinement ran: a frame is compared with its
    # neighbour already read through that neighbour's field
    for fr in sorted(loc.frames, key=lambda fr: abs(fr.frame - reg.reference)):
        k, j = fr.frame, fr.against
        a = _warp(lin[j], inv[j], fields_used.get(j))
        dark_first = exposures[j] <= exposures[k]
        ratio = exposures[k] / exposures[j] if dark_first else exposures[j] / exposures[k]

        def measure(bk: np.ndarray, a=a, dark_first=dark_first, ratio=ratio):
            d, br = (a, bk) if dark_first else (bk, a)
            r = residual_motion(
                np.where(np.isnan(d), np.nan, d),
                br,
                float(ratio),
                None,
                saturation=sat,
                noise_floor=nf,
            )
            return r

        g = _warp(lin[k], inv[k])
        cand = fr.candidate
        f1 = _warp(lin[k], inv[k], cand)
        lo = max(nf, 1e-3) / exposures[min(j, k)]
        hi = sat / exposures[max(j, k)]
        ia = _log8(a / exposures[j], lo, hi)
        ib = _log8(g / exposures[k], lo, hi)
        flow = dis.calc(ia, ib, None)  # ia(x) ~ ib(x + flow(x))
        # the flow is in the reference grid: read frame k at H(x + flow) ~ H(x) + flow
        f2 = _warp(lin[k], inv[k], None, flow)
        r0, r1, r2 = measure(g), measure(f1), measure(f2)
        if fr.kept:
            fields_used[k] = cand

        def cell(r) -> str:
            return "-" if r.status == "unmeasured" else f"{r.median:.2f} / {r.p90:.2f}"

        print(
            f"| {k} vs {j} | {cell(r0)} | {cell(r1)} | {cell(r2)} | "
            f"{'yes' if fr.kept else 'no'} | {cand.median_px:.2f} / {cand.max_px:.2f} |"
        )


def speed() -> None:
    import os

    cache = ROOT / "bench" / "out" / "models_24mp_pair.npz"
    if not cache.exists():
        print("\n(speed: run bench/bench_models_real.py --speed first to render the pair)")
        return
    z = np.load(cache)
    dark, bright, ml = z["dark"], z["bright"], int(z["ml"])
    sys.path.insert(0, str(ROOT))
    from tests.registration._pairs import perspective

    truth = perspective(dark.shape, 7.3, -4.2, 0.35, 0.995, 0.0, 0.0)

    def best(fn):
        walls, cpus = [], []
        for _ in range(3):
            t0, c0 = time.perf_counter(), time.process_time()
            out = fn()
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
        return min(walls), min(cpus), out

    w1, c1, loc = best(
        lambda: refine_bracket(
            [dark, bright], [1.0, 4.0], [np.eye(3), truth], 0, saturation=0.98, noise_floor=3 / ml
        )
    )
    d8 = np.clip(np.rint(np.sqrt(np.clip(dark * 4.0, 0, 1)) * 255), 0, 255).astype(np.uint8)
    b8 = np.clip(np.rint(np.sqrt(np.clip(bright, 0, 1)) * 255), 0, 255).astype(np.uint8)
    mtb = cv2.createAlignMTB()
    w2, c2, _ = best(lambda: mtb.calculateShift(d8, b8))
    fr = loc.frames[0]
    print(
        f"\n## Speed: 24 MP pair (6000x4000), best of 3; load {os.getloadavg()[0]:.1f} on 2 cores\n"
    )
    print("| | wall s | CPU s | vs AlignMTB (wall) |")
    print("|---|---|---|---|")
    print(
        f"| local refinement ({loc.tile} px nodes, level {loc.level}) | {w1:.2f} | {c1:.2f} | "
        f"{w1 / w2:.2f}x |"
    )
    print(f"| AlignMTB (cv2) | {w2:.2f} | {c2:.2f} | 1 |")
    print(
        f"\nfield on the exact global motion: {fr.candidate.median_px:.3f} px median, "
        f"{fr.candidate.max_px:.3f} px max; {fr.message}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--brackets", nargs="*", default=["handheld-pixel7-lab", "handheld-xperia-library"]
    )
    ap.add_argument(
        "--align",
        default="auto",
        help="the global motion model the fields refine (default auto; the "
        "pipeline's default is similarity)",
    )
    ap.add_argument(
        "--tile",
        type=int,
        default=None,
        help="node spacing of the field (default: the library's choice)",
    )
    ap.add_argument("--speed", action="store_true", help="the 24 MP speed section only")
    args = ap.parse_args()
    if args.speed:
        speed()
        return
    for name in args.brackets:
        run(name, args.tile, args.align)


if __name__ == "__main__":
    main()
