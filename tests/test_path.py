"""Motion on the cell lattice: descent of a distance field, moves, and the blocking rules."""

from __future__ import annotations

import math

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bfsop_jax.config import get_preset
from bfsop_jax.navigation import (
    NEIGHBOURS,
    cell_blocked,
    distance_field,
    geodesic_route,
    motion_blocked,
    move_headings,
    move_lengths,
    next_cell,
    plan_cell_to_xy,
    planning_blocked,
    true_blocked,
    xy_to_plan_cell,
)
from bfsop_jax.sensing.mapping import ANGLE_UNITS

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

_next = jax.jit(next_cell, static_argnums=2)


def walk(cell, field=FIELD, max_moves=500):
    """Descend until arrival; returns (cells visited, move indices, arrived)."""
    cell = jnp.asarray(cell, jnp.int32)
    cells, moves = [np.asarray(cell)], []
    for _ in range(max_moves):
        cell, move, at_goal, ok = _next(field, cell, PRESET)
        if bool(at_goal) or not bool(ok):
            return np.array(cells), np.array(moves, int), bool(at_goal)
        cells.append(np.asarray(cell))
        moves.append(int(move))
    return np.array(cells), np.array(moves, int), False


def test_move_tables():
    lengths = move_lengths(PRESET)
    np.testing.assert_allclose(lengths[:4], PC)
    np.testing.assert_allclose(lengths[4:], PC * math.sqrt(2), rtol=1e-6)
    heads = move_headings() * (2 * math.pi / ANGLE_UNITS)
    for (dr, dc), h in zip(NEIGHBOURS, heads, strict=True):
        np.testing.assert_allclose(
            [math.cos(h), math.sin(h)], np.array([dc, dr]) / math.hypot(dr, dc), atol=1e-3
        )


@pytest.mark.parametrize("start", [(2.1, 10.3), (3.0, 2.0), (7.43, 5.57)])
def test_descent_reaches_goal_along_a_shortest_path(start):
    cell = xy_to_plan_cell(jnp.asarray(start), PRESET)
    cells, moves, arrived = walk(cell)
    assert arrived
    np.testing.assert_array_equal(cells[-1], np.asarray(xy_to_plan_cell(GOAL, PRESET)))
    # the move lengths add up to the field value at the start: a shortest path
    total = move_lengths(PRESET)[moves].sum()
    np.testing.assert_allclose(total, float(FIELD[cell[0], cell[1]]), rtol=1e-5)
    # every move joins neighbouring cells and never enters a blocked cell
    np.testing.assert_array_equal(cells[1:] - cells[:-1], NEIGHBOURS[moves])
    assert not np.asarray(BLOCKED)[cells[:, 0], cells[:, 1]].any()
    xy = np.asarray(plan_cell_to_xy(jnp.asarray(cells), PRESET))
    assert (xy[:, 1] < 2.0).any()  # it passes the door


def test_geodesic_route_follows_the_shortest_paths_through_its_waypoints():
    """A tour's polyline: each leg descends the next waypoint's field (through the door),
    from waypoint to waypoint, as long as the fields say (up to the snap to cell centres)."""
    points = np.array([[2.1, 10.3], [13.0, 9.0], [3.0, 2.0]], np.float32)
    route = geodesic_route(BLOCKED, points, PRESET)
    assert route.dtype == np.float32 and route.ndim == 2 and route.shape[1] == 2
    np.testing.assert_array_equal(route[0], points[0])
    np.testing.assert_array_equal(route[-1], points[-1])
    inner = route[1:-1]
    steps = np.linalg.norm(np.diff(inner, axis=0), axis=1)
    steps = steps[steps > 1e-6]  # a waypoint between two legs repeats near a cell centre
    assert (steps <= PC * math.sqrt(2) * 1.5 + 0.3).all()  # cell to cell, or a waypoint
    cells = np.asarray(xy_to_plan_cell(jnp.asarray(inner), PRESET))
    assert not np.asarray(BLOCKED)[cells[:, 0], cells[:, 1]].any()
    assert int((route[:, 1] < 2.0).sum()) > 2  # both legs go through the door (y < 2 m)
    length = np.linalg.norm(np.diff(route, axis=0), axis=1).sum()
    fields = [distance_field(BLOCKED, jnp.asarray(p), PRESET) for p in points[1:]]
    starts = np.asarray(xy_to_plan_cell(jnp.asarray(points[:-1]), PRESET))
    geodesic = sum(float(f[c[0], c[1]]) for f, c in zip(fields, starts, strict=True))
    assert geodesic < length < geodesic + 4 * PC  # plus a snap at each end of each leg
    one = geodesic_route(BLOCKED, points[:1], PRESET)
    np.testing.assert_array_equal(one, points[:1])


