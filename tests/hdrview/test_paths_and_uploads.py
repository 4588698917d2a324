"""Every path through one resolver, uploads with limits (issue 13, points 3-5).

Symbolic links out of the root (frames in a folder, a folder's times list), loops, zip members;
upload sets that recover from a bad file; limits checked before a byte is stored (a raw
WebSocket client declares a large file); a frame's pixels read from its header; the temporary
folder removed at exit, also on SIGTERM; a busy port and a non-loopback address refused.
"""

from __future__ import annotations

import io
import os
import signal
import socket
import struct
import subprocess
import sys
import time
import zipfile
import zlib
from pathlib import Path

import msgspec
import pytest
from websockets.sync.client import connect

from hdrview.app import InspectorApp, create_app, main
from hdrview.security import RootResolver
from hdrview.uploads import UploadLimits, remove_stale_work_dirs

from ._brackets import write_png_bracket


def _errors(app: InspectorApp) -> list[str]:
    return [f"{t}: {b}" for lvl, t, b in app.notifications if lvl == "error"]


@pytest.fixture
def outside(tmp_path: Path) -> Path:
    """A bracket and a secret next to (not under) the inspector's root."""
    out = tmp_path / "outside"
    write_png_bracket(out / "bracket")
    (out / "secret.txt").write_text("root:x:0:0:secret first line\n")
    return out


# -- point 3: one resolver --------------------------------------------------------------------


def test_folder_of_links_to_files_outside_the_root_is_refused(
    app: InspectorApp, bracket_root: Path, outside: Path
) -> None:
    linked = bracket_root / "linked"
    linked.mkdir()
    for p in sorted((outside / "bracket").glob("*.png")):
        (linked / p.name).symlink_to(p)
    assert not app.request_path("linked")
    err = _errors(app)[-1]
    assert "outside the folder this inspector may read" in err and "frame0.png" in err
    assert app.wait_idle(10) and app.session.bracket is None


def test_times_list_linking_outside_is_refused_and_never_shown(
    app: InspectorApp, bracket_root: Path, outside: Path
) -> None:
    b = bracket_root / "bracket"
    (b / "exposure_times.txt").unlink()
    (b / "exposure_times.txt").symlink_to(outside / "secret.txt")
    assert not app.request_path("bracket")
    err = _errors(app)[-1]
    assert "exposure_times.txt" in err and "outside" in err
    assert all("secret first line" not in e for e in _errors(app))
    assert app.session.bracket is None


@pytest.mark.parametrize("where", ["typed", "in folder", "times list"])
def test_symlink_loop_is_a_notification_not_a_traceback(
    app: InspectorApp, bracket_root: Path, where: str
) -> None:
    b = bracket_root / "bracket"
    if where == "typed":
        (bracket_root / "a").symlink_to(bracket_root / "b")
        (bracket_root / "b").symlink_to(bracket_root / "a")
        text = "a"
    elif where == "in folder":
        (b / "loop.png").symlink_to(b / "loop.png")
        text = "bracket"
    else:
        (b / "exposure_times.txt").unlink()
        (b / "exposure_times.txt").symlink_to(b / "exposure_times.txt")
        text = "bracket"
    assert not app.request_path(text)
    assert app.wait_idle(10)
    errs = _errors(app)
    assert len(errs) == 1 and "symbolic link loop" in errs[0]
    assert "Internal error" not in errs[0]


def test_links_inside_the_root_and_operator_files_load(
    bracket_root: Path, outside: Path, tmp_path: Path
) -> None:
    inside = bracket_root / "alias"
    inside.symlink_to(bracket_root / "bracket")
    r = RootResolver(bracket_root)
    got = r.bracket_inputs(["alias"])
    assert [p.name for p in got.files] == ["frame0.png", "frame1.png", "frame2.png"]
    assert got.times is not None and got.times.name == "exposure_times.txt"
    # A folder the operator named on the command line may hold links out of the root.
    linked = tmp_path / "cmdline"
    linked.mkdir()
    for p in sorted((outside / "bracket").iterdir()):
        (linked / p.name).symlink_to(p)
    r2 = RootResolver(bracket_root, files=[linked])
    assert len(r2.bracket_inputs([linked]).files) == 3
    with pytest.raises(Exception, match="outside"):
        r2.resolve(outside / "secret.txt")


