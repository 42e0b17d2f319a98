"""BF-SOP strategy switcher: tours planned by the VNS teacher, greedy plan estimate."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bfsop_jax.agents import BFSOP, VNSPlanner, max_macro_steps, rollout
from bfsop_jax.agents.bfsop import greedy_estimate
from bfsop_jax.config import get_preset
from bfsop_jax.env import reset
from bfsop_jax.sop.types import SOPInstance, evaluate, validate
from bfsop_jax.world.constants import N_CATEGORIES, N_TARGETS
from bfsop_jax.world.generator import generate_house

SMOKE = get_preset("smoke")


def test_greedy_estimate_on_a_line():
    xy = jnp.asarray([[1.0, 0.0], [2.0, 0.0], [3.0, 0.0], [10.0, 0.0]])
    reward = jnp.asarray([1.0, 1.0, 1.0, 5.0])
    valid = jnp.asarray([True, True, True, False])
    r, c = greedy_estimate(xy, reward, valid, jnp.zeros(2), jnp.asarray(100.0))
    assert float(r) == pytest.approx(3.0)
    assert float(c) == pytest.approx(3.0 * 1.3, rel=1e-5)  # straight line x detour
    r, c = greedy_estimate(xy, reward, valid, jnp.zeros(2), jnp.asarray(2.7))
    assert float(r) == pytest.approx(2.0) and float(c) <= 2.7


def test_bfsop_episode_switches_and_plans_feasible_tours():
    house = jax.jit(generate_house, static_argnums=1)(jax.random.key(7), SMOKE)
    prior = jnp.full((N_CATEGORIES, N_TARGETS), 0.5)  # every receptacle is a landmark
    state = jax.jit(reset, static_argnums=3)(jax.random.key(7), house, 8, SMOKE, prior)
    n = max_macro_steps(SMOKE.budget_m, SMOKE, slack=2.0)
    strategy = BFSOP(VNSPlanner(0, max_iters=100, max_no_improve=50), record=True)
    run = jax.jit(lambda s: rollout(s, strategy, SMOKE, n))
    final, traj = run(state)
    instances, plans = traj.record

    assert int(traj.switched.sum()) >= 1
    assert float(final.path_length) <= float(final.budget) + 1e-5
    switched = np.nonzero(np.asarray(traj.planned))[0]
    assert len(switched) >= 1
    for t in switched:
        inst = jax.tree_util.tree_map(lambda a, t=t: np.asarray(a)[t], instances)
        inst = SOPInstance.create(
            inst.cost, inst.set_id, inst.set_reward, 0, -1, inst.budget, inst.coords
        )
        validate(inst)
        nodes = [int(v) for v in np.asarray(plans.nodes[t]) if v >= 0]
        reward, cost, feasible = evaluate(inst, nodes)
        assert feasible and nodes[0] == 0
    touring = np.asarray(traj.touring)[np.asarray(traj.active)]
    assert touring.any() and (~touring).any()
    assert np.asarray(traj.moved).any()
