"""Batch bench (issue 19): grouping against HDRMerge's fixed gap, throughput of ``hdrcore batch``
(worker processes and a Dask LocalCluster) against ``hdrcore merge`` run on each bracket in
turn, and a run killed half-way then restarted. Each part on simulated folders AND on a folder
that mixes the real brackets of ../shared/data (symbolic links in a temporary folder).

* ``--part grouping``: simulated sessions (held-out seeds 1000+; 15 brackets of 3/5/7/9 frames
  in darker-first, brighter-first and centre-out orders, single shots and bursts of equal
  exposures between them, pauses of 0.2-5 s), with subsecond clocks and with whole-second
  clocks, 1 and 2 EV steps: brackets found exactly, groups that are no bracket, by our
  signals and by HDRMerge's rule (a new set after a pause of more than G s, end of one
  exposure to the start of the next; HDRMerge's default G = 2 s) at several G. Then a few
  sessions written as JPEG files and read back (EXIF, thumbnails). Then the real folder.
* ``--part throughput``: 40 simulated 3-frame brackets (``--size``, default 120x160):
  ``hdrcore merge`` on each in turn (a new process each, as a shell loop would), ``hdrcore
  batch --workers 1``, ``--workers 2``, ``--dask --workers 2``; wall and CPU (children), and
  the EXRs compared pixel for pixel. Then the real folder's brackets the same way.
* ``--part resume``: ``hdrcore batch --workers 2`` killed (SIGKILL to its process group: a
  crash) once half the brackets have their sidecar, then run again: brackets merged twice,
  brackets lost, EXRs against an uninterrupted run. Simulated, then real.
* ``--part urls``: the same folders through fsspec URLs with ``--workers 2``: plain paths,
  ``file://`` URLs and ``s3://`` (s3fs against moto's S3 server started here: the object-store
  protocol with its copy-then-delete moves, no network), each run twice (the second finds
  everything up to date), pixels against plain paths; then a run to ``s3://`` killed half-way
  and restarted.

    python bench/bench_batch.py [--part grouping|throughput|resume|urls|all] [--repeat 2]
        [--size 120x160] [--no-real]

Timings share a loaded 2-core machine with other work: each is printed with the load average
and the CPU time, and repeated (``--repeat``).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
OUT = HERE / "out" / "batch"
SHARED = (ROOT / ".." / "shared" / "data").resolve()

from hdrcore.batch import group_shots, scan_shots  # noqa: E402
from hdrcore.batch.scan import Shot  # noqa: E402
from hdrcore.batch.simulate import simulate_session, true_groups, write_session  # noqa: E402

#: the real folder: what is truly one bracket (by source folder); the CRW files are singles
REAL_BRACKETS = (
    "frobisher-colour-hdri",
    "handheld-pixel7-lab",
    "handheld-xperia-library",
    "memorial-debevec",
)
REAL_SINGLES = ("raw-singles-cc0-canon-crw",)


def _load() -> str:
    return f"load {os.getloadavg()[0]:.1f}"


def _shots_from_sim(sim, folder: str, subsec: bool) -> list[Shot]:
    out = []
    for s in sim:
        t = 1.0e9 + s.time
        out.append(
            Shot(
                path=f"{folder}/{s.name}",
                folder=folder,
                time=t if subsec else float(int(t)),
                subsec=subsec,
                exposure_time=float(s.exposure_time),
                iso=100.0,
                f_number=8.0,
                exposure_bias=float(s.bias),
                camera="SimCam S1",
                size=(64, 48),
            )
        )
    return out


def _score(groups, truth: set[frozenset[str]]) -> tuple[int, int]:
    found = {frozenset(g.paths) for g in groups if g.is_bracket}
    return len(found & truth), len(found - truth)


def _row(name: str, exact: int, total: int, wrong: int, extra: str = "") -> str:
    return (
        f"| {name:<34} | {exact:>5} / {total:<5} | {100.0 * exact / max(total, 1):6.2f} % "
        f"| {wrong:>6} |{extra}"
    )


def part_grouping(args: argparse.Namespace) -> None:
    print(
        "\n## Grouping: simulated sessions (metadata only, held-out seeds "
        f"1000..{1000 + args.sessions - 1})\n"
    )
    print("| rule | brackets exact | share | groups that are no bracket |")
    print("|---|---|---|---|")
    gaps = (0.5, 1.0, 2.0, 3.0)
    for subsec in (True, False):
        for step in (1, 2):
            tag = f"{'subsec' if subsec else 'whole-second'} clock, {step} EV steps"
            tot = 0
            ours = [0, 0]
            theirs = {g: [0, 0] for g in gaps}
            for seed in range(1000, 1000 + args.sessions):
                sim = simulate_session(seed, n_brackets=15, step=step)
                shots = _shots_from_sim(sim, "/s", subsec)
                truth = {frozenset(f"/s/{Path(p).name}" for p in g) for g in true_groups(sim, "/s")}
                tot += len(truth)
                e, w = _score(group_shots(shots), truth)
                ours[0] += e
                ours[1] += w
                for g in gaps:
                    e, w = _score(group_shots(shots, "gap", gap=g), truth)
                    theirs[g][0] += e
                    theirs[g][1] += w
            print(_row(f"ours ({tag})", ours[0], tot, ours[1]))
            for g in gaps:
                print(
                    _row(
                        f"HDRMerge gap {g:g} s" + (" (default)" if g == 2.0 else ""),
                        theirs[g][0],
                        tot,
                        theirs[g][1],
                    )
                )
    print(
        "\n## Grouping: simulated sessions written as 64x48 JPEG and read back (EXIF, thumbnails)\n"
    )
    print("| session | brackets exact | share | groups that are no bracket | scan s |")
    print("|---|---|---|---|---|")
    for seed in range(2000, 2000 + args.files):
        with tempfile.TemporaryDirectory() as d:
            sim = simulate_session(seed, n_brackets=15)
            write_session(d, sim, seed=seed, same_scene=seed % 2 == 0, subsec=seed % 3 != 0)
            t0 = time.perf_counter()
            shots = scan_shots([d])
            dt = time.perf_counter() - t0
            truth = set(true_groups(sim, d))
            e, w = _score(group_shots(shots), truth)
            he, hw = _score(group_shots(shots, "gap", gap=2.0), truth)
            print(_row(f"{seed} ours", e, len(truth), w, f" {dt:5.2f} |"))
            print(_row(f"{seed} HDRMerge 2 s", he, len(truth), hw, " |"))
    if args.real:
        real_grouping()


def real_folder(root: Path) -> Path:
    """Symbolic links to every real frame in one flat folder (never copies)."""
    d = root / "real-mixed"
    d.mkdir(parents=True, exist_ok=True)
    for name in REAL_BRACKETS + REAL_SINGLES:
        for f in sorted((SHARED / name).iterdir()):
            if f.suffix.lower() in (".jpg", ".png", ".crw"):
                link = d / f.name
                if not link.exists():
                    link.symlink_to(f)
    return d


def _real_truth(d: Path) -> set[frozenset[str]]:
    out = set()
    for name in REAL_BRACKETS:
        src = {f.name for f in (SHARED / name).iterdir()}
        out.add(frozenset(str(p) for p in d.iterdir() if p.name in src))
    return out


def real_grouping() -> None:
    if not SHARED.is_dir():
        print("\n(real data not available: skipped)")
        return
    with tempfile.TemporaryDirectory() as tmp:
        d = real_folder(Path(tmp))
        shots = scan_shots([d])
        truth = _real_truth(d)
        print(
            f"\n## Grouping: the real brackets in one folder ({len(shots)} files: "
            + ", ".join(REAL_BRACKETS)
            + "; + 2 CRW singles)\n"
        )
        print("| rule | brackets exact | share | groups that are no bracket | groups |")
        print("|---|---|---|---|---|")
        for name, groups in (
            ("ours", group_shots(shots)),
            ("HDRMerge gap 2 s", group_shots(shots, "gap", gap=2.0)),
            ("HDRMerge gap 20 s", group_shots(shots, "gap", gap=20.0)),
        ):
            e, w = _score(groups, truth)
            sizes = sorted((len(g.shots) for g in groups if g.is_bracket), reverse=True)
            print(
                _row(
                    name,
                    e,
                    len(truth),
                    w,
                    f" {sizes} + {sum(not g.is_bracket for g in groups)} singles |",
                )
            )
        for g in group_shots(shots):
            print(
                f"    {len(g.shots):>2} {Path(g.paths[0]).name:<24} .. "
                f"{Path(g.paths[-1]).name:<24} {g.reason}"
            )


# --------------------------------------------------------------------------------------------
LAST_ERR = [""]


def _run(cmd: list[str]) -> tuple[float, float, int]:
    """Wall and CPU seconds (the child and everything it waited for) of one command; its
    stderr's last line is kept in ``LAST_ERR``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(
        cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    LAST_ERR[0] = (proc.stderr.strip().splitlines() or [""])[-1]
    return wall, cpu, proc.returncode


