"""Work split over a few Python threads (the compiled kernels release the GIL).

One policy for the whole project: at most two workers by default (this is a 2-core target and
a second thread already hides most waiting). ``workers`` overrides it with scipy's convention:
a positive count, or ``-1`` for every core, ``-2`` for all but one, and so on; ``0`` is an
error. :func:`set_workers` changes the default for the code run inside it (a context variable:
per thread and per task, never for the whole process), which is how
``PipelineParams(workers=...)`` reaches every kernel of a run; :func:`thread_map` carries it
into its threads.
"""

from __future__ import annotations

import contextvars
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import TypeVar

from .errors import ParameterError

T = TypeVar("T")
R = TypeVar("R")

__all__ = [
    "cpu_count",
    "resolve_workers",
    "ordered_map",
    "run_row_spans",
    "set_workers",
    "thread_map",
    "worker_count",
]

#: The default of the code running in this context (``None``: the project's policy).
_DEFAULT: contextvars.ContextVar[int | None] = contextvars.ContextVar(
    "hdrcore_workers", default=None
)


def cpu_count() -> int:
    """The cores this process may run on (its CPU affinity where the system says)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def resolve_workers(workers: int | None) -> int:
    """The thread count ``workers`` asks for: ``None`` the default (the context's, else up to
    two), ``n >= 1`` itself, ``-1`` every core, ``-k`` all cores but ``k - 1`` (at least one
    thread either way). Raises :class:`~hdrcore.errors.ParameterError` for 0, a count below
    ``-cores`` or a non-integer."""
    if workers is None:
        workers = _DEFAULT.get()
        if workers is None:
            return min(2, cpu_count())
    if isinstance(workers, bool) or not isinstance(workers, int):
        try:
            as_int = int(workers)
        except (TypeError, ValueError):
            as_int = None
        if as_int is None or as_int != workers or isinstance(workers, bool):
            raise ParameterError(
                "workers must be an integer",
                expected="n >= 1, or -1 for every core (scipy's convention)",
                found=repr(workers),
            )
        workers = as_int
    if workers >= 1:
        return workers
    cores = cpu_count()
    if workers == 0 or cores + 1 + workers < 1:
        raise ParameterError(
            "workers out of range",
            expected=f"1..n, or -1..-{cores} (-1: all {cores} cores)",
            found=str(workers),
        )
    return cores + 1 + workers


@contextmanager
def set_workers(workers: int | None) -> Iterator[None]:
    """Inside the ``with`` block, ``workers=None`` means ``workers`` (checked at once);
    ``None`` leaves the surrounding default."""
    if workers is None:
        yield
        return
    resolve_workers(workers)  # bad values fail here, not in a kernel
    token = _DEFAULT.set(int(workers))
    try:
        yield
    finally:
        _DEFAULT.reset(token)


def worker_count(workers: int | None) -> int:
    """Threads to use for ``workers`` (:func:`resolve_workers`)."""
    return resolve_workers(workers)


def thread_map(fn: Callable[[T], R], items: Sequence[T], workers: int | None = None) -> list[R]:
    """``[fn(x) for x in items]`` on ``worker_count(workers)`` threads (in order); each call
    runs in a copy of the caller's context, so a nested kernel sees the same default."""
    return ordered_map(fn, items, workers)


def ordered_map(
    fn: Callable[[T], R],
    items: Sequence[T],
    workers: int | None = None,
    done: Callable[[int], None] | None = None,
) -> list[R]:
    """:func:`thread_map` that calls ``done(i)`` on the calling thread as the results come in,
    in order (a progress bar); when ``done`` raises (a cancelled run), the calls not started
    are dropped and the exception goes on once the running ones end."""
    n = worker_count(workers)
    if n == 1 or len(items) < 2:
        out = []
        for i, x in enumerate(items):
            out.append(fn(x))
            if done is not None:
                done(i)
        return out
    with ThreadPoolExecutor(max_workers=min(n, len(items))) as pool:
        futures = [pool.submit(contextvars.copy_context().run, fn, x) for x in items]
        try:
            out = []
            for i, f in enumerate(futures):
                out.append(f.result())
                if done is not None:
                    done(i)
            return out
        except BaseException:
            for f in futures:
                f.cancel()
            raise


def run_row_spans(h: int, workers: int | None, fn: Callable[[int, int], None]) -> None:
    """``fn(r0, r1)`` over ``h`` rows cut into eight spans per worker (for load balance)."""
    n = worker_count(workers)
    rows = max(1, -(-h // (8 * n)))
    spans = [(r, min(h, r + rows)) for r in range(0, h, rows)]
    thread_map(lambda span: fn(*span), spans, n)
