"""Batch inputs and outputs behind fsspec URLs (``s3://``, ``gcs://``, ``memory://``,
``file://``, ...); plain paths never come here and work as they always did.

* **Reading.** Folders are listed through the filesystem (:func:`list_images`). Every decoder
  of :mod:`hdrcore.io` takes a path (Pillow, LibRaw, the EXIF reader), so a remote frame is
  copied byte for byte to a local temporary file named as the original (:func:`stage`): its
  EXIF is intact, and the copy is removed when the bracket ends. Several frames are fetched in
  one call (concurrently on the asynchronous filesystems: s3fs, gcsfs, adlfs, http).
* **Writing.** :func:`put_atomic` uploads to a hidden temporary name in the output folder
  (``.NAME.exr.<hex>.tmp``), then moves it onto the final name. What that move gives depends
  on the filesystem (:func:`atomicity`): a ``rename`` on ``file://`` (and SFTP) is atomic, so
  a reader sees the old file or the new one; object stores (S3, GCS, Azure) have no rename:
  fsspec copies server-side then deletes, and since an object store shows an object only once
  it is whole, the final name still never holds a partial file; a crash between copy and
  delete leaves a ``.tmp`` object that the next run removes. ``memory://`` moves a dict entry.
* **Resume.** A remote frame's identity is its size and the cheapest stamp the filesystem's
  listing gives (:data:`STAMP_FIELDS`, first found: S3's ``ETag``, GCS's ``md5Hash``, Azure's
  ``etag``, else a modification or creation time); when both match the sidecar's, its SHA-256
  is taken from the sidecar, else the frame is read again and hashed, as for local files.
* **Errors.** A URL whose filesystem library is missing, an unknown protocol or a folder that
  does not exist is an :class:`~hdrcore.errors.InputError` naming the URL (and the package to
  install), raised before any work.
"""

from __future__ import annotations

import hashlib
import os
import posixpath
import re
import uuid
from collections.abc import Iterable, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

from ..errors import InputError, OutputError

__all__ = [
    "STAMP_FIELDS",
    "is_url",
    "filesystem",
    "check_url",
    "join",
    "parent",
    "basename",
    "list_images",
    "info_of",
    "stamp",
    "digest",
    "stage",
    "put_atomic",
    "write_text_atomic",
    "read_text",
    "listing",
    "remove",
    "same_folder",
    "atomicity",
    "process_local",
    "makedirs",
    "Infos",
]

#: Fields of a filesystem's listing that change when a file's content does, in the order
#: tried: content hashes first (S3 ETag, GCS md5Hash/crc32c, Azure etag), then times.
STAMP_FIELDS = (
    "ETag",
    "etag",
    "md5Hash",
    "crc32c",
    "content_md5",
    "checksum",
    "mtime",
    "LastModified",
    "last_modified",
    "updated",
    "modified",
    "created",
)

_PROTOCOL = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]+)://")
_CHUNK = 1 << 22


def is_url(text: str | os.PathLike) -> bool:
    """``proto://...`` (a protocol of two letters or more: ``C:\\`` stays a path) or a chained
    fsspec URL (``simplecache::s3://...``)."""
    s = os.fspath(text)
    return isinstance(s, str) and (bool(_PROTOCOL.match(s)) or "::" in s and "://" in s)


def _protocol(url: str) -> str:
    m = _PROTOCOL.match(url.split("::")[0])
    return m.group(1) if m else url.split("://")[0]


def _package_for(protocol: str, exc: ImportError) -> str:
    cause = exc.__cause__ or exc
    name = getattr(cause, "name", None)
    if name:
        return name.split(".")[0]
    from fsspec.registry import known_implementations

    cls = known_implementations.get(protocol, {}).get("class", "")
    return cls.split(".")[0] or protocol


def filesystem(url: str) -> tuple[Any, str]:
    """``(fsspec filesystem, path within it)`` of a URL; a clear :class:`InputError` when the
    protocol is unknown or its library is not installed (``pip install s3fs``)."""
    try:
        import fsspec
    except ImportError:
        raise InputError(
            "reading URLs needs the Python package fsspec (pip install fsspec)", path=url
        ) from None
    proto = _protocol(url)
    try:
        fsspec.get_filesystem_class(proto)
        return fsspec.core.url_to_fs(url)
    except ImportError as exc:
        pkg = _package_for(proto, exc)
        raise InputError(
            f"the {proto}:// filesystem needs the Python package {pkg}, which is "
            f"not installed (pip install {pkg})",
            path=url,
        ) from None
    except ValueError as exc:
        if "Protocol not known" in str(exc):
            from fsspec.registry import known_implementations

            raise InputError(
                f"unknown filesystem {proto!r} in this URL",
                path=url,
                expected="a protocol fsspec knows (s3, gcs, az, memory, file, "
                f"... {len(known_implementations)} in all)",
            ) from None
        raise InputError(f"not a usable URL ({exc})", path=url) from None
    except Exception as exc:  # credentials, a malformed bucket name, ...
        raise InputError(f"cannot open this URL ({type(exc).__name__}: {exc})", path=url) from None


