"""Camera RGB to a standard linear working space (linear sRGB / Rec.709 primaries by default).

The camera matrix is the one LibRaw (and rawpy) report as ``rgb_xyz_matrix``: it maps CIE XYZ
(D65) to camera RGB, ``cam = C @ xyz`` (Adobe's ``ColorMatrix``; the fourth row of rawpy's 4x3
array is the second green or zeros and is ignored). Following dcraw/LibRaw's ``convert_to_rgb``:

1. ``cam_rgb = C @ M_sRGB->XYZ``, each row normalised to sum 1 (a neutral of the working space
   then gives equal camera values once white-balanced),
2. ``rgb_cam = inverse(cam_rgb)``,
3. ``working = M_sRGB->space @ rgb_cam @ diag(wb / wb_green) @ camera``.

The colourspace matrices and chromatic adaptation (Bradford, when the working space's white is not
D65) come from colour-science. Arrays in, arrays out: the matrix and white balance are passed as
numbers, read from the RAW file by ``hdrcore.io``.

Pixels clipped in every frame have an unknown colour; if their mask is given they are made
neutral (all channels the white-balanced maximum), which is how raw converters avoid magenta
highlights where the green channel clipped first.

Reference: D. Coffin, dcraw.c, ``convert_to_rgb()`` and ``cam_xyz_coeff()``; LibRaw's
``rgb_cam`` computation.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from .._numba import AVAILABLE
from .._numba import njit as _njit
from .._threads import run_row_spans
from ..errors import ParameterError, validate_method

__all__ = [
    "WORKING_SPACES",
    "ColourConversion",
    "apply_colour",
    "camera_to_working_matrix",
    "camera_to_working",
    "colour_conversion",
    "convert_space_in_place",
    "space_to_space_matrix",
]

WORKING_SPACES: dict[str, str] = {
    "sRGB": "sRGB",
    "Rec.709": "ITU-R BT.709",
    "Rec.2020": "ITU-R BT.2020",
    "ACEScg": "ACEScg",
    "Display P3": "Display P3",
    "Adobe RGB (1998)": "Adobe RGB (1998)",
    "ProPhoto RGB": "ProPhoto RGB",
}
"""Working spaces by name -> colour-science's ``RGB_COLOURSPACES`` key (all linear here)."""

_SRGB_PRIMARIES = ("sRGB", "ITU-R BT.709")

_SRGB_TO_XYZ = np.array(
    [[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]]
)
"""colour-science's ``RGB_COLOURSPACES["sRGB"].matrix_RGB_to_XYZ`` (IEC 61966-2-1), copied so
that the default working space needs no ``import colour`` (about a second on first use)."""


def _white_balance(camera_whitebalance: Sequence[float] | np.ndarray | None) -> np.ndarray:
    if camera_whitebalance is None:
        return np.ones(3)
    wb = np.asarray(camera_whitebalance, dtype=np.float64).ravel()
    if wb.size not in (3, 4):
        raise ParameterError(
            "camera white balance must have 3 or 4 multipliers (R, G, B[, G2])",
            found=str(wb.size),
        )
    wb = wb[:3]
    if not np.all(np.isfinite(wb)) or np.any(wb <= 0):
        raise ParameterError(
            "camera white balance multipliers must be positive", found=str(wb.tolist())
        )
    return wb / wb[1]


def camera_to_working_matrix(
    rgb_xyz_matrix: np.ndarray | None = None,
    camera_whitebalance: Sequence[float] | np.ndarray | None = None,
    working_space: str = "sRGB",
    source_space: str = "sRGB",
) -> np.ndarray:
    """The 3x3 matrix taking (black-subtracted) camera RGB to linear ``working_space`` RGB.

    ``rgb_xyz_matrix`` is rawpy's XYZ -> camera matrix (3x3 or the first 3 rows of 4x3); ``None``
    or all zeros means the data are already in linear ``source_space`` primaries (a JPEG/PNG/TIFF
    linearised by its response: sRGB, or the Display P3 or Adobe RGB its profile names), so only
    the white balance and the source -> working-space step apply.
    ``camera_whitebalance`` holds rawpy's as-shot multipliers (normalised to green here).
    """
    key = validate_method(working_space, WORKING_SPACES, "working space")
    wb = _white_balance(camera_whitebalance)
    rgb_cam = np.eye(3)
    source = source_space  # the camera's matrix, when there is one, leads to linear sRGB
    if rgb_xyz_matrix is not None:
        cam_xyz = np.asarray(rgb_xyz_matrix, dtype=np.float64)
        if cam_xyz.ndim != 2 or cam_xyz.shape[1] != 3 or cam_xyz.shape[0] not in (3, 4):
            raise ParameterError(
                "camera matrix must be rawpy's rgb_xyz_matrix",
                expected="(3, 3) or (4, 3)",
                found=str(cam_xyz.shape),
            )
        cam_xyz = cam_xyz[:3]
        if not np.all(np.isfinite(cam_xyz)):
            raise ParameterError("camera matrix must be finite")
        if np.any(cam_xyz != 0):
            source = "sRGB"
            cam_rgb = cam_xyz @ _SRGB_TO_XYZ
            sums = cam_rgb.sum(axis=1, keepdims=True)
            if np.any(np.abs(sums) < 1e-12):
                raise ParameterError("camera matrix is singular", found=str(cam_xyz.tolist()))
            cam_rgb = cam_rgb / sums
            try:
                rgb_cam = np.linalg.inv(cam_rgb)
            except np.linalg.LinAlgError as exc:
                raise ParameterError(
                    "camera matrix is singular", found=str(cam_xyz.tolist())
                ) from exc
    return space_to_space_matrix(source, key) @ rgb_cam @ np.diag(wb)


