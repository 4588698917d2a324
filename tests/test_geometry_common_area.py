"""The rectangle every frame covers (hdrcore.geometry.common_area), against a brute-force
search over the pixels."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.geometry import apply, common_area, invert, rigid_matrix, similarity_matrix


def _covered(mats, shape, margin):
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    ok = np.ones(shape, bool)
    for m in mats:
        if m is None:
            continue
        sx, sy = apply(invert(np.asarray(m, float)), xx, yy)
        ok &= (sx >= margin) & (sx <= w - 1 - margin) & (sy >= margin) & (sy <= h - 1 - margin)
    return ok


@pytest.mark.parametrize(
    "mats",
    [
        [None, np.array([[1, 0, 5.0], [0, 1, -3.0]])],
        [None, np.array([[1, 0, 5.0], [0, 1, -3.0]]), np.array([[1, 0, -7.5], [0, 1, 10.2]])],
        [None, rigid_matrix(2.0, -4.0, 0.8, (120, 180))],
        [similarity_matrix(-3.0, 1.5, 0.5, 1.01, (120, 180)), None],
    ],
)
def test_rectangle_is_covered_and_cannot_grow(mats) -> None:
    shape = (120, 180)
    ok = _covered(mats, shape, 2.0)
    x0, y0, x1, y1 = common_area(mats, shape, margin=2.0, step=8)
    assert x1 > x0 and y1 > y0
    assert ok[y0:y1, x0:x1].all()  # every pixel of it covered by every frame
    grown = ((x0 - 1, y0, x1, y1), (x0, y0 - 1, x1, y1), (x0, y0, x1 + 1, y1), (x0, y0, x1, y1 + 1))
    for gx0, gy0, gx1, gy1 in grown:
        if gx0 >= 0 and gy0 >= 0 and gx1 <= shape[1] and gy1 <= shape[0]:
            assert not ok[gy0:gy1, gx0:gx1].all()  # no side can move out


def test_identity_keeps_the_whole_frame_and_disjoint_frames_give_nothing() -> None:
    assert common_area([None, np.eye(3)], (50, 70)) == (0, 0, 70, 50)
    far = np.array([[1, 0, 200.0], [0, 1, 0.0]])
    assert common_area([None, far], (50, 70)) == (0, 0, 0, 0)
