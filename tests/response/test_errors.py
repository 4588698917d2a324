"""Bad input gives clear errors; every method's output is monotone (property test)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrcore.errors import BracketError, ParameterError
from hdrcore.response import RESPONSE_METHODS, recover_response
from hdrcore.synthetic import simulate_bracket

from ._truth import SEED_TIMES, seed_bracket

METHODS = list(RESPONSE_METHODS)


@pytest.mark.parametrize("method", METHODS)
def test_one_frame(method: str) -> None:
    b = seed_bracket("gamma", 1.0)
    with pytest.raises(BracketError, match="at least two frames"):
        recover_response(b.frames[:1], SEED_TIMES[:1], method=method)


@pytest.mark.parametrize("method", METHODS)
def test_identical_exposures(method: str) -> None:
    b = seed_bracket("gamma", 1.0)
    with pytest.raises(BracketError, match="same exposure time"):
        recover_response(b.frames[:3], (2.0, 2.0, 8.0), method=method)


@pytest.mark.parametrize("method", ["mitsunaga1999", "grossberg2003"])
def test_ratio_of_one(method: str) -> None:
    b = seed_bracket("gamma", 1.0)
    with pytest.raises(BracketError, match="different exposure"):
        recover_response(b.frames[:2], None, method=method, ratios=[1.0])


def test_order_and_missing_times() -> None:
    b = seed_bracket("gamma", 1.0)
    with pytest.raises(BracketError, match="darkest first"):
        recover_response(b.frames[::-1], SEED_TIMES[::-1], method="debevec1997")
    with pytest.raises(ParameterError, match="needs the exposure times"):
        recover_response(b.frames, None, method="debevec-histogram")
    with pytest.raises(ParameterError, match="rough exposure ratios"):
        recover_response(b.frames, None, method="grossberg2003")
    with pytest.raises(ParameterError, match="one exposure time per frame"):
        recover_response(b.frames, SEED_TIMES[:3], method="debevec1997")


def test_unknown_method_lists_valid_names() -> None:
    b = seed_bracket("gamma", 1.0)
    with pytest.raises(
        ParameterError,
        match="'debevec1997', 'debevec-histogram', 'mitsunaga1999', 'grossberg2003'",
    ):
        recover_response(b.frames, SEED_TIMES, method="robertson")
    with pytest.raises(ParameterError, match="unknown parameter.*order"):
        recover_response(b.frames, SEED_TIMES, method="debevec1997", order=3)


def test_bad_frames() -> None:
    b = seed_bracket("gamma", 1.0)
    with pytest.raises(ParameterError, match="integer"):
        recover_response([f.astype(np.float32) for f in b.frames], SEED_TIMES)
    with pytest.raises(BracketError, match="same size"):
        recover_response([b.frames[0], b.frames[1][:-1]], SEED_TIMES[:2])
    with pytest.raises(ParameterError, match="outside 0..max_level"):
        recover_response(b.frames, SEED_TIMES, max_level=100)
    with pytest.raises(ParameterError, match="cutoff"):
        recover_response(b.frames, SEED_TIMES, cutoff=1.5)


@pytest.mark.parametrize("method", METHODS)
def test_all_saturated_bracket(method: str) -> None:
    frames = [np.full((32, 32, 3), 255, np.uint8) for _ in range(3)]
    with pytest.raises(Exception, match="channel 0"):
        recover_response(frames, (1.0, 2.0, 4.0), method=method)


@pytest.mark.parametrize("method", METHODS)
@settings(max_examples=5, deadline=None)
@given(
    response=st.sampled_from(["polynomial3", "gamma", "s-curve", "srgb", "linear"]),
    noise=st.sampled_from([0.0, 1.0, 3.0]),
    n_frames=st.integers(2, 5),
    step=st.sampled_from([2.0, 4.0, 8.0]),
    seed=st.integers(0, 1000),
    monotone_off=st.booleans(),
)
def test_every_output_is_monotone(method, response, noise, n_frames, step, seed, monotone_off):
    """Monotone and normalised whatever the data (even unconstrained fits are made usable)."""
    times = [step**k for k in range(n_frames)]
    b = simulate_bracket(
        scene="window",
        shape=(48, 64),
        exposure_times=times,
        bits=8,
        response=response,
        noise_sigma=noise,
        seed=seed,
    )
    curve = recover_response(b.frames, times, method=method, monotone=not monotone_off)
    assert np.all(np.diff(curve.g, axis=1) >= 0)
    assert np.allclose(curve.g[:, 0], 0) and np.allclose(curve.g[:, -1], 1)
    assert curve.status in ("ok", "warning")
