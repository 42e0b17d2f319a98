"""Batched VNS on host processes, and the jitted JAX callback."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bfsop_jax.sop import plan_length, solve_vns, solve_vns_batch, vns_callback
from bfsop_jax.sop.io import random_instance

SMALL = dict(max_iters=30, max_no_improve=15)


def _batch(n: int):
    insts = [random_instance(s, num_sets=6, viewpoints=3, closed=s % 2 == 1) for s in range(n)]
    return insts, jax.tree_util.tree_map(lambda *x: np.stack(x), *insts)


def test_process_pool_matches_solve_vns():
    insts, batch = _batch(3)
    seeds = np.array([4, 5, 6])
    out = solve_vns_batch(batch, seeds, processes=2, **SMALL)
    assert out.nodes.shape == (3, plan_length(7)) and out.nodes.dtype == np.int32
    for b, inst in enumerate(insts):
        ref = solve_vns(inst, seed=int(seeds[b]), **SMALL).padded(plan_length(7))
        np.testing.assert_array_equal(out.nodes[b], ref.nodes)
        assert out.reward[b] == ref.reward and out.cost[b] == ref.cost
    again = solve_vns_batch(batch, seeds, processes=2, **SMALL)  # the pool is reused
    np.testing.assert_array_equal(again.nodes, out.nodes)


def test_jitted_callback_matches_solve_vns():
    insts, batch = _batch(2)
    seeds = jnp.array([1, 2])

    @jax.jit
    def label(instances, seeds):
        sol = vns_callback(instances, seeds, **SMALL)
        return sol, jnp.sum(sol.reward)

    sol, total = label(jax.tree_util.tree_map(jnp.asarray, batch), seeds)
    assert sol.nodes.shape == (2, plan_length(7))
    for b, inst in enumerate(insts):
        ref = solve_vns(inst, seed=int(seeds[b]), **SMALL).padded(plan_length(7))
        np.testing.assert_array_equal(np.asarray(sol.nodes[b]), ref.nodes)
        assert float(sol.cost[b]) == float(ref.cost)
    assert float(total) == pytest.approx(float(np.sum(sol.reward)))


def test_unbatched_input_is_rejected():
    with pytest.raises(ValueError, match="batch"):
        solve_vns_batch(random_instance(0), [0])
