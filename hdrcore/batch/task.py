"""One bracket of a batch: a plain, picklable task and the record it leaves.

:func:`run_task` is a module-level function of a frozen dataclass, so the same code runs in
this process, in a ``ProcessPoolExecutor`` and on a Dask worker. It merges through the
``hdrcore merge`` command itself (:func:`hdrcore.cli.merge.run`: the pipeline, the output
checks, the atomic EXR / PNG / report writing), never a copy of it, then writes the bracket's
sidecar ``NAME.json`` last, atomically: a sidecar whose key matches says the bracket is done.

The key (:func:`bracket_key`) is a SHA-256 of the frames' contents (in order), the merge
options, the outputs asked for and the version of hdrcore, in the manner of Dask's
``tokenize``: a changed frame or option gives another key and the bracket is merged again.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from .. import __version__
from ..errors import HdrError
from ..io import atomic_write
from ..status import BATCH_STATUSES, BatchStatus, is_batch_status
from . import remote

__all__ = [
    "BracketTask",
    "BracketRecord",
    "run_task",
    "file_digest",
    "bracket_key",
    "quality_from_report",
    "frame_stamp",
    "SIDECAR_VERSION",
]

SIDECAR_VERSION = 1
_CHUNK = 1 << 22


def file_digest(path: str | os.PathLike) -> str:
    """SHA-256 of a file's bytes (hex)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(_CHUNK), b""):
            h.update(block)
    return h.hexdigest()


def bracket_key(
    digests: list[str], options: dict[str, Any], preview: bool, extra: str = "", dng: bool = False
) -> str:
    """The bracket's content key: frames' digests in order, merge options, outputs, version
    and ``extra`` (the digests of the option files: ``--times``, a ``--response`` curve)."""
    doc = {
        "frames": digests,
        "options": options,
        "preview": bool(preview),
        "hdrcore": __version__,
        "sidecar": SIDECAR_VERSION,
        "extra": extra,
    }
    if dng:  # keys of runs without a DNG stay as they were
        doc["dng"] = True
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


@dataclass(frozen=True)
class BracketTask:
    """Everything a worker needs to merge one bracket (paths every worker can read, or fsspec
    URLs: :mod:`hdrcore.batch.remote`).

    ``options``: the ``hdrcore merge`` options by destination name (``{"align":
    "homography"}``), JSON-ready; unnamed options keep the merge's defaults.
    """

    name: str
    files: tuple[str, ...]
    outdir: str
    options: dict[str, Any] = field(default_factory=dict)
    preview: bool = False
    extra_key: str = ""
    dng: bool = False

    @property
    def key_args(self) -> tuple:
        """What :func:`bracket_key` takes besides the frames' digests."""
        return (self.options, self.preview, self.extra_key, self.dng)

    @property
    def remote(self) -> bool:
        """Whether a frame or the output folder is an fsspec URL."""
        return remote.is_url(self.outdir) or any(remote.is_url(f) for f in self.files)

    @property
    def sidecar_name(self) -> str:
        return f"{self.name}.json"

    def target(self, name: str) -> str:
        """Where an output file of this name goes: a URL in a remote output folder, else a
        path (as a string)."""
        if remote.is_url(self.outdir):
            return remote.join(self.outdir, name)
        return str(Path(self.outdir) / name)

    @property
    def exr(self) -> Path:
        return Path(self.outdir) / f"{self.name}.exr"

    @property
    def png(self) -> Path:
        return Path(self.outdir) / f"{self.name}.png"

    @property
    def dng_path(self) -> Path:
        return Path(self.outdir) / f"{self.name}.dng"

    @property
    def sidecar(self) -> Path:
        return Path(self.outdir) / f"{self.name}.json"


