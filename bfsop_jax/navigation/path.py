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

import math

import jax
import jax.numpy as jnp
import numpy as np

from bfsop_jax.config import Preset, require_preset
from bfsop_jax.sensing.mapping import ANGLE_UNITS

__all__ = ["NEIGHBOURS", "move_headings", "move_lengths", "next_cell"]

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