def _pixels(out: Path) -> dict[str, np.ndarray]:
    from hdrcore.io import read_exr

    return {p.stem: read_exr(p)[0] for p in sorted(out.glob("*.exr"))}


def _same(a: dict, b: dict) -> str:
    if a.keys() != b.keys():
        return f"different sets ({len(a)} vs {len(b)})"
    diff = [k for k in a if not np.array_equal(a[k], b[k], equal_nan=True)]
    return "identical" if not diff else f"{len(diff)} differ"


def sim_brackets(size: tuple[int, int], n: int) -> Path:
    d = OUT / f"sim40_{size[0]}x{size[1]}"
    if (d / "done").exists():
        return d
    shutil.rmtree(d, ignore_errors=True)
    sim = simulate_session(
        4242, n_brackets=n, sizes=(3,), singles=0.0, bursts=0.0, gap_range=(0.5, 3.0)
    )
    write_session(d, sim, seed=5, shape=size, same_scene=False)
    (d / "done").write_text("ok")
    return d


def _plan_groups(folder: Path) -> list[list[str]]:
    from hdrcore.batch import make_plan

    return [list(b.files) for b in make_plan(group_shots(scan_shots([folder]))).brackets]


def throughput(folder: Path, label: str, repeat: int, extra: list[str]) -> None:
    groups = _plan_groups(folder)
    py = sys.executable
    print(f"\n## Throughput: {label} ({len(groups)} brackets; {_load()} at start)\n")
    print("| run | contender | wall s | CPU s | x merge-in-turn | outputs |")
    print("|---|---|---|---|---|---|")
    for r in range(repeat):
        base = OUT / f"tp_{label.split()[0]}"
        shutil.rmtree(base, ignore_errors=True)
        base.mkdir(parents=True)
        loop = base / "loop"
        loop.mkdir()
        t_wall = t_cpu = 0.0
        failed = []
        for k, files in enumerate(groups):
            name = Path(files[0]).stem
            w, c, rc = _run(
                [
                    py,
                    "-m",
                    "hdrcore",
                    "merge",
                    *files,
                    "-o",
                    str(loop / f"{name}_{k}.exr"),
                    "--quiet",
                    *extra,
                ]
            )
            if rc not in (0, 1):
                failed.append(f"{name} (exit {rc}: {LAST_ERR[0]})")
            t_wall += w
            t_cpu += c
        ref_wall = t_wall
        ref = {k.rsplit("_", 1)[0]: v for k, v in _pixels(loop).items()}
        print(
            f"| {r + 1} | hdrcore merge, each in turn | {t_wall:7.1f} | {t_cpu:7.1f} | 1.00 "
            f"| reference ({len(failed)} merges failed) |"
        )
        for f in failed[:5]:
            print(f"|   | failed: {f} | | | | |")
        results = {}
        for tag, opts in (
            ("batch --workers 1", ["--workers", "1"]),
            ("batch --workers 2", ["--workers", "2"]),
            ("batch --dask --workers 2", ["--dask", "--workers", "2"]),
        ):
            out = base / tag.replace(" ", "_").replace("-", "")
            w, c, rc = _run(
                [
                    py,
                    "-m",
                    "hdrcore",
                    "batch",
                    str(folder),
                    "-o",
                    str(out),
                    "--quiet",
                    *opts,
                    *extra,
                ]
            )
            px = _pixels(out)
            results[tag] = (w, px)
            first = {Path(f[0]).stem: None for f in groups}
            as_ref = {}
            for k, v in px.items():  # batch names are first-last; compare by the first frame
                as_ref[next(s for s in first if k.startswith(s))] = v
            print(
                f"| {r + 1} | {tag} (exit {rc}) | {w:7.1f} | {c:7.1f} | {w / ref_wall:4.2f} | "
                f"{_same(as_ref, ref)} vs merge |"
            )
        w2, px2 = results["batch --workers 2"]
        wd, pxd = results["batch --dask --workers 2"]
        print(f"| {r + 1} | dask / workers 2 | | | {wd / w2:4.2f} | {_same(pxd, px2)} |")
    print(f"\n({_load()} at end)")


