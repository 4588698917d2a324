"""The registration's thresholds snapped to the bracket's quantile ladder
(:mod:`hdrcore.registration.thresholds`): never more kept than asked, fewer than ``fraction`` of
the samples left out beyond the request, at most ``max_step`` of the range moved, and one answer
for every threshold inside a run (what keeps the registration's cache key)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrcore.errors import ParameterError
from hdrcore.registration.thresholds import (
    MASK_FRACTION,
    MAX_STEP,
    MIN_STEP_LEVELS,
    snap_levels,
)


def _counts(seed: int, levels: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    c = np.zeros(levels)
    idx = rng.integers(0, levels, 400)
    np.add.at(c, idx, rng.integers(1, 2000, idx.size))
    c[: levels // 4] += rng.integers(0, 5, levels // 4)  # a dense dark end
    c[levels // 2 : levels // 2 + 40] = 0.0  # an empty stretch
    return c


@settings(max_examples=300, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    levels=st.sampled_from([256, 1024, 16384, 65536]),
    fraction=st.sampled_from([1e-3, 1e-2, 0.05]),
    max_step=st.sampled_from([1 / 512, 1 / 64, 1 / 8]),
    s_pos=st.floats(0.05, 1.0),
    f_pos=st.floats(0.0, 0.9),
)
def test_snapped_thresholds_keep_a_subset_within_the_bounds(
    seed, levels, fraction, max_step, s_pos, f_pos
) -> None:
    c = _counts(seed, levels)
    s = s_pos * (levels - 1)
    f = f_pos * s - 1.0
    s2, f2 = snap_levels(c, s, f, fraction, max_step)
    z = np.arange(levels)
    kept, kept2 = (z > f) & (z < s), (z > f2) & (z < s2)
    assert not np.any(kept2 & ~kept)  # never a sample the request leaves out
    assert s2 <= np.ceil(s) and f2 >= np.floor(f)
    if (s2, f2) != (s, f):
        n = c.sum()
        assert c[(z >= s2) & (z < s)].sum() < fraction * n
        assert c[(z > f) & (z <= f2)].sum() < fraction * n
        step = max(max_step * (levels - 1), MIN_STEP_LEVELS)
        assert s - s2 < step + 1e-9
        assert f2 - f < step


@pytest.mark.parametrize("levels", [16384, 65536])
def test_every_threshold_inside_a_run_snaps_to_one_pair(levels) -> None:
    c = _counts(7, levels)
    out = [snap_levels(c, s, 3.0) for s in np.arange(0.9 * levels, 0.95 * levels, 0.5)]
    pairs = sorted(set(out))
    # the ladder: few distinct answers for many slider positions, each a contiguous stretch
    assert len(pairs) < len(out) / 10
    changes = sum(1 for a, b in zip(out, out[1:], strict=False) if a != b)
    assert changes == len(pairs) - 1


def test_a_level_holding_more_than_the_fraction_is_never_stepped_over() -> None:
    c = np.full(4096, 10.0)
    c[3000] = 1e6  # one level with most of the samples
    for s in np.arange(3000.5, 3012.0, 0.5):  # z < s keeps level 3000: so must the snapped one
        assert snap_levels(c, s, 4.0)[0] >= 3001.0
    assert snap_levels(c, 3000.0, 4.0)[0] <= 3000.0
    # 8-bit frames: 1/512 of the range is under a level; the ladder's runs still span up to
    # MIN_STEP_LEVELS levels, each holding under the fraction of the samples
    flat = np.full(256, 1.0)
    flat[:64] = 1000.0  # most samples dark: a bright level holds 0.002 % of them
    out = [snap_levels(flat, s, 4.0) for s in np.arange(240.0, 252.0, 1.0)]
    assert len(set(out)) < len(out) / 2
    for s, (s2, f2) in zip(np.arange(240.0, 252.0, 1.0), out, strict=True):
        assert s - MIN_STEP_LEVELS < s2 <= s and f2 == 4.0
    # a level holding more than the fraction is its own run at 8 bits too
    heavy = flat.copy()
    heavy[245] = 1e3
    assert snap_levels(heavy, 246.0, 4.0)[0] == 246.0


def test_no_fraction_or_no_step_returns_the_request() -> None:
    c = _counts(1, 4096)
    assert snap_levels(c, 4000.3, 20.7, fraction=0.0) == (4000.3, 20.7)
    assert snap_levels(c, 4000.3, 20.7, max_step=0.0) == (4000.3, 20.7)
    assert MASK_FRACTION == 5e-3 and MAX_STEP == 1 / 512 and MIN_STEP_LEVELS == 3


def test_bad_input_is_refused() -> None:
    with pytest.raises(ParameterError, match="per-level counts"):
        snap_levels(np.ones((2, 2, 2)), 10.0, 1.0)
    with pytest.raises(ParameterError, match="fraction in"):
        snap_levels(np.ones(16), 10.0, 1.0, fraction=1.5)
    with pytest.raises(ParameterError, match="finite"):
        snap_levels(np.ones(16), float("nan"), 1.0)
