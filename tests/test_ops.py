"""bfsop_jax.ops: the CPU-friendly arg-min/arg-max agree with jnp's, ties, inf and NaN included."""

from __future__ import annotations

import hypothesis.strategies as st
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings

from bfsop_jax import ops

# few distinct values so ties are common; inf and NaN among them
VALUES = st.sampled_from([-np.inf, -1.5, 0.0, 0.0, 2.0, 7.25, np.inf, np.nan])


@settings(max_examples=60, deadline=None)
@given(
    st.lists(VALUES, min_size=12, max_size=12),
    st.sampled_from([None, 0, 1, -1]),
    st.booleans(),
)
def test_matches_jnp(values, axis, with_nan):
    x = np.asarray(values, np.float32).reshape(3, 4)
    if not with_nan:
        x = np.where(np.isnan(x), 1.0, x).astype(np.float32)
    np.testing.assert_array_equal(ops.argmin(x, axis), jnp.argmin(x, axis))
    np.testing.assert_array_equal(ops.argmax(x, axis), jnp.argmax(x, axis))


@pytest.mark.parametrize("axis", [0, 1, None])
def test_bool_and_int_arrays(axis):
    rng = np.random.default_rng(0)
    for x in (rng.random((5, 6)) < 0.3, rng.integers(-3, 3, (5, 6)), np.zeros((5, 6), bool)):
        np.testing.assert_array_equal(ops.argmax(x, axis), jnp.argmax(x, axis))
        np.testing.assert_array_equal(ops.argmin(x, axis), jnp.argmin(x, axis))
    assert ops.argmin(np.ones((2, 3)), 1).dtype == jnp.int32
