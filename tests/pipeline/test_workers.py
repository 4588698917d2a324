"""``workers`` (issue 17, point 7): scipy's convention, scoped to a run (never process-wide),
and results that do not depend on it (so it is no cache key)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hdrcore._threads import cpu_count, resolve_workers, set_workers, thread_map, worker_count
from hdrcore.errors import ParameterError
from hdrcore.io import Bracket, load_bracket
from hdrcore.pipeline import Pipeline, PipelineParams
from hdrcore.synthetic import simulate_bracket, write_bracket

from ..conftest import shared_dir
from ._compare import differences


def test_scipy_convention() -> None:
    cores = cpu_count()
    assert resolve_workers(None) == min(2, cores)
    assert resolve_workers(3) == 3
    assert resolve_workers(-1) == cores
    assert resolve_workers(-cores) == 1
    assert resolve_workers(np.int64(2)) == 2
    for bad in (0, -(cores + 1)):
        with pytest.raises(ParameterError, match="workers out of range"):
            resolve_workers(bad)
    for bad in ("two", 1.5, True):
        with pytest.raises(ParameterError, match="workers must be an integer"):
            resolve_workers(bad)


def test_set_workers_is_scoped_and_reaches_threads() -> None:
    before = worker_count(None)
    with set_workers(3):
        assert worker_count(None) == 3
        # a kernel run on one of thread_map's threads sees the same default
        assert thread_map(lambda _: worker_count(None), range(4), workers=2) == [3] * 4
        with set_workers(None):
            assert worker_count(None) == 3
    assert worker_count(None) == before
    with pytest.raises(ParameterError, match="workers out of range"), set_workers(0):
        pass


@pytest.fixture(scope="module")
def handheld(tmp_path_factory: pytest.TempPathFactory) -> Bracket:
    sim = simulate_bracket(
        scene="window",
        shape=(72, 96),
        exposure_times=(1 / 16, 1 / 4, 1.0),
        bits=8,
        response="gamma",
        noise_sigma=1.0,
        max_shift=2,
        max_rotation_deg=0.3,
        seed=4,
    )
    out = tmp_path_factory.mktemp("workers")
    write_bracket(out, sim, fmt="png")
    return load_bracket([out])


def _same_for_any_worker_count(bracket: Bracket) -> None:
    seen: list[int] = []
    base = PipelineParams(local="on", deghost=True)
    pipe = Pipeline(bracket, progress=lambda *a: seen.append(worker_count(None)))
    one = pipe.run(base.replace(workers=1))
    assert seen and set(seen) == {1}  # the run's kernels see the run's workers
    assert worker_count(None) == min(2, cpu_count())  # and nothing else does
    assert pipe.run(base.replace(workers=3)).stages_run == ()  # no cache key holds it
    for workers in (3, -1):
        fresh = Pipeline(bracket).run(base.replace(workers=workers))
        diff = differences(replace(one, params=fresh.params), fresh)
        assert not diff, (workers, diff)


def test_results_do_not_depend_on_workers_simulated(handheld: Bracket) -> None:
    _same_for_any_worker_count(handheld)


def test_results_do_not_depend_on_workers_real() -> None:
    b = load_bracket([shared_dir("frobisher-colour-hdri")])
    small = replace(
        b,
        frames=tuple(replace(f, levels=np.ascontiguousarray(f.levels[::5, ::5])) for f in b.frames),
    )
    _same_for_any_worker_count(small)


def test_bad_workers_is_a_parameter_error(handheld: Bracket) -> None:
    with pytest.raises(ParameterError, match="workers out of range"):
        Pipeline(handheld).run(PipelineParams(workers=0))


def test_ordered_map_reports_in_order_on_the_calling_thread() -> None:
    import threading
    import time

    from hdrcore._threads import ordered_map

    caller = threading.get_ident()
    seen: list[tuple[int, int]] = []
    ran_on: set[int] = set()

    def slow_first(x: int) -> int:
        ran_on.add(threading.get_ident())
        time.sleep(0.05 if x == 0 else 0.0)  # the second finishes first
        return 10 * x

    out = ordered_map(
        slow_first, [0, 1, 2, 3], workers=2, done=lambda i: seen.append((i, threading.get_ident()))
    )
    assert out == [0, 10, 20, 30]
    assert [i for i, _ in seen] == [0, 1, 2, 3] and {t for _, t in seen} == {caller}
    assert caller not in ran_on  # the work ran on the pool's threads

    started: list[int] = []

    def record(x: int) -> int:
        started.append(x)
        time.sleep(0.02)
        return x

    def cancel(i: int) -> None:
        raise KeyboardInterrupt  # a cancelled run: the rest is not started

    with pytest.raises(KeyboardInterrupt):
        ordered_map(record, list(range(20)), workers=2, done=cancel)
    assert len(started) < 20
