"""Camera response recovery and the colour of non-linear merges (issue 15), ours and OpenCV's.

Prints, in one run:

1. Six response shapes (gamma 2.2, sRGB, poly3, S-curve, filmic ACES-like, toe-shoulder) on
   the seed's protocol (Cerman & Hlavac 2006, section 4.2): six frames 4x apart, 8 bits, noise
   sigma 1 level. Per method the RMS error of ``g`` over levels 2..98 % of the range, worst
   channel, worst of the seeds and scenes, as % of the range, two ways: after one exposure
   scale shared by the channels (``g`` is known up to that scale; a cast still shows), and
   normalised at ``g(max) = 1`` (the stricter figure: the top 2 % of the levels carry no data,
   so it measures an extrapolation), and scaled to the truth at level 250 (the top of the
   fitted range: level 255 is the clip bin, whose ``g`` no data fixes; the S-curve's last
   level alone is 7.2 % of its range). Ours: ``auto`` (the default), the joint fit, the old
   default (per-channel DM histogram) and the other methods; OpenCV CalibrateDebevec /
   CalibrateRobertson side by side.
1b. The same six shapes on real scenes: the radiance merged from the Canon and memorial
   brackets, imaged by the simulated camera (real content and dynamic range, known truth).
2. The real brackets in ../shared/data (Canon 5D Mark II JPEGs, Pixel 7 and Xperia phone JPEGs,
   the Debevec-Malik memorial film scans): through the whole pipeline, before (the old
   default: per-channel DM histogram, no colour anchoring) and after (``auto`` with the colour
   anchoring), and with the fixed curves ``--response srgb`` and gamma 2.2 (without and with
   the anchoring): the curve used,
   degeneracy signs and whether the run flagged them, the median chromaticity error of the
   merge against its reference frame decoded with sRGB (pixels well exposed there, every
   channel within 10..90 % of the range), the median chromaticity difference between
   consecutive linearised frames over pixels well exposed in both (registered by the run),
   per pixel and on 4x4-pixel means (pixel noise averaged down: what is left is the curve's
   error), also for OpenCV's curves, and the local tone mapping test.
3. ``../shared/data/memorial-debevec``: our curves against OpenCV's (shape RMS over levels
   5..230 after the best scale) and a plot in ``bench/out/memorial_response.png``.

Timings on a shared 2-core machine are pessimistic. Usage:
``python bench/bench_response.py [--quick] [--skip-synthetic] [--shapes-only]`` (``--quick``:
one seed and scene, no phone brackets; ``--shapes-only``: sections 1 and 1b).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import cv2
import numpy as np

from hdrcore.io import load_bracket
from hdrcore.merge.colour_check import colour_check
from hdrcore.pipeline import Pipeline, PipelineParams
from hdrcore.response import ResponseCurve, recover_response, render_curves
from hdrcore.response.degeneracy import degeneracy
from hdrcore.synthetic import apply_response, simulate_bracket

QUICK = "--quick" in sys.argv
TIMES = (1.0, 4.0, 16.0, 64.0, 256.0, 1024.0)
SHAPES = ("gamma", "srgb", "polynomial3", "s-curve", "filmic", "toe-shoulder")
ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bench" / "out"
DATA = (ROOT / ".." / "shared" / "data").resolve()
MEMORIAL = DATA / "memorial-debevec"

# (label, method, parameters)
OURS = [
    ("auto (default)", "auto", {}),
    ("joint histogram", "joint-histogram", {}),
    ("DM histogram (old default)", "debevec-histogram", {}),
    ("DM 1997 pixels", "debevec1997", {}),
    ("MN 1999 monotone auto", "mitsunaga1999", {}),
    ("GN 2003 monotone auto", "grossberg2003", {}),
]
PEERS = ["OpenCV Debevec", "OpenCV Robertson"]


class PeerCurve:
    """An OpenCV curve for plotting: normalised (g - g(0)) / (g(max) - g(0)), not made monotone."""

    def __init__(self, g: np.ndarray) -> None:
        g = np.asarray(g, float)
        self.g = (g - g[:, :1]) / (g[:, -1:] - g[:, :1])
        self.n_channels = g.shape[0]
        self.max_level = g.shape[1] - 1
        self.levels = np.arange(g.shape[1])
        self.channel_names = ("R", "G", "B")


def opencv_curves(frames, times, names=PEERS):
    """OpenCV's calibrations of RGB frames; returns ``{name: ((3, 256) curve, seconds)}``."""
    imgs = [np.ascontiguousarray(np.asarray(f)[..., ::-1].astype(np.uint8)) for f in frames]
    t = np.asarray(times, np.float32)
    makers = {
        "OpenCV Debevec": cv2.createCalibrateDebevec,
        "OpenCV Debevec samples=500": lambda: cv2.createCalibrateDebevec(samples=500),
        "OpenCV Robertson": cv2.createCalibrateRobertson,
    }
    out = {}
    for name in names:
        t0 = time.perf_counter()
        c = makers[name]().process(imgs, t)
        dt = time.perf_counter() - t0
        g = np.asarray(c, float)[:, 0, ::-1].T.copy()
        g[~np.isfinite(g)] = 0.0
        out[name] = (g, dt)
    return out


