"""The environment: scripted episodes with known answers, purity and no recompilation."""

from __future__ import annotations

import functools

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bfsop_jax.config import get_preset
from bfsop_jax.env import make_action, reset, step
from bfsop_jax.navigation.grid import true_blocked
from bfsop_jax.world.constants import N_CATEGORIES, N_TARGETS, is_target
from bfsop_jax.world.generator import generate_house
from bfsop_jax.world.types import House

SMOKE = get_preset("smoke")
PRIOR = jnp.ones((N_CATEGORIES, N_TARGETS), jnp.float32)  # every landmark counts in tests

reset_jit = jax.jit(reset, static_argnums=3)
step_jit = jax.jit(step, static_argnums=2)


def empty_house(preset=SMOKE) -> House:
    """A walled empty rectangle: free everywhere but a one-cell border."""
    h, w = preset.grid_shape
    occ = np.zeros((h, w), bool)
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
    m, r = preset.max_objects, preset.max_rooms
    return House(
        occupied=jnp.asarray(occ),
        room_of_cell=jnp.where(jnp.asarray(occ), -1, 0).astype(jnp.int32),
        room_type=jnp.asarray([1] + [-1] * (r - 1), jnp.int32),
        object_category=jnp.full(m, -1, jnp.int32),
        object_xy=jnp.zeros((m, 2), jnp.float32),
        object_size=jnp.zeros(m, jnp.float32),
        object_half_extent=jnp.zeros((m, 2), jnp.float32),
        object_room=jnp.full(m, -1, jnp.int32),
        object_parent=jnp.full(m, -1, jnp.int32),
        cell_size=preset.cell_size,
    )


@functools.cache
def smoke_house(seed: int = 0) -> House:
    return jax.jit(generate_house, static_argnums=1)(jax.random.key(seed), SMOKE)


def at(state, x, y, heading=0.0):
    return state.replace(pose=jnp.asarray([x, y, heading], jnp.float32))


def test_straight_motion_and_exact_budget_gate():
    state = reset_jit(jax.random.key(0), empty_house(), 0, SMOKE, PRIOR, 3.3)
    state = at(state, 2.1, 6.1)
    action = make_action(jnp.asarray([10.1, 6.1]))
    k, pc = SMOKE.micro_steps, SMOKE.plan_cell_size
    for n in (1, 2):  # one planning cell per motion step
        state, info = step_jit(state, action, SMOKE)
        np.testing.assert_allclose(float(state.path_length), n * k * pc, atol=1e-5)
        np.testing.assert_allclose(np.asarray(state.pose[:2]), [2.1 + n * k * pc, 6.1], atol=1e-5)
        assert float(state.pose[2]) == 0.0 and not bool(state.done)
    np.testing.assert_allclose(float(info.travelled), k * pc, atol=1e-5)

    state, info = step_jit(state, action, SMOKE)
    assert float(state.path_length) == pytest.approx(3.3, abs=1e-6)  # the gate is exact
    assert bool(state.done)
    np.testing.assert_allclose(float(state.pose[0]), 2.1 + 3.3, atol=1e-5)  # half a cell
    assert int(info.moved.sum()) == 1

    # A finished episode does not move any more.
    again, info = step_jit(state, action, SMOKE)
    assert float(again.path_length) == float(state.path_length)
    assert not bool(info.moved.any())
    np.testing.assert_array_equal(np.asarray(again.pose), np.asarray(state.pose))


def test_arrival_and_path_length_equal_polyline_length():
    state = reset_jit(jax.random.key(1), empty_house(), 0, SMOKE, PRIOR, 100.0)
    state = at(state, 2.1, 2.1)
    action = make_action(jnp.asarray([5.1, 7.3]))
    total, poses = 0.0, [np.asarray(state.pose[:2])]
    for _ in range(10):
        state, info = step_jit(state, action, SMOKE)
        total += float(info.travelled)
        poses += [np.asarray(p[:2]) for p, m in zip(info.poses, info.moved, strict=True) if m]
        if bool(info.arrived):
            break
    assert bool(info.arrived)
    np.testing.assert_allclose(np.asarray(state.pose[:2]), [5.1, 7.3], atol=1e-5)
    assert float(state.path_length) == pytest.approx(total, abs=1e-4)
    # Every motion step is one move between neighbouring cell centres.
    seg = np.linalg.norm(np.diff(np.stack(poses), axis=0), axis=1)
    pc = SMOKE.plan_cell_size
    assert np.all(np.isclose(seg, pc, atol=1e-5) | np.isclose(seg, pc * np.sqrt(2), atol=1e-5))
    np.testing.assert_allclose(seg.sum(), total, atol=1e-4)
    # The shortest 8-connected path over 26 rows and 15 columns: 15 diagonal, 11 straight.
    np.testing.assert_allclose(total, 15 * pc * np.sqrt(2) + 11 * pc, atol=1e-4)


