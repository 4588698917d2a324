"""Exposure ratios from histograms: ours vs HDRutils' 'cerman' and 'mst', in one run.

Prints, side by side:

1. the seed's protocol (section 5.3), darkest pair per scene;
2. accuracy over the simulator's scenes at 8 and 12 bits, tripod and hand-held (shifts up to
   20 px, rotation up to 1 degree): our histogram-only estimate, the paper's method, our estimate
   from the histograms of each pair's common field of view (overlap-restricted) with the pair
   matrices from (a) an integer eq. 5 shift, (b) ``register_bracket`` and (c) the simulator's true
   matrices, our estimate from the registered pixels (``hdrcore.exposure.registered``, what the
   pipeline uses after registration) with the registered and the true matrices, and HDRutils;
   median / p90 / max error and how many pairs over 1 % are marked not ok;
3. the same with integer-pixel motion (no rotation) and with half-pixel motion of every frame,
   and with the simulator's earlier "log-cubic" rendering, which changes the brightness of moved
   frames by up to 1 % (the default "area" rendering integrates the scene over every pixel);
4. speed on 24-megapixel 3-frame brackets (14 and 8 bits): histograms, first fit, re-fits after a
   change of saturation level and of noise floor;
5. memorial-debevec (exact 1-stop times): the linearised estimates against the known ratio 2 with
   the sRGB fallback and with a recovered response.

Timings on a shared 2-core machine are pessimistic. Usage: ``python bench/bench_exposure.py
[--quick]``.
"""

from __future__ import annotations

import logging
import sys
import time
from pathlib import Path

import numpy as np

from hdrcore.exposure import (
    bracket_exposures,
    bracket_exposures_from_histograms,
    bracket_histograms,
    default_noise_floor,
    default_saturation,
    srgb_lut,
)
from hdrcore.exposure.registered import bracket_exposures_from_pixels
from hdrcore.registration import cross_correlation_shift, register_bracket
from hdrcore.synthetic import SCENES, simulate_bracket

TIMES = (1.0, 4.0, 16.0, 64.0, 256.0, 1024.0)
QUICK = "--quick" in sys.argv