@dataclass(frozen=True)
class BracketRecord:
    """What became of one bracket. ``status``: ``ok``, ``warning`` (merged, with warnings),
    ``error`` (merged, but a stage failed: ``hdrcore merge`` exit 1), ``failed`` (nothing
    written: ``reason`` says why). ``merged``: merged in this run (``False``: skipped, its
    sidecar was up to date)."""

    name: str
    files: tuple[str, ...]
    status: BatchStatus
    reason: str = ""
    key: str = ""
    quality: dict[str, Any] = field(default_factory=dict)
    verdicts: tuple[dict[str, Any], ...] = ()
    outputs: dict[str, str | None] = field(default_factory=dict)
    merged: bool = True
    seconds: float = 0.0
    cpu_seconds: float = 0.0
    peak_rss_mb: float | None = None
    worker: str = ""
    messages: tuple[str, ...] = ()

    @property
    def failed(self) -> bool:
        return self.status in ("failed", "error")

    def to_json(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "files": list(self.files),
            "status": self.status,
            "reason": self.reason,
            "key": self.key,
            "quality": self.quality,
            "verdicts": list(self.verdicts),
            "outputs": self.outputs,
            "merged": self.merged,
            "seconds": self.seconds,
            "cpu_seconds": self.cpu_seconds,
            "peak_rss_mb": self.peak_rss_mb,
            "worker": self.worker,
            "messages": list(self.messages),
        }

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> BracketRecord:
        """A record read back (a sidecar, the index); ``ValueError`` for an unknown status."""
        status = doc.get("status", "failed")
        if not is_batch_status(status):
            raise ValueError(
                f"unknown bracket status {status!r}, expected one of " + ", ".join(BATCH_STATUSES)
            )
        return cls(
            name=str(doc["name"]),
            files=tuple(doc.get("files", ())),
            status=status,
            reason=str(doc.get("reason", "")),
            key=str(doc.get("key", "")),
            quality=dict(doc.get("quality") or {}),
            verdicts=tuple(doc.get("verdicts") or ()),
            outputs=dict(doc.get("outputs") or {}),
            merged=bool(doc.get("merged", True)),
            seconds=float(doc.get("seconds") or 0.0),
            cpu_seconds=float(doc.get("cpu_seconds") or 0.0),
            peak_rss_mb=doc.get("peak_rss_mb"),
            worker=str(doc.get("worker", "")),
            messages=tuple(doc.get("messages") or ()),
        )


def _clamp01(x: float) -> float:
    return max(0.0, min(1.0, x))


#: Quality components fall to 0 at these values (see :func:`quality_from_report`).
RATIO_CI_ZERO = 0.05
CLIPPED_ZERO = 0.20
GHOST_ZERO = 0.20
_REGISTRATION_STATUS = {"ok": 1.0, "weak": 0.5, "uncertain": 0.5}


def quality_from_report(report: dict[str, Any] | None) -> dict[str, Any]:
    """A score in [0, 1] (1 best) and its four factors, read from a merge report.

    * ``ratio``: ``1 - worst 95 % interval of an exposure ratio / 5 %`` (0 for a failed pair);
    * ``registration``: the worst pair's status (ok 1, weak 0.5, failed 0; 1 when nothing was
      registered): the report gives each pair's verdict, not its residual in pixels;
    * ``clipping``: ``1 - fraction clipped in every frame / 20 %``;
    * ``ghost``: ``1 - ghost fraction / 20 %``.

    The score is their product, so any one bad factor makes a bracket sort among the worst.
    """
    if not report:
        return {"score": 0.0}
    pairs = (report.get("ratios") or {}).get("pairs") or []
    worst_ci = 0.0
    ratio = 1.0
    for p in pairs:
        ci = p.get("ci95_relative")
        if p.get("status") == "failed" or ci is None:
            ratio = 0.0
        else:
            worst_ci = max(worst_ci, float(ci))
    ratio = min(ratio, _clamp01(1.0 - worst_ci / RATIO_CI_ZERO))
    reg = report.get("registration") or {}
    reg_statuses = [str(p.get("status")) for p in reg.get("pairs") or []]
    registration = min([_REGISTRATION_STATUS.get(s, 0.0) for s in reg_statuses], default=1.0)
    merge = report.get("merge") or {}
    clipped = float(merge.get("clipped_fraction") or 0.0)
    ghost = float(merge.get("ghost_fraction") or 0.0)
    clipping = _clamp01(1.0 - clipped / CLIPPED_ZERO)
    ghosting = _clamp01(1.0 - ghost / GHOST_ZERO)
    return {
        "score": ratio * registration * clipping * ghosting,
        "ratio": ratio,
        "registration": registration,
        "clipping": clipping,
        "ghost": ghosting,
        "worst_ratio_ci95": worst_ci if pairs else None,
        "registration_statuses": reg_statuses,
        "clipped_fraction": clipped,
        "ghost_fraction": ghost,
    }


def _peak_rss_mb() -> float | None:
    try:
        import resource
    except ImportError:  # pragma: no cover - not on POSIX
        return None
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _merge_namespace(task: BracketTask, report_path: Path) -> Any:
    from ..cli import build_parser  # the merge command's own parser and defaults

    ns = build_parser().parse_args(["merge", *task.files, "-o", str(task.exr)])
    for k, v in task.options.items():
        if not hasattr(ns, k):
            raise HdrError(f"unknown merge option {k!r}")
        setattr(ns, k, tuple(v) if k == "exclude_colour" and v is not None else v)
    ns.preview = str(task.png) if task.preview else None
    ns.dng = str(task.dng_path) if task.dng else None
    ns.report = str(report_path)
    ns.force, ns.quiet, ns.json = True, True, False
    return ns


