"""``merge(..., reuse=previous)``: the new result is written into a previous result's arrays."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.errors import ParameterError
from hdrcore.merge import merge
from hdrcore.registration import invert

from ._brackets import bracket, inverse_gamma_lut

FIELDS = (
    "radiance",
    "weight_sum",
    "shares",
    "clip_count",
    "clipped",
    "underexposed",
    "ghost_score",
    "ghost",
)


@pytest.mark.parametrize("channels", [3, 4])
@pytest.mark.parametrize("lut", [False, True])
def test_reused_arrays_receive_the_same_result(channels, lut):
    sb = bracket(
        bits=12,
        response="gamma" if lut else "linear",
        seed=3,
        max_shift=4.0,
        max_rotation_deg=1.0,
        scene="window",
    )
    kw = {"response": inverse_gamma_lut(4095, channels)} if lut else {"max_level": 4095}
    tf = [invert(t) for t in sb.to_reference]
    frames = sb.frames
    if channels == 4:  # a CFA cell's layout: green twice
        frames = [np.ascontiguousarray(np.concatenate([f, f[..., 1:2]], axis=2)) for f in frames]
    fresh = merge(frames, sb.exposure_times, transforms=tf, **kw)
    # an unrelated earlier result of the same size (tripod, other saturation): every array
    # must be overwritten, not only where the new result differs
    old = merge(frames, sb.exposure_times, saturation_level=3000, **kw)
    before = {name: getattr(old, name) for name in FIELDS}
    again = merge(frames, sb.exposure_times, transforms=tf, reuse=old, **kw)
    for name in FIELDS:
        assert getattr(again, name) is before[name], name
        np.testing.assert_array_equal(getattr(again, name), getattr(fresh, name), err_msg=name)
    assert again.message == fresh.message


def test_a_result_that_does_not_fit_is_refused():
    sb = bracket(bits=12, response="linear", seed=1)
    res = merge(sb.frames, sb.exposure_times, max_level=4095)
    with pytest.raises(ParameterError, match="does not fit"):
        merge([f[:-1] for f in sb.frames], sb.exposure_times, max_level=4095, reuse=res)
    with pytest.raises(ParameterError, match="shares"):
        merge(sb.frames[:2], sb.exposure_times[:2], max_level=4095, reuse=res)
