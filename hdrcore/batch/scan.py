"""Finding the images of a batch and reading what groups them, from headers only.

For each file: the capture time (with ``SubSecTimeOriginal`` where the camera writes it), the
exposure time, ISO, f-number and exposure bias, the camera and the stored size
(:func:`hdrcore.io.read_exif`, :func:`hdrcore.io.frame_pixels`; LibRaw's header fields for a
RAW file without TIFF EXIF: no pixel is decoded), and a tiny
grey thumbnail for the similarity tie-breaker (JPEG decoded at 1/8 scale by libjpeg's DCT
scaling; RAW files have none).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from datetime import datetime
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io import frame_pixels, is_raw_path, read_exif
from ..io.bracket import IMAGE_EXTENSIONS
from . import remote

__all__ = ["Shot", "find_images", "scan_shots", "read_shot", "read_shots", "thumbnail_similarity"]

#: Side of the grey thumbnail kept per shot (pixels).
THUMB_SIDE = 24


@dataclass(frozen=True, eq=False)
class Shot:
    """One image file and the signals the grouping reads. ``None``: the file does not say.

    ``time`` is the capture time in seconds (POSIX, local clock, subseconds included where the
    file has them); ``exposure_ev`` is ``log2(t x ISO/100 / N^2)`` (higher is brighter), from
    whatever of time, ISO and f-number the file gives (the time is required).
    """

    path: str
    folder: str
    time: float | None = None
    subsec: bool = False
    exposure_time: float | None = None
    iso: float | None = None
    f_number: float | None = None
    exposure_bias: float | None = None
    camera: str | None = None
    size: tuple[int, int] | None = None
    thumbnail: np.ndarray | None = None

    @property
    def name(self) -> str:
        return Path(self.path).name

    @property
    def exposure_ev(self) -> float | None:
        if self.exposure_time is None or self.exposure_time <= 0:
            return None
        ev = math.log2(self.exposure_time)
        if self.iso:
            ev += math.log2(self.iso / 100.0)
        if self.f_number:
            ev -= 2.0 * math.log2(self.f_number)
        return ev

    @property
    def stream(self) -> tuple:
        """Shots of one stream may be one bracket: same folder, camera and size."""
        return (self.folder, self.camera or "", self.size or (0, 0))

    def to_json(self) -> dict:
        return {
            "path": self.path,
            "time": self.time,
            "exposure_time": self.exposure_time,
            "iso": self.iso,
            "f_number": self.f_number,
            "exposure_bias": self.exposure_bias,
            "exposure_ev": self.exposure_ev,
            "camera": self.camera,
            "size": None if self.size is None else list(self.size),
        }


def _is_image(p: Path) -> bool:
    return p.suffix.lower() in IMAGE_EXTENSIONS or is_raw_path(p)


def _folder_and_name(f: Path | str) -> tuple[str, str]:
    if isinstance(f, str):
        return remote.parent(f), remote.basename(f)
    return str(f.parent), f.name


def find_images(paths: list[str | os.PathLike], *, recursive: bool = False) -> list[Path | str]:
    """The image files named (files as given, folders listed; sub-folders with ``recursive``),
    absolute, hidden files (``.name``) left out, sorted by folder then name. fsspec URLs
    (``s3://bucket/shots``) are listed through their filesystem and given back as URLs
    (:mod:`hdrcore.batch.remote`); paths as ``Path``."""
    out: list[Path | str] = []
    for item in paths:
        if remote.is_url(item):
            out.extend(remote.list_images(os.fspath(item), recursive=recursive, is_image=_is_image))
            continue
        p = Path(item)
        if p.is_dir():
            walker = os.walk(p) if recursive else [(str(p), [], os.listdir(p))]
            for root, dirs, files in walker:
                dirs[:] = sorted(d for d in dirs if not d.startswith("."))
                for f in files:
                    c = Path(root) / f
                    if not f.startswith(".") and _is_image(c) and c.is_file():
                        out.append(c.absolute())
        elif p.is_file():
            out.append(p.absolute())
        else:
            raise InputError("no such file or folder", path=p)
    out = sorted(set(out), key=_folder_and_name)
    if not out:
        raise InputError(
            "no JPEG, PNG, TIFF or RAW files found",
            path=", ".join(str(p) for p in paths),
            expected="a folder of images (add --recursive for sub-folders)",
        )
    return out


def _thumbnail(path: Path) -> np.ndarray | None:
    if is_raw_path(path):
        return None
    try:
        from PIL import Image

        with Image.open(path) as im:
            if im.format == "JPEG":
                im.draft("RGB", (THUMB_SIDE * 4, THUMB_SIDE * 4))
            arr = np.asarray(im.convert("RGB").resize((THUMB_SIDE, THUMB_SIDE)), np.float32)
    except Exception:  # a thumbnail is a tie-breaker only: an odd file simply has none
        return None
    return arr.mean(axis=2)


def _libraw_other(path: Path):  # noqa: ANN202
    """LibRaw's capture fields (time, shutter, ISO, aperture) from the header, no unpack (what
    :func:`hdrcore.io.read_raw` falls back on for files without TIFF EXIF); ``None`` if
    LibRaw cannot open the file."""
    import rawpy

    from ..io._capture import c_stderr

    try:
        with c_stderr(path), rawpy.imread(str(path)) as raw:
            return raw.other
    except (rawpy.LibRawError, OSError):
        return None


def read_shot(path: str | os.PathLike, *, thumbnail: bool = True) -> Shot:
    """The grouping signals of one file (headers only, plus the thumbnail); a URL is read
    from a local copy of its bytes (:func:`scan_shots` fetches many at once)."""
    if remote.is_url(path):
        return _read_remote([os.fspath(path)], thumbnail)[0]
    p = Path(path)
    exif = read_exif(p)
    t: float | None = None
    if isinstance(exif.capture_time, datetime):
        t = exif.capture_time.timestamp() + (exif.capture_subsec or 0.0)
    try:
        size: tuple[int, int] | None = frame_pixels(p)
    except InputError:
        size = None
    camera = " ".join(x for x in (exif.make, exif.model) if x) or None
    et = None if exif.exposure_time is None else float(exif.exposure_time)
    iso = None if exif.iso is None else float(exif.iso)
    fnum = None if exif.f_number is None else float(exif.f_number)
    if is_raw_path(p) and (t is None or et is None):  # a RAW without TIFF EXIF (Canon CRW)
        other = _libraw_other(p)
        if other is not None:
            if t is None and isinstance(other.timestamp, datetime):
                t = other.timestamp.timestamp()
            et = et or (float(other.shutter_speed) if other.shutter_speed > 0 else None)
            iso = iso or (float(other.iso_speed) if other.iso_speed > 0 else None)
            fnum = fnum or (float(other.aperture) if other.aperture > 0 else None)
    return Shot(
        path=str(p),
        folder=str(p.parent),
        time=t,
        subsec=exif.capture_subsec is not None,
        exposure_time=et,
        iso=iso,
        f_number=fnum,
        exposure_bias=None if exif.exposure_bias is None else float(exif.exposure_bias),
        camera=camera,
        size=size,
        thumbnail=_thumbnail(p) if thumbnail else None,
    )


#: Remote files fetched per call while scanning (bounds the local copies alive at once).
SCAN_CHUNK = 16


def _read_remote(urls: list[str], thumbnail: bool) -> list[Shot]:
    """:func:`read_shot` of remote files: copied whole (the thumbnail needs the whole JPEG,
    LibRaw the whole RAW) to a temporary folder, read, removed; path and folder are the URLs."""
    import tempfile

    with tempfile.TemporaryDirectory(prefix="hdrcore-scan-") as d:
        local = remote.stage(urls, d)
        return [
            replace(read_shot(lp, thumbnail=thumbnail), path=u, folder=remote.parent(u))
            for u, lp in zip(urls, local, strict=True)
        ]


def read_shots(files: list[Path | str], *, thumbnails: bool = True) -> list[Shot]:
    """:func:`read_shot` of each file, in order; URLs fetched :data:`SCAN_CHUNK` at a time."""
    shots: dict[int, Shot] = {}
    urls = [(k, f) for k, f in enumerate(files) if isinstance(f, str) and remote.is_url(f)]
    for k, f in enumerate(files):
        if not (isinstance(f, str) and remote.is_url(f)):
            shots[k] = read_shot(f, thumbnail=thumbnails)
    for i in range(0, len(urls), SCAN_CHUNK):
        part = urls[i : i + SCAN_CHUNK]
        for (k, _), s in zip(part, _read_remote([u for _, u in part], thumbnails), strict=True):
            shots[k] = s
    return [shots[k] for k in range(len(files))]


def scan_shots(
    paths: list[str | os.PathLike], *, recursive: bool = False, thumbnails: bool = True
) -> list[Shot]:
    """:func:`read_shot` of every image :func:`find_images` finds."""
    return read_shots(find_images(paths, recursive=recursive), thumbnails=thumbnails)


def thumbnail_similarity(a: np.ndarray | None, b: np.ndarray | None) -> float | None:
    """Rank correlation of two grey thumbnails over the pixels neither has clipped or black
    (exposure-invariant: a brighter frame of one scene keeps the order of its pixels), in
    [-1, 1]; ``None`` when either has no thumbnail or fewer than 16 usable pixels."""
    if a is None or b is None or a.shape != b.shape:
        return None
    use = (a > 4) & (a < 250) & (b > 4) & (b < 250)
    if int(use.sum()) < 16:
        return None
    ra = np.argsort(np.argsort(a[use])).astype(np.float64)
    rb = np.argsort(np.argsort(b[use])).astype(np.float64)
    ra -= ra.mean()
    rb -= rb.mean()
    den = math.sqrt(float((ra * ra).sum() * (rb * rb).sum()))
    return float((ra * rb).sum() / den) if den > 0 else None
