"""The strategy interface: observation only, one rollout, the baselines' defining behaviour."""

from __future__ import annotations

import functools
import inspect

import jax
import jax.numpy as jnp
import numpy as np

import bfsop_jax.agents as agents
from bfsop_jax.agents import (
    BFSOP,
    FBE,
    BFSGlobal,
    BFSGlobalConfig,
    NearestNeighbourPlanner,
    TFLReactive,
    TFLReactiveConfig,
    max_macro_steps,
    rollout,
)
from bfsop_jax.agents.sparse import sparse_cond
from bfsop_jax.agents.tour import pending_landmarks
from bfsop_jax.config import get_preset
from bfsop_jax.env import observe, reset, step
from bfsop_jax.navigation.distance import METHOD_ENV, geodesic_method
from bfsop_jax.world import generate_house
from bfsop_jax.world.constants import N_CATEGORIES, N_TARGETS

SMOKE = get_preset("smoke")
PRIOR = jnp.full((N_CATEGORIES, N_TARGETS), 0.5)  # every receptacle is a landmark of interest
BUDGET = 30.0
STEPS = max_macro_steps(BUDGET, SMOKE, slack=2.0)


@functools.cache
def _states(seeds: tuple[int, ...], category: int = 2):
    keys = jax.vmap(jax.random.key)(jnp.asarray(seeds))
    houses = jax.jit(jax.vmap(generate_house, in_axes=(0, None)), static_argnums=1)(keys, SMOKE)
    run = jax.vmap(lambda k, h: reset(k, h, category, SMOKE, PRIOR, BUDGET))
    return jax.jit(run)(keys, houses)


TFL = TFLReactive()
BFSOP_NN = BFSOP(NearestNeighbourPlanner())


@functools.cache
def _batched(strategy):
    return jax.jit(jax.vmap(lambda s: rollout(s, strategy, SMOKE, STEPS)))


def _one(states, i):
    return jax.tree_util.tree_map(lambda a: a[i], states)


def test_strategies_read_only_the_observation():
    """No strategy module touches the true house; the rollout hands them observations."""
    for module in (agents.fbe, agents.bfs_global, agents.tfl_reactive, agents.bfsop, agents.tour):
        source = inspect.getsource(module)
        assert ".house" not in source, module.__name__


