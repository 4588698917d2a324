"""The background worker: one job at a time, the latest request wins, errors are reported."""

from __future__ import annotations

import threading
import time

import pytest

from hdrview.worker import LatestWorker


@pytest.fixture
def worker():
    w = LatestWorker()
    yield w
    w.stop()


def test_latest_request_wins(worker: LatestWorker) -> None:
    started = threading.Event()
    release = threading.Event()
    ran: list[int] = []
    done: list[int] = []

    def slow(ctx):
        started.set()
        release.wait(5)
        ran.append(0)
        return 0

    worker.submit(slow, on_done=done.append)
    assert started.wait(5)
    for k in range(1, 6):
        worker.submit(lambda ctx, k=k: ran.append(k) or k, on_done=done.append)
    release.set()
    assert worker.wait_idle(5)
    # The first job ran (but its result was superseded); of the five waiting only the last ran.
    assert ran == [0, 5]
    assert done == [5]
    assert worker.dropped == 5  # four replaced while waiting + the superseded first job


def test_running_job_can_stop_early(worker: LatestWorker) -> None:
    steps: list[int] = []
    started = threading.Event()

    def loop(ctx):
        started.set()
        for i in range(200):
            ctx.check()
            steps.append(i)
            time.sleep(0.01)

    worker.submit(loop)
    assert started.wait(5)
    time.sleep(0.05)
    worker.submit(lambda ctx: None)
    assert worker.wait_idle(5)
    assert len(steps) < 200


def test_errors_go_to_on_error_and_the_worker_survives(worker: LatestWorker) -> None:
    errors: list[BaseException] = []

    def bad(ctx):
        raise ValueError("boom")

    worker.submit(bad, on_error=errors.append)
    assert worker.wait_idle(5)
    assert len(errors) == 1 and "boom" in str(errors[0])
    out: list[int] = []
    worker.submit(lambda ctx: 7, on_done=out.append)
    assert worker.wait_idle(5)
    assert out == [7]


def test_progress_and_busy_callbacks() -> None:
    seen: list[tuple[float, str]] = []
    busy: list[bool] = []
    w = LatestWorker(on_progress=lambda f, t: seen.append((f, t)), on_busy=busy.append)
    try:
        w.submit(lambda ctx: (ctx.progress(0.5, "half"), ctx.progress(2.0, "over")))
        assert w.wait_idle(5)
    finally:
        w.stop()
    assert seen == [(0.5, "half"), (1.0, "over")]
    assert busy == [True, False]


def test_submit_after_stop_raises() -> None:
    w = LatestWorker()
    w.stop()
    with pytest.raises(RuntimeError, match="stopped"):
        w.submit(lambda ctx: None)


def test_an_error_followed_soon_by_a_newer_request_is_not_shown(worker: LatestWorker) -> None:
    """A value typed into a slider's box arrives a keystroke at a time: the "2" of "200" fails
    (a noise floor above Z = 2) while "200" is on its way. An error is reported only when no
    newer request comes within ERROR_GRACE; the newer request runs at once."""
    from hdrview.worker import ERROR_GRACE

    errors: list[BaseException] = []
    done: list[int] = []
    failed = threading.Event()

    def bad(ctx):
        failed.set()
        raise ValueError("the 2 of 200")

    worker.submit(bad, on_error=errors.append)
    assert failed.wait(5)
    time.sleep(0.05)
    t0 = time.monotonic()
    worker.submit(lambda ctx: 200, on_done=done.append, on_error=errors.append)
    assert worker.wait_idle(5)
    assert errors == [] and done == [200]
    assert time.monotonic() - t0 < ERROR_GRACE  # the wait ended when the request came
    # alone, the error is shown (after the grace)
    worker.submit(bad, on_error=errors.append)
    assert worker.wait_idle(5)
    assert len(errors) == 1 and "the 2 of 200" in str(errors[0])
