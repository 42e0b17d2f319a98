"""Following a distance field, and the traversability gate (SPEC 5).

The path to a goal is the steepest descent of the goal's distance field (the field from
the goal, see :mod:`bfsop_jax.navigation.distance`): from a cell, the next cell is the
neighbour ``n`` (8-connected, no corner cutting) minimising ``field[n] + cost(move)``
among neighbours with a lower field value. On an exact field this is a shortest path.
The agent moves on the polyline from its position through the centres of those cells,
ending at the centre of the goal's cell (field value 0). Its position may be off the
cell centres (start poses, a step cut short); it then heads straight for the centre of
the next cell on the path, which keeps it inside cells the path already allows.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from bfsop_jax.config import Preset, get_preset
from bfsop_jax.navigation.grid import plan_cell_to_xy, xy_to_plan_cell

__all__ = ["advance", "default_max_moves", "is_traversable", "next_cell"]

# neighbour offsets (drow, dcol); the first four are orthogonal
_NBR = np.array([[0, 1], [1, 0], [0, -1], [-1, 0], [1, 1], [1, -1], [-1, 1], [-1, -1]], np.int32)
_INF = np.float32(np.inf)


def default_max_moves(preset: Preset) -> int:
    """Cell-to-cell moves one :func:`advance` call can make: enough for one motion step."""
    return int(math.ceil(preset.move_step_m / preset.plan_cell_size)) + 2


def next_cell(field: jax.Array, cell: jax.Array, preset: Preset | str):
    """One descent step from ``cell`` on ``field`` [Hp, Wp] (metres).

    Returns ``(next [2] int32, at_goal bool, ok bool)``: ``at_goal`` when ``cell`` itself
    has field value 0 (then ``next == cell``); ``ok`` is False when no neighbour descends
    (unreachable goal, or nothing reachable around a blocked cell).
    """
    preset = get_preset(preset)
    hp, wp = field.shape
    pc = preset.plan_cell_size
    nb = cell[None, :] + jnp.asarray(_NBR)  # [8, 2]
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
    here = field[cell[0], cell[1]]
    step_cost = jnp.asarray(np.array([pc] * 4 + [pc * math.sqrt(2.0)] * 4, np.float32))
    score = jnp.where(allowed & (val < here), val + step_cost, _INF)
    k = jnp.argmin(score)
    at_goal = here == 0.0
    ok = at_goal | jnp.isfinite(score[k])
    nxt = jnp.where(at_goal, cell, nb[k])
    return nxt.astype(jnp.int32), at_goal, ok


def advance(
    field: jax.Array,
    xy: jax.Array,
    distance_m: jax.Array | float,
    preset: Preset | str,
    max_moves: int | None = None,
):
    """Move along the descent path of a distance-to-goal field by ``distance_m`` metres.

    Args:
        field: [Hp, Wp] float32 distance (metres) to the goal, e.g. ``distance_field``
            from the goal on the planning map.
        xy: [2] float32 position (metres).
        distance_m: polyline length to move (metres, >= 0).
        preset: static preset.
        max_moves: static cap on cell-to-cell moves per call (default
            :func:`default_max_moves`, enough for ``preset.move_step_m``).
    Returns:
        ``(new_xy [2], travelled_m, arrived, heading)``: ``travelled_m`` is the exact
        polyline length moved, equal to ``distance_m`` unless the agent reached the centre
        of the goal's cell (``arrived``), cannot descend, or used up ``max_moves``;
        ``heading`` (radians) is the direction of the last movement, 0 if it did not move.
    """
    preset = get_preset(preset)
    moves = default_max_moves(preset) if max_moves is None else int(max_moves)
    xy = jnp.asarray(xy, jnp.float32)
    if xy.shape != (2,):
        raise ValueError(f"xy must have shape [2], got {xy.shape}")
    if field.shape[-2:] != tuple(preset.plan_shape):
        raise ValueError(f"field has shape {field.shape}, expected plan_shape {preset.plan_shape}")
    distance_m = jnp.maximum(jnp.asarray(distance_m, jnp.float32), 0.0)

    def move(_, state):
        pos, cell, remaining, travelled, arrived, heading = state
        nxt, at_goal, ok = next_cell(field, cell, preset)
        target = plan_cell_to_xy(nxt, preset)
        seg = target - pos
        length = jnp.sqrt(jnp.sum(seg * seg))
        live = ok & ~arrived
        step = jnp.where(live, jnp.minimum(length, remaining), 0.0)
        reach = live & (length <= remaining)
        frac = jnp.where(length > 0, step / jnp.where(length > 0, length, 1.0), 0.0)
        pos = jnp.where(reach, target, pos + frac * seg)
        heading = jnp.where(step > 0, jnp.arctan2(seg[1], seg[0]), heading)
        return (
            pos,
            jnp.where(reach, nxt, cell),
            remaining - step,
            travelled + step,
            arrived | (reach & at_goal),
            heading,
        )

    init = (
        xy,
        xy_to_plan_cell(xy, preset),
        distance_m,
        jnp.float32(0.0),
        jnp.bool_(False),
        jnp.float32(0.0),
    )
    pos, cell, _, travelled, arrived, heading = lax.fori_loop(0, moves, move, init)
    # the goal's centre reached exactly at the end of the budget of moves still counts
    _, at_goal, _ = next_cell(field, cell, preset)
    arrived = arrived | (at_goal & jnp.all(pos == plan_cell_to_xy(cell, preset)))
    return pos, travelled, arrived, heading


def is_traversable(belief: jax.Array, xy: jax.Array, preset: Preset | str) -> jax.Array:
    """Traversability gate: no known-occupied fine cell within the robot radius of ``xy``.

    ``belief`` [H, W] float32 log-odds, ``xy`` [2] metres. A fine cell counts when its
    square comes strictly closer than ``robot_radius_m`` (the rule of the planning map);
    cells outside the map count as occupied. Gathers a small window only.
    """
    preset = get_preset(preset)
    h, w = belief.shape[-2:]
    cs, r = preset.cell_size, preset.robot_radius_m
    k = int(math.ceil(r / cs)) + 1
    off = np.arange(-k, k + 1, dtype=np.int32)
    xy = jnp.asarray(xy, jnp.float32)
    a = jnp.floor(xy[1] / cs).astype(jnp.int32) + off[:, None]  # [2k+1, 1] rows
    b = jnp.floor(xy[0] / cs).astype(jnp.int32) + off[None, :]  # [1, 2k+1] cols
    inside = (a >= 0) & (a < h) & (b >= 0) & (b < w)
    occ = jnp.where(
        inside, belief[jnp.clip(a, 0, h - 1), jnp.clip(b, 0, w - 1)] > preset.logodds_known, True
    )
    dy = jnp.maximum(jnp.maximum(a * cs - xy[1], xy[1] - (a + 1) * cs), 0.0)
    dx = jnp.maximum(jnp.maximum(b * cs - xy[0], xy[0] - (b + 1) * cs), 0.0)
    near = dx * dx + dy * dy < (r - 1e-6) ** 2
    return ~jnp.any(occ & near)
