"""Scoring of the navigation benchmark: episode geometry on the true map, L_opt and PPL.

The verification matrix of an episode (geodesic distances between its start and each
target's verification point, :func:`verification_matrix`), L_opt through the found
instances (:func:`optimal_found_length`), the per-episode records of a batch of rollouts
(PPL, path lengths, mode switches, the revisited-path fraction, where the unverified
targets are) and the re-scoring of a finished chunk from its saved paths. :data:`SCORING`
names the way L_opt and PPL are computed. The protocol, the strategies and the runner are
:mod:`bfsop_jax.eval.navigation`'s, which re-exports the public names here.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np

from bfsop_jax import metrics
from bfsop_jax.config import Preset
from bfsop_jax.navigation.distance import distance_field, distance_matrix
from bfsop_jax.navigation.grid import plan_cell_to_xy, true_blocked, xy_to_plan_cell
from bfsop_jax.world.constants import TARGET_NAMES
from bfsop_jax.world.types import House

if TYPE_CHECKING:
    from bfsop_jax.eval.navigation import Episode, HouseSet, _Runner

__all__ = ["SCORING", "optimal_found_length", "target_distances", "verification_matrix"]

# How episodes are scored: raised whenever L_opt (and so PPL) would come out differently for
# the same rollout. 1: Held-Karp up to 12 found instances, one plain local search above.
# 2: Held-Karp up to 18, an iterated local search above.
SCORING = 2


# -- episode geometry on the true map ------------------------------------------------------


def verification_matrix(
    house: House, start_xy: jax.Array, targets: jax.Array, valid: jax.Array, preset: Preset
) -> jax.Array:
    """[S+1, S+1] geodesic distances (true map) between the start and targets' points.

    ``targets`` int32 [S] object slots, ``valid`` bool [S]. Each target's point is the
    traversable planning cell within ``verify_distance_m`` of its centre nearest to the
    start; with none, its centre (snapped to the nearest free cell).
    """
    blocked = true_blocked(house.occupied, preset)
    field = distance_field(blocked, start_xy, preset)
    r = math.ceil(preset.verify_distance_m / preset.plan_cell_size)
    d = np.arange(-r, r + 1)
    offsets = jnp.asarray(np.stack(np.meshgrid(d, d, indexing="ij"), -1).reshape(-1, 2))
    centre = house.object_xy[targets]  # [S, 2]
    cells = xy_to_plan_cell(centre, preset)[:, None, :] + offsets[None]  # [S, C, 2]
    hp, wp = preset.plan_shape
    rows, cols = cells[..., 0], cells[..., 1]
    inside = (rows >= 0) & (rows < hp) & (cols >= 0) & (cols < wp)
    cells = jnp.clip(cells, 0, jnp.asarray([hp - 1, wp - 1]))
    gap = plan_cell_to_xy(cells, preset) - centre[:, None]
    near = jnp.sum(gap * gap, axis=-1) <= preset.verify_distance_m**2
    cost = field[cells[..., 0], cells[..., 1]]
    ok = inside & near & ~blocked[cells[..., 0], cells[..., 1]] & jnp.isfinite(cost)
    best = jnp.argmin(jnp.where(ok, cost, jnp.inf), axis=1)
    point = plan_cell_to_xy(cells[jnp.arange(cells.shape[0]), best], preset)
    point = jnp.where(ok.any(axis=1)[:, None], point, centre)
    points = jnp.concatenate([start_xy[None], point], axis=0)
    return distance_matrix(blocked, points, jnp.concatenate([jnp.ones(1, bool), valid]), preset)


@functools.cache
def _geometry(preset: Preset) -> Any:
    """Jitted, vmapped :func:`verification_matrix` (one program per preset)."""
    return jax.jit(jax.vmap(lambda h, s, t, v: verification_matrix(h, s, t, v, preset)))


def target_distances(
    episodes: Sequence[Episode], houses: HouseSet, start_xy: np.ndarray
) -> tuple[list[np.ndarray], np.ndarray]:
    """Each episode's target object slots, and its :func:`verification_matrix` from its
    start ``start_xy`` float32 [E, 2] (metres): ``dist`` [E, W+1, W+1] with W the largest
    target count rounded up to a multiple of 8 (few distinct shapes, few compilations);
    episode e's targets are rows and columns ``1..len(targets[e])``."""
    targets = [
        np.flatnonzero(np.asarray(houses[ep.house].object_category) == ep.category)
        for ep in episodes
    ]
    width = 8 * math.ceil(max([1, *(len(t) for t in targets)]) / 8)
    tgt = np.zeros((len(episodes), width), np.int32)
    ok = np.zeros((len(episodes), width), bool)
    for i, idx in enumerate(targets):
        tgt[i, : len(idx)], ok[i, : len(idx)] = idx, True
    house_batch = _stack([houses[ep.house] for ep in episodes])
    start = jnp.asarray(start_xy, jnp.float32)
    return targets, np.asarray(_geometry(houses.preset)(house_batch, start, tgt, ok))


