"""2x3 motion matrices: rigid parameters, composition, inversion, chaining pairs to a reference.

Convention (the project's, see :mod:`hdrcore.synthetic.camera`): a 2x3 affine matrix ``A`` maps
pixel coordinates ``(x, y, 1)`` of one frame to pixel coordinates of another; x to the right,
y down, origin at the centre of the top-left pixel. A *pair* matrix of the consecutive frames
(dark ``i``, bright ``i + 1``) maps coordinates of the brighter frame to the darker one; a
*to-reference* matrix maps coordinates of frame ``k`` to the reference frame.

Cerman & Hlavac (2006), section 6, register only consecutive frames (their exposures overlap
most) and chain the pair transforms to the reference frame; :func:`to_reference` does the chaining.

The elementary maths (``rigid_matrix``, ``compose``, ``invert``) is the simulator's, re-exported
here so registration and ground truth can never disagree on a convention.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import ParameterError
from ..synthetic.camera import compose, invert, rigid_matrix

__all__ = [
    "rigid_matrix",
    "compose",
    "invert",
    "identity",
    "rigid_parameters",
    "to_reference",
    "pair_from_reference",
    "apply",
    "corner_error",
    "scale_matrix",
]


def identity() -> np.ndarray:
    """The 2x3 identity."""
    return np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def apply(matrix: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map point coordinates ``(x, y)`` through the 2x3 ``matrix``."""
    m = np.asarray(matrix, float)
    return m[0, 0] * x + m[0, 1] * y + m[0, 2], m[1, 0] * x + m[1, 1] * y + m[1, 2]


def rigid_parameters(matrix: np.ndarray, shape: tuple[int, int]) -> tuple[float, float, float]:
    """``(dx, dy, angle_deg)`` such that ``rigid_matrix(dx, dy, angle_deg, shape)`` is ``matrix``.

    The inverse of :func:`rigid_matrix` (rotation about the image centre, then shift). For a
    matrix that is not exactly rigid the angle is that of the nearest rotation.
    """
    m = np.asarray(matrix, float)
    h, w = shape
    angle = float(np.degrees(np.arctan2(m[1, 0] - m[0, 1], m[0, 0] + m[1, 1])))
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    d = m[:, :2] @ centre + m[:, 2] - centre
    return float(d[0]), float(d[1]), angle


def scale_matrix(matrix: np.ndarray, factor: float) -> np.ndarray:
    """The same motion expressed on an image resampled by ``factor`` (2x2 block means: 0.5).

    A pixel centre ``x`` of the resampled image sits at ``(x + 0.5) / factor - 0.5`` in the
    original, so the matrix is conjugated by that affine change of coordinates.
    """
    f = float(factor)
    s = np.array([[1 / f, 0, 0.5 / f - 0.5], [0, 1 / f, 0.5 / f - 0.5]])  # resampled -> original
    return compose(invert(s), compose(matrix, s))


def to_reference(pairs: Sequence[np.ndarray], reference: int) -> tuple[np.ndarray, ...]:
    """Chain consecutive pair matrices into per-frame matrices to the ``reference`` frame.

    ``pairs[i]`` maps coordinates of frame ``i + 1`` to frame ``i``. Returns ``n = len(pairs) + 1``
    matrices; entry ``k`` maps coordinates of frame ``k`` to the reference frame (identity for the
    reference itself).
    """
    n = len(pairs) + 1
    if not 0 <= int(reference) < n:
        raise ParameterError(
            "reference frame out of range", expected=f"0..{n - 1}", found=str(reference)
        )
    ref = int(reference)
    out: list[np.ndarray | None] = [None] * n
    out[ref] = identity()
    for k in range(ref + 1, n):  # brighter frames: k -> k-1 -> ... -> ref
        out[k] = compose(out[k - 1], pairs[k - 1])
    for k in range(ref - 1, -1, -1):  # darker frames: k -> k+1 -> ... -> ref
        out[k] = compose(out[k + 1], invert(pairs[k]))
    return tuple(np.asarray(m) for m in out)


def pair_from_reference(
    to_ref: Sequence[np.ndarray], dark: int, bright: int
) -> np.ndarray:
    """Matrix mapping coordinates of frame ``bright`` to frame ``dark``."""
    return compose(invert(to_ref[dark]), to_ref[bright])


def corner_error(estimate: np.ndarray, truth: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Distances (pixels) between the four image corners mapped by ``estimate`` and ``truth``."""
    h, w = shape
    x = np.array([0.0, w - 1.0, 0.0, w - 1.0])
    y = np.array([0.0, 0.0, h - 1.0, h - 1.0])
    ex, ey = apply(estimate, x, y)
    tx, ty = apply(truth, x, y)
    return np.hypot(ex - tx, ey - ty)
