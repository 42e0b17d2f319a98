"""Batched VNS on host processes, and the jitted JAX callback."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bfsop_jax.sop import plan_length, solve_vns, solve_vns_batch, vns_callback
from bfsop_jax.sop.callback import vns_masked_callback
from bfsop_jax.sop.io import random_instance
from bfsop_jax.sop.vns import VNSConfig

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


def test_config_equals_old_keywords():
    insts, batch = _batch(2)
    seeds = np.array([3, 8])
    old = solve_vns_batch(batch, seeds, processes=1, **SMALL)
    new = solve_vns_batch(batch, seeds, processes=1, config=VNSConfig(**SMALL))
    np.testing.assert_array_equal(new.nodes, old.nodes)
    np.testing.assert_array_equal(new.cost, old.cost)


def test_masked_callback_takes_a_config():
    insts, batch = _batch(2)
    mask = jnp.array([False, True])
    plan = jax.vmap(lambda i, m: vns_masked_callback(i, m, 4, config=VNSConfig(**SMALL)))
    sol = plan(jax.tree_util.tree_map(jnp.asarray, batch), mask)
    ref = solve_vns(insts[1], seed=4, **SMALL).padded(plan_length(7))
    np.testing.assert_array_equal(np.asarray(sol.nodes[1]), ref.nodes)
    assert int(sol.nodes[0, 0]) == int(insts[0].start)
    assert (np.asarray(sol.nodes[0, 1:]) == -1).all()
    assert float(sol.reward[0]) == 0.0
