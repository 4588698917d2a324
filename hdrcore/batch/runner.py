"""Running a batch's tasks: skip the brackets already done, run the rest in this process, in
worker processes (``workers``) or on a Dask cluster (``scheduler``), report each as it ends.

A bracket is *done* when its sidecar holds the key its frames and options give now
(:func:`up_to_date`): frames are re-hashed only when their size or modification time differ
from the sidecar's (as ``make`` and git decide), so a restart reads no frame it need not; a
remote frame (an fsspec URL) is re-hashed when its size or its listing's stamp (ETag,
md5Hash, ... or time: :func:`hdrcore.batch.remote.stamp`) differ. A remote output folder is
listed once per run, not queried per output.
Ctrl-C stops the run: brackets in progress lose their temporary files (atomic writers) and
write no sidecar; everything finished is kept, and the next run skips it.
"""

from __future__ import annotations

import json
import os
import time
import uuid
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, replace
from multiprocessing import get_context
from pathlib import Path
from typing import Any

from ..errors import HdrError, InputError
from . import remote
from .plan import Plan
from .task import SIDECAR_VERSION, BracketRecord, BracketTask, bracket_key, file_digest, run_task

__all__ = ["BatchRun", "tasks_from_plan", "up_to_date", "remove_temporaries", "run_batch"]

Progress = Callable[[int, int, BracketRecord], None]


@dataclass(frozen=True)
class BatchRun:
    """Records in task order; ``interrupted``: stopped before every task ended."""

    records: tuple[BracketRecord, ...]
    interrupted: bool = False
    seconds: float = 0.0

    @property
    def merged(self) -> int:
        return sum(r.merged for r in self.records)

    @property
    def failed(self) -> int:
        return sum(r.failed for r in self.records)


def tasks_from_plan(
    plan: Plan,
    outdir: str | os.PathLike,
    options: dict[str, Any] | None = None,
    *,
    preview: bool = False,
    dng: bool = False,
    extra_key: str = "",
) -> list[BracketTask]:
    out = os.fspath(outdir).rstrip("/") if remote.is_url(outdir) else str(Path(outdir).absolute())
    return [
        BracketTask(b.name, tuple(b.files), out, dict(options or {}), preview, extra_key, dng)
        for b in plan.brackets
    ]


def up_to_date(
    task: BracketTask,
    *,
    retry_failed: bool = False,
    present: set[str] | None = None,
    infos: Callable[[str], dict | None] | None = None,
) -> BracketRecord | None:
    """The sidecar's record (``merged=False``) when the bracket needs no merge, else ``None``.

    For a remote output folder, ``present`` (the names :func:`remote.listing` found in it)
    saves one request per output; ``infos`` (a :class:`remote.Infos`) gives remote frames'
    listing entries a folder at a time."""
    try:
        if remote.is_url(task.outdir):
            if present is not None and task.sidecar_name not in present:
                return None
            text = remote.read_text(task.target(task.sidecar_name))
        else:
            text = task.sidecar.read_text()
        doc = json.loads(text)
        rec = BracketRecord.from_json(doc["batch"])
        frames = doc["frames"]
    except (OSError, ValueError, KeyError, TypeError, HdrError):
        return None
    if doc.get("version") != SIDECAR_VERSION or not rec.key:
        return None
    if [f.get("path") for f in frames] != list(task.files):
        return None
    if rec.status == "failed" and retry_failed:
        return None
    digests = []
    for f in frames:
        path = f["path"]
        if remote.is_url(path):
            info = infos(path) if infos is not None else remote.info_of(path)
            if info is None:
                return None
            now = remote.stamp(info)
            same = (
                now.get("stamp") is not None
                and now.get("stamp") == f.get("stamp")
                and now.get("size") == f.get("size")
            )
            try:
                digests.append(f["sha256"] if same else remote.digest(path))
            except Exception:  # noqa: BLE001 - unreadable now: merge again (and fail there)
                return None
            continue
        try:
            st = os.stat(path)
        except OSError:
            return None
        same = st.st_size == f.get("size") and st.st_mtime_ns == f.get("mtime_ns")
        digests.append(f["sha256"] if same else file_digest(path))
    if bracket_key(digests, *task.key_args) != rec.key:
        return None
    wanted = [rec.outputs.get(k) for k in ("exr", "preview", "dng")]
    if rec.status != "failed":
        wanted += [
            task.target(f"{task.name}.png") if task.preview else None,
            task.target(f"{task.name}.dng") if task.dng else None,
        ]
    for path in wanted:
        if path and not _exists(path, task, present):
            return None
    return replace(rec, merged=False)