def check_url(url: str) -> None:
    """Fail now (one line, the URL and what to install) rather than in every worker."""
    filesystem(url)


def process_local(url: str) -> bool:
    """Whether a URL's files exist in this process only (``memory://``)."""
    return _protocol(url) == "memory"


def join(folder: str, name: str) -> str:
    return folder.rstrip("/") + "/" + name


def parent(url: str) -> str:
    head, _, _ = url.rstrip("/").rpartition("/")
    return head


def basename(url: str) -> str:
    return url.rstrip("/").rpartition("/")[2]


def same_folder(a: str, b: str) -> bool:
    """Two URLs name one folder (same filesystem, same path once normalised)."""
    try:
        fa, pa = filesystem(a)
        fb, pb = filesystem(b)
    except InputError:
        return False
    return type(fa) is type(fb) and pa.rstrip("/") == pb.rstrip("/")


def _fresh(fs: Any, path: str) -> None:
    """Forget what this process's filesystem object listed before (s3fs and gcsfs keep
    listings): other processes may have written since."""
    try:
        fs.invalidate_cache(path)
    except Exception:  # noqa: BLE001 - a filesystem without a listings cache
        pass


def _hidden(rel: str) -> bool:
    return any(part.startswith(".") for part in rel.split("/") if part)


def list_images(url: str, *, recursive: bool, is_image) -> list[str]:  # noqa: ANN001
    """The image files of a URL (a file, or a folder listed; sub-folders with ``recursive``),
    as URLs, hidden names (``.name``, in any sub-folder) left out."""
    fs, root = filesystem(url)
    _fresh(fs, root)
    try:
        info = fs.info(root)
    except FileNotFoundError:
        raise InputError("no such file or folder", path=url) from None
    except Exception as exc:
        raise InputError(f"cannot read this URL ({type(exc).__name__}: {exc})", path=url) from None
    if info.get("type") != "directory":
        return [url]
    try:
        found = fs.find(root, maxdepth=None if recursive else 1, detail=False)
    except Exception as exc:
        raise InputError(
            f"cannot list this folder ({type(exc).__name__}: {exc})", path=url
        ) from None
    base = root.rstrip("/")
    out = []
    for p in found:
        rel = p[len(base) :] if p.startswith(base) else posixpath.basename(p)
        if not _hidden(rel) and is_image(Path(posixpath.basename(p))):
            out.append(fs.unstrip_protocol(p))
    return out


def _stamp_value(v: Any) -> str:
    if isinstance(v, datetime):
        return repr(v.timestamp())
    return repr(v) if isinstance(v, float) else str(v)


def stamp(info: dict[str, Any]) -> dict[str, Any]:
    """``{"size": ..., "stamp": "ETag=..."}`` from a listing entry (:data:`STAMP_FIELDS`)."""
    out: dict[str, Any] = {"size": info.get("size")}
    for k in STAMP_FIELDS:
        if info.get(k) not in (None, ""):
            out["stamp"] = f"{k}={_stamp_value(info[k])}"
            break
    return out


class Infos:
    """Listing entries of remote files, one listing per folder (one request for a bracket's
    frames instead of one per frame)."""

    def __init__(self) -> None:
        self._folders: dict[str, dict[str, dict[str, Any]]] = {}

    def __call__(self, url: str) -> dict[str, Any] | None:
        folder = parent(url)
        if folder not in self._folders:
            try:
                fs, path = filesystem(folder)
                _fresh(fs, path)
                self._folders[folder] = {
                    posixpath.basename(e["name"].rstrip("/")): e for e in fs.ls(path, detail=True)
                }
            except Exception:  # noqa: BLE001 - a folder that cannot be listed: no entries
                self._folders[folder] = {}
        return self._folders[folder].get(basename(url))


def info_of(url: str) -> dict[str, Any] | None:
    """One file's listing entry, ``None`` if it is missing or unreadable."""
    try:
        fs, path = filesystem(url)
        _fresh(fs, path)
        return fs.info(path)
    except Exception:  # noqa: BLE001
        return None


def digest(url: str) -> str:
    """SHA-256 of a remote file's bytes (hex), read in 4 MB blocks."""
    fs, path = filesystem(url)
    h = hashlib.sha256()
    with fs.open(path, "rb") as fh:
        for block in iter(lambda: fh.read(_CHUNK), b""):
            h.update(block)
    return h.hexdigest()


