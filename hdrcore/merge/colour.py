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

import numpy as np

from .._threads import run_row_spans
from ..errors import ParameterError, validate_method

try:
    import numba
except ImportError:  # pragma: no cover - numba is a dependency; numpy does the work without it
    numba = None

__all__ = ["WORKING_SPACES", "camera_to_working_matrix", "camera_to_working"]

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
) -> np.ndarray:
    """The 3x3 matrix taking (black-subtracted) camera RGB to linear ``working_space`` RGB.

    ``rgb_xyz_matrix`` is rawpy's XYZ -> camera matrix (3x3 or the first 3 rows of 4x3); ``None``
    or all zeros means the data are already in linear sRGB primaries (a JPEG/PNG/TIFF linearised
    by its response), so only the white balance and the sRGB -> working-space step apply.
    ``camera_whitebalance`` holds rawpy's as-shot multipliers (normalised to green here).
    """
    key = validate_method(working_space, WORKING_SPACES, "working space")
    wb = _white_balance(camera_whitebalance)
    rgb_cam = np.eye(3)
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
    if WORKING_SPACES[key] in _SRGB_PRIMARIES:
        # Same primaries and white: exactly the identity (colour's rounded IEC matrices are not
        # exact inverses of each other).
        to_space = np.eye(3)
    else:
        import colour  # lazily: colour-science (with colour.plotting) takes about a second

        srgb = colour.RGB_COLOURSPACES["sRGB"]
        target = colour.RGB_COLOURSPACES[WORKING_SPACES[key]]
        to_space = np.asarray(
            colour.matrix_RGB_to_RGB(srgb, target, chromatic_adaptation_transform="Bradford"),
            dtype=np.float64,
        )
    return to_space @ rgb_cam @ np.diag(wb)


if numba is not None:

    @numba.njit(nogil=True, cache=True, fastmath=False)
    def _matrix_rows(src, m, wb, mask, has_mask, dst, r0, r1):  # pragma: no cover - compiled
        """``dst = m @ src`` per pixel (float64 sums, float32 out); masked pixels first become
        the neutral ``max(wb * rgb) / wb``. ``dst`` may be ``src``."""
        w = src.shape[1]
        for y in range(r0, r1):
            for x in range(w):
                r = np.float64(src[y, x, 0])
                g = np.float64(src[y, x, 1])
                b = np.float64(src[y, x, 2])
                if has_mask and mask[y, x]:
                    v = max(r * wb[0], g * wb[1], b * wb[2])
                    r = v / wb[0]
                    g = v / wb[1]
                    b = v / wb[2]
                dst[y, x, 0] = np.float32(m[0, 0] * r + m[0, 1] * g + m[0, 2] * b)
                dst[y, x, 1] = np.float32(m[1, 0] * r + m[1, 1] * g + m[1, 2] * b)
                dst[y, x, 2] = np.float32(m[2, 0] * r + m[2, 1] * g + m[2, 2] * b)


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
    rad = np.asarray(radiance)
    if rad.ndim != 3 or rad.shape[2] != 3:
        raise ParameterError("radiance must be (H, W, 3)", found=str(rad.shape))
    h, w, _ = rad.shape
    matrix = camera_to_working_matrix(rgb_xyz_matrix, camera_whitebalance, working_space)
    wb = _white_balance(camera_whitebalance)
    mask = None
    if clipped is not None:
        mask = np.asarray(clipped, dtype=bool)
        if mask.shape != (h, w):
            raise ParameterError(
                "clipped mask does not match the radiance", expected=str((h, w)),
                found=str(mask.shape),
            )
    if out is not None and (
        out.shape != (h, w, 3) or out.dtype != np.float32 or not out.flags.c_contiguous
    ):
        raise ParameterError(
            "out must be a C-contiguous float32 array of the radiance's shape",
            expected=str((h, w, 3)), found=f"{out.shape} {out.dtype}",
        )
    if numba is not None and h * w > 0:
        src = rad if rad.flags.c_contiguous else np.ascontiguousarray(rad)
        if src.dtype not in (np.float32, np.float64):
            src = src.astype(np.float32)
        dst = out if out is not None else np.empty((h, w, 3), np.float32)
        m = np.ascontiguousarray(matrix, dtype=np.float64)
        msk = np.ascontiguousarray(mask) if mask is not None else np.zeros((1, 1), bool)

        def work(r0: int, r1: int) -> None:
            _matrix_rows(src, m, wb, msk, mask is not None, dst, r0, r1)

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
        v = balanced.max(axis=1, keepdims=True)
        # A neutral of value v in white-balanced camera RGB is a neutral in the working space.
        neutral = np.repeat(v, 3, axis=1) / wb
        res[idx] = (neutral @ matrix.T).astype(np.float32)
    return res.reshape(h, w, 3)
