"""``hdrcore batch`` end to end on a small simulated folder: index files, a bad bracket in the
middle, skip-on-resume (a changed frame or option re-merges only what it touches), an
interrupted run restarted, and the same tasks on worker processes and on a Dask LocalCluster
giving identical outputs."""

from __future__ import annotations

import csv
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from hdrcore.batch import (
    group_shots,
    make_plan,
    read_index,
    run_batch,
    scan_shots,
    tasks_from_plan,
    worst_first,
)
from hdrcore.batch.scan import read_shot
from hdrcore.cli import main
from hdrcore.io import read_exr

from .conftest import bad_frame, make_folder


def _index(out: Path) -> dict:
    return json.loads((out / "index.json").read_text())


def _merged(out: Path) -> set[str]:
    return {b["name"] for b in _index(out)["brackets"] if b["merged"]}


def _pixels(out: Path) -> dict[str, np.ndarray]:
    return {p.stem: read_exr(p)[0] for p in sorted(out.glob("*.exr"))}


def test_scan_reads_what_the_camera_wrote(sim_folder):
    folder, sim = sim_folder
    s = read_shot(folder / sim[1].name)
    assert s.subsec and s.camera == "SimCam S1" and s.size == (64, 48)
    assert s.exposure_time == pytest.approx(float(sim[1].exposure_time))
    assert s.exposure_bias == pytest.approx(float(sim[1].bias))
    assert s.time is not None and (s.time - read_shot(folder / sim[0].name).time) == pytest.approx(
        sim[1].time - sim[0].time, abs=2e-3
    )


def test_folder_with_a_bad_bracket(sim_folder, tmp_path, capsys):
    folder, sim = sim_folder
    out = tmp_path / "out"
    assert main(["batch", str(folder), "-o", str(out), "--quiet"]) == 1
    err = capsys.readouterr().err
    doc = _index(out)
    names = [b["name"] for b in doc["brackets"]]
    assert len(names) == 5
    bad = [b for b in doc["brackets"] if b["status"] == "failed"]
    assert len(bad) == 1 and str(folder / bad_frame(sim)) in bad[0]["files"]
    assert bad_frame(sim) in bad[0]["reason"] and bad[0]["quality"]["score"] == 0.0
    assert f"failed: {bad[0]['name']}" in err
    good = [b for b in doc["brackets"] if b["status"] != "failed"]
    for b in good:
        assert Path(b["outputs"]["exr"]).is_file()
        assert 0.0 < b["quality"]["score"] <= 1.0
        side = json.loads(Path(b["outputs"]["sidecar"]).read_text())
        assert side["batch"]["key"] == b["key"] and side["report"]["merge"]["n_frames"] == 3
    singles = {s.name for s in sim if s.kind != "bracket"}
    assert {Path(p).name for p in doc["singles"]} == singles
    rows = list(csv.DictReader((out / "index.csv").open()))
    assert [r["name"] for r in rows[:5]] == names
    assert {r["status"] for r in rows[5:]} == {"single"} and len(rows) == 5 + len(singles)
    assert worst_first(read_index(out))[0].status == "failed"
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporaries left


def test_resume_merges_only_what_changed(tmp_path):
    folder = tmp_path / "shots"
    sim = make_folder(folder)
    out = tmp_path / "out"
    args = ["batch", str(folder), "-o", str(out), "--quiet"]
    assert main(args) == 1
    everything = {b["name"] for b in _index(out)["brackets"]}
    assert _merged(out) == everything
    main(args)
    assert _merged(out) == set()  # nothing again, not even the failed bracket
    # a frame touched (same bytes) is re-hashed, not re-merged
    first = folder / sim[0].name
    os.utime(first, (1e9, 1e9))
    main(args)
    assert _merged(out) == set()
    # a frame changed: that bracket only
    target = next(b for b in _index(out)["brackets"] if b["status"] != "failed")
    frame = Path(target["files"][0])
    data = bytearray(frame.read_bytes())
    data[-10] ^= 0x01  # one bit of the entropy-coded data
    frame.write_bytes(bytes(data))
    main(args)
    assert _merged(out) == {target["name"]}
    # an option changed: every bracket (the failed one is tried again: its key changed)
    main([*args, "--threshold", "0.12"])
    assert _merged(out) == everything
    main([*args, "--threshold", "0.12", "--retry-failed"])
    assert {b["name"] for b in _index(out)["brackets"] if b["merged"]} == {
        b["name"] for b in _index(out)["brackets"] if b["status"] == "failed"
    }