def test_no_corner_cutting():
    cells, moves, _ = walk(xy_to_plan_cell(jnp.asarray([2.1, 10.3]), PRESET))
    blocked = np.asarray(BLOCKED)
    for c, k in zip(cells[:-1], moves, strict=True):
        dr, dc = NEIGHBOURS[k]
        if dr and dc:
            assert not blocked[c[0] + dr, c[1]] and not blocked[c[0], c[1] + dc]


def test_at_goal_and_unreachable():
    goal = xy_to_plan_cell(GOAL, PRESET)
    nxt, move, at_goal, ok = _next(FIELD, goal, PRESET)
    assert bool(at_goal) and bool(ok) and int(move) == -1
    np.testing.assert_array_equal(np.asarray(nxt), np.asarray(goal))
    shut = np.array(OCC)
    shut[10:20, 80:82] = True  # close the door
    field = distance_field(true_blocked(shut, PRESET), GOAL, PRESET)
    start = xy_to_plan_cell(jnp.array([3.0, 9.0]), PRESET)
    nxt, move, at_goal, ok = _next(field, start, PRESET)
    assert not bool(at_goal) and not bool(ok) and int(move) == -1
    np.testing.assert_array_equal(np.asarray(nxt), np.asarray(start))


def test_vmap_equals_single_and_no_retrace():
    starts = xy_to_plan_cell(jnp.array([[2.1, 10.3], [3.0, 2.0], [7.43, 5.57]]), PRESET)
    out = jax.vmap(lambda c: next_cell(FIELD, c, PRESET))(starts)
    for k in range(3):
        single = _next(FIELD, starts[k], PRESET)
        for a, b in zip(out, single, strict=True):
            np.testing.assert_array_equal(np.asarray(a[k]), np.asarray(b))

    @jax.jit
    @chex.assert_max_traces(n=1)
    def descend(field, cell):
        return next_cell(field, cell, PRESET)

    for k in range(3):
        descend(FIELD, starts[k])[0].block_until_ready()


# --- the blocking rule for single cells and the motion map -----------------------------------


def test_cell_blocked_equals_planning_map():
    """The traversability gate's per-cell rule is the planning map's rule, cell for cell."""
    rng = np.random.default_rng(0)
    belief = np.where(OCC, 3.0, 0.0).astype(np.float32)
    belief[rng.random(OCC.shape) < 0.5] = 0.0  # half unknown: does not block
    full = np.asarray(planning_blocked(belief, PRESET))
    hp, wp = PRESET.plan_shape
    cells = np.stack(np.meshgrid(np.arange(hp), np.arange(wp), indexing="ij"), -1)
    per_cell = np.asarray(jax.jit(cell_blocked, static_argnums=2)(belief, cells, PRESET))
    np.testing.assert_array_equal(per_cell, full)
    assert full.any() and not full.all()
    outside = jnp.array([[-1, 3], [hp, 0], [2, wp]])
    assert bool(cell_blocked(belief, outside, PRESET).all())


def test_motion_map_lets_a_blocked_agent_back_out():
    belief = np.full(OCC.shape, -3.0, np.float32)
    belief[58:62, 30:50] = 3.0  # a freshly seen edge of furniture
    blocked = np.asarray(planning_blocked(belief, PRESET))
    inside = jnp.array([4.1, 5.7])  # cell (28, 20): within the robot radius of the edge
    c = np.asarray(xy_to_plan_cell(inside, PRESET))
    assert blocked[c[0], c[1]]
    motion = np.asarray(motion_blocked(belief, inside, PRESET))
    assert not motion[c[0], c[1]]
    # only cells next to the agent open, and never one holding an occupied fine cell
    assert (
        not (blocked & ~motion)[:, : c[1] - 3].any()
        and not (blocked & ~motion)[:, c[1] + 3 :].any()
    )
    assert motion[29, 20]  # holds occupied fine cells (rows 58-59)
    field = distance_field(jnp.asarray(motion), jnp.array([4.1, 3.1]), PRESET)
    cells, _, arrived = walk(c, field)
    assert arrived and len(cells) > 1
    # an agent in free space moves on the plain planning map
    free_xy = jnp.array([4.1, 3.1])
    np.testing.assert_array_equal(np.asarray(motion_blocked(belief, free_xy, PRESET)), blocked)
