"""A batch plan: the brackets to merge (name, files, why grouped) and the single shots left out.

The plan is what ``hdrcore batch --plan --json`` prints; it can be edited (files moved between
brackets, brackets split or joined, renamed) and given back with ``--plan-file``, which is
checked here: a clear error names the plan file and the entry that is wrong.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import InputError
from . import remote
from .group import Group

__all__ = ["PlannedBracket", "Plan", "make_plan", "read_plan", "plan_table", "PLAN_VERSION"]

PLAN_VERSION = 1
_SAFE = re.compile(r"[^A-Za-z0-9._+-]+")


@dataclass(frozen=True)
class PlannedBracket:
    name: str
    files: tuple[str, ...]
    reason: str = ""

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "files": list(self.files), "reason": self.reason}


@dataclass(frozen=True)
class Plan:
    brackets: tuple[PlannedBracket, ...]
    singles: tuple[str, ...] = ()
    method: str = "signals"

    def to_json(self) -> dict[str, Any]:
        return {
            "version": PLAN_VERSION,
            "method": self.method,
            "brackets": [b.to_json() for b in self.brackets],
            "singles": list(self.singles),
        }


def _name_for(files: Sequence[str]) -> str:
    first, last = Path(files[0]).stem, Path(files[-1]).stem
    digits = re.search(r"(\d+)$", last)
    tail = digits.group(1) if digits and last[: digits.start()] == first[: digits.start()] else last
    name = first if tail == first else f"{first}-{tail}"
    return _SAFE.sub("_", name).strip("._") or "bracket"


def _unique(names: list[str]) -> list[str]:
    seen: dict[str, int] = {}
    out = []
    for n in names:
        k = seen.get(n, 0)
        seen[n] = k + 1
        out.append(n if k == 0 else f"{n}_{k + 1}")
    return out


def make_plan(groups: Sequence[Group], method: str = "signals") -> Plan:
    """Brackets (groups of two or more) named after their first and last file, unique."""
    brackets = [g for g in groups if g.is_bracket]
    names = _unique([_name_for(g.paths) for g in brackets])
    return Plan(
        brackets=tuple(
            PlannedBracket(n, tuple(g.paths), g.reason)
            for n, g in zip(names, brackets, strict=False)
        ),
        singles=tuple(g.paths[0] for g in groups if not g.is_bracket),
        method=method,
    )


def read_plan(path: str | os.PathLike) -> Plan:
    """A plan file as printed by ``--plan --json`` (maybe edited); relative file names are
    taken from the plan file's folder. Files (and the plan file) may be fsspec URLs."""
    is_url = remote.is_url(path)
    p: Path | str = os.fspath(path) if is_url else Path(path)
    try:
        doc = json.loads(remote.read_text(p) if isinstance(p, str) else p.read_text())
    except FileNotFoundError:
        raise InputError("cannot read the plan file (no such file)", path=p) from None
    except OSError as exc:
        raise InputError(f"cannot read the plan file ({exc.strerror or exc})", path=p) from None
    except ValueError as exc:
        raise InputError(f"the plan file is not JSON ({exc})", path=p) from None
    if not isinstance(doc, dict) or not isinstance(doc.get("brackets"), list):
        raise InputError(
            "not a batch plan",
            path=p,
            expected="an object with a 'brackets' list (hdrcore batch --plan --json)",
        )
    out: list[PlannedBracket] = []
    seen_files: dict[str, str] = {}
    for k, b in enumerate(doc["brackets"]):
        where = f"bracket {k + 1}"
        if not isinstance(b, dict) or not isinstance(b.get("files"), list):
            raise InputError(f"{where} has no 'files' list", path=p)
        files = []
        for f in b["files"]:
            if not isinstance(f, str) or not f:
                raise InputError(f"{where}: a file name is not a string", path=p, found=repr(f))
            if remote.is_url(f) or isinstance(p, str) and not f.startswith("/"):
                url = f if remote.is_url(f) else remote.join(remote.parent(str(p)), f)
                remote.check_url(url)
                if remote.info_of(url) is None:
                    raise InputError(f"{where}: no such file", path=p, found=url)
                key, shown, entry = url, remote.basename(url), url
            else:
                q = Path(f) if Path(f).is_absolute() else Path(p).parent / f
                if not q.is_file():
                    raise InputError(f"{where}: no such file", path=p, found=str(q))
                key, shown, entry = str(q.resolve()), q.name, str(q)
            if key in seen_files:
                raise InputError(f"{where}: {shown} is also in {seen_files[key]}", path=p)
            seen_files[key] = where
            files.append(entry)
        if len(files) < 2:
            raise InputError(
                f"{where} has {len(files)} file(s)",
                path=p,
                expected="at least two frames per bracket",
            )
        name = b.get("name") or _name_for(files)
        if not isinstance(name, str) or _SAFE.sub("_", name) != name or name.startswith("."):
            raise InputError(
                f"{where}: the name cannot be a file name",
                path=p,
                expected="letters, digits, '.', '_', '+', '-'",
                found=repr(name),
            )
        out.append(PlannedBracket(name, tuple(files), str(b.get("reason") or "from plan file")))
    names = [b.name for b in out]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputError("two brackets have one name", path=p, found=", ".join(dup))
    singles = tuple(str(s) for s in doc.get("singles", []) if isinstance(s, str))
    return Plan(tuple(out), singles, str(doc.get("method", "plan-file")))


def plan_table(plan: Plan) -> str:
    """The plan as a plain-text table: one line per bracket, then the single shots."""
    lines = [f"{'bracket':<28} {'frames':>6}  files / why"]
    for b in plan.brackets:
        names = [Path(f).name for f in b.files]
        shown = ", ".join(names) if len(names) <= 4 else f"{names[0]}, {names[1]} ... {names[-1]}"
        lines.append(f"{b.name:<28} {len(b.files):>6}  {shown}  ({b.reason})")
    if plan.singles:
        names = [Path(f).name for f in plan.singles]
        shown = ", ".join(names[:8]) + (f" ... ({len(names)} in all)" if len(names) > 8 else "")
        lines.append(f"{'single shots (not merged)':<28} {len(names):>6}  {shown}")
    lines.append(
        f"{len(plan.brackets)} bracket(s), "
        f"{sum(len(b.files) for b in plan.brackets)} frames, "
        f"{len(plan.singles)} single shot(s); grouping: {plan.method}"
    )
    return "\n".join(lines)
