"""End-to-end bench: a 3-frame 24-megapixel RAW-like (12-bit DNG) hand-held bracket.

Prints, in one run, side by side:

* ours: decode (rawpy, reported separately), then the pipeline (histograms, ratios,
  registration, warp + merge + colour, full-resolution preview) with per-stage times and the
  process's peak memory;
* OpenCV: AlignMTB + MergeDebevec (+ its tonemap) on the same frames, given as 8-bit (what
  OpenCV's Debevec merge accepts), decode excluded; once with the allocator setting our
  programs use (hdrcore._memory: freed memory kept and reused) and once on glibc's defaults,
  under which most of MergeDebevec's time is the first touch of its fresh buffers;
* HDRutils: ``HDRutils.merge`` on the same DNG files (its time includes its own decode).

The whole command, decode INCLUDED (issue 18), side by side in the same run:

* ``hdrcore merge FRAMES -o OUT.exr --preview OUT.png --report OUT.json`` in a new process
  (our mosaic decode and compiled demosaic; the same with ``HDRCORE_RAW_DEMOSAIC=libraw-ahd``
  for LibRaw's postprocess), wall, CPU and peak memory of that process;
* the peer: rawpy ``postprocess`` (LibRaw AHD, sRGB, 8-bit: what OpenCV's Debevec merge takes)
  of every frame on two threads, OpenCV AlignMTB + MergeDebevec, and the EXR written with the
  OpenEXR module (half, PIZ, as ours), in a new process.

Each contender runs in its own child process so that peak memory (``ru_maxrss``) is its own.
Targets (issue 6): ours <= 4 s end to end without decode, peak <= 3 GB; the merge step alone
<= 0.3x MergeDebevec. Issue 18: the whole command <= 2.5 s wall and <= 0.45x the peer, peak
<= 1.5 GB (3 x 24 MP 12-bit); a 5 x 45 MP 14-bit bracket (``--size 5760x8640 --frames 5
--bits 14``) printed, peak <= 3 GB.

    python bench/bench_pipeline.py [--size 4000x6000] [--frames 3] [--bits 12] [--skip ...]

``--skip ours,opencv,hdrutils,libraw,dng,peer --repeat 1`` runs the plain ``hdrcore merge``
command alone (the 45 MP bracket's peak memory in one run).

The synthetic bracket is cached under ``bench/out/`` (gitignored) between runs.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
OUT = HERE / "out"


def make_bracket(size: tuple[int, int], frames: int, bits: int = 12) -> Path:
    from hdrcore.synthetic import simulate_bracket, write_bracket

    h, w = size
    d = OUT / (f"pipeline_{h}x{w}_{frames}" + ("" if bits == 12 else f"_{bits}bit"))
    if (d / "truth.json").exists() and json.loads((d / "truth.json").read_text()).get(
        "rendering"
    ) == "area":
        return d  # (a bracket from the earlier log-cubic renderer is made again)
    d.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    times = tuple(2.0 ** (2 * k) / 256 for k in range(frames))
    sim = simulate_bracket(
        scene="window",
        shape=(h, w),
        exposure_times=times,
        bits=bits,
        response="linear",
        noise_sigma=2.0,
        shot_noise_full_well=20000,
        max_shift=20,
        max_rotation_deg=1.0,
        key=0.24,
        seed=11,
        keep_linear=True,
    )
    write_bracket(d, sim, "dng", force=True)
    print(f"# made {d} in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return d


def _peak_mb() -> float:
    """Peak resident memory of this process (VmHWM; ru_maxrss survives exec from the parent)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return float(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def child_ours(d: Path) -> dict:
    from hdrcore._memory import retain_freed_memory
    from hdrcore.io import load_bracket
    from hdrcore.pipeline import Pipeline, PipelineParams

    # As the hdrcore and hdrview programs do (HDRCORE_RETAIN_MEMORY=0 to compare without).
    retained = retain_freed_memory()

    t0 = time.perf_counter()
    bracket = load_bracket([d])
    decode = time.perf_counter() - t0
    base_mb = _peak_mb()
    # As ``hdrcore merge --preview``: a preview PNG of at most 2048 px on its longest side.
    # reuse_buffers: the second run writes its merge into the first run's arrays (a long-lived
    # process; the first run, as 'hdrcore merge', allocates them).
    pipe = Pipeline(
        bracket,
        PipelineParams(preview_max_side=2048, registration_previews=False),
        reuse_buffers=True,
    )
    t1 = time.perf_counter()
    res = pipe.run()
    cold = time.perf_counter() - t1
    cold_stages = {k: v for k, v in res.timings.items() if k != "total"}
    # Again in the same process: numba kernels loaded (a long-lived hdrview server, or a
    # second bracket in one script), nothing else cached.
    pipe.clear_cache()
    t1 = time.perf_counter()
    res = pipe.run()
    total = time.perf_counter() - t1
    # Slider-style re-fits on the cached histograms.
    t2 = time.perf_counter()
    pipe.run(res.params.replace(saturation=res.saturation * 0.98), until="ratios")
    refit = time.perf_counter() - t2
    peak = _peak_mb()
    # The merge step on the frames as given (no warp), as MergeDebevec gets its (AlignMTB-
    # shifted) frames: best of 2, after the runs above (kernels loaded), into the last
    # result's arrays (as the second run did).
    aligned = []
    for _ in range(2):
        t3 = time.perf_counter()
        pipe._merge(res.params, res.lut, res.exposure_times, None, None, reuse=res.merge)
        aligned.append(time.perf_counter() - t3)
    truth = json.loads((d / "truth.json").read_text())
    err = [abs(r / t - 1) for r, t in zip(res.exposures.ratios, truth["ratios"], strict=True)]
    from hdrcore.registration import corner_error

    corner = (
        [
            float(
                np.max(corner_error(p.matrix, np.array(truth["pairs"][k]["matrix"]), bracket.shape))
            )
            for k, p in enumerate(res.registration.pairs)
        ]
        if res.registration is not None
        else []
    )
    return {
        "retain_freed_memory": retained,
        "decode_s": decode,
        "pipeline_s": total,
        "cold_s": cold,
        "cold_stages": cold_stages,
        "stages": {k: v for k, v in res.timings.items() if k != "total"},
        "merge_internal": res.merge.timings,
        "merge_as_given_s": min(aligned),
        "refit_s": refit,
        "peak_mb": peak,
        "after_decode_mb": base_mb,
        "ratio_errors_pct": [100 * e for e in err],
        "corner_error_px": corner,
    }


def child_opencv(d: Path) -> dict:
    import cv2

    from hdrcore._memory import retain_freed_memory
    from hdrcore.io import load_bracket

    # The same allocator setting as ours (on this VM fresh memory is slow to fault in, and
    # MergeDebevec's own time is mostly that: 2.1 of its 2.6-3.3 s are system time).
    retain_freed_memory()

    bracket = load_bracket([d])
    times = np.array([f.exposure_time for f in bracket.frames], np.float32)
    imgs8 = []
    for f in bracket.frames:
        # What OpenCV's Debevec merge accepts: 8-bit frames (a gamma-free linear scaling).
        x = np.minimum(f.levels, f.max_level).astype(np.float32) * (255.0 / f.max_level)
        imgs8.append(np.ascontiguousarray(np.rint(x).astype(np.uint8)[..., ::-1]))
    del bracket
    base_mb = _peak_mb()
    t0 = time.perf_counter()
    cv2.createAlignMTB().process(imgs8, imgs8)
    t_align = time.perf_counter() - t0
    t1 = time.perf_counter()
    hdr = cv2.createMergeDebevec().process(imgs8, times)
    t_merge = time.perf_counter() - t1
    t2 = time.perf_counter()
    ldr = cv2.createTonemapReinhard().process(hdr)
    _ = np.clip(ldr * 255, 0, 255).astype(np.uint8)
    t_tm = time.perf_counter() - t2
    return {
        "align_s": t_align,
        "merge_s": t_merge,
        "tonemap_s": t_tm,
        "pipeline_s": t_align + t_merge + t_tm,
        "peak_mb": _peak_mb(),
        "after_decode_mb": base_mb,
    }


def child_hdrutils(d: Path) -> dict:
    import logging

    import HDRutils
    import HDRutils.io as hio
    import rawpy

    original = hio.imread_libraw

    def imread_libraw(raw, color_space="srgb"):
        # HDRutils passes user_wb=(1, 1, 1, 1) for raw colour, a tuple the installed rawpy
        # rejects ("expected list"); the same call with a list.
        if color_space.lower() == "raw":
            return raw.postprocess(
                gamma=(1, 1),
                no_auto_bright=True,
                output_bps=16,
                user_wb=[1, 1, 1, 1],
                user_flip=0,
                output_color=rawpy.ColorSpace.raw,
            )
        return original(raw, color_space)

    hio.imread_libraw = imread_libraw
    logging.disable(logging.WARNING)
    files = sorted(str(p) for p in d.glob("*.dng"))
    truth = json.loads((d / "truth.json").read_text())
    n = len(files)
    t0 = time.perf_counter()
    # Its EXIF reader does not find our DNG tags, so the metadata is given by hand.
    HDRutils.merge(
        files,
        demosaic_first=True,
        color_space="raw",
        exp=np.array(truth["exposure_times"]),
        gain=np.ones(n),
        aperture=np.ones(n),
    )
    return {
        "pipeline_s": time.perf_counter() - t0,
        "peak_mb": _peak_mb(),
        "note": "includes its own decode",
    }


def _child_rusage() -> tuple[float, float]:
    """CPU seconds and peak MB of the finished child processes (the command run)."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime, r.ru_maxrss / 1024.0


def child_command(d: Path) -> dict:
    """``hdrcore merge`` as a user runs it: a new process, decode, EXR, preview and report
    (and a float DNG when ``HDRCORE_BENCH_DNG`` is set)."""
    import tempfile

    frames = sorted(str(p) for p in d.glob("*.dng"))
    with tempfile.TemporaryDirectory(dir=OUT) as tmp:
        cmd = [
            sys.executable,
            "-m",
            "hdrcore",
            "merge",
            *frames,
            "-o",
            f"{tmp}/m.exr",
            "--preview",
            f"{tmp}/m.png",
            "--report",
            f"{tmp}/m.json",
            "--quiet",
            "--force",
        ]
        if os.environ.get("HDRCORE_BENCH_DNG"):
            cmd += ["--dng", f"{tmp}/m.dng"]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, cwd=HERE.parent)
        wall = time.perf_counter() - t0
        if proc.returncode not in (0, 1):
            raise RuntimeError(proc.stderr.strip().splitlines()[-1])
        report = json.loads(Path(f"{tmp}/m.json").read_text())
    cpu, peak = _child_rusage()
    return {
        "wall_s": wall,
        "cpu_s": cpu,
        "peak_mb": peak,
        "decode_s": report["timings"].get("decode"),
        "write_s": report["timings"].get("write"),
        "stages": {
            k: v for k, v in report["timings"].items() if k not in ("decode", "write", "total")
        },
    }


def _process_age() -> float:
    """Seconds since this process started (its start time in /proc, in clock ticks after boot:
    10 ms steps), so that a wall time includes the interpreter's start and the imports, as the
    wall time of ``hdrcore merge`` measured around its process does."""
    ticks = os.sysconf("SC_CLK_TCK")
    fields = Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()
    start = int(fields[19]) / ticks  # field 22, starttime (fields[0] is field 3)
    return float(Path("/proc/uptime").read_text().split()[0]) - start


def child_peer(d: Path) -> dict:
    """rawpy decode (2 threads) + AlignMTB + MergeDebevec + EXR write, in this new process.
    Its wall time runs from the process's start (interpreter and imports included, as ours);
    ``after_imports_s`` from the end of its imports."""
    from concurrent.futures import ThreadPoolExecutor

    import cv2
    import OpenEXR
    import rawpy

    from hdrcore._memory import retain_freed_memory

    retain_freed_memory()
    files = sorted(str(p) for p in d.glob("*.dng"))
    times = np.array(json.loads((d / "truth.json").read_text())["exposure_times"], np.float32)
    t0 = time.perf_counter()

    def decode(f: str) -> np.ndarray:
        with rawpy.imread(f) as raw:
            # LibRaw's AHD to 8-bit sRGB, linear (gamma 1): what MergeDebevec takes.
            return raw.postprocess(gamma=(1, 1), no_auto_bright=True, output_bps=8)[..., ::-1]

    with ThreadPoolExecutor(2) as pool:
        imgs = [np.ascontiguousarray(x) for x in pool.map(decode, files)]
    t_dec = time.perf_counter()
    cv2.createAlignMTB().process(imgs, imgs)
    t_al = time.perf_counter()
    hdr = cv2.createMergeDebevec().process(imgs, times)
    t_me = time.perf_counter()
    with tempfile_dir() as tmp:
        rgb = np.ascontiguousarray(hdr[..., ::-1])
        header = {"compression": OpenEXR.PIZ_COMPRESSION, "type": OpenEXR.scanlineimage}
        OpenEXR.File(header, {"RGB": rgb.astype(np.float16)}).write(f"{tmp}/peer.exr")
    t_wr = time.perf_counter()
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    return {
        "wall_s": _process_age(),
        "after_imports_s": t_wr - t0,
        "cpu_s": r1.ru_utime + r1.ru_stime,
        "peak_mb": _peak_mb(),
        "decode_s": t_dec - t0,
        "align_s": t_al - t_dec,
        "merge_s": t_me - t_al,
        "write_s": t_wr - t_me,
    }


def tempfile_dir():
    import tempfile

    return tempfile.TemporaryDirectory(dir=OUT)


CHILDREN = {
    "ours": child_ours,
    "opencv": child_opencv,
    "hdrutils": child_hdrutils,
    "command": child_command,
    "peer": child_peer,
}


def run_child(name: str, d: Path, retain: bool = True, **extra_env: str) -> dict:
    env = dict(os.environ, HDRCORE_RETAIN_MEMORY="1" if retain else "0", **extra_env)
    proc = subprocess.run(
        [sys.executable, __file__, "--child", name, "--dir", str(d)],
        capture_output=True,
        text=True,
        timeout=1800,
        env=env,
    )
    if proc.returncode != 0:
        tail = (proc.stderr or "").strip().splitlines()[-1:] or ["?"]
        return {"error": tail[0][:160]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def whole_command(d: Path, repeat: int, skip: set[str]) -> None:
    """The issue-18 table: the whole command, decode included, beside the peer."""
    runs: dict[str, list[dict]] = {}
    contenders = [
        ("hdrcore merge (ours: mosaic read + demosaic)", "command", {}, "command"),
        (
            "hdrcore merge, LibRaw AHD decode",
            "command",
            {"HDRCORE_RAW_DEMOSAIC": "libraw-ahd"},
            "libraw",
        ),
        ("hdrcore merge (ours) + --dng", "command", {"HDRCORE_BENCH_DNG": "1"}, "dng"),
        ("rawpy + AlignMTB + MergeDebevec + EXR", "peer", {}, "peer"),
    ]
    # --skip names a child (command: every hdrcore row) or a row (libraw, dng)
    contenders = [c for c in contenders if c[1] not in skip and c[3] not in skip]
    for _ in range(repeat):
        for label, child, env, _ in contenders:
            runs.setdefault(label, []).append(run_child(child, d, **env))
    print(
        "\n## the whole command, decode INCLUDED (each in a new process; best of "
        f"{repeat} by wall, alternated; load average now {os.getloadavg()[0]:.2f})"
    )
    print(
        f"{'contender':<46}{'wall s':>8}{'CPU s':>8}{'decode':>8}{'write':>8}"
        f"{'peak MB':>9}{'x peer':>8}"
    )
    best = {}
    for label, rs in runs.items():
        ok = [r for r in rs if "error" not in r]
        if not ok:
            print(f"{label:<46} failed: {rs[0].get('error')}")
            continue
        best[label] = min(ok, key=lambda r: r["wall_s"])
    peer = best.get("rawpy + AlignMTB + MergeDebevec + EXR")
    for label, r in best.items():
        ratio = "-" if peer is None else f"{r['wall_s'] / peer['wall_s']:.2f}"
        dec = "-" if r.get("decode_s") is None else f"{r['decode_s']:.2f}"
        wr = "-" if r.get("write_s") is None else f"{r['write_s']:.2f}"
        print(
            f"{label:<46}{r['wall_s']:>8.2f}{r['cpu_s']:>8.2f}{dec:>8}{wr:>8}"
            f"{r['peak_mb']:>9.0f}{ratio:>8}"
        )
    for label, rs in runs.items():
        walls = ", ".join(f"{r['wall_s']:.2f}" for r in rs if "error" not in r)
        print(f"#   {label}: every run {walls} s")
    if peer is not None:
        print(
            "#   wall and CPU of every row from its process's start (interpreter and imports "
            f"included); the peer's after its imports: {peer['after_imports_s']:.2f} s"
        )
    ours = best.get("hdrcore merge (ours: mosaic read + demosaic)")
    if ours:
        print(
            "#   ours per stage (s): "
            + ", ".join(f"{k} {v:.2f}" for k, v in ours["stages"].items() if isinstance(v, float))
        )
    print(
        "#   targets (3 x 24 MP): ours <= 2.5 s wall, <= 0.45x the peer, peak <= 1.5 GB "
        "(peak MB: ru_maxrss in MiB; 1.5 GB = 1536 MiB, as the README's GB columns)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--size", default="4000x6000")
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--bits", type=int, default=12)
    ap.add_argument(
        "--repeat",
        type=int,
        default=2,
        help="runs of the whole-command contenders, alternated (best reported)",
    )
    ap.add_argument("--child", choices=sorted(CHILDREN))
    ap.add_argument("--dir")
    ap.add_argument(
        "--skip",
        default="",
        help="comma list of contenders to skip: ours, opencv, hdrutils, command (every "
        "hdrcore merge row), libraw, dng (one of those rows), peer",
    )
    args = ap.parse_args()
    if args.child:
        print(json.dumps(CHILDREN[args.child](Path(args.dir))))
        return
    h, w = (int(v) for v in args.size.lower().split("x"))
    d = make_bracket((h, w), args.frames, args.bits)
    skip = {s for s in args.skip.split(",") if s}
    print(
        f"# {args.frames}-frame {w}x{h} ({h * w / 1e6:.0f} MP) {args.bits}-bit DNG hand-held "
        f"bracket, 2 stops; load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores"
    )
    if "command" not in skip:
        whole_command(d, args.repeat, skip)
    res = {n: run_child(n, d) for n in ("ours", "opencv", "hdrutils") if n not in skip}
    if "opencv" not in skip:
        res["opencv-default"] = run_child("opencv", d, retain=False)
    ours, cv = res.get("ours", {}), res.get("opencv", {})
    cv0 = res.get("opencv-default", {})
    if "error" not in ours and ours:
        print(
            "\n## ours, per stage (seconds): first run in a new process (numba kernels load "
            "from their cache) and a second run in the same process; glibc keeps freed "
            f"memory as in the hdrcore program: {ours.get('retain_freed_memory')}"
        )
        print(f"{'stage':<20}{'first':>8}{'second':>8}")
        print(f"{'decode':<20}{ours['decode_s']:>8.2f}   (excluded from the totals)")
        for k, v in ours["stages"].items():
            print(f"{k:<20}{ours['cold_stages'].get(k, float('nan')):>8.2f}{v:>8.2f}")
        print(f"{'total':<20}{ours['cold_s']:>8.2f}{ours['pipeline_s']:>8.2f}   target <= 4.0")
        print(f"{'re-fit (Z)':<14}{ours['refit_s']:>8.3f}")
        print(f"ratio errors %: {', '.join(f'{e:.3f}' for e in ours['ratio_errors_pct'])}")
        print(f"corner errors px: {', '.join(f'{e:.3f}' for e in ours['corner_error_px'])}")
    print("\n## side by side (decode excluded unless noted)")
    print(f"{'contender':<34}{'total s':>9}{'merge s':>9}{'peak MB':>9}{'x ours':>8}")
    base = ours.get("pipeline_s") if "error" not in ours else None
    cold_total = ours.get("cold_s")
    rows = [
        (
            "ours (2nd run, 2048 px preview)",
            ours.get("pipeline_s"),
            ours.get("stages", {}).get("merge"),
            ours.get("peak_mb"),
        ),
        (
            "ours (1st run, new process)",
            cold_total,
            ours.get("cold_stages", {}).get("merge"),
            ours.get("peak_mb"),
        ),
        (
            "ours (1st run + decode)",
            None if cold_total is None else cold_total + ours.get("decode_s", 0.0),
            None,
            ours.get("peak_mb"),
        ),
        (
            "OpenCV AlignMTB+MergeDebevec+TM",
            cv.get("pipeline_s"),
            cv.get("merge_s"),
            cv.get("peak_mb"),
        ),
        (
            "  the same, glibc defaults",
            cv0.get("pipeline_s"),
            cv0.get("merge_s"),
            cv0.get("peak_mb"),
        ),
        (
            "HDRutils.merge (incl. decode)",
            res.get("hdrutils", {}).get("pipeline_s"),
            None,
            res.get("hdrutils", {}).get("peak_mb"),
        ),
    ]
    for name, tot, mer, mb in rows:

        def f(v: float | None, fmt: str = ".2f") -> str:
            return "-" if v is None else format(v, fmt)

        ratio = f(tot / base) if (tot and base) else "-"
        print(f"{name:<34}{f(tot):>9}{f(mer):>9}{f(mb, '.0f'):>9}{ratio:>8}")
    for n, r in res.items():
        if "error" in r:
            print(f"# {n} failed: {r['error']}")
    if ours.get("stages", {}).get("merge") and cv.get("merge_s"):
        print("\nmerge step / MergeDebevec (target <= 0.30 for the merge of the same frames):")
        for label, ref in (("same allocator setting", cv), ("MergeDebevec on glibc defaults", cv0)):
            if ref.get("merge_s"):
                print(f"  {label}:")
                print(
                    f"    merge + colour of the frames as given  "
                    f"{ours['merge_as_given_s'] / ref['merge_s']:.2f}"
                )
                print(
                    f"    hand-held: warp 2 frames + merge + colour  "
                    f"{ours['stages']['merge'] / ref['merge_s']:.2f} (our second run), "
                    f"{ours['cold_stages']['merge'] / ref['merge_s']:.2f} (first)"
                )
        print(
            "  (MergeDebevec gets AlignMTB-shifted 8-bit frames; ours 12-bit levels. Our "
            "first run pays the first touch of its output arrays in a new process, as "
            "MergeDebevec does in its own; bench_merge.py compares both in one process)"
        )
    if ours.get("peak_mb"):
        print(f"peak memory ours: {ours['peak_mb'] / 1024:.2f} GB   target <= 3 GB")


if __name__ == "__main__":
    main()