def _l_opt(dist: np.ndarray, found_mask: np.ndarray) -> float:
    """Metres: the shortest open path from the start (row 0 of ``dist``, [S+1, S+1])
    through the found targets (``found_mask`` bool [S]); 0 with none found."""
    sel = np.concatenate([[0], 1 + np.flatnonzero(found_mask)])
    return float(metrics.optimal_visit_length(dist[np.ix_(sel, sel)])) if len(sel) > 1 else 0.0


def optimal_found_length(
    episode: Episode, houses: HouseSet, start_xy: np.ndarray, found_slots: np.ndarray
) -> float:
    """L_opt (metres) of one episode from its start ``start_xy`` [2] through the target
    instances in object slots ``found_slots`` (the benchmark's scoring)."""
    targets, dist = target_distances([episode], houses, np.asarray(start_xy, np.float32)[None])
    return _l_opt(dist[0], np.isin(targets[0], found_slots))


def _found_slots(paths: Any, i: int, targets: np.ndarray, house: House) -> np.ndarray:
    """The found target slots of episode ``i`` of a saved chunk: stored since scoring 2,
    recovered from the found instances' centres (stored exactly) before."""
    if f"{i}_found_slots" in paths:
        return np.asarray(paths[f"{i}_found_slots"], np.int64)
    centres = np.asarray(house.object_xy)[targets].astype(np.float32)
    taken = np.zeros(len(targets), bool)
    for xy in np.asarray(paths[f"{i}_found"], np.float32):
        hit = np.flatnonzero(np.all(centres == xy, axis=1) & ~taken)
        if not len(hit):
            raise ValueError(f"episode {i}: a found instance at {xy.tolist()} is no target")
        taken[hit[0]] = True
    return targets[taken]


def _rescore_chunk(
    records: list[dict[str, Any]], paths: Any, chunk: Sequence[Episode], houses: HouseSet
) -> list[dict[str, Any]]:
    """``records`` of a finished chunk with L_opt, PPL and PPL at the end recomputed by
    today's scoring from its saved ``paths`` (the start is each path's first point)."""
    start = np.stack([np.asarray(paths[f"{i}_xy"][0], np.float32) for i in range(len(chunk))])
    targets, dist = target_distances(chunk, houses, start)
    out = []
    for i, (ep, r) in enumerate(zip(chunk, records, strict=True)):
        found_mask = np.isin(targets[i], _found_slots(paths, i, targets[i], houses[ep.house]))
        if (r["house_seed"], r["category"]) != (ep.house, TARGET_NAMES[ep.category]) or (
            int(found_mask.sum()) != r["found"]
        ):
            raise ValueError(f"episode {i}: the saved records do not match the protocol")
        l_opt = _l_opt(dist[i], found_mask)
        out.append(dict(
            r, l_opt=l_opt,
            ppl=float(metrics.ppl(r["found"], r["total"], r["path_length"], l_opt)),
            ppl_end=float(metrics.ppl(r["found"], r["total"], r["path_length_end"], l_opt)),
        ))  # fmt: skip
    return out


def _stack(trees: Sequence[Any]) -> Any:
    return jax.tree_util.tree_map(lambda *a: jnp.stack(a), *trees)


# -- per-episode records ----------------------------------------------------------------


def _last_find_length(initial: int, traj: Any, b: int) -> tuple[float, float]:
    """(L at the last verification, L at the end) of episode ``b`` (metres)."""
    found = np.asarray(traj.found_count[b])
    end = float(np.asarray(traj.path_length[b])[-1]) if len(found) else 0.0
    total = int(found[-1]) if len(found) else initial
    if total <= initial:
        return (0.0 if total > 0 else end), end
    t = int(np.argmax(found >= total))
    micro = np.asarray(traj.micro_found[b, t])
    k = np.flatnonzero(micro >= total)
    at = traj.micro_length[b, t, k[0]] if len(k) else traj.path_length[b, t]
    return float(at), end


def _revisit(start_xy: np.ndarray, traj: Any, b: int, preset: Preset) -> float:
    moved = np.asarray(traj.moved[b]).ravel()
    lengths = np.diff(np.asarray(traj.micro_length[b]).ravel(), prepend=0.0)
    xy = np.asarray(traj.poses[b, ..., :2]).reshape(-1, 2)[moved]
    cells = np.floor(xy / preset.plan_cell_size).astype(np.int64)[:, ::-1]
    start = np.floor(start_xy / preset.plan_cell_size).astype(np.int64)[::-1]
    return metrics.revisit_fraction(start, cells, lengths[moved])


