"""Uploaded brackets: limits checked before anything is stored, one staging folder per set.

The upload button takes one file at a time: single frames gather into the open *upload set*
(two or more make a bracket and load), a ``.zip`` is a set of its own. A set is closed, so the
next upload starts a new one, by a zip, by a refused upload, by a load that fails, and by
loading anything else (a path, the demo); "New upload set" closes it by hand.

Limits (settable with ``--max-upload-mb``, ``--max-upload-total-mb``, ``--max-upload-pixels``):

* a file's size is checked when its transfer *starts* (the size the browser declares, before a
  byte is buffered; parts beyond the declared size drop the transfer), against the per-file limit
  and against what the open set already holds (the total limit);
* a zip's members are checked the same way from the archive's directory before extraction;
* a frame's pixel count is read from its header (:func:`hdrcore.io.frame_pixels`, which decodes
  no pixel data) before the set is loaded, so a small file that declares 20000x20000 is refused
  without allocating its pixels.

Everything lives in one temporary folder per inspector process (``hdrview-<pid>-*``), removed
when the inspector stops (also on SIGTERM, SIGHUP and Ctrl-C); folders left by an inspector that
was killed outright (SIGKILL) are removed by the next one to start.
"""

from __future__ import annotations

import logging
import os
import shutil
import tempfile
import threading
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from typing import Any

from hdrcore.errors import InputError

from . import security

__all__ = [
    "UploadLimits",
    "UploadStore",
    "install_upload_limits",
    "make_work_dir",
    "remove_stale_work_dirs",
]

log = logging.getLogger(__name__)

MB = 1_000_000
WORK_PREFIX = "hdrview-"


@dataclass(frozen=True)
class UploadLimits:
    """Largest upload the inspector accepts (0: no limit)."""

    file_bytes: int = 256 * MB  # a 61 MP 16-bit TIFF is ~370 MB uncompressed, RAW files < 130 MB
    total_bytes: int = 1024 * MB  # one upload set
    frame_pixels: int = 64_000_000  # per frame; a 24 MP bracket of 8 frames uses ~3 GB here

    def describe(self) -> str:
        return (
            f"{_mb(self.file_bytes)} per file, {_mb(self.total_bytes)} per set, "
            f"{self.frame_pixels / 1e6:g} MP per frame"
        )


def _mb(n: int) -> str:
    return "no limit" if not n else f"{n / MB:g} MB"


# -- the inspector's temporary folder ------------------------------------------------------------


def make_work_dir() -> Path:
    """A fresh private temporary folder named after this process."""
    return Path(tempfile.mkdtemp(prefix=f"{WORK_PREFIX}{os.getpid()}-"))


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def remove_stale_work_dirs(parent: str | Path | None = None) -> list[Path]:
    """Remove this user's ``hdrview-<pid>-*`` folders whose process is gone; return them."""
    parent = Path(parent or tempfile.gettempdir())
    removed: list[Path] = []
    try:
        entries = list(parent.iterdir())
    except OSError:
        return removed
    uid = os.getuid() if hasattr(os, "getuid") else None
    for p in entries:
        name = p.name
        if not name.startswith(WORK_PREFIX):
            continue
        pid_text = name[len(WORK_PREFIX) :].split("-", 1)[0]
        if not pid_text.isdigit():
            continue
        try:
            st = p.lstat()
        except OSError:
            continue
        if not p.is_dir() or p.is_symlink() or (uid is not None and st.st_uid != uid):
            continue
        if int(pid_text) == os.getpid() or _alive(int(pid_text)):
            continue
        shutil.rmtree(p, ignore_errors=True)
        removed.append(p)
    return removed


# -- upload sets ----------------------------------------------------------------------------------


