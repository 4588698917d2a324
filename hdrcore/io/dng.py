"""Floating-point DNG output: the merged radiance as a raw file that raw editors open.

Adobe, "Digital Negative (DNG) Specification", version 1.4.0.0 (2012): floating-point samples
(SampleFormat 3, 16, 24 or 32 bits) are a DNG 1.4 feature, which HDRMerge's output uses
(J. Celaya, HDRMerge, ``DngFloatWriter.cpp``). Two layouts:

* **LinearRaw** (PhotometricInterpretation 34892, three samples a pixel): camera RGB after
  demosaicing, no white balance, no colour conversion; works for every bracket (hand-held
  frames are merged after registration and demosaic);
* **CFA** (PhotometricInterpretation 32803, one sample a pixel, Bayer 2x2): the merged mosaic of
  a tripod RAW bracket, demosaiced by the raw editor.

Samples are linear with black 0 and white 1 (BlackLevel 0, WhiteLevel 1): the merged camera
values scaled by ``scale`` so the brightest finite sample is 1.0, so nothing is clipped by an
editor that honours WhiteLevel. ``BaselineExposure`` (50730) is ``-log2(scale)`` stops minus the
reference frame's: an editor that reads it shows the reference frame's brightness.

Tags (type): IFD0 holds the image (NewSubFileType 0) as uncompressed strips: ImageWidth 256,
ImageLength 257 [LONG]; BitsPerSample 258, Compression 259 (1), PhotometricInterpretation 262,
SamplesPerPixel 277, PlanarConfiguration 284 (1), SampleFormat 339 (3) [SHORT]; RowsPerStrip
278, StripOffsets 273, StripByteCounts 279 [LONG]; Make 271, Model 272, Software 305, DateTime
306 [ASCII]; Orientation 274 [SHORT]; XMP 700 [BYTE] (our provenance, namespace
``https://hdrcore.invalid/ns/1.0/``: exposure times and ratios, the reference frame,
transforms, sources, the scale); ExifIFD 34665 (ExposureTime, FNumber, ISO, DateTimeOriginal of
the reference frame); DNGVersion 50706 1.4.0.0, DNGBackwardVersion 50707 1.4.0.0 [BYTE];
UniqueCameraModel 50708 [ASCII]; BlackLevel 50714, WhiteLevel 50717 [LONG]; ColorMatrix1 50721
[SRATIONAL] (the camera's, XYZ -> camera); AsShotNeutral 50728 [RATIONAL] (``1 / wb``);
BaselineExposure 50730 [SRATIONAL]; CalibrationIlluminant1 50778 [SHORT] 21 (D65). CFA adds
CFARepeatPatternDim 33421 [SHORT] 2,2; CFAPattern 33422 [BYTE]; CFAPlaneColor 50710 [BYTE]
0,1,2; CFALayout 50711 [SHORT] 1.

Why our own encoder and not ``tifffile``: tifffile writes the image and any tag given as
``extratags`` but places IFD0 and the EXIF sub-IFD its own way and does not write a linked EXIF
IFD from a mapping; the classic-TIFF encoder of :mod:`hdrcore.synthetic.dng` (already used for
the simulator's DNGs that LibRaw reads) writes every entry as given, and the pixel data is
streamed to the file in row blocks after the header, so no second copy of a 24 MP float image is
made. Uncompressed strips: LibRaw (0.22) and darktable (rawspeed) read them; writing is disk
speed. What LibRaw does with float DNGs: it converts them to integers with the largest sample
at 16383 (``raw.white_level`` 16383), so rawpy reads our samples back to 1 part in 16383 of the
brightest, not to float precision; :func:`read_float_dng` reads them exactly.
"""

from __future__ import annotations

import math
import os
import struct
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime
from fractions import Fraction
from pathlib import Path
from typing import Any
from xml.sax.saxutils import escape

import numpy as np

from .._numba import njit
from ..errors import ImageReadError, ParameterError

# One TIFF encoder for the project (the simulator's DNGs use it too).
from ._tiff import TiffTag, _encode_ifd, as_rational, exif_tags
from .atomic import atomic_write

__all__ = [
    "DNG_KINDS",
    "DNG_SAMPLE_BITS",
    "DngMetadata",
    "FloatDng",
    "read_float_dng",
    "write_float_dng",
]

