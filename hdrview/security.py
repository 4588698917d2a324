"""Path and upload checks: the inspector only reads files under the folders it was given.

Every path the inspector opens goes through one :class:`RootResolver`: a typed path, each file
of a typed folder, a folder's exposure-times list, the frames and the times list of an upload
set (and so each member extracted from a zip), the demo bracket and the command line's files.
Each is resolved with ``..`` and symbolic links followed and refused unless the real file lies
inside an allowed folder (``--root``, the upload staging folder, the demo folder) or is a
command-line file; a link that points outside, a symbolic link loop or an unreadable folder is a
:class:`PathRefused` (an ``InputError``: the page shows it as a notification, never a traceback).
Uploaded files are sniffed by content before anything reads them; names are reduced to a safe
base name so an upload can never write outside its staging folder; zip members that are
symbolic links are skipped.
"""

from __future__ import annotations

import errno
import re
import stat
import zipfile
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path

from hdrcore.errors import InputError
from hdrcore.io import RAW_EXTENSIONS

__all__ = [
    "PathRefused",
    "RootResolver",
    "BracketInputs",
    "TIMES_FILES",
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


#: Exposure-time lists picked up automatically from a bracket's folder.
TIMES_FILES = ("exposure_times.txt", "times.txt")


def _real(p: Path, shown: str | Path) -> Path:
    """``p`` with every symbolic link and ``..`` resolved; a loop or an unreadable folder on the
    way is a :class:`PathRefused` naming ``shown``."""
    try:
        return p.resolve(strict=False)
    except RuntimeError as exc:  # Python < 3.13: "Symlink loop from ..."
        raise PathRefused("symbolic link loop", path=shown) from exc
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise PathRefused("symbolic link loop", path=shown) from exc
        raise PathRefused(f"cannot resolve path ({exc.strerror or exc})", path=shown) from exc


def _inside(p: Path, folder: Path) -> bool:
    return p == folder or p.is_relative_to(folder)


@dataclass(frozen=True)
class BracketInputs:
    """What one load reads: the frame files and the exposure-times list, all resolved."""

    files: tuple[Path, ...]
    times: Path | None = None


class RootResolver:
    """The one place that decides whether the inspector may read a path.

    ``root``: the folder the page may browse (``--root``); relative paths are taken from it.
    ``folders``: further folders whose files may be read (upload staging, the demo bracket);
    ``files``: single files the operator named on the command line.
    """

    def __init__(
        self,
        root: str | Path,
        *,
        folders: Iterable[str | Path] = (),
        files: Iterable[str | Path] = (),
    ) -> None:
        self.root = _real(Path(root), root)
        self._folders = [self.root]
        self._files: set[Path] = set()
        for f in folders:
            self.allow_folder(f)
        for f in files:
            self.allow_file(f)

    def allow_folder(self, folder: str | Path) -> None:
        real = _real(Path(folder), folder)
        if real not in self._folders:
            self._folders.append(real)

    def allow_file(self, file: str | Path) -> None:
        """A path the operator gave: a file, or a folder (then all of it)."""
        real = _real(Path(file), file)
        if real.is_dir():
            self.allow_folder(real)
            # The operator chose this folder: what its entries link to is chosen too.
            for child in Path(file).iterdir():
                try:
                    self._files.add(_real(child, child))
                except PathRefused:
                    continue
        else:
            self._files.add(real)

    def allowed(self, real: Path) -> bool:
        return real in self._files or any(_inside(real, f) for f in self._folders)

    def resolve(self, path: str | Path, *, shown: str | Path | None = None) -> Path:
        """The real path of ``path`` (typed text or a path; relative to the root) if allowed."""
        shown = path if shown is None else shown
        if isinstance(path, str):
            raw = path.strip().strip('"').strip("'")
            if not raw:
                raise InputError("empty path", expected="a file or folder under " + str(self.root))
            if "\x00" in raw:
                raise PathRefused("path contains a NUL character", found=repr(raw))
            p = Path(raw).expanduser()
        else:
            p = Path(path)
        if not p.is_absolute():
            p = self.root / p
        real = _real(p, shown)
        if not self.allowed(real):
            where = "" if str(real) == str(p) else f" (it leads to {real})"
            raise PathRefused(
                f"path is outside the folder this inspector may read{where}",
                path=shown,
                expected=f"a path under {self.root} (see --root)",
            )
        return real

    def bracket_inputs(self, paths: Sequence[str | Path]) -> BracketInputs:
        """Resolve and check every file one load will read.

        A folder gives its image files (sorted by name, as :func:`hdrcore.io.load_bracket`
        takes them) and its exposure-times list; each of them is checked on its own, so a
        folder inside the root whose frames link to files outside is refused, naming the link.
        """
        from hdrcore.io.bracket import IMAGE_EXTENSIONS, is_raw_path

        files: list[Path] = []
        times: Path | None = None
        for item in paths:
            real = self.resolve(item)
            if not real.exists():
                raise InputError("file or folder not found", path=item)
            if not real.is_dir():
                files.append(real)
                continue
            try:
                children = sorted(real.iterdir())
            except OSError as exc:
                raise PathRefused(f"cannot list folder ({exc.strerror or exc})", path=item) from exc
            found = 0
            for child in children:
                if child.name in TIMES_FILES and len(paths) == 1 and times is None:
                    times = self.resolve(child, shown=child)
                    if not times.is_file():
                        raise InputError("exposure-times list is not a file", path=child)
                    continue
                if not (child.suffix.lower() in IMAGE_EXTENSIONS or is_raw_path(child)):
                    continue
                real_child = self.resolve(child, shown=child)
                if real_child.is_file():
                    files.append(real_child)
                    found += 1
            if not found:
                raise InputError("folder holds no JPEG, PNG, TIFF or RAW files", path=item)
        return BracketInputs(tuple(files), times)


def resolve_under_root(text: str, root: Path) -> Path:
    """Resolve ``text`` (relative paths are taken from ``root``) and refuse it outside ``root``."""
    return RootResolver(root).resolve(text)


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


def extract_zip_images(
    content: bytes,
    dest: Path,
    *,
    members: Sequence[zipfile.ZipInfo] | None = None,
) -> list[Path]:
    """Extract the image files of a zip archive into ``dest`` (flat, safe names); return them.

    Members that are not images by content are skipped, and so are symbolic links (a zip can
    store one; it is never followed nor created); an exposure-times list
    (``exposure_times.txt``) is kept. ``members``: the already checked directory entries
    (:mod:`hdrview.uploads` checks them against its limits). Raises :class:`InputError` for a
    broken archive or one that would extract to more than ``MAX_EXTRACTED_BYTES``.
    """
    try:
        zf = zipfile.ZipFile(BytesIO(content))
    except (zipfile.BadZipFile, ValueError) as exc:
        raise InputError("uploaded archive is not a valid zip file") from exc
    out: list[Path] = []
    with zf:
        infos = list(members) if members is not None else zf.infolist()
        total = sum(i.file_size for i in infos)
        if total > MAX_EXTRACTED_BYTES:
            raise InputError(
                "uploaded archive is too large once extracted",
                expected=f"at most {MAX_EXTRACTED_BYTES // 1_000_000} MB",
                found=f"{total} bytes",
            )
        for info in infos:
            if info.is_dir() or stat.S_ISLNK(info.external_attr >> 16):
                continue
            name = safe_upload_name(info.filename)
            try:
                data = zf.read(info)
            except (zipfile.BadZipFile, OSError, EOFError, NotImplementedError) as exc:
                raise InputError(f"archive member {info.filename} cannot be read ({exc})") from exc
            if len(data) > info.file_size:
                raise InputError(f"archive member {info.filename} is larger than it declares")
            if name.lower() in TIMES_FILES:
                (dest / name.lower()).write_bytes(data)
                continue
            kind = sniff_upload(name, data)
            if kind is None or kind == "zip":
                continue
            target = dest / name
            target.write_bytes(data)
            out.append(target)
    return sorted(set(out))


def is_image_name(name: str) -> bool:
    suffix = Path(name).suffix.lower()
    return suffix in _IMAGE_SUFFIXES or suffix in RAW_EXTENSIONS