def test_zip_member_that_is_a_symlink_is_skipped(app: InspectorApp, bracket_root: Path) -> None:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for p in sorted((bracket_root / "bracket").iterdir()):
            zf.write(p, p.name)
        link = zipfile.ZipInfo("evil.png")
        link.external_attr = 0o120777 << 16  # a symbolic link to /etc/passwd
        zf.writestr(link, "/etc/passwd")
    assert app.handle_upload("b.zip", buf.getvalue())
    assert app.wait_idle(60)
    assert app.session.bracket is not None and len(app.session.bracket) == 3
    assert not list(app.uploads.dir.rglob("evil.png"))


# -- point 4: uploads ---------------------------------------------------------------------------


def _png_declaring(width: int, height: int) -> bytes:
    """A tiny PNG whose header declares ``width`` x ``height`` (its pixel data is a stub)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data))
            + kind
            + data
            + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
        )

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", ihdr)
        + chunk(b"IDAT", zlib.compress(b"\x00" * 64))
        + chunk(b"IEND", b"")
    )


def test_upload_box_works_again_after_a_bad_upload(app: InspectorApp, bracket_root: Path) -> None:
    frames = sorted((bracket_root / "bracket").glob("*.png"))
    truncated = frames[0].read_bytes()[:200]
    assert app.handle_upload("broken.png", truncated)  # stored: one frame is not a bracket yet
    assert app.handle_upload(frames[1].name, frames[1].read_bytes())
    assert app.wait_idle(60)
    assert app.session.bracket is None and _errors(app)  # the set with the broken frame failed
    # The failure closed that set: the next two uploads make a bracket of their own.
    assert app.handle_upload(frames[1].name, frames[1].read_bytes())
    assert app.handle_upload(frames[2].name, frames[2].read_bytes())
    assert app.wait_idle(60)
    assert app.session.bracket is not None
    assert [f.name for f in app.session.bracket.frames] == ["frame1.png", "frame2.png"]


def test_a_refused_upload_closes_the_set(app: InspectorApp, bracket_root: Path) -> None:
    frames = sorted((bracket_root / "bracket").glob("*.png"))
    assert app.handle_upload(frames[0].name, frames[0].read_bytes())
    assert not app.handle_upload("notes.png", b"not an image at all")
    assert app.handle_upload(frames[1].name, frames[1].read_bytes())
    assert app.session.bracket is None  # frame0 belonged to the closed set
    assert app.handle_upload(frames[2].name, frames[2].read_bytes())
    assert app.wait_idle(60)
    assert [f.name for f in app.session.bracket.frames] == ["frame1.png", "frame2.png"]


def test_after_a_zip_a_single_upload_starts_a_new_set(
    app: InspectorApp, bracket_root: Path
) -> None:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for p in sorted((bracket_root / "bracket").iterdir()):
            zf.write(p, p.name)
    assert app.handle_upload("b.zip", buf.getvalue())
    assert app.wait_idle(60) and len(app.session.bracket) == 3
    frame = bracket_root / "bracket" / "frame0.png"
    assert app.handle_upload("extra.png", frame.read_bytes())
    assert app.wait_idle(10)
    assert len(app.session.bracket) == 3  # the zip's bracket is untouched
    assert "one more frame" in app.notifications[-1][2]


def test_frame_declaring_huge_size_is_refused_before_decoding(app: InspectorApp) -> None:
    big = _png_declaring(20000, 20000)
    assert len(big) < 200
    assert not app.handle_upload("bomb.png", big)
    err = _errors(app)[-1]
    assert "400.0 MP" in err and "20000x20000" in err and "--max-upload-pixels" in err
    assert not [p for p in app.uploads.dir.rglob("*.png")]


def test_zip_member_too_large_is_refused_from_the_directory(bracket_root: Path) -> None:
    import viser

    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    inspector = InspectorApp(
        server,
        root=bracket_root,
        demo_dir=None,
        limits=UploadLimits(file_bytes=50_000, total_bytes=80_000),
    )
    app = inspector.headless_view()
    try:
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
            zf.writestr("a.png", b"\x00" * 60_000)  # compresses to almost nothing
            zf.writestr("b.png", b"\x00" * 10)
        assert len(buf.getvalue()) < 2000
        assert not app.handle_upload("z.zip", buf.getvalue())
        assert "a.png is 0.1 MB once extracted" in _errors(app)[-1]
        assert not list(app.uploads.dir.rglob("*.png"))
    finally:
        inspector.stop()
        server.stop()


class RawPage:
    """A page as a raw WebSocket client: connects with the token, reports a camera (viser
    counts a page as connected from then on) and uploads as the page does
    (FileTransferStartUpload, then 512 kB parts)."""

    def __init__(self, app: InspectorApp) -> None:
        import viser

        assert app.guard is not None
        port = app.server.get_port()
        before = set(app.views)
        self.ws = connect(
            f"ws://127.0.0.1:{port}/?token={app.guard.token}",
            origin=f"http://127.0.0.1:{port}",
            subprotocols=[f"viser-v{viser.__version__}"],
            open_timeout=5,
            max_size=None,
        )
        self.ws.send(
            msgspec.msgpack.encode(
                {
                    "type": "ViewerCameraMessage",
                    "wxyz": [1.0, 0.0, 0.0, 0.0],
                    "position": [0.0, 0.0, 1.0],
                    "fov": 1.0,
                    "near": 0.01,
                    "far": 100.0,
                    "image_height": 600,
                    "image_width": 800,
                    "look_at": [0.0, 0.0, 0.0],
                    "up_direction": [0.0, 1.0, 0.0],
                }
            )
        )
        deadline = time.time() + 10
        while not set(app.views) - before and time.time() < deadline:
            time.sleep(0.02)
        (cid,) = set(app.views) - before
        self.view = app.views[cid]

    def upload(self, name: str, content: bytes, declared: int | None = None) -> None:
        chunk = 512 * 1024
        parts = [content[i : i + chunk] for i in range(0, len(content), chunk)]
        uuid = self.view.upload_button._impl.uuid
        self.ws.send(
            msgspec.msgpack.encode(
                {
                    "type": "FileTransferStartUpload",
                    "source_component_uuid": uuid,
                    "transfer_uuid": "t-" + name,
                    "filename": name,
                    "mime_type": "image/png",
                    "part_count": len(parts),
                    "size_bytes": len(content) if declared is None else declared,
                }
            )
        )
        for i, part in enumerate(parts):
            self.ws.send(
                msgspec.msgpack.encode(
                    {
                        "type": "FileTransferPart",
                        "source_component_uuid": uuid,
                        "transfer_uuid": "t-" + name,
                        "part_index": i,
                        "content": part,
                    }
                )
            )
        time.sleep(0.5)

    def close(self) -> None:
        self.ws.close()


@pytest.fixture
def served(bracket_root: Path):
    app = create_app(
        [],
        port=0,
        root=str(bracket_root),
        verbose=False,
        demo_dir=None,
        limits=UploadLimits(file_bytes=1_000_000, total_bytes=1_500_000),
    )
    try:
        yield app
    finally:
        app.stop()
        app.server.stop()


def test_too_large_upload_is_refused_before_it_is_stored(served: InspectorApp) -> None:
    page = RawPage(served)
    try:
        view = page.view
        page.upload("huge.png", b"\x89PNG\r\n\x1a\n" + b"\x00" * 1_200_000)
        err = _errors(view)[-1]
        assert "huge.png is 1.2 MB, more than the limit of 1 MB per file" in err
        assert not view.gui._current_file_upload_states  # no part was buffered
        assert not list(view.uploads.dir.rglob("*"))  # nothing stored
        # A client that declares less than it sends is dropped as well.
        page.upload("liar.png", b"\x89PNG\r\n\x1a\n" + b"\x00" * 900_000, declared=1000)
        assert not view.gui._current_file_upload_states
        assert not list(view.uploads.dir.rglob("*"))
    finally:
        page.close()


def test_a_normal_upload_still_arrives(served: InspectorApp, bracket_root: Path) -> None:
    page = RawPage(served)
    try:
        for p in sorted((bracket_root / "bracket").glob("*.png"))[:2]:
            page.upload(p.name, p.read_bytes())
        assert page.view.wait_idle(60)
        assert page.view.session.bracket is not None and len(page.view.session.bracket) == 2
    finally:
        page.close()


def test_two_pages_keep_their_own_state(served: InspectorApp, bracket_root: Path) -> None:
    """Each page has its own uploads, bracket, controls and notifications."""
    a, b = RawPage(served), RawPage(served)
    try:
        frames = sorted((bracket_root / "bracket").glob("*.png"))
        a.upload(frames[0].name, frames[0].read_bytes())
        b.upload(frames[1].name, frames[1].read_bytes())
        # One frame each: neither page has a bracket (they did not join one upload set).
        assert a.view.session.bracket is None and b.view.session.bracket is None
        assert a.view.uploads.dir != b.view.uploads.dir
        a.view.request_path("bracket")
        a.view.set_control("threshold", 0.3)
        assert a.view.wait_idle(60) and b.view.wait_idle(60)
        assert a.view.session.bracket is not None and b.view.session.bracket is None
        assert a.view.controls.threshold == 0.3 and b.view.controls.threshold is None
        assert any("Loaded" in t for _, t, _ in a.view.notifications)
        assert not any("Loaded" in t for _, t, _ in b.view.notifications)
        # A page that leaves takes its uploads with it; the other keeps working.
        b.close()
        deadline = time.time() + 10
        while b.view.uploads.dir.exists() and time.time() < deadline:
            time.sleep(0.05)
        assert not b.view.uploads.dir.exists() and a.view.session.bracket is not None
    finally:
        a.close()
        b.close()


def test_total_limit_counts_the_open_set(app, bracket_root: Path) -> None:
    frame = (bracket_root / "bracket" / "frame0.png").read_bytes()
    app.uploads.limits = UploadLimits(file_bytes=1_000_000, total_bytes=len(frame) + 100)
    assert app.uploads.refuse_transfer("a.png", len(frame)) is None
    assert app.handle_upload("a.png", frame)
    reason = app.uploads.refuse_transfer("b.png", 200) or ""
    assert "would bring this upload set" in reason and "New upload set" in reason
    app.new_upload_set()
    assert app.uploads.refuse_transfer("b.png", 200) is None


def test_work_dir_is_removed_at_stop_and_stale_ones_at_start(
    bracket_root: Path, tmp_path: Path
) -> None:
    import viser

    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    app = InspectorApp(server, root=bracket_root, demo_dir=None)
    frame = bracket_root / "bracket" / "frame0.png"
    app.headless_view().handle_upload(frame.name, frame.read_bytes())
    assert list(app.work_dir.rglob("frame0.png"))
    app.stop()
    server.stop()
    assert not app.work_dir.exists()
    # A folder left by a killed inspector (its process is gone) goes; a live one stays.
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale = tmp_path / f"hdrview-{dead.pid}-abc"
    live = tmp_path / f"hdrview-{os.getpid()}-def"
    stale.mkdir()
    live.mkdir()
    other = tmp_path / "hdrview-notapid"
    other.mkdir()
    assert remove_stale_work_dirs(tmp_path) == [stale]
    assert live.exists() and other.exists()


def test_sigterm_removes_uploads(bracket_root: Path, tmp_path: Path) -> None:
    """The program, stopped by SIGTERM with an upload staged, leaves no temporary folder."""
    code = (
        "import sys, hdrview.app as a\n"
        "orig = a.create_app\n"
        "frame = sys.argv[-1]\n"
        "def create(*args, **kw):\n"
        "    app = orig(*args, **kw)\n"
        "    app.headless_view().handle_upload('f.png', open(frame, 'rb').read())\n"
        "    print('WORK', app.work_dir, flush=True)\n"
        "    return app\n"
        "a.create_app = create\n"
        "sys.argv = sys.argv[:-1]\n"
        "sys.exit(a.main())\n"
    )
    env = dict(os.environ, TMPDIR=str(tmp_path))
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            code,
            "--port",
            "0",
            "--root",
            str(bracket_root),
            str(bracket_root / "bracket"),
            str(bracket_root / "bracket" / "frame0.png"),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        line = ""
        while not line.startswith("WORK"):  # viser's banner comes first
            line = proc.stdout.readline()
            assert line, proc.stderr.read()
        work = Path(line.split(None, 1)[1].strip())
        assert list(work.rglob("f.png"))
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)  # read the pipes to the end while it stops
        assert proc.returncode == 128 + signal.SIGTERM, err
    finally:
        if proc.poll() is None:
            proc.kill()
    assert not work.exists()
    assert not list(tmp_path.glob("hdrview-*"))


# -- point 5: start-up refusals ----------------------------------------------------------------


def test_busy_port_is_an_error(bracket_root: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        port = s.getsockname()[1]
        assert (
            main(["--port", str(port), "--root", str(bracket_root), str(bracket_root / "bracket")])
            == 2
        )
    err = capsys.readouterr().err
    assert f"port {port} on 127.0.0.1 is in use" in err and "--port 0" in err
    assert len(err.strip().splitlines()) == 1


def test_non_loopback_address_needs_allow_remote(
    bracket_root: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["--host", "0.0.0.0", "--port", "0", "--root", str(bracket_root)]) == 2
    err = capsys.readouterr().err
    assert "--allow-remote" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("opt", ["--max-upload-mb", "--max-upload-pixels"])
def test_negative_limits_are_refused(opt: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main([opt, "-1"]) == 2
    assert "must be 0 or more" in capsys.readouterr().err


def test_sigterm_to_another_thread_stops_the_program(bracket_root: Path, tmp_path: Path) -> None:
    """A SIGTERM the kernel hands to a background thread still stops the program at once: the
    main thread must not be asleep in one long time.sleep, which the signal does not interrupt."""
    code = (
        "import signal, sys, threading, hdrview.app as a\n"
        "def kill_from_a_thread():\n"
        "    sys.stdin.readline()\n"
        "    signal.pthread_kill(threading.get_ident(), signal.SIGTERM)\n"
        "threading.Thread(target=kill_from_a_thread, daemon=True).start()\n"
        "sys.exit(a.main())\n"
    )
    env = dict(os.environ, TMPDIR=str(tmp_path))
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            code,
            "--port",
            "0",
            "--root",
            str(bracket_root),
            str(bracket_root / "bracket"),
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        line = ""
        while "open http" not in line:
            line = proc.stderr.readline()
            assert line, proc.stdout.read()
        time.sleep(0.5)  # the main thread is asleep by now
        proc.stdin.write("go\n")
        proc.stdin.flush()
        _, err = proc.communicate(timeout=30)
        assert proc.returncode == 128 + signal.SIGTERM, err
    finally:
        if proc.poll() is None:
            proc.kill()
    assert not list(tmp_path.glob("hdrview-*"))
