"""The merge resamples a frame through a homography (issue 14): a frame rendered through a known
perspective motion merges back onto the reference grid, the kernel's result is the
specification's (1, 3 and 4 channels), and an affine motion written as 3x3 gives what its 2x3
form gives."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from hdrcore.merge import merge
from hdrcore.merge.plan import as_transforms as _as_transforms

from ._spec_check import kernel_vs_spec, same_bits


def _scene(h: int, w: int) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    base = 0.25 + 0.2 * np.sin(xx / 9.0) * np.cos(yy / 11.0) + 0.1 * np.sin((xx + yy) / 17.0)
    return np.stack([base, base * 0.9, base * 0.8], axis=-1)


@pytest.fixture(scope="module")
def frames():
    h, w = 96, 128
    # output (reference) pixel -> frame pixel: a small perspective motion
    t = np.array([[1.004, 0.003, 2.3], [-0.002, 0.997, -1.7], [2.0e-5, -1.5e-5, 1.0]])
    ref = _scene(h, w)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    # frame pixel q shows the scene at t^-1 q: render it from the (smooth) reference scene
    inv = np.linalg.inv(t)
    s = inv[2, 0] * xx + inv[2, 1] * yy + inv[2, 2]
    sx = (inv[0, 0] * xx + inv[0, 1] * yy + inv[0, 2]) / s
    sy = (inv[1, 0] * xx + inv[1, 1] * yy + inv[1, 2]) / s
    moved = np.stack(
        [ndimage.map_coordinates(ref[..., c], [sy, sx], order=3, mode="nearest") for c in range(3)],
        axis=-1,
    )
    to16 = lambda a: np.clip(np.rint(a * 60000), 0, 65535).astype(np.uint16)  # noqa: E731
    return to16(ref), to16(moved), t


def test_frame_through_a_homography_merges_onto_the_reference(frames) -> None:
    ref, moved, t = frames
    out = merge([moved], [1.0], max_level=65535, transforms=[t]).radiance
    truth = ref.astype(np.float64) / 65535.0
    inner = (slice(8, -8), slice(8, -8))
    lit = truth[inner] > 0  # black pixels have no relative error
    err = np.abs(out[inner] - truth[inner])[lit] / truth[inner][lit]
    assert lit.mean() > 0.9
    assert np.nanmedian(err) < 2e-3 and np.nanpercentile(err, 99) < 2e-2


@pytest.mark.parametrize("c", [1, 3, 4])
def test_kernel_agrees_and_affine_3x3_equals_2x3(frames, c) -> None:
    ref, moved, t = frames
    pick = [0, 1, 2, 1][:c] if c > 1 else [1]
    ref, moved = ref[..., pick], moved[..., pick]
    kernel_vs_spec([ref, moved], [1.0, 2.0], max_level=65535, transforms=[None, t])
    affine = np.array([[1.01, 0.002, 1.5], [0.001, 0.99, -0.5]])
    three = np.vstack([affine, [0.0, 0.0, 1.0]])
    assert np.array_equal(_as_transforms([affine], 1)[0], _as_transforms([three], 1)[0])
    kw = dict(max_level=65535, ghost_test="pixels")
    same_bits(
        merge([ref, moved], [1.0, 2.0], transforms=[None, affine], **kw),
        merge([ref, moved], [1.0, 2.0], transforms=[None, three], **kw),
    )
    with pytest.raises(Exception, match="2x3 affine matrix or 3x3 homography"):
        _as_transforms([np.ones((4, 4))], 1)
