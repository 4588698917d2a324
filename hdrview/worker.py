"""One background job at a time; the latest request wins.

Slider callbacks arrive every 50 ms from viser's thread pool. Each one calls
:meth:`LatestWorker.submit`; a request that arrives while a job runs replaces any request still
waiting, so at most one job runs and at most one waits. A running job can ask
:meth:`JobContext.check` whether it has been superseded and stop early; results of superseded jobs
are dropped, never shown.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = ["Superseded", "JobContext", "LatestWorker"]

log = logging.getLogger(__name__)


class Superseded(Exception):  # noqa: N818 (a control-flow signal, not an error)
    """Raised inside a job when a newer request has arrived."""


@dataclass
class _Request:
    generation: int
    job: Callable[[JobContext], Any]
    on_done: Callable[[Any], None] | None
    on_error: Callable[[BaseException], None] | None
    label: str


class JobContext:
    """Handed to a running job: progress reporting and the superseded check."""

    def __init__(self, worker: LatestWorker, generation: int, label: str) -> None:
        self._worker = worker
        self.generation = generation
        self.label = label

    @property
    def superseded(self) -> bool:
        return self._worker._latest_generation != self.generation

    def check(self) -> None:
        """Raise :class:`Superseded` if a newer request is waiting."""
        if self.superseded:
            raise Superseded(self.label)

    def progress(self, fraction: float, text: str = "") -> None:
        cb = self._worker.on_progress
        if cb is not None and not self.superseded:
            try:
                cb(max(0.0, min(1.0, float(fraction))), text)
            except Exception:  # a drawing error must not kill the job
                log.exception("progress callback failed")


#: Seconds a failed job waits for a newer request before its error is shown (see
#: :meth:`LatestWorker._loop`): a key press arrives within it while a value is typed.
ERROR_GRACE = 0.6


class LatestWorker:
    """A single daemon thread running the most recent request."""

    def __init__(
        self,
        on_progress: Callable[[float, str], None] | None = None,
        on_busy: Callable[[bool], None] | None = None,
        name: str = "hdrview-worker",
    ) -> None:
        self.on_progress = on_progress
        self.on_busy = on_busy
        self._cond = threading.Condition()
        self._pending: _Request | None = None
        self._running = False
        self._stopped = False
        self._latest_generation = 0
        self.completed = 0
        self.dropped = 0
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def submit(
        self,
        job: Callable[[JobContext], Any],
        *,
        on_done: Callable[[Any], None] | None = None,
        on_error: Callable[[BaseException], None] | None = None,
        label: str = "job",
    ) -> int:
        """Queue ``job``, replacing any request still waiting; return its generation number."""
        with self._cond:
            if self._stopped:
                raise RuntimeError("worker stopped")
            self._latest_generation += 1
            if self._pending is not None:
                self.dropped += 1
            self._pending = _Request(self._latest_generation, job, on_done, on_error, label)
            self._cond.notify_all()
            return self._latest_generation

    @property
    def busy(self) -> bool:
        with self._cond:
            return self._running or self._pending is not None

    def wait_idle(self, timeout: float | None = None) -> bool:
        """Block until nothing runs or waits; return False on timeout."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while self._running or self._pending is not None:
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return False
                self._cond.wait(remaining)
            return True

    def stop(self, timeout: float = 5.0) -> None:
        with self._cond:
            self._stopped = True
            self._pending = None
            self._latest_generation += 1
            self._cond.notify_all()
        self._thread.join(timeout)

    def _set_busy(self, busy: bool) -> None:
        if self.on_busy is not None:
            try:
                self.on_busy(busy)
            except Exception:
                log.exception("busy callback failed")

    def _loop(self) -> None:
        while True:
            with self._cond:
                while self._pending is None and not self._stopped:
                    self._cond.wait()
                if self._stopped:
                    return
                req = self._pending
                assert req is not None  # the wait above ends on a request or on stop
                self._pending = None
                self._running = True
            self._set_busy(True)
            ctx = JobContext(self, req.generation, req.label)
            try:
                result = req.job(ctx)
                if ctx.superseded:
                    raise Superseded(req.label)
                if req.on_done is not None:
                    req.on_done(result)
                self.completed += 1
            except Superseded:
                self.dropped += 1
            except BaseException as exc:  # noqa: BLE001 -- reported to the user, never fatal
                if not ctx.superseded and req.on_error is not None:
                    # A value typed into a slider's box arrives a keystroke at a time ("200"
                    # as 2, 20, 200): a failure is reported only when no newer request comes
                    # within ERROR_GRACE s (the "2" said "noise floor out of range" while the
                    # "200" was on its way). A newer request ends the wait at once.
                    with self._cond:
                        self._cond.wait_for(
                            lambda: self._pending is not None or self._stopped, ERROR_GRACE
                        )
                if ctx.superseded:
                    self.dropped += 1
                elif req.on_error is not None:
                    try:
                        req.on_error(exc)
                    except Exception:
                        log.exception("error callback failed")
                else:
                    log.exception("job %s failed", req.label)
            finally:
                with self._cond:
                    self._running = False
                    idle = self._pending is None
                    self._cond.notify_all()
                if idle:
                    self._set_busy(False)
