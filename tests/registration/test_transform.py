"""Transform algebra: rigid parameters, composition, chaining pairs to a reference."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrcore.errors import ParameterError
from hdrcore.registration import compose, corner_error, invert, rigid_matrix, to_reference
from hdrcore.registration.transform import (
    identity,
    pair_from_reference,
    rigid_parameters,
    scale_matrix,
)
from hdrcore.synthetic import pair_matrix

SHAPE = (120, 180)
motion = st.tuples(st.floats(-40, 40), st.floats(-40, 40), st.floats(-5, 5))


@given(motion)
@settings(max_examples=50, deadline=None)
def test_rigid_parameters_invert_rigid_matrix(m):
    dx, dy, a = rigid_parameters(rigid_matrix(*m, SHAPE), SHAPE)
    assert np.allclose((dx, dy, a), m, atol=1e-9)


@given(motion, motion)
@settings(max_examples=50, deadline=None)
def test_compose_with_inverse_is_identity(m1, m2):
    a = rigid_matrix(*m1, SHAPE)
    b = rigid_matrix(*m2, SHAPE)
    assert np.allclose(compose(invert(a), a), identity(), atol=1e-9)
    # associativity through points
    x, y = np.array([0.0, 179.0, 33.0]), np.array([0.0, 119.0, 71.0])
    ab = compose(a, b)
    bx = b[:, :2] @ np.vstack([x, y]) + b[:, 2:]
    abx = a[:, :2] @ bx + a[:, 2:]
    assert np.allclose(ab[:, :2] @ np.vstack([x, y]) + ab[:, 2:], abx)


@pytest.mark.parametrize("reference", [0, 1, 2, 3])
def test_to_reference_recovers_truth_from_pairs(reference):
    rng = np.random.default_rng(reference)
    truth = [rigid_matrix(*rng.uniform(-10, 10, 2), rng.uniform(-2, 2), SHAPE) for _ in range(4)]
    # re-express the truth relative to the chosen reference
    truth = [compose(invert(truth[reference]), t) for t in truth]
    pairs = [pair_matrix(truth, i, i + 1) for i in range(3)]
    chained = to_reference(pairs, reference)
    for k in range(4):
        assert np.allclose(chained[k], truth[k], atol=1e-9)
    assert np.allclose(chained[reference], identity())
    for i in range(3):
        assert np.allclose(pair_from_reference(chained, i, i + 1), pairs[i], atol=1e-9)


def test_to_reference_rejects_bad_reference():
    with pytest.raises(ParameterError, match="reference frame out of range"):
        to_reference([identity()], 2)


def test_scale_matrix_round_trip_and_shift_scaling():
    m = rigid_matrix(8.0, -4.0, 1.0, SHAPE)
    assert np.allclose(scale_matrix(scale_matrix(m, 0.25), 4.0), m)
    s = scale_matrix(rigid_matrix(8.0, -4.0, 0.0, SHAPE), 0.5)
    assert np.allclose(s[:, 2], [4.0, -2.0])


def test_corner_error_is_distance_of_mapped_corners():
    a = rigid_matrix(1.0, 0.0, 0.0, SHAPE)
    assert np.allclose(corner_error(a, identity(), SHAPE), 1.0)