def run_task(task: BracketTask) -> BracketRecord:
    """Merge one bracket and write its sidecar; never raises for a bad bracket (the record
    says why it failed). ``KeyboardInterrupt`` passes: the outputs in progress are removed by
    the atomic writers and no sidecar is written. A task with URLs (:attr:`BracketTask.remote`)
    merges local copies of its remote frames and uploads its outputs (:func:`_run_remote`)."""
    if task.remote:
        return _run_remote(task)
    record, report, digests = _merge(task)
    problem = write_sidecar(task, record, report, digests)
    if problem:
        record = replace(record, messages=(*record.messages, problem))
    return record


def _merge(task: BracketTask) -> tuple[BracketRecord, dict[str, Any] | None, list[str]]:
    """The merge of a bracket of local files into a local folder: its record (outputs named
    as written), the merge report and the frames' digests. Writes no sidecar."""
    from ..cli import merge as merge_cli

    t0, c0 = time.perf_counter(), time.process_time()
    report_path = Path(task.outdir) / f".{task.name}.report.json"
    said = io.StringIO()
    report: dict[str, Any] | None = None
    digests: list[str] = []
    status: BatchStatus = "failed"
    reason = ""
    try:
        digests = [file_digest(f) for f in task.files]
        ns = _merge_namespace(task, report_path)
        with (
            contextlib.redirect_stderr(said),
            contextlib.redirect_stdout(said),
            warnings.catch_warnings(),
        ):
            warnings.simplefilter("ignore")
            code = merge_cli.run(ns)
        report = json.loads(report_path.read_text())
        worst = {v.get("severity") for v in report.get("verdicts", [])}
        status = "error" if code == 1 else "warning" if "warning" in worst else "ok"
        if code == 1:
            verdicts = report.get("verdicts", [])
            errs = [v["message"] for v in verdicts if v.get("severity") == "error"] + [
                v["message"] for v in verdicts if v.get("code") in merge_cli.STAGE_FAILED
            ]
            reason = errs[0] if errs else "a stage failed"
    except HdrError as exc:
        reason = str(exc)
    except OSError as exc:
        reason = f"{getattr(exc, 'filename', '') or ''}: {exc.strerror or exc}".lstrip(": ")
    except MemoryError:
        reason = "out of memory"
    except Exception as exc:  # one bad bracket never stops the run: recorded, not raised
        reason = f"internal error: {type(exc).__name__}: {exc}"
    finally:
        report_path.unlink(missing_ok=True)
    merged = status != "failed"
    record = BracketRecord(
        name=task.name,
        files=task.files,
        status=status,
        reason=reason,
        key=bracket_key(digests, *task.key_args) if digests else "",
        quality=quality_from_report(report) if merged else {"score": 0.0},
        verdicts=tuple(
            {k: v.get(k) for k in ("code", "severity", "message")}
            for v in (report or {}).get("verdicts", [])
            if v.get("severity") in ("warning", "error")
        ),
        outputs={
            "exr": str(task.exr) if merged else None,
            "preview": str(task.png) if merged and task.preview else None,
            "dng": str(task.dng_path) if merged and task.dng else None,
            "sidecar": str(task.sidecar),
        },
        merged=True,
        seconds=time.perf_counter() - t0,
        cpu_seconds=time.process_time() - c0,
        peak_rss_mb=_peak_rss_mb(),
        worker=f"{os.uname().nodename}:{os.getpid()}",
        messages=tuple(line for line in said.getvalue().splitlines() if line.strip())[:20],
    )
    return record, report, digests


