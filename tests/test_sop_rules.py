"""The JAX SOP rules (bfsop_jax.sop.rules) against the NumPy reference evaluator."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from bfsop_jax.sop import evaluate
from bfsop_jax.sop.io import random_instance
from bfsop_jax.sop.rules import (
    allowed_next,
    blocked_sets,
    close_plan,
    fits_budget,
    next_mask,
    open_nodes,
    plan_reward,
    plan_value,
)
from bfsop_jax.sop.types import plan_length


def _batch(closed: bool):
    insts = [random_instance(s, num_sets=5, viewpoints=3, closed=closed) for s in range(4)]
    return insts, jax.tree_util.tree_map(lambda *x: jnp.asarray(np.stack(x)), *insts)


def test_blocked_and_open_sets_single_equals_batched():
    for closed in (False, True):
        insts, batch = _batch(closed)
        blocked = blocked_sets(batch)
        for i, inst in enumerate(insts):
            np.testing.assert_array_equal(blocked_sets(inst), blocked[i])
            start_set = inst.set_id[inst.start]
            assert bool(blocked[i, start_set]) and int(blocked[i].sum()) == 1  # closed: end=start
            free = open_nodes(jnp.asarray(inst.set_id), blocked[i])
            np.testing.assert_array_equal(free, (inst.set_id >= 0) & (inst.set_id != start_set))


def test_plan_value_matches_the_reference_evaluator():
    rng = np.random.default_rng(0)
    for closed in (False, True):
        insts, batch = _batch(closed)
        t = plan_length(insts[0].num_sets)
        plans = np.full((len(insts), t), -1, np.int32)
        for i, inst in enumerate(insts):
            sets = rng.permutation(np.arange(1, inst.num_sets))[: t - 2]
            nodes = [int(rng.choice(np.flatnonzero(inst.set_id == s))) for s in sets]
            plans[i, : 1 + len(nodes)] = [int(inst.start)] + nodes
        plans = np.asarray(close_plan(batch, jnp.asarray(plans)))
        reward, cost = plan_value(batch, jnp.asarray(plans))
        for i, inst in enumerate(insts):
            want_r, want_c, _ = evaluate(inst, plans[i])
            np.testing.assert_allclose(float(reward[i]), want_r, rtol=1e-6)
            np.testing.assert_allclose(float(cost[i]), want_c, rtol=1e-6)
            assert plan_reward(inst, jnp.asarray(plans[i])) == reward[i]
            if closed:
                assert plans[i][plans[i] >= 0][-1] == inst.end


def test_next_mask_applies_the_budget_rule_only_when_asked():
    _, batch = _batch(False)
    b, k = batch.set_reward.shape
    visited = jnp.broadcast_to(blocked_sets(batch)[:, None], (b, 1, k))
    last = batch.start[:, None]
    travelled = jnp.zeros((b, 1), jnp.float32)
    plain = allowed_next(batch, visited, last)
    np.testing.assert_array_equal(next_mask(batch, visited, last, travelled, False), plain)
    masked = next_mask(batch, visited, last, travelled, True)
    np.testing.assert_array_equal(masked, fits_budget(batch, plain, last, travelled))
    assert bool(plain[..., -1].all())  # END is always allowed without the budget rule
