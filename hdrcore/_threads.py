"""Work split over a few Python threads (the compiled kernels release the GIL).

One policy for the whole project: at most two workers by default (this is a 2-core target and
a second thread already hides most waiting), ``workers`` to override it.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")

__all__ = ["worker_count", "thread_map", "run_row_spans"]


def worker_count(workers: int | None) -> int:
    """``workers`` (at least 1), or up to two, as many as there are cores."""
    return min(2, os.cpu_count() or 1) if workers is None else max(1, int(workers))


def thread_map(fn: Callable[[T], R], items: Sequence[T], workers: int | None = None) -> list[R]:
    """``[fn(x) for x in items]`` on ``worker_count(workers)`` threads (in order)."""
    n = worker_count(workers)
    if n == 1 or len(items) < 2:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(max_workers=n) as pool:
        return list(pool.map(fn, items))


def run_row_spans(h: int, workers: int | None, fn: Callable[[int, int], None]) -> None:
    """``fn(r0, r1)`` over ``h`` rows cut into eight spans per worker (for load balance)."""
    n = worker_count(workers)
    rows = max(1, -(-h // (8 * n)))
    spans = [(r, min(h, r + rows)) for r in range(0, h, rows)]
    thread_map(lambda span: fn(*span), spans, n)
