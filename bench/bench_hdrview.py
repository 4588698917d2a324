"""Benchmark of the hdrview inspector (issue 7); prints a table, asserts nothing.

* first page ready: from starting ``hdrview`` (a subprocess on the demo bracket) to the page in
  chromium showing the loaded bracket, on a warm machine: the project's bytecode compiled first,
  as pip compiles an installed package's (an editable install under this machine's
  ``PYTHONDONTWRITEBYTECODE=1`` never caches it: every start then compiles hdrcore and hdrview
  again, 0.25-0.3 s);
* a saturation or noise-floor change on a large bracket: new ratios and BTF plot drawn;
* a threshold-t change: registration re-run (preview resolution inside the pipeline) and drawn;
* per control, how many of its steps kept the previous registration (the registration reads
  its thresholds snapped to the bracket's quantile ladder, :mod:`hdrcore.registration.thresholds`:
  the first saturation and noise-floor steps jump far from the defaults, the next move one
  level), and how many kept the previous merge (the bench bracket is a tripod one: after a
  threshold step its registration moves no frame the merge reads, so the merge is kept; a
  hand-held bracket's threshold step re-merges).

With ``hdrcore.pipeline`` installed the changes go through the app exactly as a slider does
(``set_control`` then wait for the worker); without it the stage functions the pipeline would call
are timed directly (re-fit from cached histograms + drawing), and the table says so.

* ``--steps pixel7,xperia`` (or ``all``): one-level saturation and noise-floor steps on the real
  brackets through the app, whether each kept the registration, its draft, its interim picture
  (a step that registers again: the full merge on the last motion first) and full result;

* a large bracket's draft preview (:mod:`hdrcore.draft`) drawn before the full re-merge, and
  which registration each step's draft used (the last full run's, scaled, or its own of the
  binned frames).

Usage: ``python bench/bench_hdrview.py [--megapixels 24] [--repeat 3]``. Numbers measured while
other work runs on the machine are pessimistic.

``--draft sim,pixel7,xperia,frobisher,memorial`` (or ``all``) prints only the draft's table: per
bracket a saturation change run as the inspector runs it (the draft with the previous full run's
response, times and motion, its frames binned by the draft before it, then the full re-run),
CPU and wall seconds of both, and how far the draft's
preview is from the full merge's own preview made at the draft's size; ``--draft-side`` sets
the draft's longer side (1024, the inspector's; smaller sides bin the small real brackets).
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import os
import re
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def first_page_ready(probe: str = "address") -> tuple[float, float] | None:
    """Seconds from ``hdrview`` start to the demo's frame table visible in chromium, and to the
    merged result drawn (the status line lists the stages it computed).

    ``probe``: when the browser opens the page. ``"address"`` (as a user does): when the
    inspector prints the address to open (``hdrview: open http://...``), the server listening.
    ``"goto"`` (this bench before 2026-12-07): the browser retries the address every 50 ms from
    the start; each refused try renders chromium's error page, and on this 2-core machine those
    renders took CPU from the starting inspector (its imports 0.4 s alone, 1.0 s beside them).
    """
    if not Path("/usr/bin/chromium").exists():
        return None
    import compileall
    import threading

    from playwright.sync_api import sync_playwright

    for package in ("hdrcore", "hdrview"):  # a warm machine: see the module's docstring
        compileall.compile_dir(str(ROOT / package), quiet=1)
    port = _free_port()
    with sync_playwright() as p:
        b = p.chromium.launch(
            executable_path="/usr/bin/chromium",
            args=[
                "--no-sandbox",
                "--disable-gpu",
                "--enable-unsafe-swiftshader",
                "--disable-dev-shm-usage",
            ],
        )
        page = b.new_page(viewport={"width": 1600, "height": 1000})
        t0 = time.perf_counter()  # the browser is already running: time the app only
        proc = subprocess.Popen(
            # --no-token: the page is opened without the printed address (the Host and
            # Origin checks stay on).
            [
                sys.executable,
                "-c",
                "from hdrview.app import main; main()",
                "--port",
                str(port),
                "--no-token",
            ],
            cwd=ROOT,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        announced = threading.Event()

        def read_stderr() -> None:  # drained to the end: a full pipe would block the app
            assert proc.stderr is not None
            for line in proc.stderr:
                if line.startswith("hdrview: open "):
                    announced.set()
            announced.set()  # ended without it: the page load below says why

        threading.Thread(target=read_stderr, daemon=True).start()
        try:
            if probe == "address":
                if not announced.wait(60):
                    raise TimeoutError("hdrview did not print its address within 60 s")
            while True:
                try:
                    page.goto(f"http://127.0.0.1:{port}", timeout=2000)
                    break
                except Exception:
                    if time.perf_counter() - t0 > 60:
                        raise
                    time.sleep(0.05)
            page.get_by_text("frame00.dng").first.wait_for(state="visible", timeout=60_000)
            elapsed = time.perf_counter() - t0
            page.get_by_text(
                re.compile(r"^(Computed:|Everything came from the cache)")
            ).first.wait_for(state="visible", timeout=120_000)
            result = time.perf_counter() - t0
        finally:
            proc.terminate()
            proc.wait(10)
            b.close()
    return elapsed, result


#: The large bracket's encodings: ``linear16`` 16-bit linear TIFFs as raw converters write them,
#: ``srgb8`` 8-bit sRGB TIFFs (a camera's JPEG rendering, without its compression).
ENCODINGS = {"linear16": (16, "linear", 8.0), "srgb8": (8, "srgb", 0.5)}


def large_bracket(megapixels: float, encoding: str = "linear16"):
    from hdrcore.synthetic import simulate_bracket

    # 16-bit linear TIFFs use the full 16-bit range (14-bit levels left in a 16-bit container
    # clip at a quarter of it; the loader reads those as 14-bit, narrow-container). Noise: 2
    # levels at 14 bits; half a level at 8 bits.
    bits, response, noise = ENCODINGS[encoding]
    w = int(round(np.sqrt(megapixels * 1e6 * 1.5)))
    h = int(round(w / 1.5))
    return simulate_bracket(
        scene="window",
        shape=(h, w),
        exposure_times=(1.0, 4.0, 16.0),
        bits=bits,
        response=response,
        noise_sigma=noise,
        seed=5,
    )


def bench_components(sim, repeat: int) -> list[tuple]:
    """Without the pipeline: the re-fit the pipeline runs on a Z change, plus the BTF drawing."""
    import viser

    from hdrcore.exposure import bracket_exposures_from_histograms, bracket_histograms
    from hdrview.panels.btf import BtfPanel
    from hdrview.panels.masks import MasksPanel

    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        btf, masks = BtfPanel(server.gui), MasksPanel(server.gui)
        t = time.perf_counter()
        hists = bracket_histograms(list(sim.frames), sim.max_level)
        t_hist = time.perf_counter() - t
        rows = [("histograms of the bracket (once per load)", t_hist, "hdrcore")]

        class _B:
            frames = [
                type("F", (), {"levels": f, "name": f"f{k}"})() for k, f in enumerate(sim.frames)
            ]
            warnings = ()

        for what, kw in (("saturation", "saturation"), ("noise floor", "noise_floor")):
            times_fit, times_draw = [], []
            for r in range(repeat):
                value = (0.95 - 0.01 * r) * sim.max_level if kw == "saturation" else 40.0 + 5 * r
                t = time.perf_counter()
                exposure = bracket_exposures_from_histograms(
                    hists, exposure_times=list(sim.exposure_times), **{kw: value}
                )
                times_fit.append(time.perf_counter() - t)
                result = type("R", (), {"exposure": exposure})()
                t = time.perf_counter()
                btf.show(_B, result, {"pair": 0})
                masks.show(_B, result, {"pair": 0})
                times_draw.append(time.perf_counter() - t)
            rows.append(
                (
                    f"{what} change: ratios re-fit from cached histograms",
                    float(np.median(times_fit)),
                    "hdrcore",
                )
            )
            rows.append(
                (f"{what} change: BTF plot + masks drawn", float(np.median(times_draw)), "hdrview")
            )
            rows.append(
                (
                    f"{what} change: total (target < 0.3 s)",
                    float(np.median(times_fit) + np.median(times_draw)),
                    "both",
                )
            )
        return rows
    finally:
        server.stop()


def bench_pipeline(sim, repeat: int, drafts: bool = True) -> list[tuple]:
    """With the pipeline: the app's own path, set_control -> worker -> pipeline -> panels."""
    import viser

    from hdrcore.io import write_png  # noqa: F401  (frames go through the loader below)
    from hdrview.app import InspectorApp

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        import tifffile

        folder = Path(tmp) / "big"
        folder.mkdir()
        names = []
        for k, f in enumerate(sim.frames):
            p = folder / f"frame{k}.tif"
            tifffile.imwrite(p, f.astype(np.uint8 if sim.bits == 8 else np.uint16))
            names.append(p.name)
        (folder / "exposure_times.txt").write_text(
            "".join(f"{n} {t:g}\n" for n, t in zip(names, sim.exposure_times, strict=True))
        )
        server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
        inspector = InspectorApp(server, root=tmp, demo_dir=None)
        app = inspector.headless_view()  # one page's view, without a browser
        app.drafts = drafts
        try:
            t = time.perf_counter()
            app.request_path("big")
            app.wait_idle(600)
            rows.append(("load + full pipeline + draw (once)", time.perf_counter() - t, "app"))
            rows.append(
                (
                    "load: draft preview drawn",
                    app.last_draft_seconds or float("nan"),
                    "app",
                    app.last_draft_cpu or float("nan"),
                )
            )
            top = app.saturation_slider.max
            for label, control, values in (
                ("saturation change", "saturation", [0.95 * top - r for r in range(repeat)]),
                ("noise-floor change", "noise_floor", [40.0 + r for r in range(repeat)]),
                ("threshold-t change", "threshold", [0.05 + 0.01 * r for r in range(repeat)]),
            ):
                times, quick, reg, cpu = [], [], [], {"quick": [], "reg": [], "all": []}
                draft, cpu["draft"] = [], []
                shown_full, cpu["shown"] = [], []  # the full-resolution result drawn
                kept = 0  # steps whose result holds the previous step's registration object
                merged = 0  # steps whose result holds the previous step's merge (a tripod
                # bracket's threshold step: nothing the merge reads changed, see _Reading)
                motion: list[str] = []  # which registration each step's draft used
                for v in values:
                    before = getattr(app, "_drawn_result", None)
                    app.last_draft_seconds = app.last_draft_cpu = None
                    app.last_shown_seconds = app.last_shown_cpu = None
                    if hasattr(app.session, "draft_registration"):
                        app.session.draft_registration = ""
                    t = time.perf_counter()
                    app.set_control(control, float(v))
                    app.wait_idle(600)
                    times.append(time.perf_counter() - t)
                    draft.append(app.last_draft_seconds or float("nan"))
                    shown_full.append(getattr(app, "last_shown_seconds", None) or float("nan"))
                    cpu["shown"].append(getattr(app, "last_shown_cpu", None) or float("nan"))
                    cpu["draft"].append(app.last_draft_cpu or float("nan"))
                    quick.append(app.last_ratios_seconds or float("nan"))
                    reg.append(app.last_registration_seconds or float("nan"))
                    cpu["quick"].append(getattr(app, "last_ratios_cpu", None) or float("nan"))
                    cpu["reg"].append(getattr(app, "last_registration_cpu", None) or float("nan"))
                    cpu["all"].append(getattr(app, "last_job_cpu", None) or float("nan"))
                    motion.append(getattr(app.session, "draft_registration", "") or "no draft")
                    shown = getattr(app, "_drawn_result", None)
                    kept += (
                        before is not None
                        and shown is not None
                        and shown.registration is not None
                        and shown.registration is before.registration
                    )
                    merged += (
                        before is not None
                        and shown is not None
                        and shown.merge is not None
                        and shown.merge is before.merge
                    )
                quick_target = " (target < 0.3 s)" if control != "threshold" else ""
                reg_target = " (target < 1.5 s)" if control == "threshold" else ""
                for what, walls, key in (
                    (f"ratios + BTF drawn{quick_target}", quick, "quick"),
                    ("draft preview drawn (target < 2 s)", draft, "draft"),
                    (f"re-registered + overlays drawn{reg_target}", reg, "reg"),
                    ("full-resolution result drawn (target < 2 s)", shown_full, "shown"),
                    ("every stage re-run and drawn (ghost test too)", times, "all"),
                ):
                    rows.append(
                        (
                            f"{label}: {what}",
                            float(np.median(walls)),
                            "app",
                            float(np.median(cpu[key])),
                        )
                    )
                # the registration reads its thresholds snapped to the bracket's quantile
                # ladder (hdrcore.registration.thresholds): which steps kept it
                rows.append(
                    (f"{label}: steps that kept the registration: {kept} of {len(values)}",)
                )
                rows.append((f"{label}: steps that kept the merge: {merged} of {len(values)}",))
                # the draft takes the last full run's motion, scaled, unless the kind of
                # motion changed (hdrview.session.Session.draft_motion)
                used = {m: motion.count(m) for m in dict.fromkeys(motion)}
                rows.append(
                    (
                        f"{label}: the drafts' registration: "
                        + "; ".join(f"{m} ({n} of {len(values)})" for m, n in used.items()),
                    )
                )
            errors = [n for n in app.notifications if n[0] == "error"]
            if errors:
                rows.append((f"errors during the bench: {errors[-1][2][:80]}", float("nan"), "app"))
        finally:
            inspector.stop()
            server.stop()
    return rows


DATA = (ROOT / ".." / "shared" / "data").resolve()
# name: (folder, exposure-times file, parameters beyond the inspector's defaults)
REAL = {
    "frobisher": ("frobisher-colour-hdri", None, {}),
    "memorial": ("memorial-debevec", "exposure_times.txt", {"exclude_colour": (0, 0, 255)}),
    "pixel7": ("handheld-pixel7-lab", None, {}),
    "xperia": ("handheld-xperia-library", "iso100_equivalent_times.txt", {}),
}


def _timed(fn):
    t, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - t, time.process_time() - c


def _difference(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per pixel, the largest |difference| over RGB of two 8-bit images (cropped alike)."""
    h, w = min(a.shape[0], b.shape[0]), min(a.shape[1], b.shape[1])
    return np.abs(np.asarray(a, np.float32)[:h, :w] - np.asarray(b, np.float32)[:h, :w]).max(2)


def draft_agreement(bracket, extra: dict, max_side: int) -> dict:
    """A saturation change (-1 level from the default) as the inspector runs it: the draft
    (hdrcore.draft) with the previous full run's response and times, then the full re-run.
    The draft's preview is compared with the full merge's own preview made at the draft's size
    (the same operator on the full radiance map area-reduced: what the draft approximates) and
    with the full preview area-reduced in display values (what the page swaps)."""
    from hdrcore.draft import DraftCache, draft_factor, run_draft
    from hdrcore.pipeline import Pipeline, PipelineParams
    from hdrcore.resample import downsample_area

    pipe = Pipeline(bracket, PipelineParams(**extra))
    first = pipe.run()
    p = first.params.replace(saturation=first.params.saturation - 1)
    # As hdrview.session.Session.draft_motion: the full run's motion, scaled, when it is of
    # the whole bracket; the frames binned by an earlier draft (a slider step's draft)
    motion = first.registration if first.full_bracket is None else None
    cache = DraftCache()

    def step(params, quick):
        # as Session.run_draft: the step's whole-frame ratios of the full frames (the quick
        # run's, made before the draft as the inspector does, not timed with it) and, with the
        # full run's motion, its frame measures
        return run_draft(
            bracket,
            params.replace(
                response=first.response if first.response is not None else params.response
            ),
            max_side=max_side,
            exposure_times=first.exposure_times,
            registration=motion,
            cache=cache,
            ratios=quick.exposures if quick.bracket is bracket else None,
            frame_measures=first.frame_measures if motion is not None else None,
        )

    quick = pipe.run(first.params, until="ratios")
    _, t_bin, _ = _timed(lambda: step(first.params, quick))
    quick = pipe.run(p, until="ratios")
    draft, t_draft, c_draft = _timed(lambda: step(p, quick))
    full, t_full, c_full = _timed(lambda: pipe.run(p))
    a = np.asarray(draft.preview.image)
    same_size = pipe.run(p.replace(preview_max_side=max(a.shape[:2]))).preview.image
    d = _difference(a, same_size)
    f = draft.preview_factor // full.preview_factor
    shown = _difference(a, downsample_area(np.asarray(full.preview.image, np.float32), f))
    return {
        "full_s": t_full,
        "full_cpu": c_full,
        "draft_s": t_draft,
        "draft_cpu": c_draft,
        "mean": float(d.mean()),
        "p99": float(np.percentile(d, 99)),
        "over10": float(np.mean(d > 10)),
        "shown": float(shown.mean()),
        "size": f"{a.shape[1]}x{a.shape[0]}",
        "ops": f"{full.preview.method}/{draft.preview.method}",
        "first_s": t_bin,
        # (at factor 1 the draft registers its frames: the full-resolution registration)
        "reg": "none"
        if draft.registration is None
        else "full"
        if motion is not None and draft_factor(bracket.shape, max_side) > 1
        else "own",
    }


def bench_draft(names: list[str], max_side: int, sim=None) -> None:
    from hdrcore.io import load_bracket

    print(
        f"\ndraft preview (hdrcore.draft, longer side <= {max_side}) against the full "
        "re-merge after a saturation change: |difference| of 8-bit previews, max over RGB, "
        "against the full merge's preview made at the draft's size (mean, 99th percentile, "
        "share over 10 levels) and against the full preview area-reduced ('shown', mean); "
        "times wall / CPU s: 'draft s' a slider step's draft (frames binned by the draft "
        "before it, 'first s' wall, which bins them); 'reg': the draft's registration (the "
        f"full run's, scaled, or its own); load average {os.getloadavg()[0]:.1f}"
    )
    print(
        f"{'bracket':<22} {'draft':>10} {'full s':>7} {'cpu':>6} {'first s':>7} {'draft s':>7} "
        f"{'cpu':>6} {'reg':>4} {'mean':>6} {'p99':>5} {'>10':>7} {'shown':>6}  "
        "tonemap full/draft"
    )
    rows = []
    if sim is not None:
        rows.append(("simulated 24 MP", sim, {}))
    for name in names:
        folder, times, extra = REAL[name]
        d = DATA / folder
        if not d.is_dir():
            print(f"{name:<22} skipped: {d} absent")
            continue
        files = sorted(q for q in d.iterdir() if q.suffix.lower() in (".jpg", ".png"))
        rows.append(
            (name, load_bracket(files, exposure_times=None if times is None else d / times), extra)
        )
    for label, b, extra in rows:
        r = draft_agreement(b, extra, max_side)
        print(
            f"{label:<22} {r['size']:>10} {r['full_s']:>7.2f} {r['full_cpu']:>6.2f} "
            f"{r['first_s']:>7.2f} {r['draft_s']:>7.2f} {r['draft_cpu']:>6.2f} {r['reg']:>4} "
            f"{r['mean']:>6.2f} {r['p99']:>5.0f} {100 * r['over10']:>6.2f}% {r['shown']:>6.2f}  "
            f"{r['ops']}"
        )


def bench_steps(names: list[str]) -> None:
    """One-level slider steps on the real brackets, through the app (a headless page) as a
    slider sends them: per step whether the registration was kept, the draft and the
    full-resolution result drawn (seconds after the change)."""
    import viser

    from hdrview.app import InspectorApp

    print(
        "\nslider steps on the real brackets (headless page, one level at a time; seconds from "
        f"the change; load average {os.getloadavg()[0]:.1f})"
    )
    print(
        f"{'bracket':<10} {'control':<12} {'value':>6} {'registration':>13} "
        f"{'draft':>6} {'interim':>7} {'full':>6}"
    )
    for name in names:
        folder, _, _ = REAL[name]
        if not (DATA / folder).is_dir():
            print(f"{name:<10} skipped: {DATA / folder} absent")
            continue
        server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
        inspector = InspectorApp(server, root=DATA, demo_dir=None)
        app = inspector.headless_view()
        try:
            app.request_path(folder)
            app.wait_idle(900)
            first = app.session.result
            assert first is not None
            top = math.floor(first.saturation)
            floor = first.noise_floor
            steps = [("saturation", float(top - d)) for d in range(1, 7)]
            steps += [("noise_floor", round(floor + d, 1)) for d in (0.2, 0.5, 1.1, 1.4)]
            # threshold t: read by the registration alone (it always registers again; no draft)
            t0 = float(first.params.threshold)
            steps += [("threshold", round(t0 + d, 3)) for d in (0.02, 0.04)]
            kept = {"saturation": 0, "noise_floor": 0, "threshold": 0}
            for control, value in steps:
                before = app.session.result
                app.last_draft_seconds = app.last_shown_seconds = None
                app.last_interim_seconds = None
                app.set_control(control, value)
                app.wait_idle(900)
                after = app.session.result
                same = (
                    before is not None
                    and after is not None
                    and after.registration is before.registration
                )
                kept[control] += same
                print(
                    f"{name:<10} {control:<12} {value:>6g} {'kept' if same else 'registered':>13} "
                    f"{app.last_draft_seconds or float('nan'):>6.2f} "
                    f"{app.last_interim_seconds or float('nan'):>7.2f} "
                    f"{app.last_shown_seconds or float('nan'):>6.2f}"
                )
            print(
                f"{name:<10} registration kept: saturation {kept['saturation']} of 6, "
                f"noise floor {kept['noise_floor']} of 4, threshold {kept['threshold']} of 2"
            )
        finally:
            inspector.stop()
            server.stop()


def _sim_bracket(sim):
    """The simulated frames as a Bracket (TIFF levels, the times known)."""
    import tifffile

    from hdrcore.io import load_bracket

    tmp = Path(tempfile.mkdtemp(prefix="bench_hdrview_"))
    names = []
    for k, f in enumerate(sim.frames):
        tifffile.imwrite(tmp / f"frame{k}.tif", f.astype(np.uint8 if sim.bits == 8 else np.uint16))
        names.append(f"frame{k}.tif")
    (tmp / "exposure_times.txt").write_text(
        "".join(f"{n} {t:g}\n" for n, t in zip(names, sim.exposure_times, strict=True))
    )
    return load_bracket([tmp / n for n in names], exposure_times=tmp / "exposure_times.txt")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--megapixels", type=float, default=24.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--skip-browser", action="store_true")
    ap.add_argument(
        "--encoding",
        choices=sorted(ENCODINGS),
        default="linear16",
        help="the large bracket's TIFFs: 16-bit linear (default) or 8-bit sRGB",
    )
    ap.add_argument(
        "--draft",
        default=None,
        metavar="NAMES",
        help="only the draft preview's agreement and speed: 'sim' and/or real "
        f"brackets ({','.join(REAL)}), comma-separated, or 'all'",
    )
    ap.add_argument("--draft-side", type=int, default=1024)
    ap.add_argument(
        "--steps",
        default=None,
        metavar="NAMES",
        help="only one-level slider steps on real brackets through the app "
        f"({','.join(REAL)}, comma-separated, or 'all'): registration kept, draft, full result",
    )
    ap.add_argument(
        "--no-draft",
        action="store_true",
        help="the app without its draft previews (the full re-merge's own cost)",
    )
    args = ap.parse_args()
    # the allocator setting the hdrview program makes (hdrview.app.main): freed buffers are
    # reused, not given back and touched anew at the next re-merge
    from hdrcore._memory import retain_freed_memory

    retained = retain_freed_memory()
    if args.steps is not None:
        bench_steps(list(REAL) if args.steps == "all" else args.steps.split(","))
        return 0
    if args.draft is not None:
        names = list(REAL) + ["sim"] if args.draft == "all" else args.draft.split(",")
        sim = (
            _sim_bracket(large_bracket(args.megapixels, args.encoding)) if "sim" in names else None
        )
        bench_draft([n for n in names if n != "sim"], args.draft_side, sim)
        return 0
    os.environ.setdefault("PYTHONPATH", str(ROOT))
    rows: list[tuple] = []
    if not args.skip_browser:
        t = first_page_ready()
        rows.append(
            (
                "first page ready after start (target < 3 s)",
                float("nan") if t is None else t[0],
                "demo, chromium",
            )
        )
        rows.append(
            (
                "first page: merged result drawn after start",
                float("nan") if t is None else t[1],
                "demo, chromium",
            )
        )
    t = time.perf_counter()
    sim = large_bracket(args.megapixels, args.encoding)
    h, w = sim.frames[0].shape[:2]
    print(
        f"simulated 3-frame {w}x{h} ({w * h / 1e6:.1f} MP) {sim.bits}-bit {sim.response} TIFF "
        "bracket in "
        f"{time.perf_counter() - t:.1f} s"
    )
    if importlib.util.find_spec("hdrcore.pipeline") is not None:
        rows += bench_pipeline(sim, args.repeat, drafts=not args.no_draft)
        mode = "through the app and hdrcore.pipeline" + (
            ", freed memory reused as in the hdrview program" if retained else ""
        )
    else:
        rows += bench_components(sim, args.repeat)
        mode = "hdrcore.pipeline absent: stage functions timed directly"
    print(
        f"\nhdrview bench ({mode}); median of {args.repeat}; load average "
        f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    )
    print(
        "  cpu: CPU seconds of the whole process (every thread) over the same span; on a "
        "shared machine the load stretches the wall time, not these"
    )
    print(f"{'what':<62} {'seconds':>9} {'cpu':>7}  by")
    for what, *timed in rows:
        if not timed:  # a line of words
            print(f"{what}")
            continue
        sec, by, *cpu = timed
        c = f"{cpu[0]:>7.3f}" if cpu else f"{'':>7}"
        print(f"{what:<62} {sec:>9.3f} {c}  {by}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
