"""Path and upload checks: the inspector only reads files under its ``--root`` folder.

A path typed into the page is resolved (``..`` and symbolic links followed) and refused unless it
lies inside the root. Uploaded files are sniffed by content before anything reads them; names are
reduced to a safe base name so an upload can never write outside its staging folder.
"""

from __future__ import annotations

import re
import zipfile
from io import BytesIO
from pathlib import Path

from hdrcore.errors import InputError
from hdrcore.io import RAW_EXTENSIONS

__all__ = [
    "PathRefused",
    "resolve_under_root",
    "split_path_field",
    "safe_upload_name",
    "sniff_upload",
    "extract_zip_images",
    "IMAGE_KINDS",
]

IMAGE_KINDS = ("png", "jpeg", "tiff", "raw")
_IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".tif", ".tiff"}
# Largest archive the upload button accepts once extracted (a 24 MP 16-bit TIFF is ~150 MB).
MAX_EXTRACTED_BYTES = 2_000_000_000


class PathRefused(InputError):
    """A path lies outside the inspector's root folder."""


def resolve_under_root(text: str, root: Path) -> Path:
    """Resolve ``text`` (relative paths are taken from ``root``) and refuse it outside ``root``."""
    raw = text.strip().strip('"').strip("'")
    if not raw:
        raise InputError("empty path", expected="a file or folder under " + str(root))
    if "\x00" in raw:
        raise PathRefused("path contains a NUL character", found=repr(raw))
    root_r = Path(root).resolve()
    p = Path(raw).expanduser()
    if not p.is_absolute():
        p = root_r / p
    resolved = p.resolve()
    if resolved != root_r and not resolved.is_relative_to(root_r):
        raise PathRefused(
            "path is outside the folder this inspector may read",
            path=raw, expected=f"a path under {root_r} (see --root)",
        )
    return resolved


def split_path_field(text: str) -> list[str]:
    """Split the path field into paths: separated by ``;``, ``,`` or new lines."""
    return [part.strip() for part in re.split(r"[;,\n]", text) if part.strip()]


def safe_upload_name(name: str) -> str:
    """A base name with only letters, digits, ``.``, ``_`` and ``-`` (never empty, never hidden)."""
    base = Path(name.replace("\\", "/")).name
    cleaned = re.sub(r"[^A-Za-z0-9._-]+", "_", base).lstrip(".")
    return cleaned or "upload"


def sniff_upload(name: str, content: bytes) -> str | None:
    """Kind of an uploaded file from its first bytes: an image kind, ``"zip"`` or ``None``.

    RAW files are accepted by extension only when they also start like a TIFF container (DNG and
    most RAW formats) or carry a RAW extension LibRaw knows; everything else is refused.
    """
    head = content[:16]
    suffix = Path(name).suffix.lower()
    if head.startswith(b"\x89PNG\r\n\x1a\n"):
        return "png"
    if head.startswith(b"\xff\xd8\xff"):
        return "jpeg"
    if head.startswith(b"PK\x03\x04"):
        return "zip"
    is_tiff = head.startswith(b"II*\x00") or head.startswith(b"MM\x00*")
    if suffix in RAW_EXTENSIONS and len(content) > 1024:
        return "raw"
    if is_tiff:
        return "tiff"
    return None


def extract_zip_images(content: bytes, dest: Path) -> list[Path]:
    """Extract the image files of a zip archive into ``dest`` (flat, safe names); return them.

    Members that are not images by content are skipped; an exposure-times list
    (``exposure_times.txt``) is kept. Raises :class:`InputError` for a broken archive or one that
    would extract to more than ``MAX_EXTRACTED_BYTES``.
    """
    try:
        zf = zipfile.ZipFile(BytesIO(content))
    except zipfile.BadZipFile as exc:
        raise InputError("uploaded archive is not a valid zip file") from exc
    out: list[Path] = []
    with zf:
        total = sum(i.file_size for i in zf.infolist())
        if total > MAX_EXTRACTED_BYTES:
            raise InputError(
                "uploaded archive is too large once extracted",
                expected=f"at most {MAX_EXTRACTED_BYTES // 1_000_000} MB", found=f"{total} bytes",
            )
        for info in zf.infolist():
            if info.is_dir():
                continue
            name = safe_upload_name(info.filename)
            data = zf.read(info)
            if name.lower() in ("exposure_times.txt", "times.txt"):
                (dest / name.lower()).write_bytes(data)
                continue
            kind = sniff_upload(name, data)
            if kind is None or kind == "zip":
                continue
            target = dest / name
            target.write_bytes(data)
            out.append(target)
    return sorted(out)


def is_image_name(name: str) -> bool:
    suffix = Path(name).suffix.lower()
    return suffix in _IMAGE_SUFFIXES or suffix in RAW_EXTENSIONS
