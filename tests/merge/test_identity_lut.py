"""A response LUT that is the identity (a linear TIFF's recovered gamma 1.0000005) is applied
as the identity: the kernel's vectorised linear path, the same merge (0.87 -> 0.15 s at 24 MP)."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.geometry import invert
from hdrcore.merge import merge
from hdrcore.merge import plan as plan_module
from hdrcore.synthetic import simulate_bracket


@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize("moved", [False, True])
def test_an_identity_lut_merges_as_the_table_did(bits, moved, monkeypatch) -> None:
    sim = simulate_bracket(
        scene="window",
        shape=(120, 180),
        exposure_times=(1.0, 4.0, 16.0),
        bits=bits,
        response="linear",
        noise_sigma=1.0,
        seed=3,
        max_shift=2.0,
    )
    top = (1 << bits) - 1
    frames = [f.astype(np.uint8 if bits == 8 else np.uint16) for f in sim.frames]
    # the recovered curve of a linear bracket: gamma within 1e-6 of 1
    lut = np.tile((np.arange(top + 1) / top) ** 1.0000005, (3, 1))
    transforms = None
    if moved:
        transforms = [
            None if k == sim.reference else invert(np.asarray(sim.to_reference[k]))
            for k in range(3)
        ]
    kw = dict(response=lut, max_level=top, weighting="hat", transforms=transforms)
    fast = merge(frames, sim.exposure_times, **kw)
    monkeypatch.setattr(plan_module, "IDENTITY_LUT_TOLERANCE", -1.0)  # the LUT's table path
    table = merge(frames, sim.exposure_times, **kw)
    np.testing.assert_allclose(
        fast.radiance, table.radiance, rtol=1e-5, atol=1e-9
    )  # the tolerance itself
    np.testing.assert_array_equal(fast.weight_sum, table.weight_sum)
    np.testing.assert_array_equal(fast.shares, table.shares)
    np.testing.assert_array_equal(fast.clipped, table.clipped)
    np.testing.assert_array_equal(fast.ghost, table.ghost)  # the region test reads the LUT
    if not moved:
        assert fast.ghost.any()  # frames merged where they lie: the motion is a ghost


def test_an_identity_lut_still_refuses_levels_past_it() -> None:
    from hdrcore.errors import ParameterError

    frames = [np.full((4, 5, 3), 100 * (k + 1), np.uint16) for k in range(3)]
    frames[1][0, 0, 0] = 300
    with pytest.raises(ParameterError, match="levels above max_level"):
        merge(frames, (1, 2, 4), response=np.linspace(0, 1, 256), max_level=255)
    assert plan_module._identity(np.tile(np.linspace(0, 1, 256), (3, 1)), 255)
    assert not plan_module._identity(np.tile(np.linspace(0, 1, 256) ** 1.01, (3, 1)), 255)