class UploadStore:
    """The upload sets of one inspector, staged under ``work_dir/uploads``."""

    def __init__(self, work_dir: Path, limits: UploadLimits | None = None) -> None:
        self.dir = Path(work_dir) / "uploads"
        self.dir.mkdir(parents=True, exist_ok=True)
        self.limits = limits or UploadLimits()
        self._lock = threading.Lock()
        self._count = 0
        self._open: Path | None = None  # the set single frames join

    # The size check a transfer gets before its first byte is kept.
    def refuse_transfer(self, name: str, size: int) -> str | None:
        """Why an upload of ``size`` bytes may not start (``None``: it may)."""
        lim = self.limits
        if size < 0:
            return f"{name}: the browser declared a negative size"
        if lim.file_bytes and size > lim.file_bytes:
            return (
                f"{name} is {size / MB:.1f} MB, more than the limit of "
                f"{_mb(lim.file_bytes)} per file (--max-upload-mb)"
            )
        if lim.total_bytes and not name.lower().endswith(".zip"):
            held = self.open_set_bytes()
            if held + size > lim.total_bytes:
                return (
                    f"{name} ({size / MB:.1f} MB) would bring this upload set to "
                    f"{(held + size) / MB:.1f} MB, more than the limit of "
                    f"{_mb(lim.total_bytes)} (--max-upload-total-mb); "
                    f"press New upload set to start again"
                )
        return None

    def open_set_bytes(self) -> int:
        with self._lock:
            d = self._open
        if d is None or not d.is_dir():
            return 0
        return sum(p.stat().st_size for p in d.iterdir() if p.is_file())

    def close_set(self) -> None:
        """The next single frame starts a new set (the files of this one stay until exit or
        until a newer set replaces them)."""
        with self._lock:
            self._open = None

    def _new_set(self) -> Path:
        with self._lock:
            self._count += 1
            d = self.dir / f"set{self._count}"
            d.mkdir(parents=True)
            # Older sets are not needed once a new one starts (only the latest can be loaded).
            for old in self.dir.iterdir():
                if old != d and old.name.startswith("set"):
                    shutil.rmtree(old, ignore_errors=True)
            return d

    def add_frame(self, name: str, content: bytes) -> list[Path]:
        """Store one uploaded frame in the open set; return the set's frames (checked)."""
        kind = security.sniff_upload(name, content)
        if kind is None or kind == "zip":
            raise InputError(
                "uploaded file is not an image",
                path=security.safe_upload_name(name),
                expected="PNG, JPEG, TIFF, a camera RAW file or a .zip of them",
            )
        reason = self.refuse_transfer(name, len(content))
        if reason:
            raise InputError(reason)
        with self._lock:
            d = self._open
        if d is None:
            d = self._new_set()
            with self._lock:
                self._open = d
        target = d / security.safe_upload_name(name)
        target.write_bytes(content)
        try:
            self.check_pixels(target, shown=name)
        except InputError:
            target.unlink(missing_ok=True)
            raise
        return sorted(p for p in d.iterdir() if security.is_image_name(p.name))

    def add_zip(self, name: str, content: bytes) -> Path:
        """Extract a zipped bracket into a set of its own (closing the open set)."""
        self.close_set()
        members = _zip_members(name, content, self.limits)
        d = self._new_set()
        images = security.extract_zip_images(content, d, members=members)
        if len(images) < 2:
            raise InputError(
                "the archive holds fewer than two images",
                path=name,
                found=f"{len(images)} image(s)",
            )
        for p in images:
            self.check_pixels(p, shown=f"{name}: {p.name}")
        return d

    def check_pixels(self, path: Path, *, shown: str | Path) -> None:
        limit = self.limits.frame_pixels
        if not limit:
            return
        from hdrcore.io import frame_pixels

        try:
            w, h = frame_pixels(path)
        except InputError:
            return  # not readable as an image header: the loader gives the real error
        if w * h > limit:
            raise InputError(
                f"frame is {w * h / 1e6:.1f} MP ({w}x{h}), more than the upload limit of "
                f"{limit / 1e6:g} MP (--max-upload-pixels)",
                path=shown,
            )

    def remove(self) -> None:
        shutil.rmtree(self.dir, ignore_errors=True)