def _exists(path: str, task: BracketTask, present: set[str] | None) -> bool:
    if not remote.is_url(path):
        return Path(path).is_file()
    if present is not None and remote.parent(path) == task.outdir.rstrip("/"):
        return remote.basename(path) in present
    return remote.info_of(path) is not None


def remove_temporaries(outdir: str | os.PathLike, names: Sequence[str]) -> int:
    """Remove what a killed worker left of these brackets (``.NAME.exr.*.tmp.exr`` and the
    like from :func:`hdrcore.io.atomic_write`, ``.NAME.exr.*.tmp`` from
    :func:`remote.put_atomic`, ``.NAME.report.json``); returns how many."""
    wanted = set(names)
    n = 0
    if remote.is_url(outdir):
        entries = sorted(remote.listing(os.fspath(outdir)) or ())
    else:
        try:
            entries = [p.name for p in Path(outdir).iterdir()]
        except OSError:
            return 0
    for s in entries:
        if not s.startswith(".") or ".tmp" not in s and not s.endswith(".report.json"):
            continue
        for suffix in (".exr.", ".png.", ".dng.", ".json.", ".report.json"):
            cut = s.find(suffix, 1)
            if cut > 0 and s[1:cut] in wanted:
                if remote.is_url(outdir):
                    try:
                        remote.remove(remote.join(os.fspath(outdir), s))
                    except Exception:  # noqa: BLE001 - another run removed it first
                        continue
                else:
                    (Path(outdir) / s).unlink(missing_ok=True)
                n += 1
                break
    return n


#: Dask settings of the LocalCluster ``--dask`` starts (passed on to its worker processes by
#: their nannies). Measured with bench_batch --part throughput (40 simulated brackets, quiet
#: machine, two runs each): Dask / ``--workers 2`` wall 1.17 and 1.23 with Dask's defaults,
#: 1.19 and 1.11 with these (within the runs' noise; Dask still costs 3 CPU s more, the
#: nannies' and workers' start).
LOCAL_CLUSTER_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.scheduler.work-stealing": False,
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.worker.memory.monitor-interval": "1s",
}


def _worker_setup(limit_bytes: int | None = None) -> None:
    """Set up a worker process this run started: the allocator setting of the ``hdrcore``
    programs (:func:`hdrcore._memory.retain_freed_memory`: freed memory is reused instead of
    touched afresh, which costs this VM about 2 s of system time per GB), and with
    ``limit_bytes`` its address space capped (``RLIMIT_AS``), so one bracket too large fails
    with MemoryError (recorded) instead of swapping the machine."""
    from .._memory import retain_freed_memory

    retain_freed_memory()
    if limit_bytes:
        import resource

        resource.setrlimit(resource.RLIMIT_AS, (int(limit_bytes), int(limit_bytes)))


def _lost(task: BracketTask, exc: BaseException, hint: str = "") -> BracketRecord:
    return BracketRecord(
        task.name,
        task.files,
        "failed",
        reason=f"the worker failed: {type(exc).__name__}: "
        f"{str(exc).splitlines()[0] if str(exc) else ''}{hint}",
        quality={"score": 0.0},
        outputs={"sidecar": None},
    )


def _run_local(
    todo: list[BracketTask],
    workers: int,
    memory_limit: int | None,
    done: Callable[[BracketTask, BracketRecord], None],
) -> None:
    if workers <= 1:  # this process: a library caller's allocator is left alone
        if memory_limit:
            _worker_setup(memory_limit)
        for t in todo:
            done(t, run_task(t))
        return
    pool = ProcessPoolExecutor(
        max_workers=workers,
        mp_context=get_context("spawn"),
        initializer=_worker_setup,
        initargs=(memory_limit,),
    )
    try:
        futures = {pool.submit(run_task, t): t for t in todo}
        for fut in as_completed(futures):
            t = futures[fut]
            try:
                rec = fut.result()
            except Exception as exc:  # BrokenProcessPool: a worker was killed (OOM killer)
                rec = _lost(
                    t,
                    exc,
                    f" (each worker is limited to {memory_limit / 1e9:g} GB: "
                    f"a higher --worker-memory may help)"
                    if memory_limit
                    else "",
                )
            done(t, rec)
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