def test_observation_hides_undetected_objects():
    state = _one(_states((1000000,)), 0)
    obs = observe(state)
    seen = np.asarray(obs.object_seen)
    assert seen.any() and (~seen).any()
    cats = np.asarray(obs.object_category)
    assert np.all(cats[~seen] == -1) and np.all(np.asarray(obs.object_xy)[~seen] == 0)
    # Any change to undetected objects leaves the observation bit for bit unchanged.
    house = state.house
    rng = np.random.default_rng(0)
    m = seen.shape[0]
    moved = house.replace(
        object_xy=jnp.where(seen[:, None], house.object_xy, jnp.asarray(rng.uniform(0, 9, (m, 2)))),
        object_category=jnp.where(seen, house.object_category, 3),
    )
    other = observe(state.replace(house=moved))
    for a, b in zip(jax.tree_util.tree_leaves(obs), jax.tree_util.tree_leaves(other), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_moving_an_unseen_target_changes_no_action():
    """End to end: a target never detected is moved; every pose of the episode is the same."""
    state = _one(_states((1000001,)), 0)
    strategy = TFLReactive()
    run = jax.jit(lambda s: rollout(s, strategy, SMOKE, STEPS))
    final, traj = run(state)
    house = state.house
    cats = np.asarray(house.object_category)
    never = np.flatnonzero((cats >= 0) & (cats < N_TARGETS) & ~np.asarray(final.found))
    never = [i for i in never if not bool(final.receptacles_seen[i] | final.landmarks_seen[i])]
    assert never, "the scene has no undetected target"
    i = never[0]
    # Targets do not occupy grid cells, so the move changes nothing the agent can sense
    # except the detection of that very object (checked to stay undetected).
    target = jnp.asarray(house.object_xy[i]) + jnp.asarray([0.05, -0.05])
    moved = state.replace(house=house.replace(object_xy=house.object_xy.at[i].set(target)))
    final2, traj2 = run(moved)
    assert not bool(final2.found[i])
    np.testing.assert_array_equal(np.asarray(traj.poses), np.asarray(traj2.poses))
    np.testing.assert_array_equal(np.asarray(traj.touring), np.asarray(traj2.touring))


def test_bfs_global_does_not_exploit_before_its_fraction():
    states = _states((1000000, 1000002))
    fraction = 0.5
    _, traj = _batched(BFSGlobal(BFSGlobalConfig(fraction=fraction)))(states)
    for b in range(2):
        length_before = np.concatenate([[0.0], np.asarray(traj.path_length[b])[:-1]])
        touring = np.asarray(traj.touring[b])
        assert touring.any(), "no tour at all: the test would be vacuous"
        assert np.all(length_before[touring] >= fraction * BUDGET - 1e-5)
        assert np.all(length_before[np.asarray(traj.planned[b])] >= fraction * BUDGET - 1e-5)


def test_tfl_reactive_switches_when_a_landmark_comes_within_its_radius():
    state = _one(_states((1000000,)), 0)
    cfg = TFLReactiveConfig(radius_m=2.5, timer_m=1e6)  # the timer never fires here
    strategy = TFLReactive(cfg)
    act = jax.jit(strategy.act, static_argnums=2)
    env_step = jax.jit(step, static_argnums=2)
    update = jax.jit(strategy.update)
    memory = strategy.init(observe(state), SMOKE)
    switched_near = 0
    for _ in range(60):
        obs = observe(state)
        pending = np.asarray(pending_landmarks(obs, memory.tour.retired))
        near = np.linalg.norm(np.asarray(obs.object_xy) - np.asarray(obs.pose[:2]), axis=1)
        trigger = bool(np.any(pending & (near <= cfg.radius_m))) and not bool(memory.tour.touring)
        action, decision, memory = act(memory, obs, SMOKE)
        assert bool(decision.planned) == (trigger and not bool(obs.done))
        switched_near += int(bool(decision.switched))
        if not bool(decision.has_goal) or bool(state.done):
            break
        state, info = env_step(state, action, SMOKE)
        memory = update(memory, obs, observe(state), info)
    assert switched_near >= 1


def test_tfl_reactive_timer_forces_a_visit():
    states = _states((1000000,))
    strategy = TFLReactive(TFLReactiveConfig(radius_m=0.0, timer_m=6.0))
    _, traj = jax.jit(jax.vmap(lambda s: rollout(s, strategy, SMOKE, STEPS)))(states)
    assert int(traj.switched.sum()) >= 1


def test_tour_strategies_are_batch_invariant():
    """Batched episodes equal the same episodes run one by one, bit for bit."""
    states = _states((1000000, 1000001))
    for strategy in (TFL, BFSOP_NN):
        _, batched = _batched(strategy)(states)
        single = jax.jit(lambda s, strategy=strategy: rollout(s, strategy, SMOKE, STEPS))
        for i in range(2):
            _, alone = single(_one(states, i))
            np.testing.assert_array_equal(np.asarray(alone.poses), np.asarray(batched.poses[i]))
            np.testing.assert_array_equal(np.asarray(alone.touring), np.asarray(batched.touring[i]))


def test_accelerator_geodesics_give_the_same_episodes(monkeypatch):
    """The whole-grid relaxation that GPUs and TPUs use for geodesics (distance fields,
    matrices, frontier labelling) drives the same episodes as the CPU's sweeps, bit for
    bit: forced here on the CPU for FBE, whose every step plans on them."""
    states = _states((1000000, 1000001))
    _, sweeps = _batched(FBE())(states)
    monkeypatch.setenv(METHOD_ENV, "relax")
    assert geodesic_method() == "relax"
    _, relax = jax.jit(jax.vmap(lambda s: rollout(s, FBE(), SMOKE, STEPS)))(states)
    assert int(np.asarray(sweeps.moved).sum()) > 0
    for field in ("poses", "moved", "micro_length", "path_length", "found_count", "active"):
        np.testing.assert_array_equal(
            np.asarray(getattr(relax, field)), np.asarray(getattr(sweeps, field)), err_msg=field
        )


def test_one_trajectory_record_for_every_strategy():
    states = _states((1000000, 1000001))
    shapes = []
    for strategy in (FBE(), BFSGlobal(), TFL, BFSOP_NN):
        _, traj = _batched(strategy)(states)
        shapes.append({k: np.shape(v) for k, v in vars(traj).items() if v is not None})
        assert np.all(np.asarray(traj.switched) <= np.asarray(traj.planned))
    assert all(s == shapes[0] for s in shapes)


def test_sparse_cond_calls_the_host_only_for_rows_that_ask():
    calls = []

    def host(mask, x):
        calls.append(np.asarray(mask).copy())
        return np.where(mask, 10 * x, 0).astype(np.float32)

    def dear(mask, x):
        out = jax.ShapeDtypeStruct(x.shape, jnp.float32)
        return jax.pure_callback(host, out, mask, x, vmap_method="broadcast_all")

    f = jax.jit(jax.vmap(lambda p, x: sparse_cond(p, dear, lambda x: -x, x)))
    out = f(jnp.asarray([True, False, True]), jnp.arange(3.0))
    np.testing.assert_array_equal(np.asarray(out), [0.0, -1.0, 20.0])
    assert len(calls) == 1 and calls[0].sum() == 2  # the two rows that asked, one padding
    out = f(jnp.zeros(3, bool), jnp.arange(3.0))
    np.testing.assert_array_equal(np.asarray(out), [-0.0, -1.0, -2.0])
    assert len(calls) == 1  # nobody asked: no host call at all
    # more rows ask than one sub-batch holds: several rounds, still only those rows
    g = jax.jit(jax.vmap(lambda p, x: sparse_cond(p, dear, lambda x: -x, x, capacity=2)))
    calls.clear()
    out = g(jnp.asarray([True, True, False, True, False]), jnp.arange(5.0))
    np.testing.assert_array_equal(np.asarray(out), [0.0, 10.0, -2.0, 30.0, -4.0])
    assert [c.tolist() for c in calls] == [[True, True], [True, False]]
    single = jax.jit(lambda p, x: sparse_cond(p, dear, lambda x: -x, x))
    assert float(single(True, 2.0)) == 20.0 and float(single(False, 2.0)) == -2.0