def _zip_members(name: str, content: bytes, limits: UploadLimits) -> list[zipfile.ZipInfo]:
    """The archive's members, checked against the limits from its directory (nothing extracted)."""
    try:
        with zipfile.ZipFile(BytesIO(content)) as zf:
            infos = [i for i in zf.infolist() if not i.is_dir()]
    except (zipfile.BadZipFile, ValueError) as exc:
        raise InputError("uploaded archive is not a valid zip file", path=name) from exc
    total = 0
    for info in infos:
        if limits.file_bytes and info.file_size > limits.file_bytes:
            raise InputError(
                f"archive member {info.filename} is {info.file_size / MB:.1f} MB once extracted, "
                f"more than the limit of {_mb(limits.file_bytes)} per file (--max-upload-mb)",
                path=name,
            )
        total += info.file_size
    cap = limits.total_bytes or security.MAX_EXTRACTED_BYTES
    if total > cap:
        raise InputError(
            f"archive is {total / MB:.1f} MB once extracted, more than the limit of "
            f"{_mb(cap)} per set (--max-upload-total-mb)",
            path=name,
        )
    return infos


# -- the transfer hook --------------------------------------------------------------------------


def install_upload_limits(
    gui: Any,
    server: Any,
    button: Any,
    refuse: Callable[[str, int], str | None],
    on_refused: Callable[[Any, str], None],
) -> None:
    """Check each upload of ``button`` when its transfer starts, before viser buffers it.

    ``gui``: the GUI the upload button belongs to (a page's ``client.gui``, or the server's).
    viser registers its own handler for the ``FileTransferStartUpload`` message; ours runs
    instead (installed once per GUI, routing each transfer to its button's checks): a refused
    transfer is never registered, so its parts are dropped as they arrive (nothing is stored),
    the page's transfer is ended with a final acknowledgement and its progress toast hidden,
    and ``on_refused(client, reason)`` tells the user. A transfer whose parts add up to more
    than it declared is dropped as well.
    """
    routes = getattr(gui, "_hdrview_upload_routes", None)
    if routes is None:
        routes = {}
        gui._hdrview_upload_routes = routes
        _install_handlers(gui, server, routes)
    routes[button._impl.uuid] = (refuse, on_refused)


def _install_handlers(gui: Any, server: Any, routes: dict) -> None:
    from viser import _messages

    ws = gui._websock_interface
    start_msg, part_msg = _messages.FileTransferStartUpload, _messages.FileTransferPart
    viser_start = gui._handle_file_transfer_start
    viser_part = gui._handle_file_transfer_part

    def start(client_id: Any, message: Any) -> None:
        route = routes.get(message.source_component_uuid)
        if route is None:
            viser_start(client_id, message)  # not an upload we check (viser ignores unknowns)
            return
        refuse, on_refused = route
        reason = refuse(message.filename, int(message.size_bytes))
        if reason is None:
            viser_start(client_id, message)
            return
        log.warning("upload refused: %s", reason)
        client = server.get_clients().get(client_id)
        if client is not None:
            try:
                # End the page's transfer (so its upload button is free again), then hide the
                # progress toast, which would otherwise say "File uploaded successfully".
                conn = client._websock_connection
                conn.queue_message(
                    _messages.FileTransferPartAck(
                        source_component_uuid=message.source_component_uuid,
                        transfer_uuid=message.transfer_uuid,
                        transferred_bytes=int(message.size_bytes),
                        total_bytes=int(message.size_bytes),
                    )
                )
                conn.queue_message(
                    _messages.RemoveNotificationMessage(uuid="upload-" + message.transfer_uuid)
                )
            except Exception:  # noqa: BLE001 -- a page that went away
                log.debug("closing the refused upload's progress failed", exc_info=True)
        on_refused(client, reason)

    def part(client_id: Any, message: Any) -> None:
        state = gui._current_file_upload_states.get(message.transfer_uuid)
        if state is not None and (
            state["transferred_bytes"] + len(message.content) > state["total_bytes"]
        ):
            gui._current_file_upload_states.pop(message.transfer_uuid, None)
            log.warning("upload %r dropped: more bytes than declared", state["filename"])
            return
        viser_part(client_id, message)

    ws.unregister_handler(start_msg, viser_start)
    ws.register_handler(start_msg, start)
    ws.unregister_handler(part_msg, viser_part)
    ws.register_handler(part_msg, part)
