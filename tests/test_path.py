"""Path following on a distance field, and the traversability gate."""

from __future__ import annotations

import math

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bfsop_jax.config import get_preset
from bfsop_jax.navigation import (
    advance,
    distance_field,
    is_traversable,
    plan_cell_to_xy,
    true_blocked,
    xy_to_plan_cell,
)

PRESET = get_preset("smoke")
PC = PRESET.plan_cell_size


def two_room_house() -> np.ndarray:
    """[H, W] bool: a 16 x 12 m box split by a wall at x = 8 m with a 1 m door near the top."""
    h, w = PRESET.grid_shape
    occ = np.zeros((h, w), bool)
    occ[:2], occ[-2:], occ[:, :2], occ[:, -2:] = True, True, True, True
    occ[:, 80:82] = True
    occ[10:20, 80:82] = False  # door at y in [1.0, 2.0) m
    occ[60:70, 30:50] = True  # a table in the left room
    return occ


OCC = two_room_house()
BLOCKED = true_blocked(OCC, PRESET)
GOAL = jnp.array([13.0, 9.0], jnp.float32)  # right room, far from the door
FIELD = distance_field(BLOCKED, GOAL, PRESET)

_advance = jax.jit(advance, static_argnums=3)


def walk(xy, step=PRESET.move_step_m, max_calls=500):
    """Call advance until arrival; returns (positions, travelled per call, arrived)."""
    xy = jnp.asarray(xy, jnp.float32)
    poses, lengths = [np.asarray(xy)], []
    for _ in range(max_calls):
        xy, travelled, arrived, _ = _advance(FIELD, xy, step, PRESET)
        poses.append(np.asarray(xy))
        lengths.append(float(travelled))
        assert float(travelled) <= step + 1e-6
        if bool(arrived):
            return np.array(poses), np.array(lengths), True
    return np.array(poses), np.array(lengths), False


def field_at(xy):
    c = np.asarray(xy_to_plan_cell(jnp.asarray(xy), PRESET))
    return float(np.asarray(FIELD)[c[0], c[1]])


@pytest.mark.parametrize("start", [(2.1, 10.3), (3.0, 2.0), (7.43, 5.57)])
def test_reaches_goal_along_the_field(start):
    poses, lengths, arrived = walk(start)
    assert arrived
    np.testing.assert_allclose(
        poses[-1], plan_cell_to_xy(xy_to_plan_cell(GOAL, PRESET), PRESET), atol=1e-5
    )
    # the polyline follows the field: same length up to one planning cell
    assert abs(lengths.sum() - field_at(start)) <= PC * math.sqrt(2) + 1e-4
    # every step but the arriving one is exactly one motion step long
    np.testing.assert_allclose(lengths[:-1], PRESET.move_step_m, rtol=1e-5)
    # it never enters a blocked planning cell (it starts and stays in free space)
    cells = np.asarray(xy_to_plan_cell(jnp.asarray(poses), PRESET))
    assert not np.asarray(BLOCKED)[cells[:, 0], cells[:, 1]].any()
    # it passes the door
    assert (poses[:, 1] < 2.0).any()


def test_from_cell_centre_length_equals_field():
    start = plan_cell_to_xy(jnp.array([40, 10]), PRESET)
    _, lengths, arrived = walk(start, step=100.0, max_calls=1)  # one call, enough moves?
    assert not arrived  # default max_moves covers one motion step only
    xy, travelled, arrived, _ = jax.jit(advance, static_argnums=(3, 4))(
        FIELD, start, 100.0, PRESET, 400
    )
    assert bool(arrived)
    np.testing.assert_allclose(float(travelled), field_at(start), rtol=1e-5)


def test_heading_is_direction_of_motion():
    xy = jnp.array([3.0, 9.0], jnp.float32)
    new_xy, travelled, _, heading = _advance(FIELD, xy, 0.1, PRESET)
    d = np.asarray(new_xy - xy)
    np.testing.assert_allclose(float(travelled), 0.1, rtol=1e-5)
    np.testing.assert_allclose(float(heading), math.atan2(d[1], d[0]), atol=1e-5)


