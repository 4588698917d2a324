"""A smooth displacement field on a coarse grid: what is left after a global motion model.

Hand-held frames of a scene with depth differ by more than one homography can hold: objects
nearer than the dominant plane move against it (parallax). Local refinement
(:mod:`hdrcore.registration.local`) estimates, after the global fit, a displacement on a grid of
nodes ``step`` output pixels apart (as HDR+ aligns tiles of 16-64 px; our nodes are interpolated
bilinearly, so the field is continuous and the merge has no tile seams). A frame is then read at

    p_k(x) = H_k(x) + d_k(x)

for every output (reference) pixel ``x``: ``H_k`` the global homography (reference -> frame
``k``), ``d_k`` the field interpolated at ``x``. Node ``(i, j)`` sits at output pixel
``(origin_x + j * step, origin_y + i * step)``; outside the nodes the field is constant (the
nearest edge's value). ``offsets[i, j] = (dx, dy)`` in frame pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError

__all__ = ["DisplacementField", "map_points"]


@dataclass(frozen=True, eq=False)
class DisplacementField:
    """Per-node displacements ``offsets (gh, gw, 2)`` (float32, frame pixels, ``(dx, dy)``) on
    nodes ``step`` output pixels apart, node ``(0, 0)`` at output pixel ``origin``."""

    step: float
    offsets: np.ndarray
    origin: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        off = np.ascontiguousarray(self.offsets, dtype=np.float32)
        if off.ndim != 3 or off.shape[2] != 2 or min(off.shape[:2]) < 2:
            raise ParameterError(
                "a displacement field needs (rows, columns, 2) offsets",
                expected="at least a 2 x 2 grid of (dx, dy)",
                found=str(off.shape),
            )
        if not np.all(np.isfinite(off)):
            raise ParameterError("a displacement field's offsets must be finite")
        if not (np.isfinite(self.step) and self.step > 0):
            raise ParameterError(
                "a displacement field's node spacing must be positive", found=str(self.step)
            )
        off.setflags(write=False)
        object.__setattr__(self, "offsets", off)
        object.__setattr__(self, "step", float(self.step))
        object.__setattr__(self, "origin", (float(self.origin[0]), float(self.origin[1])))

    @staticmethod
    def grid(shape: tuple[int, int], step: float) -> tuple[int, int]:
        """Nodes ``(rows, columns)`` that cover an output of ``shape`` with ``step``."""
        h, w = shape
        return (max(2, int(np.ceil((h - 1) / step)) + 1), max(2, int(np.ceil((w - 1) / step)) + 1))

    @classmethod
    def zeros(cls, shape: tuple[int, int], step: float) -> DisplacementField:
        gh, gw = cls.grid(shape, step)
        return cls(step, np.zeros((gh, gw, 2), np.float32))

    def at(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(dx, dy)`` at output pixels ``(x, y)`` (bilinear between nodes, float64)."""
        gh, gw = self.offsets.shape[:2]
        fx = np.clip((np.asarray(x, np.float64) - self.origin[0]) / self.step, 0.0, gw - 1.0)
        fy = np.clip((np.asarray(y, np.float64) - self.origin[1]) / self.step, 0.0, gh - 1.0)
        j = np.minimum(fx.astype(np.intp), gw - 2)
        i = np.minimum(fy.astype(np.intp), gh - 2)
        u = fx - j
        v = fy - i
        k = i * gw + j
        out = []
        for c in range(2):
            o = self.offsets[..., c].astype(np.float64).ravel()
            top = o.take(k) * (1 - u) + o.take(k + 1) * u
            bot = o.take(k + gw) * (1 - u) + o.take(k + gw + 1) * u
            out.append(top * (1 - v) + bot * v)
        return out[0], out[1]

    def _weights(self, coords: np.ndarray, origin: float, n: int) -> np.ndarray:
        f = np.clip((np.asarray(coords, np.float64) - origin) / self.step, 0.0, n - 1.0)
        j = np.minimum(f.astype(np.intp), n - 2)
        u = f - j
        w = np.zeros((f.size, n))
        rows = np.arange(f.size)
        w[rows, j] = 1 - u
        w[rows, j + 1] += u
        return w

    def on_grid(self, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(dx, dy)`` on the grid of output pixels ``xs x ys``: arrays ``(len(ys),
        len(xs))`` (the same values as :meth:`at`, separably)."""
        gh, gw = self.offsets.shape[:2]
        wy = self._weights(ys, self.origin[1], gh)
        wx = self._weights(xs, self.origin[0], gw)
        o = self.offsets.astype(np.float64)
        return wy @ o[..., 0] @ wx.T, wy @ o[..., 1] @ wx.T

    def shifted(self, dx: float = 0.0, dy: float = 0.0) -> DisplacementField:
        """The same field for an output grid whose pixel ``(0, 0)`` is this one's ``(dx, dy)``
        (a band of rows: ``dy`` = the band's first row)."""
        return DisplacementField(
            self.step, self.offsets, (self.origin[0] - dx, self.origin[1] - dy)
        )

    def scaled(self, factor: float) -> DisplacementField:
        """The field of the same motion on frames ``factor`` times larger (binned registration
        scaled back; pixel centres: ``x_full = factor * x + (factor - 1) / 2``)."""
        c = (factor - 1) / 2.0
        return DisplacementField(
            self.step * factor,
            self.offsets * np.float32(factor),
            (self.origin[0] * factor + c, self.origin[1] * factor + c),
        )

    @property
    def magnitudes(self) -> np.ndarray:
        return np.hypot(self.offsets[..., 0], self.offsets[..., 1])

    @property
    def max_px(self) -> float:
        return float(self.magnitudes.max())

    @property
    def median_px(self) -> float:
        return float(np.median(self.magnitudes))

    def to_json(self) -> dict:
        return {
            "step": self.step,
            "origin": list(self.origin),
            "shape": list(self.offsets.shape[:2]),
            "median_px": round(self.median_px, 4),
            "max_px": round(self.max_px, 4),
            "offsets": np.round(self.offsets.astype(np.float64), 4).tolist(),
        }


def map_points(
    homography: np.ndarray, field: DisplacementField | None, x: np.ndarray, y: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Output pixels ``(x, y)`` mapped into a frame: ``H (x, y) + d(x, y)`` (3x3 ``H``,
    perspective divide; ``field`` None: the homography alone)."""
    m = np.asarray(homography, np.float64)
    if m.shape == (2, 3):
        m = np.vstack([m, [0.0, 0.0, 1.0]])
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    s = m[2, 0] * x + m[2, 1] * y + m[2, 2]
    sx = (m[0, 0] * x + m[0, 1] * y + m[0, 2]) / s
    sy = (m[1, 0] * x + m[1, 1] * y + m[1, 2]) / s
    if field is not None:
        dx, dy = field.at(x, y)
        sx = sx + dx
        sy = sy + dy
    return sx, sy