def _swap(obj: Any, pairs: list[tuple[str, str]]) -> Any:
    """``obj`` (JSON-like) with each local path of ``pairs`` replaced by its URL."""
    if isinstance(obj, str):
        for local, url in pairs:
            obj = obj.replace(local, url)
        return obj
    if isinstance(obj, dict):
        return {k: _swap(v, pairs) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(_swap(v, pairs) for v in obj)
    return obj


def _run_remote(task: BracketTask) -> BracketRecord:
    """:func:`run_task` with URLs: remote frames copied to a local temporary folder (names
    kept, bytes identical, so EXIF and digests are the originals'), merged there; with a
    remote output folder every output is uploaded atomically (:func:`remote.put_atomic`) and
    the sidecar last. Paths in the record, report and messages are given back as URLs."""
    import tempfile

    t0, c0 = time.perf_counter(), time.process_time()
    with tempfile.TemporaryDirectory(prefix="hdrcore-batch-") as tmp:
        urls = [f for f in task.files if remote.is_url(f)]
        try:
            staged = dict(zip(urls, remote.stage(urls, Path(tmp) / "in"), strict=True))
        except Exception as exc:  # a missing or unreadable frame: this bracket fails
            reason = (
                str(exc)
                if isinstance(exc, HdrError)
                else f"cannot read the frames ({type(exc).__name__}: {exc})"
            )
            record = BracketRecord(
                task.name,
                task.files,
                "failed",
                reason=reason,
                quality={"score": 0.0},
                outputs={
                    "exr": None,
                    "preview": None,
                    "dng": None,
                    "sidecar": task.target(task.sidecar_name),
                },
                seconds=time.perf_counter() - t0,
                cpu_seconds=time.process_time() - c0,
                worker=f"{os.uname().nodename}:{os.getpid()}",
            )
            problem = write_sidecar(task, record, None, [])
            return replace(record, messages=(problem,)) if problem else record
        files = tuple(str(staged[f]) if f in staged else f for f in task.files)
        out_remote = remote.is_url(task.outdir)
        local_out = Path(tmp) / "out" if out_remote else Path(task.outdir)
        local_out.mkdir(exist_ok=True)
        local = replace(task, files=files, outdir=str(local_out))
        record, report, digests = _merge(local)
        pairs = sorted(
            [(str(staged[u]), u) for u in urls]
            + ([(str(local_out), task.outdir.rstrip("/"))] if out_remote else []),
            key=lambda p: -len(p[0]),
        )
        outputs = dict(record.outputs)
        try:
            if out_remote:
                for kind in ("exr", "preview", "dng"):
                    if outputs.get(kind):
                        name = Path(str(outputs[kind])).name
                        outputs[kind] = remote.put_atomic(
                            local_out / name, task.target(name), inputs=task.files
                        )
        except HdrError as exc:  # the upload failed: nothing of this bracket counts as done
            record = replace(
                record, status="failed", reason=str(exc), quality={"score": 0.0}, key=""
            )
            outputs = {k: None for k in ("exr", "preview", "dng")}
        outputs["sidecar"] = task.target(task.sidecar_name)
        record = replace(
            BracketRecord.from_json(_swap(record.to_json(), pairs)),
            files=task.files,
            outputs=outputs,
            seconds=time.perf_counter() - t0,
            cpu_seconds=time.process_time() - c0,
        )
        report = _swap(report, pairs)
    problem = write_sidecar(task, record, report, digests if record.key else [])
    if problem:
        record = replace(record, messages=(*record.messages, problem))
    return record


def frame_stamp(path: str) -> dict[str, Any] | None:
    """What tells whether a frame changed without reading it: ``size`` and ``mtime_ns`` of a
    local file; ``size`` and ``stamp`` (:func:`remote.stamp`: the ETag, md5Hash, ... or a
    time the filesystem's listing gives) of a URL. ``None`` if it cannot be had."""
    if remote.is_url(path):
        info = remote.info_of(path)
        return None if info is None else remote.stamp(info)
    try:
        st = os.stat(path)
    except OSError:
        return None
    return {"size": st.st_size, "mtime_ns": st.st_mtime_ns}


def write_sidecar(
    task: BracketTask, record: BracketRecord, report: dict[str, Any] | None, digests: list[str]
) -> str | None:
    """``NAME.json``: the record, each frame's size, time stamp and digest, and the report.
    Returns what went wrong writing it (the record still reaches the index), else ``None``."""
    frames = []
    for f, d in zip(task.files, digests, strict=False):
        frames.append({"path": f, **(frame_stamp(f) or {}), "sha256": d})
    doc = {
        "version": SIDECAR_VERSION,
        "batch": record.to_json(),
        "frames": frames,
        "options": task.options,
        "preview": task.preview,
        "dng": task.dng,
        "report": report,
    }
    text = json.dumps(doc, indent=1, default=str)
    try:
        if remote.is_url(task.outdir):
            remote.write_text_atomic(task.target(task.sidecar_name), text)
        else:
            atomic_write(
                task.sidecar, lambda tmp: tmp.write_text(text), force=True, inputs=task.files
            )
    except HdrError as exc:
        return f"sidecar not written: {exc}"
    return None