#: The layouts: ``"linear"`` (LinearRaw RGB) and ``"cfa"`` (Bayer mosaic).
DNG_KINDS = ("linear", "cfa")
#: Float sample sizes written: 16 (half) and 32 (single).
DNG_SAMPLE_BITS = (16, 32)
XMP_NAMESPACE = "https://hdrcore.invalid/ns/1.0/"
_LINEAR_RAW = 34892
_CFA = 32803
_STRIP_BYTES = 1 << 22  # 4 MiB strips


#: XYZ (D65) -> linear sRGB (IEC 61966-2-1): the ColorMatrix1 of a DNG whose "camera" space is
#: linear sRGB (merged JPEG brackets, the simulator's camera); with AsShotNeutral (1, 1, 1) the
#: colour maths of a raw editor come out as the identity.
SRGB_XYZ_TO_CAMERA = (
    (3.2404542, -1.5371385, -0.4985314),
    (-0.9692660, 1.8760108, 0.0415560),
    (0.0556434, -0.2040259, 1.0572252),
)


@dataclass(frozen=True)
class DngMetadata:
    """What a raw editor needs besides the samples, from the reference frame.

    ``color_matrix``: XYZ (D65) -> camera, 3x3 (rawpy's ``rgb_xyz_matrix``, DNG ColorMatrix1);
    ``white_balance``: the as-shot multipliers (R, G, B), written as AsShotNeutral ``1 / wb``
    normalised to green; ``orientation``: the EXIF value of the stored samples;
    ``baseline_exposure``: stops (see module docstring); ``provenance``: JSON-like values
    written into the XMP packet, one element each.
    """

    make: str | None = None
    model: str | None = None
    color_matrix: tuple[tuple[float, ...], ...] | None = None
    white_balance: tuple[float, ...] | None = None
    orientation: int = 1
    exposure_time: Fraction | float | None = None
    f_number: Fraction | float | None = None
    iso: int | None = None
    capture_time: datetime | None = None
    baseline_exposure: float = 0.0
    software: str = "hdrcore"
    provenance: Mapping[str, Any] = field(default_factory=dict)


def _xmp_packet(values: Mapping[str, Any]) -> bytes:
    """An XMP packet holding ``values`` as ``hdrcore:`` properties (JSON text for lists)."""
    import json

    props = []
    for k, v in values.items():
        if not k.isidentifier():
            raise ParameterError("XMP property names must be identifiers", found=repr(k))
        text = v if isinstance(v, str) else json.dumps(v, separators=(",", ":"))
        props.append(f"   <hdrcore:{k}>{escape(text)}</hdrcore:{k}>")
    body = "\n".join(props)
    return (
        '<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?>\n'
        '<x:xmpmeta xmlns:x="adobe:ns:meta/">\n'
        ' <rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">\n'
        f'  <rdf:Description rdf:about="" xmlns:hdrcore="{XMP_NAMESPACE}">\n'
        f"{body}\n"
        "  </rdf:Description>\n"
        " </rdf:RDF>\n"
        "</x:xmpmeta>\n"
        '<?xpacket end="w"?>'
    ).encode()


def _srational(v: float) -> Fraction:
    f = Fraction(float(v)).limit_denominator(10000)
    if abs(f.numerator) > 0x7FFFFFFF:
        raise ParameterError("value does not fit a TIFF signed rational", found=str(v))
    return f


def _check_image(image: np.ndarray, kind: str) -> np.ndarray:
    arr = np.asarray(image)
    if kind == "linear":
        if arr.ndim != 3 or arr.shape[2] != 3:
            raise ParameterError(
                "a LinearRaw DNG needs an RGB image", expected="(H, W, 3)", found=str(arr.shape)
            )
    elif arr.ndim != 2 or arr.shape[0] < 2 or arr.shape[1] < 2:
        raise ParameterError(
            "a CFA DNG needs a mosaic", expected="(H, W), H, W >= 2", found=str(arr.shape)
        )
    if arr.dtype.kind != "f":
        raise ParameterError("DNG float samples need a float image", found=str(arr.dtype))
    return arr