def _viewpoint_for(house: House, target: int) -> np.ndarray:
    """A traversable planning-cell centre 0.4-0.9 m from the target with a clear line."""
    blocked = np.asarray(true_blocked(house.occupied, SMOKE))
    pc = SMOKE.plan_cell_size
    txy = np.asarray(house.object_xy[target])
    ii, jj = np.nonzero(~blocked)
    pts = np.stack([(jj + 0.5) * pc, (ii + 0.5) * pc], axis=1)
    d = np.linalg.norm(pts - txy, axis=1)
    order = np.argsort(np.where((d > 0.3) & (d < 0.9), d, np.inf))
    return pts[order[0]]


def test_scripted_drive_to_a_target_verifies_it():
    house = smoke_house(0)
    cats = np.asarray(house.object_category)
    targets = np.nonzero(np.asarray(is_target(cats)))[0]
    assert len(targets) > 0
    target = int(targets[0])
    goal = _viewpoint_for(house, target)
    state = reset_jit(jax.random.key(2), house, int(cats[target]), SMOKE, PRIOR, 500.0)
    action = make_action(jnp.asarray(goal), look_xy=house.object_xy[target])
    for _ in range(60):
        state, info = step_jit(state, action, SMOKE)
        if bool(info.arrived):
            break
    assert bool(info.arrived), "the agent did not reach the viewpoint"
    assert bool(state.found[target]), "the target next to the agent was not verified"
    # Only instances of the episode's category are ever verified.
    assert np.all(cats[np.asarray(state.found)] == cats[target])


def test_vmap_and_no_recompilation():
    houses = jax.tree_util.tree_map(lambda a, b: jnp.stack([a, b]), smoke_house(0), smoke_house(1))
    categories = jnp.asarray([0, 8], jnp.int32)
    keys = jax.vmap(jax.random.key)(jnp.arange(2))
    states = jax.jit(jax.vmap(reset, in_axes=(0, 0, 0, None, None)), static_argnums=3)(
        keys, houses, categories, SMOKE, PRIOR
    )

    @jax.jit
    @chex.assert_max_traces(n=1)
    def batched_step(states, goals):
        return jax.vmap(step, in_axes=(0, 0, None))(states, make_action(goals), SMOKE)

    for i in range(3):
        goals = states.pose[:, :2] + jnp.asarray([[1.0, 0.0], [0.0, 1.0]]) * (i + 1)
        states, info = batched_step(states, goals)
    assert states.path_length.shape == (2,)
    assert np.all(np.isfinite(np.asarray(states.belief)))
    assert np.all(np.asarray(states.path_length) <= np.asarray(states.budget))
    assert np.any(np.asarray(states.belief) != 0)
    # Landmarks of interest are the receptacles seen whose prior is positive.
    lois, seen = np.asarray(states.landmarks_seen), np.asarray(states.receptacles_seen)
    assert np.all(seen[lois]) and seen.any()


def test_reset_is_deterministic_and_rejects_bad_prior():
    house = smoke_house(0)
    a = reset_jit(jax.random.key(5), house, 1, SMOKE, PRIOR)
    b = reset_jit(jax.random.key(5), house, 1, SMOKE, PRIOR)
    np.testing.assert_array_equal(np.asarray(a.pose), np.asarray(b.pose))
    np.testing.assert_array_equal(np.asarray(a.belief), np.asarray(b.belief))
    with pytest.raises(ValueError, match="prior must have shape"):
        reset(jax.random.key(0), house, 1, SMOKE, jnp.ones((3, 3)))
