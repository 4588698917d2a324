"""``hdrcore batch`` through fsspec URLs: ``memory://`` in this process and on a Dask
LocalCluster of threads (which shares it), ``file://`` on worker processes; the outputs equal
a run on plain paths; resume against the remote sidecars; the missing-library error, bad
URLs, and atomic uploads that leave nothing behind when they fail."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
import uuid
from pathlib import Path

import numpy as np
import pytest

from hdrcore.batch import (
    make_plan,
    read_index,
    read_shot,
    remote,
    run_batch,
    scan_shots,
    tasks_from_plan,
)
from hdrcore.batch.group import group_shots
from hdrcore.cli import main
from hdrcore.errors import InputError, OutputError
from hdrcore.io import read_exr

from .conftest import bad_frame

fsspec = pytest.importorskip("fsspec")
ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def mem():
    """A fresh ``memory://`` root (the memory filesystem is one per process), removed after."""
    fs = fsspec.filesystem("memory")
    root = f"/t{uuid.uuid4().hex[:10]}"
    yield fs, root
    if fs.exists(root):
        fs.rm(root, recursive=True)


def _upload(fs, folder: Path, root: str) -> str:
    for p in sorted(folder.iterdir()):
        fs.pipe(f"{root}/shots/{p.name}", p.read_bytes())
    return f"memory://{root}/shots"


def _index(fs, out: str) -> dict:
    return json.loads(fs.cat_file(f"{out}/index.json"))


def _merged(fs, out: str) -> set[str]:
    return {b["name"] for b in _index(fs, out)["brackets"] if b["merged"]}


def _remote_pixels(fs, out: str, tmp: Path) -> dict[str, np.ndarray]:
    px = {}
    for p in fs.ls(out, detail=False):
        if p.endswith(".exr"):
            local = tmp / Path(p).name
            local.write_bytes(fs.cat_file(p))
            px[local.stem] = read_exr(local)[0]
    return px


def _local_pixels(out: Path) -> dict[str, np.ndarray]:
    return {p.stem: read_exr(p)[0] for p in sorted(out.glob("*.exr"))}


def _same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys() and len(a) == 4
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])


@pytest.fixture(scope="module")
def local_run(sim_folder, tmp_path_factory) -> Path:
    """The reference: the same folder merged from plain paths."""
    folder, _ = sim_folder
    out = tmp_path_factory.mktemp("plain") / "out"
    assert main(["batch", str(folder), "-o", str(out), "--quiet", "--preview"]) == 1
    return out


def test_scan_through_a_url_reads_the_same_exif(sim_folder, mem):
    folder, sim = sim_folder
    fs, root = mem
    url = _upload(fs, folder, root)
    shots = scan_shots([url])
    local = scan_shots([folder])
    assert [s.name for s in shots] == [s.name for s in local]
    assert all(s.path.startswith("memory://") and s.folder.endswith("/shots") for s in shots)
    for a, b in zip(shots, local, strict=True):
        assert (
            a.time,
            a.subsec,
            a.exposure_time,
            a.iso,
            a.f_number,
            a.exposure_bias,
            a.camera,
            a.size,
        ) == (
            b.time,
            b.subsec,
            b.exposure_time,
            b.iso,
            b.f_number,
            b.exposure_bias,
            b.camera,
            b.size,
        )
        np.testing.assert_array_equal(a.thumbnail, b.thumbnail)
    one = read_shot(f"{url}/{sim[1].name}")
    assert one.exposure_bias == pytest.approx(float(sim[1].bias))
    assert [[Path(p).name for p in g.paths] for g in group_shots(shots)] == [
        [Path(p).name for p in g.paths] for g in group_shots(local)
    ]
    assert all(p.startswith(f"{url}/") for g in group_shots(shots) for p in g.paths)