def _ifd0(
    h: int,
    w: int,
    kind: str,
    bits: int,
    meta: DngMetadata,
    cfa_pattern: np.ndarray | Sequence[Sequence[int]] | None,
    rows_per_strip: int,
    scale: float,
    provenance: Mapping[str, Any],
) -> list[TiffTag]:
    spp = 3 if kind == "linear" else 1
    now = datetime.now().strftime("%Y:%m:%d %H:%M:%S")
    make = meta.make or "unknown"
    model = meta.model or "camera"
    tags = [
        TiffTag(254, 4, (0,)),
        TiffTag(256, 4, (w,)),
        TiffTag(257, 4, (h,)),
        TiffTag(258, 3, (bits,) * spp),
        TiffTag(259, 3, (1,)),
        TiffTag(262, 3, (_LINEAR_RAW if kind == "linear" else _CFA,)),
        TiffTag(271, 2, make),
        TiffTag(272, 2, model),
        TiffTag(274, 3, (int(meta.orientation),)),
        TiffTag(277, 3, (spp,)),
        TiffTag(278, 4, (rows_per_strip,)),
        TiffTag(284, 3, (1,)),
        TiffTag(305, 2, meta.software),
        TiffTag(306, 2, now),
        TiffTag(339, 3, (3,) * spp),
        TiffTag(700, 1, _xmp_packet({**provenance, "scale": scale})),
        TiffTag(50706, 1, bytes((1, 4, 0, 0))),
        TiffTag(50707, 1, bytes((1, 4, 0, 0))),
        TiffTag(50708, 2, model if model.lower().startswith(make.lower()) else f"{make} {model}"),
        TiffTag(50714, 4, (0,)),
        TiffTag(50717, 4, (1,)),
        TiffTag(50730, 10, (_srational(meta.baseline_exposure),)),
        TiffTag(50778, 3, (21,)),
    ]
    if meta.color_matrix is not None:
        m = np.asarray(meta.color_matrix, np.float64)[:3]
        if m.shape != (3, 3) or not np.all(np.isfinite(m)) or not np.any(m != 0):
            raise ParameterError(
                "the colour matrix must be a finite, non-zero 3x3", found=str(m.tolist())
            )
        tags.append(
            TiffTag(50721, 10, tuple(Fraction(round(float(v) * 10000), 10000) for v in m.ravel()))
        )
    if meta.white_balance is not None:
        wb = np.asarray(meta.white_balance, np.float64).ravel()[:3]
        if wb.size != 3 or not np.all(np.isfinite(wb)) or np.any(wb <= 0):
            raise ParameterError(
                "white balance multipliers must be 3 positive values", found=str(wb.tolist())
            )
        neutral = wb[1] / wb
        tags.append(TiffTag(50728, 5, tuple(as_rational(v, what="AsShotNeutral") for v in neutral)))
    if kind == "cfa":
        pat = np.asarray(cfa_pattern, np.int64)
        if pat.shape != (2, 2) or sorted(pat.ravel().tolist()) != [0, 1, 1, 2]:
            raise ParameterError(
                "the CFA pattern must be a 2x2 Bayer map of 0 R, 1 G, 2 B", found=str(pat.tolist())
            )
        tags += [
            TiffTag(33421, 3, (2, 2)),
            TiffTag(33422, 1, bytes(pat.ravel().tolist())),
            TiffTag(50710, 1, bytes((0, 1, 2))),
            TiffTag(50711, 3, (1,)),
        ]
    return tags


@njit
def _clean(v):  # pragma: no cover - numba
    """A sample as written: NaN, infinities and negative values as 0."""
    if not (v > 0) or v == np.inf:
        return np.float32(0.0)
    return v


@njit
def _largest(src, mat, apply):  # pragma: no cover - numba
    """The largest clean sample of ``src`` (rows, W, C), through ``mat`` when ``apply``."""
    top = np.float32(0.0)
    h, w, c = src.shape
    for y in range(h):
        for x in range(w):
            for k in range(c):
                if apply:
                    v = (
                        mat[k, 0] * src[y, x, 0]
                        + mat[k, 1] * src[y, x, 1]
                        + mat[k, 2] * src[y, x, 2]
                    )
                else:
                    v = src[y, x, k]
                v = _clean(np.float32(v))
                if v > top:
                    top = v
    return top


@njit
def _samples(src, mat, apply, scale, out):  # pragma: no cover - numba
    """``out = clean(mat @ src) * scale`` (``src`` as is without ``apply``), one pass."""
    h, w, c = src.shape
    for y in range(h):
        for x in range(w):
            for k in range(c):
                if apply:
                    v = (
                        mat[k, 0] * src[y, x, 0]
                        + mat[k, 1] * src[y, x, 1]
                        + mat[k, 2] * src[y, x, 2]
                    )
                else:
                    v = src[y, x, k]
                out[y, x, k] = _clean(np.float32(v)) * scale


