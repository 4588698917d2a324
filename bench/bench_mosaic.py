"""Merge before demosaicing against demosaicing every frame (issue 18, part 3): accuracy.

Paths, all through the same merge (:func:`hdrcore.merge.merge`, noise-aware weights, the true
exposure times, saturation 0.98, no colour conversion: camera RGB):

* ``per-frame AHD``: each frame demosaiced by LibRaw's AHD (the project's earlier decode);
* ``per-frame Malvar`` / ``HA`` / ``RCD``: each frame demosaiced by our Malvar-He-Cutler
  (today's decode), Hamilton-Adams or RCD (ratio corrected demosaicing) kernel;
* ``mosaic Malvar`` / ``HA``: the CFA sites merged, then one demosaic
  (:func:`hdrcore.merge.mosaic.merge_mosaic`).

Simulated tripod brackets (12-bit DNG, RGGB, read noise 2 DN and shot noise, 3 frames 2 stops
apart) against the simulator's radiance: median relative error per channel, PSNR of the
reference exposure (truth and estimate times the reference time, clipped at 1) and the colour
bias: ``(sum R / sum G)_est / (sum R / sum G)_truth - 1`` (and B) over the 16x16 blocks that no
frame clips, 4 px from the border.

Real data: the two Canon CRW singles in ../shared/data (10-bit, no bracket exists): a bracket is
SIMULATED from each by scaling its black-subtracted mosaic by 1, 2 and 4 (exact integers, clipped
at the white level, no noise added). There is no truth image; what is measured is the colour bias
of each demosaic across exposure: ``sum R / sum G`` of each demosaiced frame over the pixels
unclipped in all frames (3 px from any clipping), relative to the x1 frame's (a demosaic linear
in the exposure gives 0 up to the rounding of its output to levels).

    python bench/bench_mosaic.py [--size 768x1152] [--seeds 3]

Speed (``--speed [--mp 24] [--reps 3]``): a simulated 12-bit RGGB mosaic bracket (3 frames
2 stops apart, read and shot noise, black 256) of ``--mp`` megapixels: the merge of the four
site planes alone (:func:`hdrcore.merge.merge` on ``(H/2, W/2, 4)`` uint16, tripod), the whole
:func:`~hdrcore.merge.mosaic.merge_mosaic` (planes, merge, ceiling, Malvar demosaic) and the
hand-held one (four 1-channel site merges through a small rotation), wall and CPU seconds
(min over ``--reps``), then the same for the brackets simulated from the real CRW singles.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from hdrcore.io.raw import read_raw  # noqa: E402
from hdrcore.merge import merge  # noqa: E402
from hdrcore.merge.mosaic import merge_mosaic  # noqa: E402
from hdrcore.merge.weights import NoiseModel  # noqa: E402

SHARED = HERE.parent.parent / "shared" / "data" / "raw-singles-cc0-canon-crw"


def _paths(frames, times, max_level, sat, noise, method, transforms=None):
    if method != "frames":
        t0 = time.perf_counter()
        res = merge_mosaic(
            [f.cfa for f in frames],
            times,
            max_level=max_level,
            saturation_level=sat,
            noise=noise,
            method=method,
            transforms=transforms,
        )
        return res.rgb, time.perf_counter() - t0
    t0 = time.perf_counter()
    res = merge(
        [f.levels for f in frames],
        times,
        max_level=max_level,
        saturation_level=sat,
        weighting="noise-aware",
        noise=noise,
        transforms=transforms,
    )
    return res.radiance, time.perf_counter() - t0


def simulated(
    size: tuple[int, int], seed: int, scene: str, handheld: bool = False
) -> dict[str, dict[str, float]]:
    from hdrcore.registration.transform import invert
    from hdrcore.synthetic import simulate_bracket, write_bracket

    times = (1 / 256, 1 / 64, 1 / 16)
    motion = dict(max_shift=4.0, max_rotation_deg=0.3) if handheld else {}
    sim = simulate_bracket(
        scene=scene,
        shape=size,
        exposure_times=times,
        bits=12,
        response="linear",
        noise_sigma=2.0,
        shot_noise_full_well=20000,
        seed=seed,
        keep_linear=True,
        **motion,
    )
    # Hand-held: the true motion (reference -> frame), so the paths differ only in how they
    # read the moved frames (Keys cubic on demosaiced frames, or on each site's plane).
    transforms = (
        None
        if not handheld
        else [
            None if k == sim.reference else invert(np.asarray(sim.to_reference[k]))
            for k in range(len(times))
        ]
    )
    out: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        write_bracket(tmp, sim, "dng", force=True)
        files = sorted(Path(tmp).glob("*.dng"))
        truth = sim.radiance.astype(np.float64) * sim.key
        ref = 1
        for label, demosaic in (
            ("per-frame AHD", "libraw-ahd"),
            ("per-frame Malvar", "malvar2004"),
            ("per-frame HA", "hamilton-adams"),
            ("per-frame RCD", "rcd"),
            ("mosaic Malvar", "malvar2004"),
            ("mosaic HA", "hamilton-adams"),
        ):
            frames = [read_raw(p, demosaic=demosaic) for p in files]
            m = frames[0].max_level
            noise = NoiseModel(read_noise=2.0 / m, full_well=None, level_noise=0.0)
            est, secs = _paths(
                frames,
                times,
                m,
                0.98 * m,
                noise,
                demosaic if label.startswith("mosaic") else "frames",
                transforms,
            )
            est = est.astype(np.float64)
            c = (slice(8, -8), slice(8, -8)) if handheld else (slice(4, -4), slice(4, -4))
            e, t = est[c], truth[c]
            # Unclipped in every frame: the darkest frame below 0.9 of white everywhere in
            # a 5x5 window is not needed; the brightest frame's linear value decides.
            ok = (t * times[-1] < 0.9).all(axis=2) & (t * times[0] * 4096 > 8).all(axis=2)
            rel = np.abs(e[ok] / t[ok] - 1)
            ref_e = np.clip(e * times[ref], 0, 1)
            ref_t = np.clip(t * times[ref], 0, 1)
            mse = ((ref_e - ref_t) ** 2).mean(axis=(0, 1))
            # Colour sums over whole 16x16 blocks that no frame clips (a per-pixel selection
            # by level correlates with the local texture and biases interpolated channels).
            bh, bw = ok.shape[0] // 16, ok.shape[1] // 16
            blocks = ok[: bh * 16, : bw * 16].reshape(bh, 16, bw, 16).all(axis=(1, 3))
            whole = np.repeat(np.repeat(blocks, 16, axis=0), 16, axis=1)
            sums_e = e[: bh * 16, : bw * 16][whole].sum(axis=0)
            sums_t = t[: bh * 16, : bw * 16][whole].sum(axis=0)
            out[label] = {
                "median_rel_%": 100 * float(np.median(rel)),
                "median_rel_R_%": 100 * float(np.median(rel[:, 0])),
                "median_rel_G_%": 100 * float(np.median(rel[:, 1])),
                "median_rel_B_%": 100 * float(np.median(rel[:, 2])),
                "psnr_R": float(10 * np.log10(1 / mse[0])),
                "psnr_G": float(10 * np.log10(1 / mse[1])),
                "psnr_B": float(10 * np.log10(1 / mse[2])),
                "bias_R/G_%": 100 * float((sums_e[0] / sums_e[1]) / (sums_t[0] / sums_t[1]) - 1),
                "bias_B/G_%": 100 * float((sums_e[2] / sums_e[1]) / (sums_t[2] / sums_t[1]) - 1),
                "merge_s": secs,
                "ok_share": float(ok.mean()),
            }
    return out


def real_crw(path: Path) -> dict[str, list[float]]:
    """Colour bias across a bracket simulated from one CRW (see module docstring)."""
    from scipy.ndimage import binary_erosion

    from hdrcore.synthetic.dng import write_dng

    frame = read_raw(path)
    cfa = frame.cfa
    black = int(cfa.black_level[0])
    white = int(cfa.white_level)
    lin = np.clip(cfa.data.astype(np.int64) - black, 0, None)
    out: dict[str, list[float]] = {}
    letters = "".join(cfa.colors[int(i)] for i in cfa.pattern.ravel())
    with tempfile.TemporaryDirectory() as tmp:
        names = []
        for k, g in enumerate(GAINS):
            # Integer gains: the scaled mosaic is exact (no rounding, no added noise).
            raw = np.clip(black + lin * g, 0, white)
            p = Path(tmp) / f"f{k}.dng"
            write_dng(
                p,
                raw.astype(np.uint16),
                exposure_time=g / 100,
                pattern=letters,
                black_level=black,
                white_level=white,
            )
            names.append(p)
        m = read_raw(names[0]).max_level
        for label, method in (
            ("LibRaw AHD", "libraw-ahd"),
            ("ours (Malvar)", "malvar2004"),
            ("ours (RCD)", "rcd"),
        ):
            rgbs = [read_raw(p, demosaic=method).levels.astype(np.float64) for p in names]
            ok = np.ones(rgbs[0].shape[:2], bool)
            for r in rgbs:
                ok &= (r < 0.9 * m).all(axis=2) & (r > 0).all(axis=2)
            # 3 px from anything clipped in the brightest frame or at 0, and from the border.
            ok = binary_erosion(ok, np.ones((7, 7), bool))
            ok[:4] = ok[-4:] = False
            ok[:, :4] = ok[:, -4:] = False
            base = rgbs[0][ok].sum(axis=0)
            row = []
            for r in rgbs[1:]:
                s = r[ok].sum(axis=0)
                row += [
                    100 * ((s[0] / s[1]) / (base[0] / base[1]) - 1),
                    100 * ((s[2] / s[1]) / (base[2] / base[1]) - 1),
                ]
            out[label] = row
        out["_ok_share"] = [float(ok.mean())]
    return out


GAINS = (1, 2, 4)


def _timed(fn, reps: int) -> tuple[float, float]:
    """(min wall s, min CPU s) of ``fn()`` over ``reps`` runs (one untimed run first: the
    kernels are compiled or loaded from the cache)."""
    fn()
    walls, cpus = [], []
    for _ in range(reps):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return min(walls), min(cpus)


def _speed_rows(cfas, times, max_level: int, reps: int) -> list[tuple[str, float, float]]:
    from hdrcore.exposure.registered import cfa_planes

    planes = [cfa_planes(c.data, c.pattern, c.colors, c.black_level, max_level)[0] for c in cfas]
    kw = dict(max_level=max_level, weighting="noise-aware")
    h, w = cfas[0].data.shape
    th = np.deg2rad(0.2)
    rot = np.array([[np.cos(th), -np.sin(th), 2.3], [np.sin(th), np.cos(th), -1.4]])
    return [
        ("site-plane merge (4 channels)", *_timed(lambda: merge(planes, times, **kw), reps)),
        (
            "merge_mosaic, tripod",
            *_timed(lambda: merge_mosaic(cfas, times, max_level=max_level), reps),
        ),
        (
            "merge_mosaic, hand-held (4 x 1 ch)",
            *_timed(
                lambda: merge_mosaic(
                    cfas, times, max_level=max_level, transforms=[rot, None, None]
                ),
                reps,
            ),
        ),
    ]


def speed(mp: float, reps: int) -> None:
    """The mosaic merge's speed (see the module docstring)."""
    import os

    import hdrcore
    from hdrcore.io.frame import RawCFA

    w = int(round(np.sqrt(mp * 1e6 * 1.5) / 16)) * 16  # 3:2, whole 8 x 8 blocks
    h = int(round(w / 1.5 / 16)) * 16
    rng = np.random.default_rng(0)
    # a log-normal scene of 8 x 8 blocks, RGGB gains, 2 stops between frames
    scene = np.exp(rng.normal(0.0, 1.2, (h // 8, w // 8))).astype(np.float32)
    scene = np.repeat(np.repeat(scene, 8, axis=0), 8, axis=1)
    gain = np.array([[0.55, 1.0], [1.0, 0.7]], np.float32)
    scene *= np.tile(gain, (h // 2, w // 2))
    times = (1 / 256, 1 / 64, 1 / 16)
    black, white = 256, 4095
    cfas = []
    for t in times:
        e = scene * np.float32(t * 64 * (white - black))  # the middle frame: ~ mid-scale
        e += rng.normal(0.0, 1.0, e.shape).astype(np.float32) * np.sqrt(4.0 + e / 4.0)
        data = np.clip(np.rint(e) + black, 0, white).astype(np.uint16)
        cfas.append(RawCFA(data, np.array([[0, 1], [3, 2]]), "RGBG", (black,) * 4, white))
    del scene
    print(
        f"hdrcore from {os.path.dirname(hdrcore.__file__)}; simulated 12-bit RGGB mosaic "
        f"bracket, 3 frames of {w} x {h} ({w * h / 1e6:.1f} MP); cpu count {os.cpu_count()}, "
        f"load average {os.getloadavg()[0]:.2f}"
    )
    print(f"{'':36s} {'wall s':>8s} {'cpu s':>8s}   (min of {reps})")
    for name, wall, cpu in _speed_rows(cfas, times, white - black, reps):
        print(f"{name:36s} {wall:8.3f} {cpu:8.3f}")
    if not SHARED.is_dir():
        print(f"# {SHARED} absent: real-data rows skipped")
        return
    for p in sorted(SHARED.glob("*.CRW")):
        cfa = read_raw(p).cfa
        black_r = int(cfa.black_level[0])
        white_r = int(cfa.white_level)
        lin = np.clip(cfa.data.astype(np.int64) - black_r, 0, None)
        real = [
            RawCFA(
                np.clip(black_r + lin * g, 0, white_r).astype(np.uint16),
                cfa.pattern,
                cfa.colors,
                cfa.black_level,
                white_r,
            )
            for g in GAINS
        ]
        hh, ww = cfa.data.shape
        print(f"# real {p.name} ({ww} x {hh}), bracket SIMULATED by scaling its mosaic by 1, 2, 4")
        for name, wall, cpu in _speed_rows(real, [g / 100 for g in GAINS], white_r - black_r, reps):
            print(f"{name:36s} {wall:8.3f} {cpu:8.3f}")


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--size", default="768x1152")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument(
        "--handheld",
        action="store_true",
        help="frames moved (up to 4 px, 0.3 deg), merged through the true motion",
    )
    ap.add_argument("--speed", action="store_true", help="the mosaic merge's speed only")
    ap.add_argument("--mp", type=float, default=24.0, help="megapixels of --speed's mosaic")
    ap.add_argument("--reps", type=int, default=3, help="timed runs of each --speed row")
    args = ap.parse_args()
    if args.speed:
        speed(args.mp, args.reps)
        return
    h, w = (int(v) for v in args.size.lower().split("x"))
    kind = "hand-held (true motion)" if args.handheld else "tripod"
    print(
        f"# simulated 12-bit {kind} DNG brackets {w}x{h}, 3 frames 2 stops apart, "
        f"read noise 2 DN + shot noise; {args.seeds} seeds x scenes window, landscape"
    )
    keys = [
        "median_rel_%",
        "median_rel_R_%",
        "median_rel_B_%",
        "psnr_R",
        "psnr_G",
        "psnr_B",
        "bias_R/G_%",
        "bias_B/G_%",
    ]
    print(f"{'scene/seed':<14}{'path':<16}" + "".join(f"{k:>15}" for k in keys))
    for scene in ("window", "landscape"):
        for seed in range(args.seeds):
            res = simulated((h, w), seed, scene, args.handheld)
            for label, r in res.items():
                print(
                    f"{scene + '/' + str(seed):<14}{label:<16}"
                    + "".join(f"{r[k]:>15.4f}" for k in keys)
                )
    if args.handheld:
        return
    if SHARED.is_dir():
        print(
            "\n# real Canon CRW singles, bracket SIMULATED from each by scaling its "
            "black-subtracted mosaic by 1, 2, 4 (integers: exact, no noise added): colour "
            "ratio of each frame's demosaic against the x1 frame's, % (0 = linear in the "
            "exposure), over pixels unclipped in every frame, 3 px away from clipping"
        )
        print(
            f"{'file':<18}{'demosaic':<16}"
            + "".join(f"{f'x{g} {c}':>12}" for g in GAINS[1:] for c in ("R/G", "B/G"))
        )
        for p in sorted(SHARED.glob("*.CRW")):
            res = real_crw(p)
            share = res.pop("_ok_share")[0]
            for label, row in res.items():
                print(f"{p.name:<18}{label:<16}" + "".join(f"{v:>12.4f}" for v in row))
            print(f"#   pixels used: {100 * share:.1f} %")
    else:
        print(f"# {SHARED} absent: real-data rows skipped")


if __name__ == "__main__":
    main()