def _tasks(folder: Path, out: Path):
    plan = make_plan(group_shots(scan_shots([folder])))
    out.mkdir()
    return tasks_from_plan(plan, out, {"threshold": 0.1})


def test_interrupted_run_restarts_where_it_stopped(sim_folder, tmp_path):
    folder, _ = sim_folder
    whole = _tasks(folder, tmp_path / "whole")
    assert not run_batch(whole).interrupted
    cut = _tasks(folder, tmp_path / "cut")

    def stop_after_two(done, total, record):
        if done == 2:
            raise KeyboardInterrupt

    first = run_batch(cut, progress=stop_after_two)
    assert first.interrupted and len(first.records) == 2
    again = run_batch(cut)
    assert not again.interrupted
    assert {r.name for r in again.records if r.merged} == {t.name for t in cut} - {
        r.name for r in first.records
    }
    a, b = _pixels(tmp_path / "whole"), _pixels(tmp_path / "cut")
    assert a.keys() == b.keys() and len(a) == 4
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])


def test_processes_and_dask_give_identical_outputs(sim_folder, tmp_path):
    distributed = pytest.importorskip("distributed")
    folder, _ = sim_folder
    serial = _tasks(folder, tmp_path / "serial")
    run_batch(serial)
    pool = _tasks(folder, tmp_path / "pool")
    res = run_batch(pool, workers=2)
    assert res.merged == 5 and len({r.worker for r in res.records}) == 2
    dask_tasks = _tasks(folder, tmp_path / "dask")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        # as --scheduler tcp://host:port does: a client of that address, closed at the end
        res = run_batch(dask_tasks, scheduler=cluster.scheduler_address)
    assert res.merged == 5 and res.failed == 1
    ref = _pixels(tmp_path / "serial")
    for other in ("pool", "dask"):
        px = _pixels(tmp_path / other)
        assert px.keys() == ref.keys()
        for k in ref:
            np.testing.assert_array_equal(px[k], ref[k])
    shutil.rmtree(tmp_path / "dask")


def test_bad_input_is_one_line(tmp_path, capsys):
    assert main(["batch", str(tmp_path / "nowhere"), "-o", str(tmp_path / "o")]) == 2
    assert "nowhere: no such file or folder" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["batch", str(tmp_path / "empty"), "--plan"]) == 2
    assert "no JPEG, PNG, TIFF or RAW files found" in capsys.readouterr().err
    assert main(["batch", str(tmp_path), "--gap", "1", "--group-size", "3", "--plan"]) == 2
    assert "give one" in capsys.readouterr().err


def test_workers_are_memory_bounded_by_default(sim_folder, tmp_path, monkeypatch):
    """With --workers N > 1 each worker's address space is capped at the machine's memory
    divided by N (at least 1 GB) unless --worker-memory says otherwise."""
    import hdrcore.batch as batch
    from hdrcore.batch.runner import BatchRun

    folder, _ = sim_folder
    seen = []

    def fake_run(tasks, **kw):
        seen.append(kw["memory_limit"])
        return BatchRun(records=())

    monkeypatch.setattr(batch, "run_batch", fake_run)
    total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    for argv, want in (
        (["--workers", "2"], max(int(1e9), total // 2)),
        (["--workers", "2", "--worker-memory", "3"], int(3e9)),
        (["--workers", "1"], None),
    ):
        main(["batch", str(folder), "-o", str(tmp_path / "o"), "--quiet", *argv])
        assert seen[-1] == want, argv
