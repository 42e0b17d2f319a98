"""Frontiers: known-free planning cells next to unknown space, and their clusters
(docs/design.md §5).

Planning-cell states from the fine belief (f x f fine cells per planning cell,
f = ``plan_factor``; "known" means ``|log-odds| > logodds_known``):

- *free*: a strict majority of its fine cells known free and none known occupied;
- *unknown*: at least half of its fine cells unknown and none known occupied.

A **frontier cell** is a free planning cell, unblocked on the optimistic planning map
(so the robot can stand there), with an unknown planning cell among its 4 neighbours.
Clusters are the 8-connected components of frontier cells (label propagation with
pointer jumping, run to convergence). Clusters of fewer than ``MIN_CLUSTER_CELLS`` cells
are dropped as noise; the ``preset.max_frontier_clusters`` largest are kept, largest
first (ties: lower row-major index of the cluster's first cell). Each is represented by
its member cell nearest to the cluster's centroid (rounded to a cell; integer arithmetic),
so the goal is a frontier cell itself, never a centroid inside a wall.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jax import lax

from bfsop_jax.config import Preset, require_preset
from bfsop_jax.navigation.grid import plan_cell_to_xy, planning_blocked, xy_to_plan_cell

__all__ = [
    "MIN_CLUSTER_CELLS",
    "Frontiers",
    "cluster_frontier_cells",
    "frontier_cells",
    "frontier_clusters",
    "frontier_mask",
    "nearest_frontier",
    "plan_cell_states",
    "unknown_count",
    "unknown_side",
]

MIN_CLUSTER_CELLS = 3  # planning cells (3 x 0.2 m): smaller clusters are sensing noise


@struct.dataclass
class Frontiers:
    """Up to F = ``preset.max_frontier_clusters`` frontier clusters, largest first."""

    xy: jax.Array  # [F, 2] float32: representative frontier cell centre (metres)
    size: jax.Array  # [F] int32: cluster size in planning cells (0 for empty slots)
    valid: jax.Array  # [F] bool: slot holds a cluster


def _block_counts(mask: jax.Array, preset: Preset) -> jax.Array:
    """[H, W] bool fine mask -> [Hp, Wp] int32 count per planning cell (outside: 0)."""
    h, w = mask.shape
    f = preset.plan_factor
    hp, wp = preset.plan_shape
    m = jnp.pad(mask.astype(jnp.int32), ((0, hp * f - h), (0, wp * f - w)))
    return m.reshape(hp, f, wp, f).sum(axis=(1, 3))


def plan_cell_states(belief: jax.Array, preset: Preset) -> tuple[jax.Array, jax.Array]:
    """Free and unknown planning cells of a belief (module docstring): two [Hp, Wp] bool."""
    preset = require_preset(preset)
    if belief.shape[-2:] != tuple(preset.grid_shape):
        raise ValueError(
            f"belief has shape {belief.shape}, preset {preset.name!r} expects grid_shape "
            f"{preset.grid_shape}"
        )
    k = preset.logodds_known
    n = preset.plan_factor**2
    n_free = _block_counts(belief < -k, preset)
    # fine cells beyond the map edge (partial planning cells) count as occupied
    n_occ = (
        _block_counts(belief > k, preset) + n - _block_counts(jnp.ones(belief.shape, bool), preset)
    )
    n_unknown = n - n_free - n_occ
    free = (2 * n_free > n) & (n_occ == 0)
    unknown = (2 * n_unknown >= n) & (n_occ == 0)
    return free, unknown


def frontier_cells(belief: jax.Array, preset: Preset) -> jax.Array:
    """Frontier planning cells of a belief: [H, W] float32 log-odds -> [Hp, Wp] bool."""
    preset = require_preset(preset)
    free, unknown = plan_cell_states(belief, preset)
    return frontier_mask(free, unknown, planning_blocked(belief, preset))


def frontier_mask(free: jax.Array, unknown: jax.Array, blocked: jax.Array) -> jax.Array:
    """Frontier cells from the planning-cell states (:func:`plan_cell_states`) and the
    planning map: free, unblocked, with an unknown 4-neighbour. All [Hp, Wp] bool."""
    # planning cells beyond the map edge are not unknown space
    up = jnp.pad(unknown, 1, constant_values=False)
    next_to_unknown = up[:-2, 1:-1] | up[2:, 1:-1] | up[1:-1, :-2] | up[1:-1, 2:]
    return free & next_to_unknown & ~blocked


def unknown_side(unknown: jax.Array, cells: jax.Array, radius: int) -> jax.Array:
    """Direction from each cell towards the unknown space around it.

    ``unknown`` [Hp, Wp] bool (see :func:`plan_cell_states`), ``cells`` [..., 2] int32
    -> [..., 2] int32: the sum of the (drow, dcol) offsets of the unknown cells within
    ``radius`` (Chebyshev) of the cell; (0, 0) when there are none or they balance out.
    Integer arithmetic, so a look direction built from it is exact.
    """
    unk, off = _unknown_around(unknown, cells, radius)
    return jnp.sum(jnp.where(unk[..., None], off, 0), axis=-2).astype(jnp.int32)


def unknown_count(unknown: jax.Array, cells: jax.Array, radius: int) -> jax.Array:
    """Unknown planning cells within ``radius`` (Chebyshev) of each cell.

    ``unknown`` [Hp, Wp] bool, ``cells`` [..., 2] int32 -> [...] int32 (cells beyond the
    map edge do not count): how much unseen space a look from there could resolve.
    The square sums come from one separable box filter over the map (a window sum along
    the rows, then along the columns; exact integers), read at the cells, rather than
    one lookup per cell of every square: the candidate interface asks for all clusters.
    """
    hp, wp = unknown.shape
    w = 2 * radius + 1
    grid = jnp.pad(unknown.astype(jnp.int32), 2 * radius)  # beyond the edge: not unknown
    grid = lax.reduce_window(grid, 0, lax.add, (w, 1), (1, 1), "VALID")
    grid = lax.reduce_window(grid, 0, lax.add, (1, w), (1, 1), "VALID")
    # grid[i + radius, j + radius]: the square around cell (i, j), for i in [-radius, hp + radius)
    cells = jnp.asarray(cells, jnp.int32) + radius
    rows, cols = cells[..., 0], cells[..., 1]
    inside = (rows >= 0) & (rows < hp + 2 * radius) & (cols >= 0) & (cols < wp + 2 * radius)
    value = grid[jnp.clip(rows, 0, hp + 2 * radius - 1), jnp.clip(cols, 0, wp + 2 * radius - 1)]
    return jnp.where(inside, value, 0)


def _unknown_around(
    unknown: jax.Array, cells: jax.Array, radius: int
) -> tuple[jax.Array, np.ndarray]:
    """bool [..., O]: which of the (2 radius + 1)^2 cells around each cell are unknown
    (beyond the map edge: not), with the int32 [O, 2] (drow, dcol) offsets."""
    hp, wp = unknown.shape
    r = np.arange(-radius, radius + 1, dtype=np.int32)
    off = np.stack(np.meshgrid(r, r, indexing="ij"), -1).reshape(-1, 2)  # [O, 2]
    nb = jnp.asarray(cells, jnp.int32)[..., None, :] + off
    inside = (nb[..., 0] >= 0) & (nb[..., 0] < hp) & (nb[..., 1] >= 0) & (nb[..., 1] < wp)
    unk = inside & unknown[jnp.clip(nb[..., 0], 0, hp - 1), jnp.clip(nb[..., 1], 0, wp - 1)]
    return unk, off


def _component_labels(cells: jax.Array) -> jax.Array:
    """8-connected components: [Hp, Wp] bool -> [Hp, Wp] int32 smallest member index
    (row-major) of each cell's component; ``Hp * Wp`` for non-members.

    Label propagation with hooking and pointer jumping: every label is the index of a
    member of the same component, never above the cell's own index. Each iteration takes
    the smallest label around each cell, passes it on to the cell its old label points at
    (so a whole group pointing there follows at once), then jumps pointers twice. This
    takes a few iterations even for long winding frontiers, where plain propagation would
    need one iteration per cell of the chain.
    """
    hp, wp = cells.shape
    n = hp * wp
    member = cells.reshape(-1)
    label0 = jnp.where(member, jnp.arange(n, dtype=jnp.int32), n)

    def neighbour_min(lab):
        g = jnp.pad(lab.reshape(hp, wp), 1, constant_values=n)
        out = lab.reshape(hp, wp)
        for di in (0, 1, 2):
            for dj in (0, 1, 2):
                out = jnp.minimum(out, g[di : di + hp, dj : dj + wp])
        return jnp.where(member, out.reshape(-1), n)

    def body(state):
        lab, _ = state
        low = neighbour_min(lab)
        ext = jnp.concatenate([low, jnp.array([n], jnp.int32)])  # slot n: non-members
        ext = ext.at[lab].min(low)  # hook: the old label's cell takes the new label too
        for _ in range(2):
            ext = ext[ext]
        new = ext[:n]
        return new, jnp.any(new != lab)

    lab, _ = lax.while_loop(lambda s: s[1], body, (label0, jnp.bool_(True)))
    return lab.reshape(hp, wp)


def cluster_frontier_cells(
    cells: jax.Array, preset: Preset, min_size: int = MIN_CLUSTER_CELLS
) -> Frontiers:
    """Cluster a [Hp, Wp] bool frontier mask into :class:`Frontiers` (module docstring)."""
    preset = require_preset(preset)
    hp, wp = cells.shape
    n = hp * wp
    f_max = preset.max_frontier_clusters
    lab = _component_labels(cells).reshape(-1)
    member = lab < n
    seg = jnp.where(member, lab, n)  # non-members go to a dump segment
    ii, jj = jnp.divmod(jnp.arange(n, dtype=jnp.int32), wp)
    # one scatter for size and coordinate sums of every component (indexed by its root)
    stats = jnp.stack([jnp.ones(n, jnp.int32), ii, jj], -1) * member[:, None]
    stats = jax.ops.segment_sum(stats, seg, num_segments=n + 1)[:n]
    size = stats[:, 0]
    root = member & (lab == jnp.arange(n))
    # float keys: XLA:CPU's integer top_k falls back to a full sort (30x slower); sizes are
    # exact in float32, and top_k puts the lower index first on ties
    key = jnp.where(root & (size >= min_size), size, -1).astype(jnp.float32)
    top_key, top_root = lax.top_k(key, f_max)
    top_size = top_key.astype(jnp.int32)
    valid = top_size >= min_size
    # representative: the member nearest to its cluster's centroid rounded to a cell (ties:
    # lowest index); integer arithmetic, so the choice never depends on float rounding
    lab_c = jnp.minimum(lab, n - 1)
    count = jnp.maximum(stats[lab_c, :1], 1)
    centroid = (2 * stats[lab_c, 1:] + count) // (2 * count)  # [n, 2] rounded half up
    d2 = jnp.where(member, (ii - centroid[:, 0]) ** 2 + (jj - centroid[:, 1]) ** 2, 2**30)
    best = jax.ops.segment_min(d2, seg, num_segments=n + 1)[:n]
    index = jnp.arange(n, dtype=jnp.int32)
    first = jnp.where(member & (d2 <= best[lab_c]), index, n)
    rep = jax.ops.segment_min(first, seg, num_segments=n + 1)[top_root]
    rep_cell = jnp.stack(jnp.divmod(rep, wp), axis=-1)
    xy = jnp.where(valid[:, None], plan_cell_to_xy(rep_cell, preset), 0.0)
    return Frontiers(xy=xy, size=jnp.where(valid, top_size, 0).astype(jnp.int32), valid=valid)


def frontier_clusters(belief: jax.Array, preset: Preset) -> Frontiers:
    """Frontier clusters of a belief ([H, W] float32 log-odds), largest first."""
    preset = require_preset(preset)
    return cluster_frontier_cells(frontier_cells(belief, preset), preset)


def nearest_frontier(
    frontiers: Frontiers,
    field_from_agent: jax.Array,
    preset: Preset,
    bonus: jax.Array | None = None,
) -> tuple[jax.Array, jax.Array]:
    """The geodesically nearest frontier: ``(index int32, distance float32 metres)``.

    ``field_from_agent`` is the [Hp, Wp] distance field from the agent. With ``bonus``
    (float32 [F] metres) the choice minimises distance minus bonus instead; the distance
    returned is still the geodesic one. Returns ``(-1, inf)`` when no valid frontier is
    reachable.
    """
    preset = require_preset(preset)
    cell = xy_to_plan_cell(frontiers.xy, preset)
    d = jnp.where(frontiers.valid, field_from_agent[cell[:, 0], cell[:, 1]], jnp.inf)
    score = d if bonus is None else d - jax.lax.optimization_barrier(bonus)
    k = jnp.argmin(score).astype(jnp.int32)
    dist = d[k]
    found = jnp.isfinite(dist)
    return jnp.where(found, k, -1), jnp.where(found, dist, np.float32(np.inf))
