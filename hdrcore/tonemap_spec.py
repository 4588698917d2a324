"""Tone mapping written as plainly as numpy allows: the specification the tests hold the
compiled passes to (issue 17).

Used by the tests only: :func:`hdrcore.tonemap.tonemap` runs compiled code for every built-in
operator (:func:`hdrcore.tonemap._tonemap_rows` for the global ones,
:func:`hdrcore.tonemap_local.render_durand_8bit` for the local one) and reads the local
operator's bilateral grid with :func:`hdrcore.tonemap_local._slice` everywhere.

- :func:`slice_grid`: the trilinear read of the bilateral grid at each pixel's position and log
  luminance; the kernel computes the same float64 operations in the same order (equal to the
  bit).
- :func:`global_8bit`: a built-in global operator as its public float32 function
  (:func:`~hdrcore.tonemap.tonemap_linear`, :func:`~hdrcore.tonemap.tonemap_reinhard`,
  :func:`~hdrcore.tonemap.tonemap_reinhard_rgb`) on chunks, then the sRGB table (equal to the
  bit: the kernel does the same float32 operations in the same order).
- :func:`durand_8bit`: the local operator's float form
  (:func:`hdrcore.tonemap_local.tonemap_durand`, float32) then the sRGB table; the compiled pass
  works in float64, so the two agree within one 8-bit code.
"""

from __future__ import annotations

import numpy as np

from .tonemap import (
    TONEMAP_OPERATORS,
    _luminance_weights,
    srgb_encode_8bit,
    tonemap_chunks,
)
from .tonemap_local import LocalToneParams, LocalToneState, tonemap_durand

__all__ = ["durand_8bit", "global_8bit", "slice_grid"]


def slice_grid(
    lg: np.ndarray,
    ys: np.ndarray,
    xs: np.ndarray,
    inv_cell: float,
    l0: float,
    inv_bin: float,
    grid: np.ndarray,
) -> np.ndarray:
    """Trilinear read (float64) of ``grid`` (log luminance level, row, column) at pixels of log
    luminance ``lg`` ``(len(ys), len(xs))``, rows at ``ys``, columns at ``xs``: cell
    ``(coordinate + 0.5) * inv_cell``, level ``(lg - l0) * inv_bin``, each clamped to the grid,
    the fractions to [0, 1]."""
    nz, ny, nx = grid.shape
    fy = (np.asarray(ys, np.float64)[:, None] + 0.5) * inv_cell
    fx = (np.asarray(xs, np.float64)[None, :] + 0.5) * inv_cell
    iy = np.clip(np.floor(fy).astype(np.int64), 0, ny - 2)
    ix = np.clip(np.floor(fx).astype(np.int64), 0, nx - 2)
    ty = np.clip(fy - iy, 0.0, 1.0)
    tx = np.clip(fx - ix, 0.0, 1.0)
    fz = (np.asarray(lg, np.float64) - l0) * inv_bin
    iz = np.clip(np.floor(fz).astype(np.int64), 0, nz - 2)
    tz = np.clip(fz - iz, 0.0, 1.0)
    acc = np.zeros(np.broadcast(fz, fy, fx).shape)
    for dz in range(2):
        wz = tz if dz else 1.0 - tz
        for dy in range(2):
            wy = ty if dy else 1.0 - ty
            for dx in range(2):
                wx = tx if dx else 1.0 - tx
                acc += wz * wy * wx * grid[iz + dz, iy + dy, ix + dx]
    return acc


def global_8bit(
    rad: np.ndarray, method: str, scale: float, white: float | None = None
) -> np.ndarray:
    """8-bit sRGB codes of the built-in global operator ``method`` on ``rad * scale``."""
    r = np.asarray(rad)
    if r.ndim == 2:
        r = r[..., None]
    return tonemap_chunks(r, TONEMAP_OPERATORS[method], scale, white)


def durand_8bit(
    rad: np.ndarray,
    scale: float,
    *,
    state: LocalToneState | None = None,
    offset: tuple[float, float] = (0.0, 0.0),
    pixel_size: float = 1.0,
    params: LocalToneParams | None = None,
) -> tuple[np.ndarray, LocalToneState]:
    """8-bit sRGB codes of the local operator on ``rad * scale`` (non-finite values black)
    through its float form, and the state."""
    r = np.asarray(rad)
    if r.ndim == 2:
        r = r[..., None]
    if r.shape[2] == 1:
        r = np.repeat(r, 3, axis=2)
    x = np.multiply(r, np.float32(scale), dtype=np.float32)
    np.nan_to_num(x, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
    y, st = tonemap_durand(
        x,
        _luminance_weights(),
        state=state,
        offset=offset,
        pixel_size=pixel_size,
        params=params,
    )
    return srgb_encode_8bit(y), st