# ----------------------------------------------------------------------------------- HDRutils
class _Capture(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


def bayer_mosaic(frame: np.ndarray) -> np.ndarray:
    """RGGB mosaic of an RGB frame: HDRutils' estimators expect single-channel raw mosaics
    ``(N, H, W)`` and read the green sites ``[::2, 1::2]`` (a 4-D RGB stack makes ``mst``
    fail with ValueError when it unpacks ``_, h, w = Y.shape``)."""
    h, w = frame.shape[0] // 2 * 2, frame.shape[1] // 2 * 2
    f = frame[:h, :w]
    m = np.empty((h, w), np.float64)
    m[0::2, 0::2] = f[0::2, 0::2, 0]
    m[0::2, 1::2] = f[0::2, 1::2, 1]
    m[1::2, 0::2] = f[1::2, 0::2, 1]
    m[1::2, 1::2] = f[1::2, 1::2, 2]
    return m


def hdrutils_ratios(frames, times, max_level, method):
    """Consecutive ratios from HDRutils.estimate_exposures on the whole stack; when it gives up
    (``mst`` needs valid pixels of every frame in each of its 16x16 tiles, which the darkest
    frames of a 6-frame, 10-stop stack never have), once per consecutive pair instead."""
    ratios, note = _hdrutils_stack(frames, times, max_level, method)
    if not note:
        return ratios, ""
    per_pair, notes = [], []
    for k in range(len(frames) - 1):
        r, n = _hdrutils_stack(frames[k : k + 2], times[k : k + 2], max_level, method)
        per_pair.append(r[0])
        if n:
            notes.append(f"pair {k}: {n}")
    why = f"whole stack: {note}; run per consecutive pair"
    return per_pair, why + (" (" + "; ".join(notes)[:100] + ")" if notes else "")


def _hdrutils_stack(frames, times, max_level, method):
    """Consecutive ratios from HDRutils.estimate_exposures; nan where it gave up (it then
    silently returns the EXIF times we passed, which would look perfect)."""
    import HDRutils.exposures as hx

    cap = _Capture()
    lg = logging.getLogger("HDRutils")
    lg.addHandler(cap)
    lg.setLevel(logging.WARNING)
    lg.propagate = False
    imgs = np.stack([bayer_mosaic(f) for f in frames])
    h, w = imgs.shape[1:3]
    meta = {
        "black_level": np.zeros(4),
        "h": h,
        "w": w,
        "saturation_point": default_saturation(max_level),
        "dtype": np.uint16 if max_level > 255 else np.uint8,
    }
    try:
        exp = hx.estimate_exposures(
            imgs, np.array(times, float), meta, method, noise_floor=default_noise_floor(max_level)
        )
    except Exception as exc:  # a peer's failure is a result, not a crash of the bench
        return [float("nan")] * (len(times) - 1), f"{type(exc).__name__}: {exc}"
    finally:
        lg.removeHandler(cap)
    if isinstance(exp, tuple):  # (exif, nan) when every tile was rejected
        return [float("nan")] * (len(times) - 1), "; ".join(cap.messages)[:120]
    exp = np.asarray(exp, float)
    ratios = [exp[k + 1] / exp[k] for k in range(len(exp) - 1)]
    reverted = [m for m in cap.messages if "Reverting" in m]
    if reverted:
        return [float("nan")] * (len(times) - 1), reverted[0][:120]
    return ratios, ""


# --------------------------------------------------------------------------------- our variants
def green_linear(frames, max_level):
    return [f[..., 1].astype(np.float64) / max_level for f in frames]


def integer_shift_matrices(frames, max_level, ratios):
    """Eq. 5 alone: the integer shift of each consecutive pair as a translation matrix."""
    g = green_linear(frames, max_level)
    lo = default_noise_floor(max_level) / max_level
    hi = default_saturation(max_level) / max_level
    mats = []
    for i, k in enumerate(ratios):
        a = np.log(np.clip(g[i + 1], lo, hi))
        b = np.log(np.clip(g[i] * k, lo, hi))
        s = cross_correlation_shift(a, b)
        mats.append(np.array([[1.0, 0.0, s.dx], [0.0, 1.0, s.dy]]))
    return mats


def registered_matrices(frames, max_level, ratios):
    ks = ratios
    reg = register_bracket(
        green_linear(frames, max_level),
        ks,
        saturation=default_saturation(max_level) / max_level,
        noise_floor=default_noise_floor(max_level) / max_level,
    )
    return [p.matrix for p in reg.pairs]


def ours(frames, max_level, method="Cerman 2006 refined", matrices=None):
    r = bracket_exposures(frames, max_level, method=method, pair_matrices=matrices)
    return [p.ratio for p in r.pairs], [p.ok for p in r.pairs], r


# ------------------------------------------------------------------------------------- tables
ROWS = (
    "histograms only",
    "Cerman 2006 (paper)",
    "overlap: eq.5 int shift",
    "overlap: registered",
    "overlap: true matrices",
    "pixels: registered",
    "pixels: true matrices",
    "HDRutils cerman",
    "HDRutils mst",
)
FLAGGED = ROWS[:7]


def pixels(frames, max_level, matrices, first):
    r = bracket_exposures_from_pixels(frames, max_level, matrices, fallback=first)
    return [p.ratio for p in r.pairs], [p.ok for p in r.pairs], r


def accuracy_table(
    bits,
    shape,
    seeds,
    *,
    shift=0.0,
    rotation=0.0,
    integer_motion=False,
    half_pixel=False,
    rendering="area",
):
    """``integer_motion``: whole-pixel shifts, the reference frame unmoved (no frame is
    resampled); ``half_pixel``: whole-pixel shifts plus half a pixel in x and y for every frame,
    the reference too (every frame resampled with the same sub-pixel phase)."""
    errs = {r: [] for r in ROWS}
    oks = {r: [] for r in FLAGGED}
    notes: dict[str, str] = {}
    timing = {"registration": [], "pixels": []}
    moving = shift > 0 or rotation > 0
    for scene in SCENES:
        for seed in seeds:
            motion = None
            if integer_motion or half_pixel:
                rng = np.random.default_rng(seed)
                motion = [
                    (
                        float(rng.integers(-shift, shift + 1)),
                        float(rng.integers(-shift, shift + 1)),
                        0.0,
                    )
                    for _ in TIMES
                ]
                if half_pixel:
                    motion = [(dx + 0.5, dy + 0.5, 0.0) for dx, dy, _ in motion]
                else:
                    motion[len(TIMES) // 2] = (0.0, 0.0, 0.0)
            b = simulate_bracket(
                scene=scene,
                shape=shape,
                exposure_times=TIMES,
                bits=bits,
                noise_sigma=1.0,
                seed=seed,
                motion=motion,
                max_shift=0 if motion else shift,
                max_rotation_deg=0 if motion else rotation,
                rendering=rendering,
            )
            m = b.max_level
            runs = {}
            runs["histograms only"] = ours(b.frames, m)
            runs["Cerman 2006 (paper)"] = ours(b.frames, m, "Cerman 2006")
            if moving:
                # Registration starts from the histogram-only ratios, a missing or wild one
                # replaced by the median step (BracketExposureResult.starting_ratios; no EXIF).
                first = runs["histograms only"][2].starting_ratios()
                runs["overlap: eq.5 int shift"] = ours(
                    b.frames, m, matrices=integer_shift_matrices(b.frames, m, first)
                )
                t0 = time.perf_counter()
                mats = registered_matrices(b.frames, m, first)
                timing["registration"].append(time.perf_counter() - t0)
                runs["overlap: registered"] = ours(b.frames, m, matrices=mats)
                true = [b.pair_matrix(k, k + 1) for k in range(len(TIMES) - 1)]
                runs["overlap: true matrices"] = ours(b.frames, m, matrices=true)
                t0 = time.perf_counter()
                runs["pixels: registered"] = pixels(b.frames, m, mats, runs["histograms only"][2])
                timing["pixels"].append(time.perf_counter() - t0)
                runs["pixels: true matrices"] = pixels(
                    b.frames, m, true, runs["histograms only"][2]
                )
            for name, (ratios, ok, _) in runs.items():
                errs[name] += [abs(r / 4 - 1) for r in ratios]
                oks[name] += ok
            for meth in ("cerman", "mst"):
                ratios, note = hdrutils_ratios(b.frames, TIMES, m, meth)
                errs[f"HDRutils {meth}"] += [abs(r / 4 - 1) for r in ratios]
                if note:
                    notes[f"HDRutils {meth}"] = note
    if half_pixel:
        kind = (
            f"hand-held, shifts <= {shift:g} px + 1/2 px for every frame (all resampled "
            "alike), no rotation"
        )
    elif integer_motion:
        kind = f"hand-held, integer shifts <= {shift:g} px, no rotation"
    elif moving:
        kind = f"hand-held (shift <= {shift:g} px, rotation <= {rotation:g} deg)"
        if rendering != "area":
            kind += f", {rendering} rendering (moved frames' brightness off by up to 1 %)"
    else:
        kind = "tripod"
    n_pairs = len(SCENES) * len(seeds) * (len(TIMES) - 1)
    print(
        f"\n{bits}-bit, {kind}, {shape[0]}x{shape[1]}, {len(SCENES)} scenes x {len(seeds)} "
        f"seeds x 5 pairs = {n_pairs} pairs"
    )
    print(
        f"  {'estimator':26s} {'median %':>9s} {'p90 %':>8s} {'max %':>8s} {'failed':>6s} "
        f"{'>1 %':>5s} {'>1 % not ok':>11s} {'not ok':>7s}"
    )
    for name in ROWS:
        e = np.array(errs[name], float)
        if e.size == 0:
            continue
        failed = int(np.count_nonzero(~np.isfinite(e)))
        over = ~(e < 0.01)
        if name in oks and oks[name]:
            ok = np.array(oks[name])
            flag = f"{np.count_nonzero(over & ~ok):d}"
            notok = f"{np.count_nonzero(~ok):d}"
        else:
            flag, notok = "-", "-"
        if np.all(~np.isfinite(e)):
            print(f"  {name:26s} {'nan':>9s} {'nan':>8s} {'nan':>8s} {failed:6d}")
            continue
        print(
            f"  {name:26s} {100 * np.nanmedian(e):9.3f} {100 * np.nanpercentile(e, 90):8.3f} "
            f"{100 * np.nanmax(e):8.3f} {failed:6d} {np.count_nonzero(over):5d} {flag:>11s} "
            f"{notok:>7s}"
        )
    for name, note in notes.items():
        print(f"  note {name}: {note}")
    if timing["registration"]:
        print(
            f"  registration (register_bracket 'fast', 6 frames): median "
            f"{np.median(timing['registration']):.2f} s per bracket; registered-pixel "
            f"ratios {np.median(timing['pixels']):.2f} s per bracket"
        )


def seed_protocol():
    print(
        "Seed protocol (section 5.3): times 1..1024 x4, linear, 8 bits, sigma 1 level, "
        "256x384; darkest pair (paper: 4.0178, 0.45 % off)"
    )
    for scene in SCENES:
        b = simulate_bracket(
            scene=scene, shape=(256, 384), exposure_times=TIMES, bits=8, noise_sigma=1.0, seed=1
        )
        r1, _, _ = ours(b.frames, 255)
        r2, _, _ = ours(b.frames, 255, "Cerman 2006")
        h1, n1 = hdrutils_ratios(b.frames, TIMES, 255, "cerman")
        h2, n2 = hdrutils_ratios(b.frames, TIMES, 255, "mst")
        print(
            f"  {scene:10s} refined {r1[0]:.4f}  Cerman 2006 {r2[0]:.4f}  "
            f"HDRutils cerman {h1[0]:.4f}  mst {h2[0]:.4f}" + (f"  ({n2})" if n2 else "")
        )


# -------------------------------------------------------------------------------------- speed
def _median_time(fn, repeat=5):
    ts = []
    out = None
    for _ in range(repeat):
        s = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - s)
    return float(np.median(ts)), out


def speed(bits):
    b = simulate_bracket(
        scene="window",
        shape=(500, 750),
        exposure_times=(1.0, 4.0, 16.0),
        bits=bits,
        noise_sigma=2.0,
        seed=1,
    )
    big = [np.tile(f, (8, 8, 1)) for f in b.frames]  # 4000 x 6000 = 24 MP
    m = b.max_level
    t_h, hists = _median_time(lambda: bracket_histograms(big, m), repeat=3)
    t0 = time.perf_counter()
    res = bracket_exposures_from_histograms(hists)
    t_fit = time.perf_counter() - t0
    z0, f0 = default_saturation(m), default_noise_floor(m)
    zs = iter(np.linspace(0.90, 0.96, 50) * m)
    fs = iter(np.linspace(1.2, 2.0, 50) * f0)
    t_z, _ = _median_time(lambda: bracket_exposures_from_histograms(hists, saturation=next(zs)))
    t_f, _ = _median_time(
        lambda: bracket_exposures_from_histograms(hists, saturation=z0, noise_floor=next(fs))
    )
    fresh = bracket_exposures_from_histograms(bracket_histograms(big, m))
    same = np.allclose(fresh.ratios, res.ratios, rtol=0, atol=0)
    print(
        f"  {bits:2d}-bit  stride {hists.stride}  histograms {1e3 * t_h:6.0f} ms  first fit "
        f"{1e3 * t_fit:5.0f} ms  total {1e3 * (t_h + t_fit):6.0f} ms  re-fit Z "
        f"{1e3 * t_z:5.1f} ms  re-fit floor {1e3 * t_f:5.1f} ms  ratios "
        + ", ".join(f"{r:.4f}" for r in res.ratios)
        + f"  ({res.status}; fresh fit identical: {same})"
    )


# ----------------------------------------------------------------------------------- memorial
def memorial():
    d = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "memorial-debevec"
    if not d.is_dir():
        print("\nmemorial-debevec: not available")
        return
    from hdrcore.io import load_bracket
    from hdrcore.response import recover_response

    br = load_bracket([d], exposure_times=d / "exposure_times.txt")
    frames = [f.levels for f in br.frames]
    times = [float(f.meta.exposure_time) for f in br.frames]
    border = np.zeros(frames[0].shape[:2], bool)
    for f in frames:
        border |= (f[..., 0] == 0) & (f[..., 1] == 0) & (f[..., 2] == 255)
    known = [times[k + 1] / times[k] for k in range(len(times) - 1)]
    print(
        f"\nmemorial-debevec ({len(frames)} frames from exposure_times.txt, darkest first, "
        f"1 stop: known ratio {np.median(known):g}; {border.mean():.1%} blue border masked)"
    )
    t0 = time.perf_counter()
    resp = recover_response(frames, times, method="debevec-histogram", max_level=255)
    t_resp = time.perf_counter() - t0
    for name, lut in (
        ("sRGB fallback", srgb_lut(255)),
        (f"recovered response ({t_resp:.1f} s)", resp.to_lut(255)),
        ("levels as linear", None),
    ):
        r = bracket_exposures(frames, 255, lut=lut, mask=~border)
        rat = np.array([p.ratio for p in r.pairs])
        ok = np.array([p.ok for p in r.pairs])
        err = np.abs(rat / np.array(known) - 1)
        okerr = err[ok & np.isfinite(err)]
        print(
            f"  {name:34s} median ratio {np.nanmedian(rat):.4f}, median |err| "
            f"{100 * np.nanmedian(err):6.2f} %, ok {ok.sum()}/{ok.size} (median |err| of ok "
            f"pairs {100 * np.median(okerr) if okerr.size else float('nan'):.2f} %)"
        )
        print("    ratios " + " ".join(f"{v:.3f}" for v in rat))
        print("    status " + " ".join(p.status for p in r.pairs))
    # The pipeline as 'hdrcore ratios --registered': recovered response, registration, then
    # the ratios from the registered pixels (pairs that do not register keep the histograms').
    from hdrcore.pipeline import Pipeline, PipelineParams

    t0 = time.perf_counter()
    res = Pipeline(br, PipelineParams(exclude_colour=(0, 0, 255), registration_previews=False)).run(
        until="overlap_ratios"
    )
    rat = np.array([p.ratio for p in res.exposures.pairs])
    ok = np.array([p.ok for p in res.exposures.pairs])
    err = np.abs(rat / np.array(known) - 1)
    okerr = err[ok & np.isfinite(err)]
    print(
        f"  {'registered pixels (%.1f s)' % (time.perf_counter() - t0):34s} median ratio "
        f"{np.nanmedian(rat):.4f}, median |err| {100 * np.nanmedian(err):6.2f} %, ok "
        f"{ok.sum()}/{ok.size} (median |err| of ok pairs "
        f"{100 * np.median(okerr) if okerr.size else float('nan'):.2f} %)"
    )
    print("    ratios " + " ".join(f"{v:.3f}" for v in rat))
    print("    status " + " ".join(p.status for p in res.exposures.pairs))


if __name__ == "__main__":
    t_start = time.perf_counter()
    seed_protocol()
    seeds = (1,) if QUICK else (1, 2)
    for bits in (8, 12):
        accuracy_table(bits, (256, 384), seeds)
    for bits in (8, 12):
        accuracy_table(bits, (768, 1152), seeds, shift=20, rotation=1.0)
    # Moved frames sample the scene at other sub-pixel phases, which changes their histograms
    # even on the common field of view (not their pixels). These two tables separate that:
    accuracy_table(12, (768, 1152), seeds, shift=20, integer_motion=True)
    accuracy_table(12, (768, 1152), seeds, shift=20, half_pixel=True)
    # The simulator's earlier renderer, for comparison with the first session's numbers.
    accuracy_table(12, (768, 1152), seeds, shift=20, rotation=1.0, rendering="log-cubic")
    print(
        "\nSpeed, 3 frames 4000x6000x3 (24 MP) after decoding, median of repeats; re-fits reuse "
        "the cached histograms and transfer functions"
    )
    speed(14)
    speed(8)
    memorial()
    print(f"\nbench total {time.perf_counter() - t_start:.0f} s")
