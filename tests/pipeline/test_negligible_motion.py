"""Motion below what the registration resolves is not applied: such a frame is merged where it
lies, not resampled (whose 4x4 support left the frame's border columns to the other frames)."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore import pipeline as pl
from hdrcore.geometry import rigid_matrix
from hdrcore.io import load_bracket
from tests.conftest import shared_dir

SHAPE = (4000, 6000)


@pytest.mark.parametrize(
    ("dx", "dy", "angle", "negligible"),
    [
        (0.0, 0.0, 0.0, True),
        (0.03, -0.02, 0.0, True),
        (0.0, 0.0, 1e-4, True),  # 0.006 px at the corners of a 24 MP frame
        (0.2, 0.0, 0.0, False),
        (0.0, 0.0, 0.002, False),  # 0.13 px at the corners
        (3.0, 1.0, 0.1, False),
    ],
)
def test_negligible_motion(dx, dy, angle, negligible) -> None:
    m = np.vstack([rigid_matrix(dx, dy, angle, SHAPE), [0.0, 0.0, 1.0]])
    assert pl._negligible_motion(m, SHAPE) == negligible


def test_a_real_tripod_bracket_merges_its_frames_in_place(monkeypatch) -> None:
    """frobisher (tripod): the registration finds 0.05-0.08 px at the corners where nothing
    moved; merged in place its left border column has the colour of the wall next to it,
    resampled it was left to one frame (up to 118 of 255 levels darker in the preview)."""
    d = shared_dir("frobisher-colour-hdri")
    bracket = load_bracket(sorted(d.glob("*.jpg")))
    result = pl.Pipeline(bracket).run()
    corners = [
        float(np.max(np.abs(m - np.eye(3)))) for m in result.registration.to_reference_homography
    ]
    assert max(corners) > 0  # some motion was found ...
    img = result.preview.image.astype(np.float64)
    # ... and the border column matches its neighbour as well as the next columns do
    edge = np.abs(img[:, 0] - img[:, 1]).mean()
    inner = np.abs(img[:, 1] - img[:, 2]).mean()
    assert edge < 3.0 * inner + 1.0
    monkeypatch.setattr(pl, "MIN_APPLIED_MOTION_PX", 0.0)  # motion applied however small
    resampled = pl.Pipeline(bracket).run().preview.image.astype(np.float64)
    assert np.abs(resampled[:, 0] - resampled[:, 1]).mean() > edge


def test_the_colour_checks_read_each_frame_where_the_merge_reads_it() -> None:
    """A frame the merge reads in place (the reference, negligible motion) is read in place by
    the colour checks and the anchoring too (the identity); a moved frame through its chain."""
    from hdrcore.registration import BracketRegistration

    tiny = np.vstack([rigid_matrix(0.03, -0.02, 0.0, SHAPE), [0.0, 0.0, 1.0]])
    moved = np.vstack([rigid_matrix(3.0, 1.0, 0.1, SHAPE), [0.0, 0.0, 1.0]])
    reg = BracketRegistration(
        1, (), None, "similarity", "fast", to_reference_homography=(tiny, np.eye(3), moved)
    )
    assert [m is None for m in pl._reading_chain(reg, SHAPE)] == [True, True, False]
    read = pl._read_in_place(reg, (*SHAPE, 3))
    np.testing.assert_array_equal(read[0], np.eye(3))
    np.testing.assert_array_equal(read[1], np.eye(3))
    np.testing.assert_array_equal(read[2], moved)