def part_throughput(args: argparse.Namespace) -> None:
    if args.sim:
        folder = sim_brackets(args.size, 40)
        throughput(
            folder, f"simulated 40 x 3 frames {args.size[0]}x{args.size[1]} JPEG", args.repeat, []
        )
    if args.real and SHARED.is_dir():
        with tempfile.TemporaryDirectory() as tmp:
            d = real_folder(Path(tmp))
            throughput(d, "real brackets in one folder", 1, [])


def _sidecars(out: Path) -> set[str]:
    return {p.stem for p in out.glob("*.json") if not p.name.startswith(("index", "."))}


def resume(folder: Path, label: str, n_total: int) -> None:
    py = sys.executable
    base = OUT / f"resume_{label.split()[0]}"
    shutil.rmtree(base, ignore_errors=True)
    base.mkdir(parents=True)
    whole, cut = base / "whole", base / "cut"
    _run([py, "-m", "hdrcore", "batch", str(folder), "-o", str(whole), "--quiet", "--workers", "2"])
    proc = subprocess.Popen(
        [py, "-m", "hdrcore", "batch", str(folder), "-o", str(cut), "--quiet", "--workers", "2"],
        cwd=ROOT,
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    half = max(1, n_total // 2)
    while proc.poll() is None and len(_sidecars(cut) if cut.exists() else ()) < half:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    done_before = _sidecars(cut)
    stamps = {
        n: (cut / f"{n}.exr").stat().st_mtime_ns for n in done_before if (cut / f"{n}.exr").exists()
    }
    left = [p.name for p in cut.iterdir() if p.name.startswith(".")]
    w, c, rc = _run(
        [py, "-m", "hdrcore", "batch", str(folder), "-o", str(cut), "--quiet", "--workers", "2"]
    )
    doc = json.loads((cut / "index.json").read_text())
    merged_again = [b["name"] for b in doc["brackets"] if b["merged"] and b["name"] in done_before]
    rewritten = [n for n, t in stamps.items() if (cut / f"{n}.exr").stat().st_mtime_ns != t]
    print(f"\n## Resume: {label}\n")
    print(
        "| brackets | done when killed | temporaries left by the kill | merged on restart "
        "| finished ones merged again | EXRs rewritten | outputs vs uninterrupted |"
    )
    print("|---|---|---|---|---|---|---|")
    print(
        f"| {len(doc['brackets'])} | {len(done_before)} | {len(left)} | "
        f"{sum(b['merged'] for b in doc['brackets'])} | {len(merged_again)} | "
        f"{len(rewritten)} | {_same(_pixels(cut), _pixels(whole))} |"
    )
    print(
        f"(restart: {w:.1f} s wall, {c:.1f} s CPU, exit {rc}; "
        f"{len([p for p in cut.iterdir() if p.name.startswith('.')])} temporaries after)"
    )


def part_resume(args: argparse.Namespace) -> None:
    if args.sim:
        resume(sim_brackets(args.size, 40), "simulated 40 brackets", 40)
    if args.real and SHARED.is_dir():
        with tempfile.TemporaryDirectory() as tmp:
            d = real_folder(Path(tmp))
            resume(d, "real brackets in one folder", 4)


# --------------------------------------------------------------------------------------------
def _moto():  # noqa: ANN202
    """moto's S3 server in this process (a free local port) and an s3fs filesystem on it;
    ``None`` without s3fs or moto. Subprocesses reach it through AWS_ENDPOINT_URL."""
    try:
        import fsspec
        import s3fs  # noqa: F401
        from moto.server import ThreadedMotoServer
    except ImportError:
        return None
    import logging

    logging.getLogger("werkzeug").setLevel(logging.ERROR)  # no line per request
    srv = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    srv.start()
    host, port = srv.get_host_and_port()
    os.environ.update(
        AWS_ACCESS_KEY_ID="bench",
        AWS_SECRET_ACCESS_KEY="bench",
        AWS_DEFAULT_REGION="us-east-1",
        AWS_ENDPOINT_URL=f"http://{host}:{port}",
    )
    fs = fsspec.filesystem("s3")
    fs.mkdir("bench")
    return srv, fs


def _s3_pixels(fs, prefix: str, tmp: Path) -> dict[str, np.ndarray]:  # noqa: ANN001
    from hdrcore.io import read_exr

    fs.invalidate_cache()
    out = {}
    for p in fs.ls(prefix, detail=False):
        if p.endswith(".exr"):
            local = tmp / Path(p).name
            fs.get_file(p, str(local))
            out[local.stem] = read_exr(local)[0]
    return out


def _self_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def urls(folder: Path, label: str, moto) -> None:  # noqa: ANN001
    """``hdrcore batch --workers 2`` on plain paths, on file:// URLs and on s3:// (moto's
    server on this machine: the S3 protocol through s3fs, no network), then the same command
    again (everything up to date), then a run to s3:// killed half-way and restarted."""
    py = sys.executable
    tag = label.split()[0]
    base = OUT / f"urls_{tag}"
    shutil.rmtree(base, ignore_errors=True)
    base.mkdir(parents=True)
    n = len(_plan_groups(folder))
    contenders = [
        ("plain paths", [str(folder)], str(base / "plain")),
        ("file:// URLs", [folder.resolve().as_uri()], (base / "file").as_uri()),
    ]
    fs = None
    if moto is not None:
        fs = moto[1]
        for f in sorted(folder.iterdir()):
            if f.is_file() and not f.name.startswith(".") and f.name != "done":
                fs.pipe(f"bench/{tag}/shots/{f.name}", f.read_bytes())
        contenders.append(
            ("s3:// (moto, s3fs)", [f"s3://bench/{tag}/shots"], f"s3://bench/{tag}/out")
        )
    print(f"\n## URLs: {label} ({n} brackets, --workers 2; {_load()} at start)\n")
    print(
        "| inputs and output | run | wall s | CPU s (children + S3 server) | x plain "
        "| merged | outputs vs plain |"
    )
    print("|---|---|---|---|---|---|---|")
    ref_wall = {}
    ref_px = None
    for name, ins, out in contenders:
        for run in ("first", "again (all up to date)"):
            c0 = _self_cpu()
            w, c, rc = _run(
                [py, "-m", "hdrcore", "batch", *ins, "-o", out, "--quiet", "--workers", "2"]
            )
            server = _self_cpu() - c0
            if out.startswith("s3://"):
                fs.invalidate_cache()
                doc = json.loads(fs.cat_file(out[5:] + "/index.json"))
                px = _s3_pixels(fs, out[5:], Path(tempfile.mkdtemp()))
            else:
                d = Path(out[7:]) if out.startswith("file://") else Path(out)
                doc = json.loads((d / "index.json").read_text())
                px = _pixels(d)
            if ref_px is None:
                ref_px = px
            ref_wall.setdefault(run, w)
            merged = sum(b["merged"] for b in doc["brackets"])
            print(
                f"| {name} | {run} (exit {rc}) | {w:7.1f} | {c:6.1f} + {server:4.1f} | "
                f"{w / ref_wall[run]:4.2f} | {merged} | {_same(px, ref_px)} |"
            )
    if fs is None:
        print("\n(s3fs or moto not installed: s3:// not measured)")
        return
    # killed half-way (SIGKILL to the process group: a crash), then the same command again
    out = f"s3://bench/{tag}/cut"
    cmd = [
        py,
        "-m",
        "hdrcore",
        "batch",
        f"s3://bench/{tag}/shots",
        "-o",
        out,
        "--quiet",
        "--workers",
        "2",
    ]
    proc = subprocess.Popen(
        cmd, cwd=ROOT, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )

    def names() -> list[str]:
        fs.invalidate_cache()
        try:
            return [Path(p).name for p in fs.ls(out[5:], detail=False)]
        except FileNotFoundError:
            return []

    def sidecars() -> set[str]:
        return {
            x[:-5]
            for x in names()
            if x.endswith(".json") and not x.startswith(".") and not x.startswith("index")
        }

    while proc.poll() is None and len(sidecars()) < max(1, n // 2):
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    done_before = sidecars()
    left = [x for x in names() if x.startswith(".")]
    w, c, rc = _run(cmd)
    fs.invalidate_cache()
    doc = json.loads(fs.cat_file(out[5:] + "/index.json"))
    again = [b["name"] for b in doc["brackets"] if b["merged"] and b["name"] in done_before]
    px = _s3_pixels(fs, out[5:], Path(tempfile.mkdtemp()))
    print(f"\n## Resume on s3://: {label}\n")
    print(
        "| brackets | done when killed | temporaries left by the kill | merged on restart "
        "| finished ones merged again | temporaries after | outputs vs plain |"
    )
    print("|---|---|---|---|---|---|---|")
    print(
        f"| {len(doc['brackets'])} | {len(done_before)} | {len(left)} | "
        f"{sum(b['merged'] for b in doc['brackets'])} | {len(again)} | "
        f"{len([x for x in names() if x.startswith('.')])} | {_same(px, ref_px)} |"
    )
    print(f"(restart: {w:.1f} s wall, {c:.1f} s CPU, exit {rc})")


def part_urls(args: argparse.Namespace) -> None:
    moto = _moto()
    try:
        if args.sim:
            urls(sim_brackets(args.size, 40), "simulated 40 brackets", moto)
        if args.real and SHARED.is_dir():
            with tempfile.TemporaryDirectory() as tmp:
                urls(real_folder(Path(tmp)), "real brackets in one folder", moto)
    finally:
        if moto is not None:
            moto[0].stop()


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--part", default="all", choices=("grouping", "throughput", "resume", "urls", "all")
    )
    ap.add_argument("--sessions", type=int, default=100)
    ap.add_argument("--files", type=int, default=4)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--size", default="120x160", type=lambda s: tuple(int(v) for v in s.split("x")))
    ap.add_argument("--no-real", dest="real", action="store_false")
    ap.add_argument(
        "--no-sim",
        dest="sim",
        action="store_false",
        help="throughput and resume: only the real folder",
    )
    args = ap.parse_args()
    print(f"# bench_batch ({_load()}, {os.cpu_count()} cores)")
    if args.part in ("grouping", "all"):
        part_grouping(args)
    if args.part in ("throughput", "all"):
        part_throughput(args)
    if args.part in ("resume", "all"):
        part_resume(args)
    if args.part in ("urls", "all"):
        part_urls(args)


if __name__ == "__main__":
    main()