def _episode_records(
    method: str,
    episodes: Sequence[Episode],
    houses: HouseSet,
    initial: Any,
    final: Any,
    traj: Any,
    runner: _Runner,
) -> tuple[list[dict[str, Any]], dict[str, np.ndarray]]:
    """Per-episode metrics of one chunk, plus the compact paths kept for figures."""
    preset = runner.preset
    start_xy = np.asarray(initial.pose)[:, :2]
    targets, dist = target_distances(episodes, houses, start_xy)
    records, paths = [], {}
    for i, ep in enumerate(episodes):
        found_mask = np.asarray(final.found[i])[targets[i]]
        l_opt = _l_opt(dist[i], found_mask)
        found, total = int(found_mask.sum()), len(targets[i])
        initial_found = int(np.asarray(initial.found[i]).sum())
        l_last, l_end = _last_find_length(initial_found, traj, i)
        active = np.asarray(traj.active[i])
        touring = np.asarray(traj.touring[i])  # [S] mode of each macro step
        moved = np.asarray(traj.moved[i])
        xy = np.asarray(traj.poses[i, ..., :2])[moved]
        tour = np.broadcast_to(touring[:, None], moved.shape)[moved]
        walked = np.concatenate([start_xy[i][None], xy])  # [P + 1, 2] start, then poses
        missed = _missed_targets(houses[ep.house], targets[i][~found_mask],
                                 np.asarray(final.receptacles_seen[i]), walked, preset)  # fmt: skip
        legs = np.diff(walked, axis=0)
        metres = np.sqrt(np.sum(legs * legs, axis=-1))
        gained = np.diff(np.asarray(traj.found_count[i]), prepend=initial_found)
        records.append({
            "method": method,
            "house_seed": int(ep.house),
            "house": houses.name(ep.house),
            "category": TARGET_NAMES[ep.category],
            "found": found,
            "total": total,
            "progress": found / total,
            "path_length": l_last,
            "path_length_end": l_end,
            "budget": float(np.asarray(final.budget[i])),
            "l_opt": float(l_opt),
            "ppl": float(metrics.ppl(found, total, l_last, l_opt)),
            "ppl_end": float(metrics.ppl(found, total, l_end, l_opt)),
            "switches": int(np.asarray(traj.switched[i]).sum()),
            "planner_calls": int(np.asarray(traj.planned[i]).sum()),
            "touring_steps": int(touring.sum()),
            "macro_steps": int(active.sum()),
            "revisit": _revisit(start_xy[i], traj, i, preset),
            **missed,
            "touring_share": float(metres[tour].sum() / max(metres.sum(), 1e-9)),
            "found_touring": int(gained[touring & active].sum()),
        })  # fmt: skip
        paths[f"{i}_xy"] = walked.astype(np.float32)
        paths[f"{i}_touring"] = np.concatenate([[False], tour])
        obj_xy = np.asarray(houses[ep.house].object_xy)
        paths[f"{i}_found"] = obj_xy[targets[i][found_mask]].astype(np.float32)
        paths[f"{i}_found_slots"] = targets[i][found_mask].astype(np.int32)
    return records, paths


def _missed_targets(
    house: House, missed: np.ndarray, receptacles_seen: np.ndarray, walked: np.ndarray,
    preset: Preset,
) -> dict:  # fmt: skip
    """Where an episode's unverified targets are (metrics only: reads the true house).

    ``missed`` int32 [U]: object slots of the targets not verified; ``receptacles_seen``
    bool [M]: the receptacles the agent detected; ``walked`` float32 [P, 2]: the agent's
    positions (metres). Returns the counts of those standing on a receptacle the agent
    detected (``missed_seen``: a visit, or one more, could have verified them), on one it
    never detected (``missed_unseen``: exploration did not get there), and on the floor
    (``missed_floor``); and, across those three, the ones in a room the agent never set
    foot in (``missed_unentered``: exploration's share that no better look would have
    found).
    """
    parent = np.asarray(house.object_parent)[missed]
    on_floor = parent < 0
    seen = ~on_floor & np.asarray(receptacles_seen)[np.maximum(parent, 0)]
    room_of_cell = np.asarray(house.room_of_cell)
    h, w = room_of_cell.shape
    cells = np.floor(walked / preset.cell_size).astype(np.int64)
    rows, cols = np.clip(cells[:, 1], 0, h - 1), np.clip(cells[:, 0], 0, w - 1)
    entered = np.unique(room_of_cell[rows, cols])
    room = np.asarray(house.object_room)[missed]
    return {
        "missed_seen": int(seen.sum()),
        "missed_unseen": int((~on_floor & ~seen).sum()),
        "missed_floor": int(on_floor.sum()),
        "missed_unentered": int((~np.isin(room, entered)).sum()),
    }