def test_memory_urls_in_and_out_equal_plain_paths(sim_folder, mem, local_run, tmp_path, capsys):
    folder, sim = sim_folder
    fs, root = mem
    url = _upload(fs, folder, root)
    out = f"memory://{root}/out"
    assert main(["batch", url, "-o", out, "--quiet", "--preview"]) == 1
    err = capsys.readouterr().err
    doc = _index(fs, f"{root}/out")
    bad = [b for b in doc["brackets"] if b["status"] == "failed"]
    assert len(bad) == 1 and f"{url}/{bad_frame(sim)}" in bad[0]["files"]
    assert bad_frame(sim) in bad[0]["reason"] and "hdrcore-batch-" not in bad[0]["reason"]
    assert f"failed: {bad[0]['name']}" in err and "index: memory://" in err
    for b in doc["brackets"]:
        if b["status"] == "failed":
            continue
        assert b["outputs"]["exr"] == f"{out}/{b['name']}.exr"
        for ext in ("exr", "png"):
            assert fs.isfile(f"{root}/out/{b['name']}.{ext}")
        side = json.loads(fs.cat_file(f"{root}/out/{b['name']}.json"))
        assert side["batch"]["key"] == b["key"]
        assert sorted(f["path"] for f in side["report"]["frames"]) == sorted(b["files"])
        assert all(f["stamp"].startswith("created=") and f["size"] > 0 for f in side["frames"])
    assert not [p for p in fs.ls(f"{root}/out", detail=False) if Path(p).name.startswith(".")]
    # the same brackets, keys and pixels as from plain paths
    plain = json.loads((local_run / "index.json").read_text())
    assert [(b["name"], b["status"], b["key"]) for b in doc["brackets"]] == [
        (b["name"], b["status"], b["key"]) for b in plain["brackets"]
    ]
    _same(_remote_pixels(fs, f"{root}/out", tmp_path), _local_pixels(local_run))
    assert [r.name for r in read_index(out)] == [b["name"] for b in doc["brackets"]]


def test_resume_against_url_sidecars(sim_folder, mem):
    folder, sim = sim_folder
    fs, root = mem
    url = _upload(fs, folder, root)
    out = f"memory://{root}/out"
    args = ["batch", url, "-o", out, "--quiet"]
    tasks = tasks_from_plan(make_plan(group_shots(scan_shots([url]))), out, {})

    def stop_after_two(done, total, record):
        if done == 2:
            raise KeyboardInterrupt

    first = run_batch(tasks, progress=stop_after_two)
    assert first.interrupted and len(first.records) == 2
    fs.pipe(f"{root}/out/.{tasks[-1].name}.exr.0badc0de.tmp", b"left by a killed worker")
    again = run_batch(tasks)
    assert {r.name for r in again.records if r.merged} == {t.name for t in tasks} - {
        r.name for r in first.records
    }
    assert not [p for p in fs.ls(f"{root}/out", detail=False) if ".tmp" in p]
    assert run_batch(tasks).merged == 0
    assert main(args) == 1  # the command's own options: every bracket merged once more
    assert main(args) == 1 and _merged(fs, out) == set()
    # a frame written again with the same bytes: a new stamp, re-hashed, not merged again
    name = sim[0].name
    fs.pipe(f"{root}/shots/{name}", fs.cat_file(f"{root}/shots/{name}"))
    assert main(args) == 1 and _merged(fs, out) == set()
    # a frame changed: its bracket only
    target = next(b for b in _index(fs, out)["brackets"] if b["status"] != "failed")
    frame = target["files"][0]
    data = bytearray(fs.cat_file(frame))
    data[-10] ^= 0x01
    fs.pipe(frame, bytes(data))
    assert main(args) == 1 and _merged(fs, out) == {target["name"]}
    # an output removed: that bracket only
    fs.rm_file(f"{root}/out/{target['name']}.exr")
    assert main(args) == 1 and _merged(fs, out) == {target["name"]}