def truth_g(response: str) -> np.ndarray:
    x = np.linspace(0.0, 1.0, 400_001)
    return np.interp(np.arange(256) / 255.0, apply_response(response, x), x)


LEVELS = slice(6, 250)  # levels 2..98 % of 255


def err_common_scale(g, truth):
    g = np.asarray(g, float)
    g = (g - g[:, :1]) / np.maximum(g[:, -1:] - g[:, :1], 1e-300)
    gg, tt = g[:, LEVELS], truth[LEVELS]
    s = np.sum(gg * tt[None]) / np.sum(gg * gg)
    return float(np.max(np.sqrt(np.mean((s * gg - tt[None]) ** 2, axis=1))))


def err_max_normalised(g, truth):
    g = np.asarray(g, float)
    g = (g - g[:, :1]) / np.maximum(g[:, -1:] - g[:, :1], 1e-300)
    return float(np.max(np.sqrt(np.mean((g[:, LEVELS] - truth[None, LEVELS]) ** 2, axis=1))))


#: The top of the fitted range: levels above the response's cutoff (98 %) carry no pairs.
TOP_OF_DATA = 250


def err_at_top_of_data(g, truth, level=TOP_OF_DATA):
    """RMS of ``g`` over levels 2..98 % with each channel scaled to the truth at ``level``
    (the highest level the fit sees; level 255 is the clip bin, whose ``g`` no data fixes)."""
    g = np.asarray(g, float)
    g = (g - g[:, :1]) / np.maximum(g[:, level:level + 1] - g[:, :1], 1e-300) * truth[level]
    return float(np.max(np.sqrt(np.mean((g[:, LEVELS] - truth[None, LEVELS]) ** 2, axis=1))))


def top_levels_note() -> None:
    """How much of each shape's range lies above the fitted levels (the truth, no fit)."""
    print("\ntruth above the fitted range (% of the range): g(255) - g(250) / g(255) - g(254)")
    print("  " + "; ".join(f"{s}: {100 * (1 - truth_g(s)[TOP_OF_DATA]):.1f} / "
                           f"{100 * (1 - truth_g(s)[254]):.1f}" for s in SHAPES))


