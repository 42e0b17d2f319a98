"""BF-SOP strategy switcher: tours planned by the VNS teacher, greedy plan estimate."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bfsop_jax.agents import BFSOP, VNSPlanner, max_macro_steps, rollout
from bfsop_jax.agents.bfsop import detour_costs, greedy_estimate, reach_lower_bound
from bfsop_jax.config import get_preset
from bfsop_jax.env import reset
from bfsop_jax.sop.builder import viewpoint_candidates
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


def test_detour_costs_measure_tours_against_the_way_to_the_frontier():
    # start at x=0 heading for a frontier at x=10; landmark A at x=4 lies on the way,
    # landmark B at x=-4 behind; one node unreachable from the start
    x = np.asarray([0.0, 4.0, -4.0, 6.0])
    cost = np.abs(x[:, None] - x[None]).astype(np.float32) * 1.5  # a winding geodesic
    cost[0, 3] = cost[3, 0] = np.inf
    inst = SOPInstance.create(cost, [0, 1, 2, 3], [0.0, 1.0, 1.0, 1.0], 0, -1, 20.0,
                              np.stack([x, 0 * x], 1))  # fmt: skip
    inst = jax.tree_util.tree_map(jnp.asarray, inst)
    goal = jnp.asarray([10.0, 0.0])
    out = detour_costs(inst, goal, jnp.asarray(True))
    c = np.asarray(out.cost)
    assert np.isinf(c[0, 3]) and np.isinf(c[3, 0])
    assert (c[np.isfinite(c)] >= 0).all() and np.all(np.diag(c) == 0)
    # on the way: 6 m walked, 4 m closer to the frontier; behind: 6 m walked, 4 m farther
    assert float(c[0, 1]) == pytest.approx(2.0) and float(c[0, 2]) == pytest.approx(10.0)
    # along a path the straight-line terms telescope: length + h(last) - h(start)
    path = [0, 2, 1]
    plain = sum(cost[a, b] for a, b in zip(path[:-1], path[1:], strict=True))
    shifted = sum(c[a, b] for a, b in zip(path[:-1], path[1:], strict=True))
    assert shifted == pytest.approx(plain + abs(4.0 - 10.0) - 10.0, rel=1e-5)
    # with no frontier to head for the instance is unchanged
    same = detour_costs(inst, goal, jnp.asarray(False))
    np.testing.assert_array_equal(np.asarray(same.cost), np.asarray(inst.cost))


def test_reach_lower_bound_never_exceeds_the_nearest_viewpoint():
    # landmarks 10 m ahead (towards a frontier at x=30) and 10 m behind, 1 m x 0.5 m
    centre = jnp.asarray([[10.0, 0.0], [-10.0, 0.0]])
    half = jnp.asarray([[0.5, 0.25], [0.5, 0.25]])
    r = float(np.hypot(0.5, 0.25)) + SMOKE.viewpoint_max_m
    low = np.asarray(reach_lower_bound(jnp.zeros(2), centre, half, SMOKE))
    np.testing.assert_allclose(low, [10.0 - r, 10.0 - r], atol=1 / 32)
    goal = jnp.asarray([30.0, 0.0])
    detour = np.asarray(reach_lower_bound(jnp.zeros(2), centre, half, SMOKE, goal))
    np.testing.assert_allclose(detour, [0.0, 20.0 - 2 * r], atol=1 / 32)
    # every real viewpoint of the landmark lies at least that far (straight line)
    xy, _, _ = viewpoint_candidates(centre[1], half[1], SMOKE)
    assert float(np.linalg.norm(np.asarray(xy), axis=-1).min()) >= low[1] - 1e-3


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
