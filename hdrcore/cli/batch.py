"""``hdrcore batch DIR... -o OUTDIR``: every bracket of a folder, grouped automatically, merged.

Finds the images (``--recursive`` for sub-folders), groups them into brackets from what their
EXIF says (capture time with subseconds, exposure time, ISO, aperture, bias, camera, size; a
thumbnail as tie-breaker: see :mod:`hdrcore.batch.group`), and merges each with ``hdrcore
merge`` (every merge option below applies to each bracket). Per bracket: ``NAME.exr``,
``NAME.png`` with ``--preview``, ``NAME.dng`` with ``--dng``, and ``NAME.json`` (the merge
report and a content key); for the run: ``index.json`` and ``index.csv`` (status, verdicts,
quality score per bracket).

Inputs and the output folder may be fsspec URLs (``s3://bucket/shots``, ``gcs://``,
``file://``, ``memory://``; the filesystem's library must be installed: s3fs, gcsfs, ...):
folders are listed remotely, each bracket's frames copied to a local temporary folder, and
each output uploaded under a temporary name then moved onto its own.

A bracket whose outputs exist and whose frames and options are unchanged is skipped, so an
interrupted run is restarted with the same command. One bad bracket is recorded with its
reason and never stops the run. ``--plan`` only prints the grouping (``--json``: as a plan
file, to edit and give back with ``--plan-file``).

Exit status: 0 every bracket merged; 1 some bracket failed or merged with errors (see the
index); 2 bad input; 130 interrupted (finished brackets are kept).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

from ..batch import remote
from ..errors import InputError, OutputError
from ..io.atomic import same_file
from . import merge as merge_cli
from ._common import print_json, to_jsonable

__all__ = ["add_parser", "run"]

#: merge options a batch sets per bracket itself (or means otherwise: its --workers counts
#: processes; each merge keeps the default threads)
_OWN = {"help", "files", "output", "preview", "dng", "report", "json", "quiet", "force", "workers"}


def _merge_actions() -> list[argparse.Action]:
    sub = argparse.ArgumentParser(add_help=False).add_subparsers()
    merge_cli.add_parser(sub)
    merge_parser = sub.choices["merge"]
    return [a for a in merge_parser._actions if a.dest not in _OWN]


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number of at least 1, found {text!r}")
    return value


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"expected seconds (e.g. 2 or 0.5), found {text!r}")
    return value


def default_worker_memory(workers: int) -> int | None:
    """Each of ``workers`` processes gets the machine's physical memory divided among them
    (at least 1 GB): together they cannot push the machine into swap. ``None`` where the
    memory size is unknown."""
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None
    return max(int(1e9), int(total) // max(1, int(workers)))


def _gigabytes(text: str) -> int:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value >= 1.0):
        raise argparse.ArgumentTypeError(
            f"expected gigabytes, at least 1 (a worker limited to 0.3 GB of address space "
            f"cannot even load its libraries), found {text!r}"
        )
    return int(value * 1e9)


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "batch",
        help="group a folder's images into brackets and merge them all (resumable, parallel, Dask)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "inputs",
        nargs="+",
        metavar="DIR",
        help="folders (or files) of images; or fsspec URLs (s3://bucket/shots, "
        "file:///data/shots, memory://...; s3:// needs s3fs, gcs:// gcsfs)",
    )
    p.add_argument(
        "-o",
        "--output",
        metavar="OUTDIR",
        help="output folder (created if missing), or an fsspec URL (outputs are "
        "uploaded to a temporary name, then moved); required unless --plan",
    )
    p.add_argument("--recursive", action="store_true", help="also read sub-folders")
    g = p.add_argument_group("grouping")
    g.add_argument(
        "--group-size",
        dest="group_size",
        type=_positive_int,
        metavar="N",
        help="force: every N files (in name order, per folder) are one bracket",
    )
    g.add_argument(
        "--gap",
        type=_seconds,
        metavar="SECONDS",
        help="force HDRMerge's rule: a new bracket after a pause of more than this "
        "from the end of one exposure to the start of the next",
    )
    g.add_argument(
        "--max-frames",
        dest="max_frames",
        type=_positive_int,
        default=15,
        metavar="N",
        help="largest bracket the grouping forms (default 15)",
    )
    g.add_argument(
        "--no-thumbnails",
        dest="thumbnails",
        action="store_false",
        help="do not read thumbnails (their likeness only breaks ties)",
    )
    g.add_argument(
        "--plan",
        action="store_true",
        help="only print the grouping (with --json: a plan file to edit)",
    )
    g.add_argument(
        "--plan-file",
        dest="plan_file",
        metavar="PLAN.json",
        help="merge the brackets of this (edited) plan instead of grouping",
    )
    r = p.add_argument_group("running")
    r.add_argument(
        "--workers",
        type=_positive_int,
        default=1,
        metavar="N",
        help="worker processes on this machine (default 1)",
    )
    r.add_argument(
        "--dask", action="store_true", help="run on a Dask LocalCluster of --workers processes"
    )
    r.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on an existing Dask cluster (tcp://host:8786); paths must be the "
        "same on every worker (or give URLs every worker can reach: s3://...)",
    )
    r.add_argument(
        "--worker-memory",
        dest="worker_memory",
        type=_gigabytes,
        metavar="GB",
        help="address-space limit of each worker process (a bracket that needs more "
        "fails with 'out of memory' instead of swapping; default with --workers "
        "N > 1: the machine's memory divided by N, at least 1 GB); not for Dask, "
        "whose workers have their own memory_limit",
    )
    r.add_argument("--preview", action="store_true", help="also write NAME.png per bracket")
    r.add_argument(
        "--dng",
        action="store_true",
        help="also write NAME.dng per bracket (hdrcore merge --dng: float linear DNG)",
    )
    r.add_argument(
        "--force", action="store_true", help="merge every bracket again, even those up to date"
    )
    r.add_argument(
        "--retry-failed",
        dest="retry_failed",
        action="store_true",
        help="try again the brackets that failed (by default a failed bracket "
        "with unchanged frames and options is not tried again)",
    )
    r.add_argument(
        "--json",
        action="store_true",
        help="print the index (with --plan: the plan) as JSON on stdout",
    )
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    m = p.add_argument_group("merge options (as hdrcore merge, for every bracket)")
    for action in _merge_actions():
        m._add_action(action)
    p.set_defaults(run=run)


class _Progress:
    """``[#####-----] 12/40 brackets, 1 failed, ETA 0:01:20`` on a terminal (stderr)."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled and sys.stderr.isatty()
        self.t0 = time.perf_counter()
        self.merged = 0
        self.failed = 0

    def __call__(self, done: int, total: int, record) -> None:  # noqa: ANN001
        self.merged += record.merged
        self.failed += record.failed
        if not self.enabled:
            return
        width = 24
        n = int(round(width * done / max(total, 1)))
        dt = time.perf_counter() - self.t0
        left = total - done
        eta = dt / self.merged * left if self.merged else math.nan
        eta_s = time.strftime("%H:%M:%S", time.gmtime(eta)) if math.isfinite(eta) else "--:--:--"
        sys.stderr.write(
            f"\r[{'#' * n}{'-' * (width - n)}] {done}/{total} brackets, "
            f"{self.failed} failed, ETA {eta_s} "
        )
        sys.stderr.flush()

    def close(self) -> None:
        if self.enabled:
            sys.stderr.write("\n")


def _options(args: argparse.Namespace) -> tuple[dict, str]:
    from ..batch.task import file_digest

    options = {a.dest: to_jsonable(getattr(args, a.dest)) for a in _merge_actions()}
    extra = []
    for name in ("times", "response"):
        value = getattr(args, name, None)
        if isinstance(value, str) and Path(value).is_file():
            extra.append(f"{name}:{file_digest(value)}")
    return options, ";".join(extra)


def _in_output(f: Path | str, outdir: Path | str | None) -> bool:
    """Whether an image found is in the output folder (the batch's own previews)."""
    if outdir is None:
        return False
    if isinstance(f, str) or isinstance(outdir, str):
        return (
            isinstance(f, str)
            and isinstance(outdir, str)
            and remote.same_folder(remote.parent(f), outdir)
        )
    return outdir.is_dir() and (f.parent == outdir or same_file(f.parent, outdir))


def _plan(args: argparse.Namespace, outdir: Path | str | None):  # noqa: ANN202
    from ..batch import group_shots, make_plan, read_plan
    from ..batch.scan import find_images, read_shots

    if args.plan_file:
        return read_plan(args.plan_file)
    files = find_images(args.inputs, recursive=args.recursive)
    files = [f for f in files if not _in_output(f, outdir)]
    if not files:
        raise InputError("no images to group outside the output folder", path=args.inputs[0])
    shots = read_shots(files, thumbnails=args.thumbnails)
    if args.group_size:
        method, kw = "count", {"size": args.group_size}
    elif args.gap is not None:
        method, kw = "gap", {"gap": args.gap}
    else:
        method, kw = "signals", {"max_frames": args.max_frames, "thumbnails": args.thumbnails}
    return make_plan(group_shots(shots, method, **kw), method)


def run(args: argparse.Namespace) -> int:
    from ..batch import plan_table, run_batch, tasks_from_plan, write_index

    if args.group_size and args.gap is not None:
        raise InputError("--group-size and --gap are two rules; give one")
    if args.scheduler and args.dask:
        raise InputError("--dask starts a cluster here, --scheduler uses one; give one")
    for url in [*args.inputs, args.output, args.plan_file]:  # a missing library: fail now
        if url is not None and remote.is_url(url):
            remote.check_url(url)
    outdir: Path | str | None = None
    if args.output is not None:
        outdir = (
            args.output.rstrip("/") if remote.is_url(args.output) else Path(args.output).absolute()
        )
    if args.plan:
        plan = _plan(args, outdir)
        if args.json:
            print_json(plan.to_json())
        else:
            print(plan_table(plan))
        return 0
    if outdir is None:
        raise OutputError("an output folder is needed", expected="-o OUTDIR (or --plan)")
    if isinstance(outdir, Path) and outdir.exists() and not outdir.is_dir():
        raise OutputError("the output is not a folder", path=outdir)
    plan = _plan(args, outdir)
    if isinstance(outdir, str):
        remote.makedirs(outdir)
    else:
        try:
            outdir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputError(
                f"cannot create the output folder ({exc.strerror or exc})", path=outdir
            ) from None
    options, extra = _options(args)
    tasks = tasks_from_plan(
        plan, outdir, options, preview=args.preview, dng=args.dng, extra_key=extra
    )
    progress = _Progress(not args.quiet)
    scheduler = args.scheduler or ("local" if args.dask else None)
    memory_limit = args.worker_memory
    if memory_limit is None and scheduler is None and args.workers > 1:
        memory_limit = default_worker_memory(args.workers)
    try:
        result = run_batch(
            tasks,
            workers=args.workers,
            scheduler=scheduler,
            progress=progress,
            retry_failed=args.retry_failed,
            force=args.force,
            memory_limit=memory_limit,
        )
    finally:
        progress.close()
    write_index(
        outdir,
        result.records,
        plan.singles,
        summary={
            "grouping": plan.method,
            "seconds": result.seconds,
            "interrupted": result.interrupted,
            "workers": args.workers,
            "scheduler": scheduler,
        },
    )
    recs = result.records
    counts = {s: sum(r.status == s for r in recs) for s in ("ok", "warning", "error", "failed")}
    skipped = sum(not r.merged for r in recs)
    index_csv = (
        remote.join(outdir, "index.csv") if isinstance(outdir, str) else outdir / "index.csv"
    )
    print(
        f"hdrcore batch: {len(recs)} of {len(tasks)} brackets: "
        + ", ".join(f"{n} {s}" for s, n in counts.items() if n)
        + f" ({skipped} up to date, not merged again); {len(plan.singles)} single shot(s) "
        f"left out; index: {index_csv}",
        file=sys.stderr,
    )
    for r in recs:
        if r.failed:
            print(f"hdrcore batch: {r.status}: {r.name}: {r.reason}", file=sys.stderr)
    if args.json:
        index_json = (
            remote.read_text(remote.join(outdir, "index.json"))
            if isinstance(outdir, str)
            else (outdir / "index.json").read_text()
        )
        print_json(json.loads(index_json))
    if result.interrupted:
        raise KeyboardInterrupt
    return 1 if any(r.failed for r in recs) else 0
