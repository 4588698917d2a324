"""The black-frame rule on a real bracket (issue 17; skipped without ../shared/data): a black
frame added to frobisher (4.7 % of its pixels clipped in every frame with this response) changes
nothing, with and without a noise floor; before the fix it set those pixels to 0."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.merge import merge


@pytest.mark.parametrize("floor", [None, 6.0])
def test_a_black_frame_changes_nothing_on_a_real_bracket(frobisher_dir, floor) -> None:
    from hdrcore.io import load_bracket

    b = load_bracket([frobisher_dir])
    levels = [f.levels for f in b.frames]  # read-only, as decoded
    times = [float(f.exposure_time) for f in b.frames]
    lut = np.tile(np.linspace(0.0, 1.0, 256) ** 2.2, (3, 1))  # a response of the right shape
    kw = dict(response=lut, noise_floor=floor, ghost_test="pixels")
    r1 = merge(levels, times, **kw)
    black = np.zeros_like(levels[0])  # writable: a type the read-only frames are not
    r2 = merge([*levels, black], [*times, min(times) / 4.0], **kw)
    assert r1.clipped.mean() > 0.04
    np.testing.assert_array_equal(r2.radiance, r1.radiance)
    np.testing.assert_array_equal(r2.clipped, r1.clipped)
    np.testing.assert_array_equal(r2.underexposed, r1.underexposed)
    assert not r2.shares[-1].any()