def synthetic_table() -> None:
    shape = (192, 288)
    seeds = (1,) if QUICK else (1, 2)
    scenes = ("window",) if QUICK else ("window", "patches")
    labels = [lab for lab, _, _ in OURS] + PEERS
    common = {lab: {s: [] for s in SHAPES} for lab in labels}
    top = {lab: {s: [] for s in SHAPES} for lab in labels}
    fitted = {lab: {s: [] for s in SHAPES} for lab in labels}
    secs = {lab: [] for lab in labels}
    chosen: dict[str, list[str]] = {s: [] for s in SHAPES}
    plot = []
    for resp in SHAPES:
        truth = truth_g(resp)
        for scene in scenes:
            for seed in seeds:
                b = simulate_bracket(scene=scene, shape=shape, exposure_times=TIMES, bits=8,
                                     response=resp, noise_sigma=1.0, seed=seed)
                for lab, method, kw in OURS:
                    t0 = time.perf_counter()
                    c = recover_response(b.frames, TIMES, method=method, **kw)
                    secs[lab].append(time.perf_counter() - t0)
                    common[lab][resp].append(err_common_scale(c.g, truth))
                    top[lab][resp].append(err_max_normalised(c.g, truth))
                    fitted[lab][resp].append(err_at_top_of_data(c.g, truth))
                    if method == "auto":
                        chosen[resp].append(c.method)
                    if resp == "filmic" and seed == seeds[0] and scene == scenes[0]:
                        plot.append((c, lab))
                for lab, (g, dt) in opencv_curves(b.frames, TIMES).items():
                    secs[lab].append(dt)
                    common[lab][resp].append(err_common_scale(g, truth))
                    top[lab][resp].append(err_max_normalised(g, truth))
                    fitted[lab][resp].append(err_at_top_of_data(g, truth))
                    if resp == "filmic" and seed == seeds[0] and scene == scenes[0]:
                        plot.append((PeerCurve(g), lab))

    def table(title, data):
        print(f"\n{title}")
        print(f"{'method':28}" + "".join(f"{s[:12]:>13}" for s in SHAPES) + f"{'s/run':>8}")
        for lab in labels:
            row = "".join(f"{100 * max(data[lab][s]):12.2f}%" for s in SHAPES)
            print(f"{lab:28}{row}{np.mean(secs[lab]):8.2f}")

    print(f"== six response shapes: 6 frames x4, 8 bits, sigma 1 level, {shape[0]}x{shape[1]}, "
          f"scenes {list(scenes)}, seeds {list(seeds)}; worst channel, worst run ==")
    table("RMS of g over levels 2..98 %, after one exposure scale shared by the channels "
          "(% of range; target <= 1 %)", common)
    table("RMS of g over levels 2..98 %, normalised at g(max) = 1 (% of range; the top 2 % "
          "has no data)", top)
    table(f"RMS of g over levels 2..98 %, each channel scaled to the truth at level "
          f"{TOP_OF_DATA}, the top of the fitted range (% of range)", fitted)
    top_levels_note()
    print("\nauto chose: " + "; ".join(f"{s}: {', '.join(sorted(set(v)))}"
                                       for s, v in chosen.items()))
    OUT.mkdir(parents=True, exist_ok=True)
    truth = PeerCurve(np.tile(truth_g("filmic"), (3, 1)))
    img = render_curves([(truth, "truth")] + plot[:9],
                        title="filmic (ACES-like), sigma 1: every method")
    p = OUT / "synthetic_filmic.png"
    img.save(p)
    print(f"plot: {p.relative_to(ROOT)}")