def _run_dask(
    todo: list[BracketTask], client: Any, done: Callable[[BracketTask, BracketRecord], None]
) -> None:
    from distributed import as_completed as dask_completed

    run = uuid.uuid4().hex[:8]
    futures = client.map(
        run_task, todo, key=[f"hdrcore-merge-{t.name}-{run}" for t in todo], pure=False
    )
    by_key = {f.key: t for f, t in zip(futures, todo, strict=False)}
    try:
        for fut in dask_completed(futures):
            t = by_key[fut.key]
            try:
                rec = fut.result()
            except Exception as exc:  # a worker died, the scheduler gave up on the task
                rec = _lost(t, exc)
            done(t, rec)
    except BaseException:
        client.cancel(futures)
        raise


def _check_shared(
    tasks: Sequence[BracketTask], workers: int, scheduler: str | None, client: Any
) -> None:
    """``memory://`` lives in one process: refuse it where worker processes would write into
    their own memory and the run would lose every output."""
    if not (workers > 1 and client is None or scheduler is not None):
        return
    for t in tasks:
        for u in (t.outdir, *t.files):
            if remote.is_url(u) and remote.process_local(u):
                raise InputError(
                    "memory:// exists in one process only; worker processes would not see it",
                    path=u,
                    expected="--workers 1, or a filesystem every worker sees (file://, s3://, ...)",
                )


def run_batch(
    tasks: Sequence[BracketTask],
    *,
    workers: int = 1,
    scheduler: str | None = None,
    client: Any = None,
    progress: Progress | None = None,
    retry_failed: bool = False,
    force: bool = False,
    memory_limit: int | None = None,
) -> BatchRun:
    """Run ``tasks`` (brackets whose sidecar is up to date are skipped unless ``force``).

    ``workers``: processes on this machine (1: this process). ``client``: a
    ``distributed.Client`` to run on; ``scheduler``: its address (``tcp://host:8786``), or
    ``"local"`` for a ``LocalCluster`` of ``workers`` processes started here. ``progress(done,
    total, record)`` is called as each bracket ends (skipped ones first).
    """
    t0 = time.perf_counter()
    _check_shared(tasks, workers, scheduler, client)
    results: dict[str, BracketRecord] = {}
    total = len(tasks)
    todo: list[BracketTask] = []
    present: dict[str, set[str] | None] = {}
    infos = remote.Infos()
    for t in tasks:
        if remote.is_url(t.outdir) and t.outdir not in present:
            present[t.outdir] = remote.listing(t.outdir) or set()
        rec = (
            None
            if force
            else up_to_date(
                t, retry_failed=retry_failed, present=present.get(t.outdir), infos=infos
            )
        )
        if rec is None:
            todo.append(t)
        else:
            results[t.name] = rec
            if progress:
                progress(len(results), total, rec)
    if todo:
        remove_temporaries(todo[0].outdir, [t.name for t in todo])

    def done(t: BracketTask, rec: BracketRecord) -> None:
        results[t.name] = rec
        if progress:
            progress(len(results), total, rec)

    interrupted = False
    try:
        if not todo:
            pass
        elif client is not None or scheduler is not None:
            own = None
            if client is None:
                from distributed import Client, LocalCluster

                if scheduler == "local":
                    import dask

                    # Our own short-lived cluster: without the workers' statistical profiler
                    # (a thread sampling every 10 ms), work stealing (one task per bracket,
                    # all queued at once) and with slower monitors: the workers' time goes to
                    # the merges (see LOCAL_CLUSTER_CONFIG)
                    with dask.config.set(LOCAL_CLUSTER_CONFIG):
                        own = LocalCluster(
                            n_workers=max(1, workers),
                            threads_per_worker=1,
                            processes=True,
                            dashboard_address=None,
                        )
                    client = Client(own)
                    client.run(_worker_setup)  # our own workers: as the pool's
                else:
                    client = Client(scheduler)
            try:
                _run_dask(todo, client, done)
            finally:
                if own is not None:
                    client.close()
                    own.close()
                elif scheduler is not None:
                    client.close()
        else:
            _run_local(todo, workers, memory_limit, done)
    except KeyboardInterrupt:
        interrupted = True
    records = tuple(results[t.name] for t in tasks if t.name in results)
    return BatchRun(records, interrupted or len(records) < total, time.perf_counter() - t0)
