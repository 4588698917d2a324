"""``hdrview --batch OUTDIR``: the brackets of an ``hdrcore batch`` run, worst first.

The list comes from the run's ``index.json`` (:func:`hdrcore.batch.read_index`, ordered by
:func:`hdrcore.batch.worst_first`: failed, merged with errors, with warnings, ok; lowest
quality score first). The terminal prints it; every page gets a "Batch" folder with the list
as a dropdown and the chosen bracket's status, score and reason; choosing one opens its frames
in the inspector (the worst one is opened first). Nothing is recomputed here: the status and
scores are the batch's own.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

from hdrcore.batch import BracketRecord, read_index, worst_first

from .panels._draw import esc

__all__ = ["load_batch", "batch_listing", "entry_label", "add_batch_panel"]


def load_batch(outdir: str | os.PathLike) -> list[BracketRecord]:
    """The brackets of ``OUTDIR/index.json``, worst first (an error names the file)."""
    return worst_first(read_index(outdir))


def _score(r: BracketRecord) -> str:
    s = (r.quality or {}).get("score")
    return "-" if s is None else f"{float(s):.2f}"


def entry_label(k: int, r: BracketRecord) -> str:
    return f"{k + 1}. {r.status} {_score(r)} {r.name}"


def batch_listing(records: Sequence[BracketRecord]) -> str:
    """One line per bracket, worst first: rank, status, score, name, frames, reason."""
    lines = [f"{'#':>3} {'status':<8} {'score':>5}  {'bracket':<28} frames  reason / verdicts"]
    for k, r in enumerate(records):
        why = r.reason or ", ".join(str(v.get("code")) for v in r.verdicts)
        lines.append(
            f"{k + 1:>3} {r.status:<8} {_score(r):>5}  {r.name:<28} {len(r.files):>6}  {why[:100]}"
        )
    return "\n".join(lines)


def _details(r: BracketRecord) -> str:
    q = r.quality or {}
    parts = [f"**{esc(r.name)}**: {r.status}, score {_score(r)}, {len(r.files)} frames"]
    if q.get("score") is not None and len(q) > 1:
        parts.append(
            " · ".join(
                f"{k} {float(q[k]):.2f}"
                for k in ("ratio", "registration", "clipping", "ghost")
                if k in q
            )
        )
    if r.reason:
        parts.append(esc(r.reason))
    for v in r.verdicts[:4]:
        parts.append(f"{v.get('severity')}: {esc(str(v.get('message')))}")
    return "\n\n".join(parts)


def add_batch_panel(view: Any, records: Sequence[BracketRecord]) -> Any:
    """A "Batch" folder on the page: the brackets worst first; choosing one opens it."""
    gui = view.gui
    labels = [entry_label(k, r) for k, r in enumerate(records)]
    by_label = dict(zip(labels, records, strict=True))
    with gui.add_folder("Batch"):
        dropdown = gui.add_dropdown(
            "Bracket",
            tuple(labels),
            initial_value=labels[0],
            hint="brackets of the batch, worst first",
        )
        details = gui.add_markdown(_details(records[0]))

    @dropdown.on_update
    def _(event: Any) -> None:
        r = by_label[dropdown.value]
        details.content = _details(r)
        view.request_paths(list(r.files), r.name, getattr(event, "client", None))

    return dropdown
