"""``Session.run_draft`` across slider steps: the full run's motion scaled instead of a binned
registration, the binned frames kept (only the saturation rule applied again)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hdrcore.draft import bin_levels, draft_factor, draft_registration
from hdrview.session import Controls, Session

from ._brackets import write_png_bracket

SIDE = 64  # 240x360 frames: drafts binned 6x6 (40x60)


@pytest.fixture
def session(tmp_path: Path) -> Session:
    s = Session()
    paths = write_png_bracket(tmp_path / "b", shape=(240, 362))  # 362: a ragged edge at 6x6
    s.load(paths, times=tmp_path / "b" / "exposure_times.txt")
    s.run(Controls())
    return s


def _draft(s: Session, controls: Controls):
    quick = s.run(controls, until="ratios")
    return s.run_draft(quick, max_side=SIDE)


def _motions(reg) -> list[np.ndarray]:
    return [np.asarray(q.matrix if q.matrix is not None else q.homography) for q in reg.pairs]


def test_a_saturation_step_uses_the_full_runs_motion_scaled(session: Session) -> None:
    full = session.result
    assert full is not None and full.registration is not None
    f = draft_factor(session.bracket.shape, SIDE)
    assert f == 6
    draft = _draft(session, Controls(saturation=240.0))
    assert session.draft_registration == "the full run's, scaled"
    assert draft.bracket.shape == (240 // 6, 362 // 6)
    expected = draft_registration(full.registration, f, draft.bracket.shape)
    got = draft.registration
    assert got is not None and got.reference == full.registration.reference
    for a, b in zip(_motions(got), _motions(expected), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-12)
    assert got.local is None
    # the region ghost test changes no pixel without deghost: the draft leaves it pending
    assert draft.merge is not None and draft.merge.ghost_test_pending
    # the hand-held motion (up to 3 px) is a sixth of it on the draft's grid
    for q, r in zip(got.pairs, full.registration.pairs, strict=True):
        assert q.dx == pytest.approx(r.dx / 6, abs=0.02)
        assert q.dy == pytest.approx(r.dy / 6, abs=0.02)
    # the noise floor and threshold t choose the registration's pixels, not its motion
    session.run(Controls(saturation=240.0))
    _draft(session, Controls(saturation=240.0, noise_floor=3.0, threshold=0.2))
    assert session.draft_registration == "the full run's, scaled"


@pytest.mark.parametrize("change", [{"align": "shift"}, {"reference": 0}])
def test_a_new_kind_of_motion_registers_the_binned_frames(session: Session, change) -> None:
    full = session.result
    assert full is not None and full.registration is not None
    quick = session.run(Controls(**change), until="ratios")
    draft = session.run_draft(quick, max_side=SIDE)
    assert session.draft_registration == "its own, of the binned frames"
    assert draft.registration is not None
    assert draft.registration.reference == quick.params.reference
    scaled = draft_registration(full.registration, 6, draft.bracket.shape)
    assert not all(
        np.allclose(a, b, atol=1e-6)
        for a, b in zip(_motions(draft.registration), _motions(scaled), strict=True)
    )


def test_no_full_run_no_full_motion(tmp_path: Path) -> None:
    s = Session()
    s.load(write_png_bracket(tmp_path / "b", shape=(240, 360)))
    _draft(s, Controls())
    assert s.draft_registration == "its own, of the binned frames"


def test_the_binned_frames_are_kept_and_clipped_again(session: Session) -> None:
    first = _draft(session, Controls(saturation=240.0))
    cache = session.draft_cache
    assert cache is not None and cache.binnings == 1
    # a noise-floor step: nothing binned again, the same levels
    same = _draft(session, Controls(saturation=240.0, noise_floor=3.0))
    assert cache.binnings == 1
    for a, b in zip(first.bracket.frames, same.bracket.frames, strict=True):
        np.testing.assert_array_equal(a.levels, b.levels)
    # a saturation step: nothing binned again, the clipped blocks follow the new level
    # (exactly what binning the frames at that level gives)
    lower = _draft(session, Controls(saturation=200.0))
    assert cache.binnings == 1
    bracket = session.bracket
    lut = lower.params.response  # the full run's curve
    assert bracket is not None
    m = bracket.max_level
    top = lower.bracket.max_level  # 16 x 255: binned in exposure, 16 times finer
    assert top == 16 * m
    for fr, small, before in zip(
        bracket.frames, lower.bracket.frames, first.bracket.frames, strict=True
    ):
        want = bin_levels(fr.levels, 6, saturation=200.0, max_level=m, lut=lut.to_lut(m))
        np.testing.assert_array_equal(small.levels, want)
        assert np.count_nonzero(small.levels == top) >= np.count_nonzero(before.levels == top)
    assert sum(np.count_nonzero(f.levels == top) for f in lower.bracket.frames) > sum(
        np.count_nonzero(f.levels == top) for f in first.bracket.frames
    )
    # another response (its table) or binning factor bins again
    _draft(session, Controls(saturation=200.0, response="srgb"))
    assert cache.binnings == 2
    session.run_draft(session.run(Controls(saturation=200.0), until="ratios"), max_side=48)
    assert cache.binnings == 3


def test_a_step_draft_reports_the_full_frames_ratios(session: Session) -> None:
    """Merged with the last full run's times, the draft takes the step's whole-frame ratios
    of the full frames (the quick run's) instead of fitting its own."""
    quick = session.run(Controls(saturation=240.0), until="ratios")
    draft = session.run_draft(quick, max_side=SIDE)
    assert draft.exposures_histogram is quick.exposures


def test_a_step_draft_takes_the_full_runs_frame_measures(session: Session) -> None:
    """A step that keeps the kind of motion: the draft reads the last full run's white balance
    and local tone mapping test; a new kind of motion (the draft registers its binned frames)
    measures its own."""
    full = session.result
    assert full is not None and full.frame_measures is not None
    draft = _draft(session, Controls(saturation=240.0))
    assert draft.frame_measures is not None
    assert draft.frame_measures.balance is full.frame_measures.balance
    other = _draft(session, Controls(align="shift"))
    assert other.frame_measures is not None
    assert other.frame_measures.balance is not full.frame_measures.balance