def test_at_goal_and_unreachable():
    goal_centre = plan_cell_to_xy(xy_to_plan_cell(GOAL, PRESET), PRESET)
    xy, travelled, arrived, _ = _advance(FIELD, goal_centre, 0.25, PRESET)
    assert bool(arrived) and float(travelled) < 1e-5
    shut = np.array(OCC)
    shut[10:20, 80:82] = True  # close the door
    field = distance_field(true_blocked(shut, PRESET), GOAL, PRESET)
    xy, travelled, arrived, _ = _advance(field, jnp.array([3.0, 9.0]), 0.25, PRESET)
    assert not bool(arrived) and float(travelled) == 0.0
    np.testing.assert_array_equal(np.asarray(xy), np.array([3.0, 9.0], np.float32))


def test_zero_distance_does_not_move():
    xy = jnp.array([3.0, 9.0], jnp.float32)
    new_xy, travelled, arrived, _ = _advance(FIELD, xy, 0.0, PRESET)
    assert float(travelled) == 0.0 and not bool(arrived)
    np.testing.assert_array_equal(np.asarray(new_xy), np.asarray(xy))


def test_vmap_and_no_retrace():
    starts = jnp.array([[2.1, 10.3], [3.0, 2.0], [7.43, 5.57]], jnp.float32)
    out = jax.vmap(lambda p: advance(FIELD, p, 0.25, PRESET))(starts)
    for k in range(3):
        single = _advance(FIELD, starts[k], 0.25, PRESET)
        for a, b in zip(out, single, strict=True):
            np.testing.assert_allclose(np.asarray(a[k]), np.asarray(b), atol=1e-6)

    @jax.jit
    @chex.assert_max_traces(n=1)
    def step(field, xy, dist):
        return advance(field, xy, dist, PRESET)

    for k in range(3):
        step(FIELD, starts[k], 0.1 * (k + 1))[0].block_until_ready()


# --- traversability gate ---------------------------------------------------------------------


def reference_traversable(belief: np.ndarray, xy) -> bool:
    cs, r = PRESET.cell_size, PRESET.robot_radius_m
    h, w = belief.shape
    for a in range(-3, h + 3):
        for b in range(-3, w + 3):
            dy = max(a * cs - xy[1], 0.0, xy[1] - (a + 1) * cs)
            dx = max(b * cs - xy[0], 0.0, xy[0] - (b + 1) * cs)
            if math.hypot(dx, dy) >= r - 1e-6:
                continue
            outside = not (0 <= a < h and 0 <= b < w)
            if outside or belief[a, b] > PRESET.logodds_known:
                return False
    return True


def test_traversable_matches_brute_force():
    rng = np.random.default_rng(0)
    belief = np.where(OCC, 3.0, 0.0).astype(np.float32)
    belief[rng.random(OCC.shape) < 0.5] = 0.0  # half unknown: does not block
    gate = jax.jit(is_traversable, static_argnums=2)
    # points near the wall, the door, the table and the map edges
    pts = np.concatenate(
        [
            rng.uniform([7.5, 0.0], [8.7, 3.0], (40, 2)),
            rng.uniform([2.5, 5.5], [5.5, 7.5], (40, 2)),
            rng.uniform([-0.2, -0.2], [0.6, 0.6], (20, 2)),
        ]
    ).astype(np.float32)
    got = [bool(gate(belief, p, PRESET)) for p in pts]
    want = [reference_traversable(belief, p) for p in pts]
    assert got == want
    assert any(got) and not all(got)


def test_known_free_space_is_traversable():
    belief = np.where(OCC, 3.0, -3.0).astype(np.float32)
    assert bool(is_traversable(belief, jnp.array([3.0, 9.0]), PRESET))
    assert not bool(is_traversable(belief, jnp.array([8.0, 9.0]), PRESET))  # inside the wall
    assert bool(is_traversable(belief, jnp.array([8.1, 1.5]), PRESET))  # in the door
