"""Motion on the lattice of planning-cell centres: following a distance field.

The agent stands on the centre of a planning cell and moves from cell to cell. The path
to a goal is the steepest descent of the goal's distance field (the field from the goal,
see :mod:`bfsop_jax.navigation.distance`): from a cell, the next cell is the neighbour
``n`` (8-connected, no corner cutting) minimising ``field[n] + cost(move)`` among
neighbours with a lower field value; ties go to the first neighbour in the fixed order of
``NEIGHBOURS``. On an exact field this is a shortest path.

One motion step is one such move: ``plan_cell_size`` metres straight, ``sqrt(2)`` times
that diagonally (0.2 m / 0.28 m with the default 0.2 m planning cells). Positions, move
lengths and headings therefore come from small integer tables, and a trajectory is the
same bit for bit whether it is computed alone or inside a ``jax.vmap`` batch: nothing a
decision depends on goes through floating-point sums whose rounding could depend on how
XLA fuses the batched program.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from bfsop_jax.config import Preset, require_preset
from bfsop_jax.navigation.distance import distance_fields, snap_to_free
from bfsop_jax.navigation.grid import plan_cell_to_xy, xy_to_plan_cell
from bfsop_jax.sensing.mapping import ANGLE_UNITS

__all__ = ["NEIGHBOURS", "geodesic_route", "move_headings", "move_lengths", "next_cell"]

# neighbour offsets (drow, dcol); the first four are orthogonal
NEIGHBOURS = np.array(
    [[0, 1], [1, 0], [0, -1], [-1, 0], [1, 1], [1, -1], [-1, 1], [-1, -1]], np.int32
)
_INF = np.float32(np.inf)


def move_lengths(preset: Preset) -> np.ndarray:
    """[8] float32 metres of each move of ``NEIGHBOURS`` (orthogonal, then diagonal)."""
    pc = preset.plan_cell_size
    return np.array([pc] * 4 + [pc * math.sqrt(2.0)] * 4, np.float32)


def move_headings() -> np.ndarray:
    """[8] int32 heading of each move in angle units (row = y, col = x; 0 = +x)."""
    angles = np.arctan2(NEIGHBOURS[:, 0], NEIGHBOURS[:, 1])
    return (np.rint(angles / (2 * np.pi) * ANGLE_UNITS).astype(np.int64) % ANGLE_UNITS).astype(
        np.int32
    )


def next_cell(field: jax.Array, cell: jax.Array, preset: Preset):
    """One descent step from ``cell`` on ``field`` [Hp, Wp] (metres).

    Returns ``(next [2] int32, move int32, at_goal bool, ok bool)``: ``move`` indexes
    ``NEIGHBOURS`` (-1 when not moving); ``at_goal`` when ``cell`` itself has field value 0
    (then ``next == cell``); ``ok`` is False when no neighbour descends (unreachable goal,
    or nothing reachable around a blocked cell).
    """
    preset = require_preset(preset)
    hp, wp = field.shape
    nb = cell[None, :] + jnp.asarray(NEIGHBOURS)  # [8, 2]
    inside = (nb[:, 0] >= 0) & (nb[:, 0] < hp) & (nb[:, 1] >= 0) & (nb[:, 1] < wp)
    val = jnp.where(
        inside, field[jnp.clip(nb[:, 0], 0, hp - 1), jnp.clip(nb[:, 1], 0, wp - 1)], _INF
    )
    finite = jnp.isfinite(val)
    # a diagonal needs both orthogonal cells it passes to be on the map's reachable part
    diag_ok = jnp.stack(
        [finite[0] & finite[1], finite[2] & finite[1], finite[0] & finite[3], finite[2] & finite[3]]
    )
    allowed = finite & jnp.concatenate([jnp.ones(4, bool), diag_ok])
    here = field[jnp.clip(cell[0], 0, hp - 1), jnp.clip(cell[1], 0, wp - 1)]
    score = jnp.where(allowed & (val < here), val + jnp.asarray(move_lengths(preset)), _INF)
    k = jnp.argmin(score).astype(jnp.int32)
    at_goal = here == 0.0
    ok = at_goal | jnp.isfinite(score[k])
    moving = ~at_goal & ok
    nxt = jnp.where(moving, nb[k], cell)
    return nxt.astype(jnp.int32), jnp.where(moving, k, -1), at_goal, ok


@functools.partial(jax.jit, static_argnums=(2, 3))
def _descend(field: jax.Array, cell: jax.Array, preset: Preset, max_moves: int):
    """Cells [max_moves + 1, 2] of the descent of ``field`` from ``cell`` (the first ``n + 1``
    are the path), ``n`` moves made, and whether the last cell is the goal."""

    def cond(carry):
        i, _, moving, _ = carry
        return moving & (i < max_moves)

    def body(carry):
        i, cell, _, cells = carry
        nxt, move, _, _ = next_cell(field, cell, preset)
        moving = move >= 0
        cells = cells.at[i + 1].set(nxt)
        return i + moving.astype(jnp.int32), nxt, moving, cells

    cells = jnp.zeros((max_moves + 1, 2), jnp.int32).at[0].set(cell)
    n, last, _, cells = jax.lax.while_loop(cond, body, (jnp.int32(0), cell, True, cells))
    return cells, n, field[last[0], last[1]] == 0.0


def geodesic_route(blocked: jax.Array, waypoints_xy: np.ndarray, preset: Preset) -> np.ndarray:
    """The polyline an agent follows through ``waypoints_xy`` in order (host-side, for
    pictures): each leg is the descent of the next waypoint's distance field on ``blocked``
    (:func:`next_cell`, a shortest path of the planning grid, as the environment moves).

    Args:
        blocked: bool [Hp, Wp] planning map, e.g. the
            :func:`~bfsop_jax.navigation.grid.planning_blocked` map of the belief map the
            waypoints were planned on.
        waypoints_xy: float [W, 2] points in metres, visiting order.
        preset: the preset (planning cell size and grid shape).

    Returns float32 [P, 2] metres: the first waypoint, the planning-cell centres of each
    leg, each later waypoint. A leg whose goal cannot be reached is a straight segment.
    """
    preset = require_preset(preset)
    pts = np.asarray(waypoints_xy, np.float32).reshape(-1, 2)
    if len(pts) < 2:
        return pts.copy()
    blocked = jnp.asarray(blocked, bool)
    fields = distance_fields(blocked, jnp.asarray(pts[1:]), preset)  # [W - 1, Hp, Wp]
    starts, _ = snap_to_free(blocked, xy_to_plan_cell(jnp.asarray(pts[:-1]), preset))
    hp, wp = preset.plan_shape
    route = [pts[:1]]
    for leg in range(len(pts) - 1):
        cells, n, arrived = _descend(fields[leg], starts[leg], preset, hp * wp)
        if bool(arrived):
            route.append(np.asarray(plan_cell_to_xy(cells[: int(n) + 1], preset)))
        route.append(pts[leg + 1 : leg + 2])
    return np.concatenate(route).astype(np.float32)
