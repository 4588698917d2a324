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


def _tripod_srgb(tmp_path):
    from hdrcore.synthetic import simulate_bracket, write_bracket

    sb = simulate_bracket(
        scene="window",
        shape=(240, 360),
        exposure_times=(1.0, 4.0, 16.0),
        bits=8,
        response="srgb",
        noise_sigma=0.5,
        max_shift=0,
        max_rotation_deg=0.0,
        seed=3,
    )
    written = write_bracket(tmp_path / "tripod", sb, fmt="tiff")
    # recorded times 5 % off per step: the merge takes the measured ratios, not these
    off = {
        p.name: float(t) * 1.05**k
        for k, (p, t) in enumerate(zip(written.frames, sb.exposure_times, strict=True))
    }
    return load_bracket(list(written.frames), exposure_times=off)


def test_a_new_registration_that_moves_no_frame_keeps_what_reads_the_frames(tmp_path) -> None:
    """The merge and the frame measures read a registration only through how the merge reads
    each frame (``_Reading``), and the registered-pixel ratios compare frames the merge reads
    in place in place: a tripod bracket registered again (threshold t moved) keeps its frame
    measures and its merge, which would come out the same."""
    bracket = _tripod_srgb(tmp_path)
    pipe = pl.Pipeline(bracket)
    first = pipe.run()
    assert first.frame_measures is not None
    assert all(m is None for m in pl._reading_chain(first.registration, bracket.shape))
    assert first.times_source == "estimated", first.times_source
    again = pipe.run(first.params.replace(threshold=first.params.threshold * 1.5))
    assert again.registration is not first.registration  # registered again ...
    assert again.frame_measures is first.frame_measures  # ... nothing read differently
    # the pairs compared in place, as the merge reads them: the same ratios, the same merge
    assert "overlap_ratios" in again.stages_run and "merge" not in again.stages_run
    assert again.merge is first.merge
    fresh = pl.Pipeline(bracket).run(again.params)
    np.testing.assert_array_equal(again.radiance, fresh.radiance)
    assert again.frame_measures.balance == fresh.frame_measures.balance


def test_pairs_the_merge_reads_in_place_are_compared_in_place(tmp_path) -> None:
    """The registered-pixel ratios of a pair whose frames the merge reads in place do not
    depend on the pair's sub-resolution motion (the same ratios to the bit)."""
    from dataclasses import replace

    bracket = _tripod_srgb(tmp_path)
    pipe = pl.Pipeline(bracket)
    res = pipe.run()
    reg = res.registration
    nudged = replace(
        reg,
        pairs=tuple(
            replace(q, matrix=np.asarray(q.matrix) + [[0, 0, 0.02], [0, 0, -0.01]])
            if q.matrix is not None
            else q
            for q in reg.pairs
        ),
    )
    assert any(
        not np.array_equal(a.matrix, b.matrix) for a, b in zip(reg.pairs, nudged.pairs, strict=True)
    )
    p = res.params.replace(saturation=res.saturation, noise_floor=res.noise_floor)
    a = pl._pixel_ratios(pipe._ctx, p, res.lut, reg, res.exposures_histogram, None)
    b = pl._pixel_ratios(pipe._ctx, p, res.lut, nudged, res.exposures_histogram, None)
    assert [q.ratio for q in a.pairs] == [q.ratio for q in b.pairs]
