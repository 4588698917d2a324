"""``index.json`` and ``index.csv``: one row per bracket of a batch (and per single shot left
out), with its status, verdicts and quality score, so the failed ones can be found and opened
(``hdrview --batch OUTDIR`` lists them worst first: :func:`worst_first`)."""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..errors import InputError
from ..io import atomic_write
from . import remote
from .task import BracketRecord

__all__ = ["write_index", "read_index", "worst_first", "INDEX_JSON", "INDEX_CSV", "CSV_COLUMNS"]

INDEX_JSON = "index.json"
INDEX_CSV = "index.csv"
CSV_COLUMNS = (
    "name",
    "status",
    "score",
    "ratio",
    "registration",
    "clipping",
    "ghost",
    "frames",
    "merged",
    "seconds",
    "reason",
    "verdicts",
    "exr",
    "preview",
    "dng",
    "sidecar",
    "files",
)
_STATUS_RANK = {"failed": 0, "error": 1, "warning": 2, "ok": 3}


def _row(r: BracketRecord) -> dict[str, Any]:
    q = r.quality or {}
    return {
        "name": r.name,
        "status": r.status,
        "score": q.get("score"),
        "ratio": q.get("ratio"),
        "registration": q.get("registration"),
        "clipping": q.get("clipping"),
        "ghost": q.get("ghost"),
        "frames": len(r.files),
        "merged": r.merged,
        "seconds": round(r.seconds, 3),
        "reason": r.reason,
        "verdicts": ";".join(str(v.get("code")) for v in r.verdicts),
        "exr": (r.outputs or {}).get("exr"),
        "preview": (r.outputs or {}).get("preview"),
        "dng": (r.outputs or {}).get("dng"),
        "sidecar": (r.outputs or {}).get("sidecar"),
        "files": ";".join(r.files),
    }


def write_index(
    outdir: str | os.PathLike,
    records: Sequence[BracketRecord],
    singles: Sequence[str] = (),
    *,
    summary: dict[str, Any] | None = None,
) -> None:
    """Write both index files atomically (replacing the previous run's); ``outdir`` may be
    an fsspec URL (:func:`hdrcore.batch.remote.put_atomic`)."""
    doc = {
        "summary": {
            "brackets": len(records),
            "by_status": {
                s: sum(r.status == s for r in records) for s in ("ok", "warning", "error", "failed")
            },
            "merged_this_run": sum(r.merged for r in records),
            "singles": len(singles),
            **(summary or {}),
        },
        "brackets": [r.to_json() for r in records],
        "singles": list(singles),
    }
    text = json.dumps(doc, indent=1, default=str)
    _write(outdir, INDEX_JSON, text)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=CSV_COLUMNS, lineterminator="\n")
    w.writeheader()
    for r in records:
        w.writerow(_row(r))
    for s in singles:
        w.writerow(
            {
                "name": Path(s).stem,
                "status": "single",
                "frames": 1,
                "merged": False,
                "reason": "single shot: not a bracket",
                "files": s,
            }
        )
    _write(outdir, INDEX_CSV, buf.getvalue())


def _write(outdir: str | os.PathLike, name: str, text: str) -> None:
    if remote.is_url(outdir):
        remote.write_text_atomic(remote.join(os.fspath(outdir), name), text)
    else:
        atomic_write(Path(outdir) / name, lambda tmp: tmp.write_text(text), force=True)


def read_index(outdir: str | os.PathLike) -> list[BracketRecord]:
    """The brackets of ``OUTDIR/index.json`` (a batch's output folder, or its URL)."""
    url = remote.is_url(outdir)
    p: Path | str = remote.join(os.fspath(outdir), INDEX_JSON) if url else Path(outdir) / INDEX_JSON
    try:
        doc = json.loads(remote.read_text(p) if isinstance(p, str) else p.read_text())
        return [BracketRecord.from_json(b) for b in doc["brackets"]]
    except FileNotFoundError:
        raise InputError(
            "cannot read the batch index (no such file)",
            path=p,
            expected="the output folder of 'hdrcore batch'",
        ) from None
    except OSError as exc:
        raise InputError(
            f"cannot read the batch index ({exc.strerror or exc})",
            path=p,
            expected="the output folder of 'hdrcore batch'",
        ) from None
    except (ValueError, KeyError, TypeError) as exc:
        raise InputError(f"not a batch index ({exc})", path=p) from None


def worst_first(records: Sequence[BracketRecord]) -> list[BracketRecord]:
    """Failed first, then merged with errors, with warnings, ok; lowest score first within."""
    return sorted(
        records,
        key=lambda r: (
            _STATUS_RANK.get(r.status, 0),
            float((r.quality or {}).get("score") or 0.0),
            r.name,
        ),
    )
