"""The row form of the Keys cubic read (hdrcore.geometry.keys_row_weights / keys_row_at): the
same values as keys_at to the bit, whatever the positions."""

from __future__ import annotations

import numba
import numpy as np

from hdrcore.geometry import keys_at, keys_row_at, keys_row_weights


@numba.njit(cache=False)
def _both(src, sx, sy):  # pragma: no cover - compiled
    n = sx.size
    ix = np.empty(n, np.int64)
    iy = np.empty(n, np.int64)
    wx = np.empty((n, 4))
    wy = np.empty((n, 4))
    keys_row_weights(sx, sy, n, ix, iy, wx, wy)
    h, w = src.shape
    a = np.full(n, np.nan)
    b = np.full(n, np.nan)
    for k in range(n):
        if sx[k] >= -3.0 and sx[k] <= w + 2.0 and sy[k] >= -3.0 and sy[k] <= h + 2.0:
            a[k] = keys_at(src, sx[k], sy[k])
            b[k] = keys_row_at(src, k, ix, iy, wx, wy)
    return a, b, ix, iy, wx, wy


def test_row_reads_equal_keys_at_to_the_bit() -> None:
    rng = np.random.default_rng(4)
    src = rng.random((23, 31)).astype(np.float32)
    # inside, at the edges (clamped taps), whole pixels and fractions near 0 and 1
    sx = np.concatenate([rng.uniform(-2.5, 32.5, 400), np.arange(-2.0, 33.0), [1 - 1e-12, 5e-13]])
    sy = np.concatenate([rng.uniform(-2.5, 24.5, 400), np.linspace(-2.0, 24.0, 35), [3.0, 7.0]])
    a, b, *_ = _both(src, sx, sy)
    inside = np.isfinite(a)
    assert inside.sum() > 300
    assert np.array_equal(a[inside].view(np.uint64), b[inside].view(np.uint64))


def test_positions_that_are_not_finite_get_the_weights_of_zero() -> None:
    src = np.ones((8, 8), np.float32)
    sx = np.array([np.nan, np.inf, -np.inf, 1e300, 2.5])
    sy = np.array([0.0, np.nan, 1.0, 1.0, 2.5])
    _, _, ix, iy, wx, wy = _both(src, sx, sy)
    zero = np.array([-0.0, 1.0, 0.0, -0.0])  # Keys' weights at 0
    for k in range(4):  # x not finite or beyond 1e15
        assert ix[k] == 0
        np.testing.assert_array_equal(wx[k], zero)
    assert iy[1] == 0 and np.array_equal(wy[1], zero)  # y NaN
    assert iy[0] == 0 and iy[2] == 1 and iy[3] == 1  # finite y as it is
    assert ix[4] == 2 and iy[4] == 2