def real_scene_shapes() -> None:
    """The six shapes again on real scenes: the radiance merged (default pipeline) from the
    Canon and memorial brackets, downsampled to at most 300 px, imaged by the simulated camera
    (six frames 4x apart, 8 bits, sigma 1 level): real content and dynamic range, known truth."""
    print("\n== six response shapes on real scenes (radiance merged from real brackets, "
          "simulated camera: 6 frames x4, 8 bits, sigma 1 level, seeds 1 and 2) ==")
    if not DATA.is_dir():
        print(f"skipped: {DATA} not available")
        return
    methods = [("auto (default)", "auto")]
    cols = ("common scale", f"at g({TOP_OF_DATA})", "g(max)=1")
    print(f"{'scene':22}{'method':18}{'shape':14}" + "".join(f"{c:>14}" for c in cols)
          + "  auto chose")
    for label, folder, excl, _ in REAL:
        if folder not in ("frobisher-colour-hdri", "memorial-debevec"):
            continue
        if not (DATA / folder).is_dir():
            continue
        b = _load(folder)
        r = Pipeline(b, PipelineParams(registration_previews=False, exclude_colour=excl)).run(
            until="merge")
        rad = np.maximum(np.asarray(r.radiance, np.float64), 0.0)
        if excl is not None:
            blue = np.zeros(rad.shape[:2], bool)
            for f in b.frames:
                blue |= np.all(f.levels == np.asarray(excl), axis=-1)
            r0, r1, c0, c1 = crop_without(blue)
            rad = rad[r0:r1, c0:c1]
        f = max(1, int(np.ceil(max(rad.shape[:2]) / 300)))
        h, w = (rad.shape[0] // f) * f, (rad.shape[1] // f) * f
        rad = rad[:h, :w].reshape(h // f, f, w // f, f, 3).mean(axis=(1, 3))
        lum = rad @ np.array([0.2126, 0.7152, 0.0722])
        pos = lum[lum > 0]
        stops = float(np.log2(np.percentile(pos, 99) / np.percentile(pos, 1)))
        scene = f"{label[:13]} {rad.shape[0]}x{rad.shape[1]}"
        for resp in SHAPES:
            truth = truth_g(resp)
            errs: dict[str, list[list[float]]] = {}
            chose = set()
            for seed in (1, 2):
                sim = simulate_bracket(rad, exposure_times=TIMES, bits=8, response=resp,
                                       noise_sigma=1.0, seed=seed)
                curves = {}
                for lab, method in methods:
                    c = recover_response(sim.frames, TIMES, method=method)
                    curves[lab] = c.g
                    chose.add(c.method)
                for lab, (g, _) in opencv_curves(sim.frames, TIMES).items():
                    curves[lab] = g
                for lab, g in curves.items():
                    errs.setdefault(lab, []).append([err_common_scale(g, truth),
                                                     err_at_top_of_data(g, truth),
                                                     err_max_normalised(g, truth)])
            for lab, rows in errs.items():
                worst = np.max(np.asarray(rows), axis=0)
                print(f"{scene:22}{lab[:17]:18}{resp:14}"
                      + "".join(f"{100 * v:13.2f}%" for v in worst)
                      + (f"  {', '.join(sorted(chose))}" if lab.startswith("auto") else ""))
        print(f"{'':22}(scene spans {stops:.1f} stops, 1st-99th percentile)")


# --- real brackets ---------------------------------------------------------------------------

REAL = [
    ("Canon 5D II JPEG", "frobisher-colour-hdri", None, False),
    ("Pixel 7 JPEG", "handheld-pixel7-lab", None, True),
    ("Xperia 1 IV JPEG", "handheld-xperia-library", None, True),
    ("memorial film PNG", "memorial-debevec", (0, 0, 255), False),
]
RESPONSE_VERDICTS = ("response-fallback", "response-degenerate", "response-channels-differ",
                     "colour-drift", "locally-tone-mapped", "white-balance-differs")


def _load(folder: str):
    d = DATA / folder
    kw = {}
    if (d / "exposure_times.txt").is_file() and folder == "memorial-debevec":
        kw["exposure_times"] = d / "exposure_times.txt"
    files = sorted(p for p in d.iterdir() if p.suffix.lower() in (".jpg", ".png"))
    return load_bracket(files, **kw)


def gamma_curve(gamma: float = 2.2, max_level: int = 255) -> ResponseCurve:
    """A fixed power-law decoding ``(z / max) ** gamma`` for every channel."""
    g = np.tile((np.arange(max_level + 1) / max_level) ** gamma, (3, 1))
    return ResponseCurve(g=g, method=f"gamma {gamma:g}", message=f"fixed power law {gamma:g}")


def real_tables() -> None:
    print("\n== real brackets through the pipeline: before (per-channel DM histogram, no colour "
          "anchoring) and after (auto + anchoring); --response srgb without and with it ==")
    if not DATA.is_dir():
        print(f"skipped: {DATA} not available")
        return
    gamma = gamma_curve()
    runs = [
        ("before: DM histogram", dict(response="debevec-histogram", colour_anchor=False)),
        ("srgb, no anchoring", dict(response="srgb", colour_anchor=False)),
        ("srgb (default anchoring)", dict(response="srgb", colour_anchor=True)),
        ("gamma 2.2, no anchoring", dict(response=gamma, colour_anchor=False)),
        ("gamma 2.2 (def. anchoring)", dict(response=gamma, colour_anchor=True)),
        ("after: auto (default)", dict(response="auto", colour_anchor=True)),
    ]
    header = (f"{'bracket':19}{'run':27}{'curve':18}{'vs sRGB ref':>12}{'others':>8}"
              f"{'frames':>8}{'WB out':>8}{'sRGB':>8}{'4x4':>8}{'s':>6}  flags")
    print("vs sRGB ref: median chromaticity error of the merge against the reference frame "
          "decoded with sRGB (pixels well exposed there); others: the same against each other "
          "frame decoded with sRGB where that frame is the best exposed (pixel-weighted mean); "
          "frames: median difference between consecutive frames linearised with the run's "
          "curve (WB out: each frame's white balance divided out; sRGB: decoded with sRGB; "
          "4x4: the same as frames on 4x4-pixel means, pixel noise averaged down)")
    print(header)
    for label, folder, excl, phone in REAL:
        if QUICK and phone:
            continue
        if not (DATA / folder).is_dir():
            print(f"{label:19}skipped: not available")
            continue
        b = _load(folder)
        pipe = Pipeline(b, PipelineParams(registration_previews=False, exclude_colour=excl))
        frames = [f.levels for f in b.frames]
        last = None
        for run, kw in runs:
            t0 = time.perf_counter()
            r = pipe.run(pipe.params.replace(**kw), until="merge")
            dt = time.perf_counter() - t0
            chk = r.colour["check"]
            cons = chk["before"]["frame_consistency"]
            cons_wb = chk["before"]["frame_consistency_wb"]
            cons_srgb = chk["before"]["frame_consistency_srgb"]
            err = chk["after"]["merge_error_srgb"]
            ref_k = chk["after"]["reference"]
            parts = [(d["median_error_srgb"], d["n_pixels"])
                     for d in chk["after"]["best_frame_errors"]
                     if d["frame"] != ref_k and d["median_error_srgb"] is not None]
            others = (sum(e * n for e, n in parts) / max(sum(n for _, n in parts), 1)
                      if parts else float("nan"))
            resp = r.response
            signs = degeneracy(resp.g, active=[c.active_constraints for c in resp.channels]
                               or None, n_nodes=resp.max_level if resp.channels else None)
            flagged = [v.code for v in r.verdicts if v.code in RESPONSE_VERDICTS]
            sign_codes = sorted({d.code for d in signs})
            caught = ("" if not signs else
                      " (flagged)" if ({"response-fallback", "response-degenerate",
                                        "response-channels-differ"} & set(flagged))
                      else " (NOT FLAGGED)")
            blocks = chk["before"]["frame_consistency_blocks"] or float("nan")
            print(f"{label:19}{run:27}{resp.method[:17]:18}{err:12.4f}{others:8.4f}"
                  f"{cons:8.4f}{cons_wb:8.4f}{cons_srgb:8.4f}{blocks:8.4f}{dt:6.0f}  "
                  f"{','.join(flagged) or '-'}"
                  + (f"; signs {','.join(sign_codes)}{caught}" if signs else ""))
            if resp.selection is not None:
                print(f"{'':19}   {resp.selection.message}")
            last = r
        if last is None:
            continue
        ltm = last.colour["check"]["local_tone_mapping"]
        print(f"{'':19}   local tone mapping: {ltm['message']}")
        # OpenCV's curves on the same registered frames (their own samples, our registration)
        reg = last.registration
        ref = 0 if reg is None else reg.reference
        tr = None if reg is None else reg.to_reference_homography
        times = [float(t) for t in last.exposure_times]
        usable = frames if excl is None else frames  # OpenCV takes no mask
        masks = None if excl is None else [~np.all(f == np.asarray(excl), axis=-1)
                                           for f in frames]
        for name, (g, _) in opencv_curves(usable, times).items():
            g = np.maximum.accumulate(np.clip(np.asarray(g, float), 0, None), axis=1)
            g = g / np.maximum(g[:, -1:], 1e-300)
            cc = colour_check(frames, last.radiance, g, max_level=255, reference=ref,
                              to_reference=tr, masks=masks)
            signs = sorted({d.code for d in degeneracy(g)})
            blocks = cc.frame_consistency_blocks
            print(f"{label:19}{name:27}{'(curve only)':18}{'':>20}{cc.frame_consistency:8.4f}"
                  f"{cc.frame_consistency_wb:8.4f}{cc.frame_consistency_srgb:8.4f}"
                  f"{blocks:8.4f}      "
                  f"signs {','.join(signs) or '-'}")


def crop_without(blue: np.ndarray) -> tuple[int, int, int, int]:
    """Greedy largest rectangle free of masked pixels (drop the worst edge until clean)."""
    r0, r1, c0, c1 = 0, blue.shape[0], 0, blue.shape[1]
    while blue[r0:r1, c0:c1].any():
        b = blue[r0:r1, c0:c1]
        edges = {"t": b[0].mean(), "b": b[-1].mean(), "l": b[:, 0].mean(), "r": b[:, -1].mean()}
        k = max(edges, key=edges.get)
        r0, r1 = r0 + (k == "t"), r1 - (k == "b")
        c0, c1 = c0 + (k == "l"), c1 - (k == "r")
    return r0, r1, c0, c1


def memorial_table() -> None:
    print("\n== memorial-debevec (16 film scans, 1-stop steps): our curves vs OpenCV's ==")
    if not MEMORIAL.is_dir():
        print(f"skipped: {MEMORIAL} not available")
        return
    br = load_bracket(sorted(MEMORIAL.glob("*.png")),
                      exposure_times=MEMORIAL / "exposure_times.txt")
    frames = [f.levels for f in br.frames]
    times = [float(t) for t in br.exposure_times]
    blue = np.zeros(frames[0].shape[:2], bool)
    for f in frames:
        blue |= np.all(f == (0, 0, 255), axis=-1)
    r0, r1, c0, c1 = crop_without(blue)
    print(f"blue border: {100 * blue.mean():.1f}% of pixels masked for ours; OpenCV gets the "
          f"blue-free crop rows {r0}:{r1}, cols {c0}:{c1}")
    curves: dict[str, np.ndarray] = {}
    secs: dict[str, float] = {}
    for lab, method, _ in OURS:
        t0 = time.perf_counter()
        c = recover_response(frames, times, method=method, mask=~blue)
        secs[lab] = time.perf_counter() - t0
        curves[lab] = c.g
        print(f"  {lab}: {c.method} {c.status} {c.message[:160]}".rstrip())
    names = ["OpenCV Debevec", "OpenCV Debevec samples=500", "OpenCV Robertson"]
    for lab, (g, dt) in opencv_curves([f[r0:r1, c0:c1] for f in frames], times,
                                      names).items():
        curves[lab] = g
        secs[lab] = dt
    sl = slice(5, 231)

    def diff(a, b):
        a, b = np.asarray(a, float)[:, sl], np.asarray(b, float)[:, sl]
        s = np.sum(a * b, axis=1) / np.sum(a * a, axis=1)
        return np.sqrt(np.mean((a * s[:, None] - b) ** 2, axis=1)) / b[:, -1]

    print("\nshape RMS vs each OpenCV curve over levels 5..230 after the best scale "
          "(% of the reference's g(230)), channels R/G/B")
    print(f"{'method':30}" + "".join(f"{r.replace('OpenCV ', 'vs '):>30}" for r in names)
          + f"{'s':>7}")
    for lab, g in curves.items():
        cells = "".join(
            f"{'/'.join(f'{100 * v:.1f}' for v in diff(g, curves[r])):>30}" for r in names
        )
        print(f"{lab:30}{cells}{secs[lab]:7.2f}")
    items = []
    anchor = np.asarray(curves["joint histogram"], float)
    for lab, g in curves.items():
        if lab.startswith("OpenCV"):
            gg = np.asarray(g, float)[:, sl]
            s = np.sum(gg * anchor[:, sl], axis=1) / np.sum(gg * gg, axis=1)
            peer = PeerCurve(g)
            peer.g = np.asarray(g, float) * s[:, None]
            items.append((peer, f"{lab} (scaled to fit 5..230)"))
        else:
            items.append((ResponseCurve(g=g, method=lab), lab))
    OUT.mkdir(parents=True, exist_ok=True)
    p = OUT / "memorial_response.png"
    render_curves(items, title="memorial-debevec: ours (g(255)=1) vs OpenCV").save(p)
    print(f"plot: {p.relative_to(ROOT)}")


if __name__ == "__main__":
    t0 = time.perf_counter()
    if "--skip-synthetic" not in sys.argv:
        synthetic_table()
        real_scene_shapes()
    if "--shapes-only" not in sys.argv:
        real_tables()
        memorial_table()
    print(f"\ntotal {time.perf_counter() - t0:.0f} s (shared 2-core machine: pessimistic)")