def stage(urls: Sequence[str], folder: str | os.PathLike) -> list[Path]:
    """Copy remote files into a local folder, byte for byte, keeping their names (in numbered
    sub-folders when two share one); one ``get`` per filesystem (concurrent where the
    filesystem is asynchronous). Returns the local paths, in order."""
    root = Path(folder)
    names = [basename(u) for u in urls]
    clash = len(set(names)) < len(names)
    local = [root / (f"{k}/{n}" if clash else n) for k, n in enumerate(names)]
    by_fs: dict[int, tuple[Any, list[str], list[str]]] = {}
    for u, lp in zip(urls, local, strict=True):
        lp.parent.mkdir(parents=True, exist_ok=True)
        fs, path = filesystem(u)
        by_fs.setdefault(id(fs), (fs, [], []))
        by_fs[id(fs)][1].append(path)
        by_fs[id(fs)][2].append(str(lp))
    for fs, rpaths, lpaths in by_fs.values():
        try:
            fs.get(rpaths, lpaths)
        except FileNotFoundError as exc:
            missing = next(
                (u for u, lp in zip(urls, local, strict=True) if not lp.is_file()), str(exc)
            )
            raise InputError("no such file", path=missing) from None
        except Exception as exc:  # network, permissions, credentials: name the file
            first = next(
                (u for u, lp in zip(urls, local, strict=True) if not lp.is_file()), urls[0]
            )
            raise InputError(
                f"cannot read this file ({type(exc).__name__}: {exc})", path=first
            ) from None
    for u, lp in zip(urls, local, strict=True):
        if not lp.is_file():
            raise InputError("could not be read", path=u)
    return local


def read_text(url: str) -> str:
    fs, path = filesystem(url)
    return fs.cat_file(path).decode()


def listing(folder: str) -> set[str] | None:
    """Names in a remote folder (one request), ``None`` if it cannot be listed."""
    try:
        fs, path = filesystem(folder)
        _fresh(fs, path)
        return {posixpath.basename(p.rstrip("/")) for p in fs.ls(path, detail=False)}
    except Exception:  # noqa: BLE001 - a missing folder: nothing in it
        return None


def remove(url: str) -> None:
    fs, path = filesystem(url)
    fs.rm_file(path)


def atomicity(url: str) -> str:
    """What :func:`put_atomic` gives on this URL's filesystem (for the report and docs)."""
    proto = _protocol(url)
    if proto in ("file", "local", "sftp", "ssh"):
        return "rename: atomic (old file or new one, never part of one)"
    if proto == "memory":
        return "dict entry moved: atomic within this process"
    return (
        "object store: copy then delete; an object appears only whole, so the final name "
        "never holds a partial file; a crash may leave a .tmp object (removed next run)"
    )


def put_atomic(local: str | os.PathLike, url: str, inputs: Iterable[str] = ()) -> str:
    """Upload a local file to ``url``: to a hidden temporary name in the same folder, then
    moved onto ``url`` (see :func:`atomicity`). Refuses to replace one of ``inputs``."""
    if url in set(inputs):
        raise OutputError("refusing to overwrite an input file", path=url)
    fs, path = filesystem(url)
    head, _, name = path.rstrip("/").rpartition("/")
    tmp = f"{head}/.{name}.{uuid.uuid4().hex[:8]}.tmp"
    try:
        fs.put_file(str(local), tmp)
        fs.mv(tmp, path)
    except BaseException as exc:
        try:
            fs.rm_file(tmp)
        except Exception:  # noqa: BLE001 - it may never have been written
            pass
        if isinstance(exc, Exception):
            raise OutputError(
                f"cannot write the output ({type(exc).__name__}: {exc})", path=url
            ) from None
        raise
    return url


def write_text_atomic(url: str, text: str) -> str:
    """:func:`put_atomic` of a text (the sidecars and the index)."""
    import tempfile

    with tempfile.TemporaryDirectory(prefix="hdrcore-batch-") as d:
        p = Path(d) / basename(url)
        p.write_text(text)
        return put_atomic(p, url)


def makedirs(url: str) -> None:
    """Create a remote output folder (a no-op on object stores, which have none)."""
    fs, path = filesystem(url)
    try:
        if fs.isfile(path):
            raise OutputError("the output is not a folder", path=url)
        fs.makedirs(path, exist_ok=True)
    except OutputError:
        raise
    except Exception as exc:
        raise OutputError(
            f"cannot create the output folder ({type(exc).__name__}: {exc})", path=url
        ) from None
