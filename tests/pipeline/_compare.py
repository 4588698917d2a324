"""Structural comparison of pipeline results: every array, number and string of two results
equal, timings left out (they measure the machine, not the result), and so are the fields a
dataclass leaves out of its own equality (``compare=False``: memos of derived values)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

#: Fields that time the computation (seconds, per-step timings) or say what was cached.
IGNORED = frozenset({"timings", "seconds", "stages_run"})


def differences(a: Any, b: Any, path: str = "result", limit: int = 20) -> list[str]:
    """Where ``a`` and ``b`` differ (at most ``limit`` paths); empty when they are equal."""
    out: list[str] = []
    _walk(a, b, path, out, limit, set())
    return out


def _walk(a: Any, b: Any, path: str, out: list[str], limit: int, seen: set) -> None:
    if len(out) >= limit:
        return
    if a is b and not isinstance(a, np.ndarray):
        return
    pair = (id(a), id(b))  # for cycles only: the comparison itself is by content
    if pair in seen:
        return
    seen.add(pair)
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a_arr, b_arr = np.asarray(a), np.asarray(b)
        if a_arr.shape != b_arr.shape or a_arr.dtype != b_arr.dtype:
            out.append(f"{path}: {a_arr.dtype}{a_arr.shape} != {b_arr.dtype}{b_arr.shape}")
        elif not np.array_equal(a_arr, b_arr, equal_nan=a_arr.dtype.kind in "fc"):
            out.append(f"{path}: arrays differ")
        return
    if type(a) is not type(b):
        out.append(f"{path}: {type(a).__name__} != {type(b).__name__}")
        return
    if isinstance(a, float):
        if not (a == b or (math.isnan(a) and math.isnan(b))):
            out.append(f"{path}: {a!r} != {b!r}")
        return
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        for f in dataclasses.fields(a):
            if f.name not in IGNORED and f.compare:  # compare=False: a memo, not the value
                _walk(getattr(a, f.name), getattr(b, f.name), f"{path}.{f.name}", out, limit, seen)
        return
    if isinstance(a, dict):
        keys = [k for k in a if k not in IGNORED]
        if set(keys) != {k for k in b if k not in IGNORED}:
            out.append(f"{path}: keys {sorted(map(str, a))} != {sorted(map(str, b))}")
            return
        for k in keys:
            _walk(a[k], b[k], f"{path}[{k!r}]", out, limit, seen)
        return
    if isinstance(a, (list, tuple)):
        if len(a) != len(b):
            out.append(f"{path}: length {len(a)} != {len(b)}")
            return
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            _walk(x, y, f"{path}[{k}]", out, limit, seen)
        return
    if isinstance(a, (int, str, bytes, bool, type(None))) or hasattr(a, "__eq__"):
        try:
            same = bool(a == b)
        except Exception:  # an object without a usable equality: compare its state
            same = True
            if hasattr(a, "__dict__"):
                _walk(vars(a), vars(b), path, out, limit, seen)
                return
        if not same:
            if hasattr(a, "__dict__") and not isinstance(a, (int, str)):
                _walk(vars(a), vars(b), path, out, limit, seen)
            else:
                out.append(f"{path}: {a!r} != {b!r}")
