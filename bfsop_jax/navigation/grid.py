"""The planning grid: a coarser, robot-inflated view of an occupancy map (docs/design.md §4).

The planning grid has cells of ``preset.plan_cell_size`` metres (``plan_factor`` fine
0.1 m cells per side) and shape ``preset.plan_shape`` = (Hp, Wp). Row ``i`` is y and
column ``j`` is x; planning cell (i, j) has its centre at ``((j + .5) * pc, (i + .5) * pc)``.

Blocking rule (the robot is a disc of radius ``robot_radius_m`` centred on the cell
centre): a planning cell is blocked when some occupied fine cell, taken as its full
square, comes strictly closer than the robot radius to the planning cell's centre.
That contains every planning cell holding an occupied fine cell of its own and then
dilates by the robot radius measured exactly on the fine grid. Fine cells outside the
map count as occupied, so the robot never leaves the map. With the default numbers
(0.1 m cells, 0.2 m planning cells, 0.2 m radius) a planning cell is blocked when any
fine cell of the 4 x 4 block around its centre is occupied, and a 0.9 m door leaves
three free planning cells across.

The belief map is optimistic for planning: unknown cells are free, only cells known to
be occupied (log-odds above ``preset.logodds_known``) block.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from bfsop_jax.config import Preset, require_preset

__all__ = [
    "ESCAPE_RADIUS",
    "cell_blocked",
    "motion_blocked",
    "planning_blocked",
    "true_blocked",
    "xy_to_plan_cell",
    "plan_cell_to_xy",
    "inflation_offsets",
]


ESCAPE_RADIUS = 2  # planning cells around a blocked agent that it may back out through


@functools.cache
def inflation_offsets(preset: Preset) -> tuple[tuple[int, int], ...]:
    """Fine-cell offsets (da, db) whose square lies strictly within the robot radius.

    Offsets are relative to the first fine cell ``(i * f, j * f)`` of planning cell
    (i, j), f = ``plan_factor``; the planning cell's centre is at ``f / 2`` fine units.
    """
    f = preset.plan_factor
    r = preset.robot_radius_m / preset.cell_size  # radius in fine cells
    c = 0.5 * f
    reach = int(math.ceil(r)) + 1
    out = []
    for da in range(-reach, f + reach):
        for db in range(-reach, f + reach):
            # distance from the centre point to the square [da, da+1] x [db, db+1]
            dy = max(da - c, 0.0, c - (da + 1))
            dx = max(db - c, 0.0, c - (db + 1))
            if math.hypot(dx, dy) < r - 1e-6:
                out.append((da, db))
    return tuple(out)


def _inflate(occupied: jax.Array, preset: Preset) -> jax.Array:
    """[H, W] bool fine occupancy -> [Hp, Wp] bool blocked planning cells."""
    h, w = preset.grid_shape
    if occupied.shape[-2:] != (h, w):
        raise ValueError(
            f"occupancy grid has shape {occupied.shape[-2:]}, preset {preset.name!r} "
            f"expects grid_shape {(h, w)}"
        )
    f = preset.plan_factor
    hp, wp = preset.plan_shape
    offsets = inflation_offsets(preset)
    lo, hi = _offset_bounds(preset)
    # Pad so every (planning cell, offset) pair indexes inside; outside the map is occupied.
    pad_h = (lo, hp * f - h + hi)
    pad_w = (lo, wp * f - w + hi)
    occ = jnp.pad(occupied.astype(bool), (pad_h, pad_w), constant_values=True)
    blocked = jnp.zeros((hp, wp), bool)
    for da, db in offsets:  # static, ~16 strided views of a small grid
        a0, b0 = lo + da, lo + db
        blocked = blocked | occ[a0 : a0 + hp * f : f, b0 : b0 + wp * f : f]
    return blocked


def _offset_bounds(preset: Preset) -> tuple[int, int]:
    offsets = inflation_offsets(preset)
    return max(0, -min(min(o) for o in offsets)), max(max(o) for o in offsets) + 1


def cell_blocked(belief: jax.Array, cells: jax.Array, preset: Preset) -> jax.Array:
    """The blocking rule of :func:`planning_blocked` for a few planning cells only.

    ``belief`` [H, W] float32 log-odds, ``cells`` [..., 2] int32 (row, col) -> [...] bool.
    Evaluates exactly the same integer offsets as the full map (gathering ~16 fine cells
    per cell), so the traversability gate and the planner can never disagree on a cell.
    Cells outside the planning grid are blocked.
    """
    preset = require_preset(preset)
    h, w = preset.grid_shape
    hp, wp = preset.plan_shape
    f = preset.plan_factor
    off = np.asarray(inflation_offsets(preset), np.int32)  # [O, 2]
    cells = jnp.asarray(cells, jnp.int32)
    a = cells[..., None, 0] * f + off[:, 0]
    b = cells[..., None, 1] * f + off[:, 1]
    inside = (a >= 0) & (a < h) & (b >= 0) & (b < w)
    occ = belief[jnp.clip(a, 0, h - 1), jnp.clip(b, 0, w - 1)] > preset.logodds_known
    on_grid = (cells[..., 0] >= 0) & (cells[..., 0] < hp) & (cells[..., 1] >= 0)
    on_grid = on_grid & (cells[..., 1] < wp)
    return jnp.any(occ | ~inside, axis=-1) | ~on_grid


def planning_blocked(belief: jax.Array, preset: Preset) -> jax.Array:
    """Optimistic planning map of a belief: [H, W] float32 log-odds -> [Hp, Wp] bool.

    Unknown is free; a planning cell is blocked when a *known-occupied* fine cell
    (log-odds > ``logodds_known``) lies within the robot radius of its centre.
    """
    preset = require_preset(preset)
    return _inflate(belief > preset.logodds_known, preset)


def true_blocked(occupied: jax.Array, preset: Preset) -> jax.Array:
    """Planning map of the true world: [H, W] bool occupancy -> [Hp, Wp] bool."""
    preset = require_preset(preset)
    return _inflate(occupied, preset)


def xy_to_plan_cell(xy: jax.Array, preset: Preset) -> jax.Array:
    """Planning cell (row, col) containing each point: [..., 2] xy metres -> [..., 2] int32.

    Points outside the map are clipped to the nearest border cell.
    """
    preset = require_preset(preset)
    hp, wp = preset.plan_shape
    xy = jnp.asarray(xy, jnp.float32)
    pc = preset.plan_cell_size
    col = jnp.clip(jnp.floor(xy[..., 0] / pc), 0, wp - 1).astype(jnp.int32)
    row = jnp.clip(jnp.floor(xy[..., 1] / pc), 0, hp - 1).astype(jnp.int32)
    return jnp.stack([row, col], axis=-1)


def plan_cell_to_xy(cells: jax.Array, preset: Preset) -> jax.Array:
    """Centre of each planning cell: [..., 2] (row, col) -> [..., 2] float32 xy metres."""
    preset = require_preset(preset)
    cells = jnp.asarray(cells)
    pc = np.float32(preset.plan_cell_size)
    x = (cells[..., 1].astype(jnp.float32) + 0.5) * pc
    y = (cells[..., 0].astype(jnp.float32) + 0.5) * pc
    return jnp.stack([x, y], axis=-1)


def motion_blocked(
    belief: jax.Array,
    agent_xy: jax.Array,
    preset: Preset,
    blocked: jax.Array | None = None,
) -> jax.Array:
    """The planning map an agent at ``agent_xy`` [2] (metres) moves on: [Hp, Wp] bool.

    Equal to :func:`planning_blocked`, except when the agent's own cell is blocked (an
    obstacle it had not seen turned out to lie within the robot radius): then the cells
    within ``ESCAPE_RADIUS`` (Chebyshev) of it that hold no known-occupied fine cell of
    their own are open, so the agent can back out of the margin instead of being stuck
    with every goal unreachable. ``blocked`` is the belief's :func:`planning_blocked` map
    when the caller already has it.
    """
    preset = require_preset(preset)
    if blocked is None:
        blocked = planning_blocked(belief, preset)
    h, w = preset.grid_shape
    f = preset.plan_factor
    hp, wp = preset.plan_shape
    occ = jnp.pad(belief > preset.logodds_known, ((0, hp * f - h), (0, wp * f - w)))
    own_occupied = occ.reshape(hp, f, wp, f).any(axis=(1, 3))
    cell = xy_to_plan_cell(agent_xy, preset)
    rows = jnp.abs(jnp.arange(hp) - cell[0]) <= ESCAPE_RADIUS
    cols = jnp.abs(jnp.arange(wp) - cell[1]) <= ESCAPE_RADIUS
    escape = rows[:, None] & cols[None, :] & ~own_occupied & blocked[cell[0], cell[1]]
    return blocked & ~escape
