"""SOP instances built from the online map (docs/design.md §7.1)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from bfsop_jax.config import get_preset
from bfsop_jax.env import reset
from bfsop_jax.navigation.grid import planning_blocked, xy_to_plan_cell
from bfsop_jax.sop.builder import build_instance
from bfsop_jax.sop.types import validate
from bfsop_jax.world.constants import N_CATEGORIES, N_TARGETS, is_receptacle
from bfsop_jax.world.generator import generate_house

SMOKE = get_preset("smoke")
APPLE = 0


def _prior() -> jnp.ndarray:
    rng = np.random.default_rng(0)
    p = rng.uniform(0.05, 0.9, (N_CATEGORIES, N_TARGETS)).astype(np.float32)
    return jnp.asarray(p)


@functools.cache
def _state(seed: int = 0):
    house = jax.jit(generate_house, static_argnums=1)(jax.random.key(seed), SMOKE)
    return jax.jit(reset, static_argnums=3)(jax.random.key(seed), house, APPLE, SMOKE, _prior())


build = jax.jit(build_instance, static_argnums=9)


def _build(state, candidates):
    h = state.house
    return build(
        state.belief,
        state.pose[:2],
        state.budget - state.path_length,
        candidates,
        h.object_category,
        h.object_xy,
        h.object_half_extent,
        state.prior,
        state.category,
        SMOKE,
    )


def test_full_instance_is_valid_and_geometric():
    state = _state(0)
    cats = np.asarray(state.house.object_category)
    candidates = jnp.asarray(is_receptacle(cats))
    inst, lois = _build(state, candidates)
    inst = inst.to_numpy()
    validate(inst)
    n, k = SMOKE.n_sop_nodes, SMOKE.n_loi + 1
    assert inst.cost.shape == (n, n) and inst.set_reward.shape == (k,)
    assert inst.set_id[0] == 0 and inst.set_reward[0] == 0 and inst.end == -1

    idx = np.asarray(lois.index)
    n_lm = int(np.sum(is_receptacle(cats)))
    assert np.sum(idx >= 0) == min(n_lm, SMOKE.n_loi)
    # Highest rewards first, and rewards are the prior of (landmark type, category).
    prior = np.asarray(state.prior)
    chosen = idx[idx >= 0]
    rewards = prior[cats[chosen], APPLE]
    assert np.all(np.diff(rewards) <= 1e-6)
    nonempty = [s for s in range(1, k) if np.any(inst.set_id == s)]
    np.testing.assert_allclose(inst.set_reward[nonempty], rewards[np.array(nonempty) - 1])

    valid = inst.set_id >= 0
    blocked = np.asarray(planning_blocked(state.belief, SMOKE))
    cells = np.asarray(xy_to_plan_cell(jnp.asarray(inst.coords), SMOKE))
    assert not blocked[cells[valid, 0], cells[valid, 1]].any()
    # Viewpoints lie viewpoint_min..max beyond their landmark's footprint.
    xy = np.asarray(state.house.object_xy)
    half = np.asarray(state.house.object_half_extent)
    for node in np.nonzero(valid)[0][1:]:
        lm = idx[inst.set_id[node] - 1]
        gap = np.abs(inst.coords[node] - xy[lm]) - half[lm]
        clearance = np.linalg.norm(np.maximum(gap, 0.0))
        assert SMOKE.viewpoint_min_m - 1e-3 <= clearance <= SMOKE.viewpoint_max_m + 1e-3
    # Costs: finite and symmetric among valid nodes, never shorter than the straight line.
    c = inst.cost[np.ix_(valid, valid)]
    assert np.all(np.isfinite(c))
    np.testing.assert_allclose(c, c.T)
    p = inst.coords[valid]
    euclid = np.linalg.norm(p[:, None] - p[None], axis=-1)
    assert np.all(c >= euclid - 2 * SMOKE.plan_cell_size)
    assert float(inst.budget) == float(state.budget - state.path_length)


def test_empty_and_partial_landmark_sets_give_masked_instances():
    state = _state(1)
    cats = np.asarray(state.house.object_category)
    inst, lois = _build(state, jnp.zeros(cats.shape, bool))
    inst = inst.to_numpy()
    validate(inst)
    assert np.all(inst.set_id[1:] == -1) and np.all(inst.set_reward == 0)
    assert np.all(np.asarray(lois.index) == -1)

    some = np.zeros(cats.shape, bool)
    some[np.nonzero(is_receptacle(cats))[0][:3]] = True
    inst, lois = _build(state, jnp.asarray(some))
    inst = inst.to_numpy()
    validate(inst)
    assert np.sum(np.asarray(lois.index) >= 0) == 3
    assert set(np.unique(inst.set_id[inst.set_id > 0])) <= {1, 2, 3}


def test_batched_build_matches_single():
    s0, s1 = _state(0), _state(1)
    states = jax.tree_util.tree_map(lambda a, b: jnp.stack([a, b]), s0, s1)
    cand = jnp.asarray(is_receptacle(np.asarray(states.house.object_category)))
    h = states.house
    batched = jax.jit(jax.vmap(build_instance, in_axes=(0,) * 9 + (None,)), static_argnums=9)
    inst, _ = batched(
        states.belief, states.pose[:, :2], states.budget - states.path_length, cand,
        h.object_category, h.object_xy, h.object_half_extent, states.prior, states.category,
        SMOKE,
    )  # fmt: skip
    single, _ = _build(s1, cand[1])
    np.testing.assert_allclose(np.asarray(inst.cost[1]), np.asarray(single.cost), rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(inst.set_id[1]), np.asarray(single.set_id))