def space_to_space_matrix(source: str, target: str) -> np.ndarray:
    """The 3x3 matrix taking linear ``source`` RGB (a :data:`WORKING_SPACES` name: the space a
    JPEG's levels are encoded in, such as Display P3) to linear ``target`` RGB (Bradford when
    their whites differ); exactly the identity between spaces of the same primaries (colour's
    rounded IEC matrices are not exact inverses of each other)."""
    src = WORKING_SPACES[validate_method(source, WORKING_SPACES, "colour space")]
    dst = WORKING_SPACES[validate_method(target, WORKING_SPACES, "working space")]
    if src == dst or (src in _SRGB_PRIMARIES and dst in _SRGB_PRIMARIES):
        return np.eye(3)
    import colour  # lazily: colour-science (with colour.plotting) takes about a second

    return np.asarray(
        colour.matrix_RGB_to_RGB(
            colour.RGB_COLOURSPACES[src],
            colour.RGB_COLOURSPACES[dst],
            chromatic_adaptation_transform="Bradford",
        ),
        dtype=np.float64,
    )


def convert_space_in_place(rgb: np.ndarray, matrix: np.ndarray, rows: int = 256) -> None:
    """``rgb`` ``(H, W, 3)`` float32 replaced by ``matrix @ rgb`` pixel by pixel, ``rows`` rows
    at a time (no full-size copy)."""
    m = np.asarray(matrix, np.float64).T.astype(rgb.dtype)
    for r0 in range(0, rgb.shape[0], rows):
        part = rgb[r0 : r0 + rows]
        np.matmul(part, m, out=part)


class ColourConversion(NamedTuple):
    """Camera RGB -> working space, as :func:`camera_to_working` applies it (and
    :func:`hdrcore.merge.merge` with ``colour=``, inside its finishing pass).

    ``matrix`` (3x3 float64): :func:`camera_to_working_matrix`. ``white_balance`` (3,): the
    as-shot multipliers normalised to green. ``neutral`` (3,): ``matrix @ (1 / white_balance)``,
    the working-space value of a neutral of white-balanced value 1; a pixel marked clipped
    becomes ``max(white_balance * rgb) * neutral``.
    """

    matrix: np.ndarray
    white_balance: np.ndarray
    neutral: np.ndarray


def colour_conversion(
    rgb_xyz_matrix: np.ndarray | None = None,
    camera_whitebalance: Sequence[float] | np.ndarray | None = None,
    working_space: str = "sRGB",
    source_space: str = "sRGB",
) -> ColourConversion:
    """The :class:`ColourConversion` of :func:`camera_to_working_matrix`'s arguments."""
    matrix = camera_to_working_matrix(
        rgb_xyz_matrix, camera_whitebalance, working_space, source_space
    )
    wb = _white_balance(camera_whitebalance)
    return ColourConversion(
        np.ascontiguousarray(matrix, np.float64),
        wb,
        np.ascontiguousarray(matrix @ (1.0 / wb), np.float64),
    )


@_njit
def convert_pixels(buf, mask, has_mask, m, wb, neutral):
    """In place, ``buf`` interleaved RGB (``3 x + ch``, float32) of ``len(buf) // 3`` pixels:
    ``m @ rgb`` in float64, rounded to float32; where ``mask`` (with ``has_mask``) the neutral
    ``max(wb * rgb) * neutral``. One array in and out and no branch per pixel: it vectorises
    (an output array that may alias the input would not)."""
    m00, m01, m02 = m[0, 0], m[0, 1], m[0, 2]
    m10, m11, m12 = m[1, 0], m[1, 1], m[1, 2]
    m20, m21, m22 = m[2, 0], m[2, 1], m[2, 2]
    w0, w1, w2 = wb[0], wb[1], wb[2]
    n0, n1, n2 = neutral[0], neutral[1], neutral[2]
    npx = len(buf) // 3
    if has_mask:
        for i in range(npx):
            e = 3 * i
            r = np.float64(buf[e])
            g = np.float64(buf[e + 1])
            b = np.float64(buf[e + 2])
            clip = mask[i]
            v = max(r * w0, g * w1, b * w2)
            o0 = m00 * r + m01 * g + m02 * b
            o1 = m10 * r + m11 * g + m12 * b
            o2 = m20 * r + m21 * g + m22 * b
            buf[e] = np.float32(v * n0 if clip else o0)
            buf[e + 1] = np.float32(v * n1 if clip else o1)
            buf[e + 2] = np.float32(v * n2 if clip else o2)
    else:
        for i in range(npx):
            e = 3 * i
            r = np.float64(buf[e])
            g = np.float64(buf[e + 1])
            b = np.float64(buf[e + 2])
            buf[e] = np.float32(m00 * r + m01 * g + m02 * b)
            buf[e + 1] = np.float32(m10 * r + m11 * g + m12 * b)
            buf[e + 2] = np.float32(m20 * r + m21 * g + m22 * b)