def _stored_view(image: np.ndarray, orientation: int) -> np.ndarray:
    """A view of an upright image as the sensor stored it (the inverse of the EXIF tag's turn,
    :func:`hdrcore.io.frame.undo_orientation` without its copy)."""
    ops = {
        1: lambda a: a,
        2: lambda a: a[:, ::-1],
        3: lambda a: a[::-1, ::-1],
        4: lambda a: a[::-1],
        5: lambda a: np.swapaxes(a, 0, 1),
        # 6 is displayed by turning the stored image 90 deg clockwise: stored = upright turned
        # back (what undo_orientation computes as apply_orientation(., 8)).
        6: lambda a: np.swapaxes(a, 0, 1)[::-1],
        7: lambda a: np.swapaxes(a[::-1, ::-1], 0, 1),
        8: lambda a: np.swapaxes(a, 0, 1)[:, ::-1],
    }
    return ops[int(orientation)](image)


def write_float_dng(
    path: str | os.PathLike,
    image: np.ndarray,
    meta: DngMetadata,
    *,
    kind: str = "linear",
    cfa_pattern: np.ndarray | Sequence[Sequence[int]] | None = None,
    matrix: np.ndarray | None = None,
    bits: int = 32,
    force: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
) -> Path:
    """Write ``image`` (camera values, linear) as a float DNG atomically; returns the path.

    ``kind``: ``"linear"``: ``image`` is ``(H, W, 3)`` upright and is stored turned back to
    the sensor's orientation ``meta.orientation`` (the tag says how to show it); ``matrix``
    (3x3), when given, is applied to each pixel first (``camera = matrix @ rgb``), strip by
    strip. ``"cfa"``: ``image`` is the ``(H, W)`` mosaic as the sensor stored it, its 2x2
    colours ``cfa_pattern`` (0 R, 1 G, 2 B). ``image`` is in units of the reference frame's
    white (1.0 = its clipping level); the samples written are ``image * scale``, ``scale = 1 /
    max`` (black 0, white 1; NaN and negative values as 0), with ``BaselineExposure`` =
    ``log2(max) + meta.baseline_exposure`` and ``scale`` in the XMP packet.
    """
    if kind not in DNG_KINDS:
        raise ParameterError(
            f"unknown DNG layout {kind!r}", expected=", ".join(DNG_KINDS), found=repr(kind)
        )
    if bits not in DNG_SAMPLE_BITS:
        raise ParameterError(
            "unsupported DNG float sample size",
            expected=", ".join(map(str, DNG_SAMPLE_BITS)),
            found=str(bits),
        )
    if int(meta.orientation) not in range(1, 9):
        raise ParameterError(
            "orientation must be an EXIF value", expected="1..8", found=str(meta.orientation)
        )
    arr = _check_image(image, kind)
    if kind == "linear":
        arr = _stored_view(arr, meta.orientation)
    m = None
    if matrix is not None:
        m = np.asarray(matrix, np.float32)
        if kind != "linear" or m.shape != (3, 3) or not np.all(np.isfinite(m)):
            raise ParameterError(
                "the pixel matrix must be a finite 3x3 (LinearRaw only)", found=str(m.shape)
            )
    h, w = arr.shape[:2]
    dtype = np.dtype("<f2" if bits == 16 else "<f4")
    row_bytes = w * (3 if kind == "linear" else 1) * dtype.itemsize
    rows = max(1, min(h, _STRIP_BYTES // row_bytes))
    strips = [(r, min(h, r + rows)) for r in range(0, h, rows)]

    mat = np.eye(3, dtype=np.float32) if m is None else m
    src = arr if arr.ndim == 3 else arr[..., None]
    apply = m is not None
    buf = np.empty((rows, w, src.shape[2]), np.float32)

    def values(r0: int, r1: int, scale: float) -> np.ndarray:
        out = buf[: r1 - r0]
        _samples(src[r0:r1], mat, apply, np.float32(scale), out)
        return out

    top = max(float(_largest(src[r0:r1], mat, apply)) for r0, r1 in strips)
    if not top > 0:
        raise ParameterError("the image holds no positive finite value", found=str(top))
    scale = 1.0 / top
    meta_out = (
        meta
        if meta.baseline_exposure == math.log2(top)
        else DngMetadata(
            **{**meta.__dict__, "baseline_exposure": meta.baseline_exposure + math.log2(top)}
        )
    )
    tags = _ifd0(h, w, kind, bits, meta_out, cfa_pattern, rows, scale, meta.provenance)
    exif = exif_tags(meta.exposure_time, meta.f_number, meta.iso, meta.capture_time)
    # Header, IFD0 at 8, the EXIF IFD after it, then the strips: the lengths of the IFDs do not
    # depend on the offsets they hold, so they are laid out once with zeros and again with the
    # values.
    counts = [(r1 - r0) * row_bytes for r0, r1 in strips]

    def header(exif_at: int, first: int) -> bytes:
        offsets = tuple(first + sum(counts[:k]) for k in range(len(counts)))
        ifd0 = tags + [
            TiffTag(273, 4, offsets),
            TiffTag(279, 4, tuple(counts)),
            TiffTag(34665, 4, (exif_at,)),
        ]
        body = _encode_ifd(ifd0, 8)
        return b"II*\x00" + struct.pack("<I", 8) + body + _encode_ifd(exif, 8 + len(body))

    exif_at = 8 + len(
        _encode_ifd(
            tags
            + [
                TiffTag(273, 4, (0,) * len(counts)),
                TiffTag(279, 4, tuple(counts)),
                TiffTag(34665, 4, (0,)),
            ],
            8,
        )
    )
    probe = header(exif_at, 0)
    first = len(probe) + (len(probe) % 2)
    head = header(exif_at, first)
    head += b"\x00" * (first - len(head))

    def writer(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            fh.write(head)
            for r0, r1 in strips:
                block = values(r0, r1, scale)
                fh.write(block.tobytes() if dtype == np.float32 else block.astype(dtype).tobytes())

    return atomic_write(path, writer, force=force, inputs=inputs)


@dataclass(frozen=True)
class FloatDng:
    """A float DNG read back by :func:`read_float_dng`: the samples as stored, the layout and
    the tags (number -> values) of IFD0."""

    image: np.ndarray
    kind: str
    tags: dict[int, Any]


def _read_ifd(data: bytes, offset: int) -> dict[int, Any]:
    sizes = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 7: 1, 10: 8, 11: 4, 12: 8}
    (n,) = struct.unpack_from("<H", data, offset)
    out: dict[int, Any] = {}
    for k in range(n):
        tag, typ, count = struct.unpack_from("<HHI", data, offset + 2 + 12 * k)
        size = sizes.get(typ, 1) * count
        at = offset + 2 + 12 * k + 8
        if size > 4:
            (at,) = struct.unpack_from("<I", data, at)
        raw = data[at : at + size]
        if typ == 2:
            out[tag] = raw.rstrip(b"\x00").decode("latin-1")
        elif typ in (1, 7):
            out[tag] = bytes(raw)
        elif typ in (5, 10):
            fmt = "<" + ("I" if typ == 5 else "i") * (2 * count)
            v = struct.unpack(fmt, raw)
            out[tag] = tuple(
                Fraction(v[2 * i], v[2 * i + 1]) if v[2 * i + 1] else Fraction(0)
                for i in range(count)
            )
        else:
            fmt = {3: "H", 4: "I", 11: "f", 12: "d"}[typ]
            out[tag] = struct.unpack("<" + fmt * count, raw)
    return out


def read_float_dng(path: str | os.PathLike) -> FloatDng:
    """Read a float DNG this module wrote (uncompressed strips, little-endian) exactly."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise ImageReadError(f"cannot read file: {exc.strerror}", path=p) from exc
    if data[:4] != b"II*\x00":
        raise ImageReadError("not a little-endian TIFF/DNG", path=p, found=repr(data[:4]))
    try:
        (ifd,) = struct.unpack_from("<I", data, 4)
        tags = _read_ifd(data, ifd)
        w, h = tags[256][0], tags[257][0]
        bits, photometric, fmt = tags[258][0], tags[262][0], tags[339][0]
        if fmt != 3 or tags[259][0] != 1 or photometric not in (_LINEAR_RAW, _CFA):
            raise ImageReadError(
                "not an uncompressed float DNG",
                path=p,
                found=f"SampleFormat {fmt}, Compression {tags[259][0]}, "
                f"PhotometricInterpretation {photometric}",
            )
        spp = tags[277][0]
        dtype = np.dtype("<f2" if bits == 16 else "<f4")
        parts = [
            np.frombuffer(data, dtype, c // dtype.itemsize, o)
            for o, c in zip(tags[273], tags[279], strict=True)
        ]
    except (KeyError, struct.error, ValueError) as exc:
        raise ImageReadError(f"damaged DNG ({exc})", path=p) from exc
    img = np.concatenate(parts).astype(np.float32).reshape((h, w, spp) if spp > 1 else (h, w))
    return FloatDng(image=img, kind="linear" if photometric == _LINEAR_RAW else "cfa", tags=tags)
