"""A registration run again on the same frames (the inspector's sliders) with a
:class:`~hdrcore.registration._memo.RunMemo`: the same result to the bit, without making its
pyramids, block means and fixed structure images again."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.registration import _problem, register_bracket, residual
from hdrcore.registration._memo import RunMemo, array_key, table_key
from hdrcore.synthetic import simulate_bracket


@pytest.fixture(scope="module")
def bracket():
    sb = simulate_bracket(
        scene="window",
        shape=(320, 480),
        exposure_times=(1.0, 4.0, 16.0),
        bits=12,
        noise_sigma=1.0,
        max_shift=6,
        max_rotation_deg=0.5,
        seed=7,
    )
    ml = sb.max_level
    lut = (np.arange(ml + 1) / ml).astype(np.float32) ** 1.1
    return sb, lut


def _same(a, b) -> None:
    for p, q in zip(a.pairs, b.pairs, strict=True):
        np.testing.assert_array_equal(p.homography, q.homography)
        assert (p.status, p.message) == (q.status, q.message)
        assert (p.residual is None) == (q.residual is None)
        if p.residual is not None:
            np.testing.assert_array_equal(p.residual.shifts, q.residual.shifts)


def test_a_run_again_is_the_same_and_makes_only_what_changed(bracket, monkeypatch):
    sb, lut = bracket
    made = {"pyramids": 0, "block means": 0}
    bin_clip, reduce_ = _problem._kernels.bin_clip, residual._block_stats

    def counted_bin_clip(*a, **k):
        made["pyramids"] += 1
        return bin_clip(*a, **k)

    def counted_reduce(*a, **k):
        made["block means"] += 1
        return reduce_(*a, **k)

    monkeypatch.setattr(_problem._kernels, "bin_clip", counted_bin_clip)
    monkeypatch.setattr(residual, "_block_stats", counted_reduce)
    kw = dict(lut=lut, check_residual=True, previews=False)
    memo = RunMemo()

    def run(threshold: float, floor: int, with_memo: bool, sat: float = 0.97):
        views = [f[..., 1] for f in sb.frames]  # new views each run: keyed by where pixels lie
        args = dict(
            threshold=threshold,
            noise_floor=float(lut[floor]),
            saturation=float(lut[-1]) * sat,
            **kw,
        )
        if not with_memo:
            return register_bracket(views, sb.ratios, **args)
        memo.new_run()
        try:
            return register_bracket(views, sb.ratios, memo=memo, **args)
        finally:
            memo.end_run()

    first = run(0.1, 40, True)
    assert first.pairs[0].residual is not None  # the check ran
    n_pyr, n_red = made["pyramids"], made["block means"]
    # every frame's block sums once (a middle frame is the bright one of a pair and the
    # dark one of the next; two pairs side by side may both make it)
    assert n_pyr == 2 * len(first.pairs) and len(sb.frames) <= n_red <= 2 * len(first.pairs)
    kept = len(memo)
    for threshold in (0.1, 0.15):
        again = run(threshold, 40, True)
        assert made == {"pyramids": n_pyr, "block means": n_red}  # nothing made again
        _same(again, run(threshold, 40, False))
        n_pyr, n_red = made["pyramids"], made["block means"]  # (the run without the memo's)
    made_before = dict(made)
    floor_moved = run(0.15, 60, True)  # another noise floor: new pyramids, same block means
    assert made["pyramids"] == made_before["pyramids"] + 2 * len(first.pairs)
    assert made["block means"] == made_before["block means"]  # they read no noise floor
    _same(floor_moved, run(0.15, 60, False))
    made_before = dict(made)
    sat_moved = run(0.15, 60, True, sat=0.9)  # another saturation: the block sums kept
    assert made["block means"] == made_before["block means"]
    _same(sat_moved, run(0.15, 60, False, sat=0.9))
    assert len(memo) <= kept  # what the last run did not use is gone


def test_keys_follow_the_pixels_and_the_values():
    a = np.arange(24, dtype=np.uint16).reshape(2, 4, 3)
    assert array_key(a[..., 1]) == array_key(a[..., 1])  # two views of the same pixels
    assert array_key(a[..., 1]) != array_key(a[..., 2])
    t = np.linspace(0, 1, 5, dtype=np.float32)
    assert table_key(t) == table_key(t.copy()) and table_key(t) != table_key(t * 2)
    assert table_key(None) is None