@_njit
def _convert_rows(buf, mask, has_mask, m, wb, neutral, r0, r1):
    for y in range(r0, r1):
        convert_pixels(buf[y], mask[y if has_mask else 0], has_mask, m, wb, neutral)


def camera_to_working(
    radiance: np.ndarray,
    rgb_xyz_matrix: np.ndarray | None = None,
    camera_whitebalance: Sequence[float] | np.ndarray | None = None,
    working_space: str = "sRGB",
    *,
    clipped: np.ndarray | None = None,
    chunk_pixels: int = 1 << 20,
    out: np.ndarray | None = None,
    workers: int | None = None,
) -> np.ndarray:
    """Linear ``working_space`` RGB of a camera-RGB radiance map, float32 ``(H, W, 3)``.

    ``clipped`` (bool ``(H, W)``, e.g. :attr:`MergeResult.clipped`) marks pixels whose colour is
    unknown; they are made neutral before the matrix (see the module doc). ``out`` (float32
    ``(H, W, 3)``, C-contiguous; it may be ``radiance`` itself) receives the result and saves
    a 12-bytes-a-pixel allocation. With numba one fused pass over row blocks on ``workers``
    threads (default: up to 2) does it; without, numpy matrix products over chunks.
    """
    conversion = colour_conversion(rgb_xyz_matrix, camera_whitebalance, working_space)
    return apply_colour(
        radiance, conversion, clipped=clipped, chunk_pixels=chunk_pixels, out=out, workers=workers
    )


def apply_colour(
    radiance: np.ndarray,
    conversion: ColourConversion,
    *,
    clipped: np.ndarray | None = None,
    chunk_pixels: int = 1 << 20,
    out: np.ndarray | None = None,
    workers: int | None = None,
) -> np.ndarray:
    """:func:`camera_to_working` with a :class:`ColourConversion` made beforehand."""
    rad = np.asarray(radiance)
    if rad.ndim != 3 or rad.shape[2] != 3:
        raise ParameterError("radiance must be (H, W, 3)", found=str(rad.shape))
    h, w, _ = rad.shape
    mask = None
    if clipped is not None:
        mask = np.asarray(clipped, dtype=bool)
        if mask.shape != (h, w):
            raise ParameterError(
                "clipped mask does not match the radiance",
                expected=str((h, w)),
                found=str(mask.shape),
            )
    if out is not None and (
        out.shape != (h, w, 3) or out.dtype != np.float32 or not out.flags.c_contiguous
    ):
        raise ParameterError(
            "out must be a C-contiguous float32 array of the radiance's shape",
            expected=str((h, w, 3)),
            found=f"{out.shape} {out.dtype}",
        )
    matrix, wb, neutral = conversion
    if AVAILABLE and h * w > 0:
        # in place on the output (float32 values, converted in float64)
        dst = out if out is not None else np.empty((h, w, 3), np.float32)
        if dst is not rad:
            np.copyto(dst, rad, casting="unsafe")
        msk = np.ascontiguousarray(mask) if mask is not None else np.zeros((1, 1), bool)
        flat = dst.reshape(h, w * 3)

        def work(r0: int, r1: int) -> None:
            _convert_rows(flat, msk, mask is not None, matrix, wb, neutral, r0, r1)

        run_row_spans(h, workers, work)
        return dst
    m_t = np.ascontiguousarray(matrix.T, dtype=np.float32)
    flat = rad.reshape(-1, 3)
    idx = np.flatnonzero(mask) if mask is not None else np.zeros(0, np.intp)
    balanced = flat[idx].astype(np.float64) * wb  # read before ``out`` may overwrite it
    res = out.reshape(-1, 3) if out is not None else np.empty((h * w, 3), np.float32)
    step = max(1, int(chunk_pixels))
    for i in range(0, h * w, step):
        chunk = flat[i : i + step].astype(np.float32)  # a copy: ``out`` may be ``radiance``
        np.matmul(chunk, m_t, out=res[i : i + step])
    if idx.size:
        # A neutral of value v in white-balanced camera RGB is a neutral in the working space.
        v = balanced.max(axis=1, keepdims=True)
        res[idx] = (v * neutral).astype(np.float32)
    return res.reshape(h, w, 3)