def test_dask_threads_share_memory_urls(sim_folder, mem, local_run, tmp_path):
    distributed = pytest.importorskip("distributed")
    folder, _ = sim_folder
    fs, root = mem
    url = _upload(fs, folder, root)
    out = f"memory://{root}/out"
    tasks = tasks_from_plan(make_plan(group_shots(scan_shots([url]))), out, {})
    with (
        distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        res = run_batch(tasks, client=client)
    assert res.merged == 5 and res.failed == 1
    _same(_remote_pixels(fs, f"{root}/out", tmp_path), _local_pixels(local_run))
    again = run_batch(tasks)
    assert again.merged == 0


def test_file_urls_on_worker_processes(sim_folder, local_run, tmp_path):
    folder, _ = sim_folder
    out = tmp_path / "out"
    res_code = main(["batch", folder.as_uri(), "-o", out.as_uri(), "--quiet", "--workers", "2"])
    assert res_code == 1
    doc = json.loads((out / "index.json").read_text())
    assert len({b["worker"] for b in doc["brackets"]}) == 2
    assert all(f.startswith("file://") for b in doc["brackets"] for f in b["files"])
    _same(_local_pixels(out), _local_pixels(local_run))
    assert not [p for p in out.iterdir() if p.name.startswith(".")]
    assert main(["batch", folder.as_uri(), "-o", out.as_uri(), "--quiet"]) == 1
    assert not [b for b in json.loads((out / "index.json").read_text())["brackets"] if b["merged"]]


def _missing_protocol() -> tuple[str, str]:
    for proto, pkg in (("s3", "s3fs"), ("gcs", "gcsfs"), ("abfs", "adlfs"), ("oci", "ocifs")):
        if importlib.util.find_spec(pkg) is None:
            return proto, pkg
    pytest.skip("every filesystem library tried is installed")


def test_missing_filesystem_library_is_one_line(tmp_path):
    proto, pkg = _missing_protocol()
    url = f"{proto}://some-bucket/shots"
    proc = subprocess.run(
        [sys.executable, "-m", "hdrcore", "batch", url, "-o", str(tmp_path / "o")],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr
    assert url in lines[0] and f"pip install {pkg}" in lines[0]
    assert not (tmp_path / "o").exists()


def test_bad_urls(sim_folder, tmp_path, capsys, mem):
    folder, _ = sim_folder
    fs, root = mem
    proto, pkg = _missing_protocol()
    assert main(["batch", str(folder), "-o", f"{proto}://b/out", "--quiet"]) == 2
    assert f"{proto}://b/out" in capsys.readouterr().err
    assert main(["batch", "nosuchfs://x/shots", "--plan"]) == 2
    assert "unknown filesystem 'nosuchfs'" in capsys.readouterr().err
    assert main(["batch", f"memory://{root}/nowhere", "--plan"]) == 2
    assert f"memory://{root}/nowhere: no such file or folder" in capsys.readouterr().err
    url = _upload(fs, folder, root)
    assert main(["batch", url, "-o", f"memory://{root}/o", "--workers", "2", "--quiet"]) == 2
    assert "memory:// exists in one process only" in capsys.readouterr().err
    with pytest.raises(InputError, match="pip install"):
        remote.check_url(f"{proto}://b")


def test_plan_file_with_urls(sim_folder, mem, tmp_path, capsys):
    folder, _ = sim_folder
    fs, root = mem
    url = _upload(fs, folder, root)
    assert main(["batch", url, "--plan", "--json"]) == 0
    plan = json.loads(capsys.readouterr().out)
    plan["brackets"] = plan["brackets"][:2]
    plan_file = tmp_path / "plan.json"
    plan_file.write_text(json.dumps(plan))
    out = f"memory://{root}/out"
    assert main(["batch", url, "--plan-file", str(plan_file), "-o", out, "--quiet"]) == 0
    assert _merged(fs, out) == {b["name"] for b in plan["brackets"]}
    plan["brackets"][0]["files"][0] = f"memory://{root}/shots/missing.jpg"
    plan_file.write_text(json.dumps(plan))
    assert main(["batch", url, "--plan-file", str(plan_file), "-o", out, "--quiet"]) == 2
    assert "bracket 1: no such file" in capsys.readouterr().err


def test_failed_upload_leaves_nothing(mem, tmp_path, monkeypatch):
    fs, root = mem
    src = tmp_path / "a.exr"
    src.write_bytes(b"x" * 1000)
    target = f"memory://{root}/out/a.exr"
    assert (
        remote.put_atomic(src, target) == target and fs.cat_file(f"{root}/out/a.exr") == b"x" * 1000
    )

    def broken_mv(self, *a, **k):
        raise OSError("connection reset")

    monkeypatch.setattr(type(fs), "mv", broken_mv)
    src.write_bytes(b"y" * 1000)
    with pytest.raises(OutputError, match="connection reset"):
        remote.put_atomic(src, target)
    assert fs.ls(f"{root}/out", detail=False) == [f"{root}/out/a.exr"]  # no .tmp left
    assert fs.cat_file(f"{root}/out/a.exr") == b"x" * 1000  # the old file, whole
    with pytest.raises(OutputError, match="input"):
        remote.put_atomic(src, target, inputs=[target])


def test_stamp_prefers_content_hashes():
    assert remote.stamp({"size": 5, "ETag": '"abc"', "LastModified": 3.0}) == {
        "size": 5,
        "stamp": 'ETag="abc"',
    }
    assert remote.stamp({"size": 5, "md5Hash": "q==", "updated": "t"})["stamp"] == "md5Hash=q=="
    assert remote.stamp({"size": 5, "mtime": 1.5})["stamp"] == "mtime=1.5"
    assert "stamp" not in remote.stamp({"size": 5})
    assert remote.is_url("s3://b/k") and remote.is_url("file:///x")
    assert not remote.is_url("/data/shots") and not remote.is_url("C:\\shots")


@pytest.fixture
def s3(monkeypatch):
    """A bucket on moto's S3 server (in this process, on a free port), through s3fs."""
    pytest.importorskip("s3fs")
    server = pytest.importorskip("moto.server")
    srv = server.ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    srv.start()
    host, port = srv.get_host_and_port()
    for k, v in (
        ("AWS_ACCESS_KEY_ID", "test"),
        ("AWS_SECRET_ACCESS_KEY", "test"),
        ("AWS_DEFAULT_REGION", "us-east-1"),
        ("AWS_ENDPOINT_URL", f"http://{host}:{port}"),
    ):
        monkeypatch.setenv(k, v)
    cls = fsspec.get_filesystem_class("s3")
    cls.clear_instance_cache()
    fs = fsspec.filesystem("s3")
    fs.mkdir("bkt")
    yield fs
    cls.clear_instance_cache()
    srv.stop()


def test_s3_through_s3fs(sim_folder, s3, local_run, tmp_path):
    """The object-store path: ETag stamps, uploads moved by copy + delete, resume."""
    folder, _ = sim_folder
    for p in sorted(folder.iterdir()):
        s3.pipe(f"bkt/shots/{p.name}", p.read_bytes())
    args = ["batch", "s3://bkt/shots", "-o", "s3://bkt/out", "--quiet", "--preview"]
    assert main(args) == 1
    s3.invalidate_cache()
    doc = json.loads(s3.cat_file("bkt/out/index.json"))
    assert sum(b["merged"] for b in doc["brackets"]) == 5
    side = json.loads(s3.cat_file(f"bkt/out/{doc['brackets'][0]['name']}.json"))
    assert all(f["stamp"].startswith('ETag="') for f in side["frames"])
    assert not [p for p in s3.ls("bkt/out", detail=False) if ".tmp" in p]
    px = {}
    for p in s3.ls("bkt/out", detail=False):
        if p.endswith(".exr"):
            s3.get_file(p, str(tmp_path / Path(p).name))
            px[Path(p).stem] = read_exr(tmp_path / Path(p).name)[0]
    _same(px, _local_pixels(local_run))
    assert main(args) == 1
    s3.invalidate_cache()
    assert not [b for b in json.loads(s3.cat_file("bkt/out/index.json"))["brackets"] if b["merged"]]
    target = next(b for b in doc["brackets"] if b["status"] != "failed")
    key = target["files"][0].removeprefix("s3://")
    data = bytearray(s3.cat_file(key))
    data[-10] ^= 0x01
    s3.pipe(key, bytes(data))
    assert main(args) == 1
    s3.invalidate_cache()
    assert {
        b["name"] for b in json.loads(s3.cat_file("bkt/out/index.json"))["brackets"] if b["merged"]
    } == {target["name"]}


def test_unreadable_remote_frame_fails_its_bracket(sim_folder, mem, monkeypatch):
    from hdrcore.batch import run_task, up_to_date

    folder, _ = sim_folder
    fs, root = mem
    url = _upload(fs, folder, root)
    task = tasks_from_plan(make_plan(group_shots(scan_shots([url]))), f"memory://{root}/o", {})[0]

    def denied(self, rpath, lpath, **kw):
        raise PermissionError("access denied")

    monkeypatch.setattr(type(fs), "get", denied)
    rec = run_task(task)
    assert rec.status == "failed" and not rec.key
    assert rec.reason.startswith(task.files[0]) and "PermissionError: access denied" in rec.reason
    assert fs.isfile(f"{root}/o/{task.name}.json") and up_to_date(task) is None  # tried again
