"""The navigation benchmark: every strategy on the same episodes, scored by PPL (Table I).

Protocol. An episode is (house, target category, start pose, budget). The default
protocol runs every target category in each of the given held-out houses (9 x 10 = 90
episodes). A category absent from a house is replaced by the next house after the range
that has it and was not used for that category yet, so every category keeps its number
of episodes. The start pose is drawn from a key fixed by (house, category), and the
budget is the preset's, so every method sees exactly the same episodes.

Methods. ``fbe``, ``bfs_global``, ``tfl_reactive``, ``bfsop_vns`` (the VNS teacher as
planner) and ``bfsop_st`` (the Strategic Transformer with its 2-opt and budget gate). All
share sensing, motion and both gates, and see only the agent's observation.

Scoring (per episode, :mod:`bfsop_jax.metrics`):

* progress P = found / total instances of the category in the house;
* PPL = P * min(1, L_opt / L) with L the path length when the last target was found
  (MultiON's convention; ``ppl_end`` uses the whole path);
* L_opt: the shortest open path from the start through the *found* instances'
  verification points, with geodesic distances on the true map. An instance's
  verification point is the traversable planning cell within the verification distance
  of its centre that is nearest to the start (geodesically); exact Held-Karp up to 18
  instances, an iterated local search above (:func:`bfsop_jax.metrics.optimal_visit_length`);
* path length, mode switches (tours started), planner calls, and the revisited-path
  fraction (share of the path spent entering cells already visited: the ping-pong).

Episodes run batched (``jax.vmap``) in chunks of ``batch`` episodes; each chunk's records
are written atomically, so an interrupted evaluation resumes from the finished chunks.
Each chunk also records which scoring (:data:`SCORING`) its L_opt and PPL come from; a
finished chunk of an older scoring is re-scored from its saved paths (start, found
instances) when the run is resumed, never run again, so one ``results.json`` never mixes
two ways of computing L_opt.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from bfsop_jax import files, metrics
from bfsop_jax.agents import (
    BFSOP,
    FBE,
    BFSGlobal,
    BFSGlobalConfig,
    BFSOPConfig,
    FBEConfig,
    TFLReactive,
    TFLReactiveConfig,
    TransformerPlanner,
    VNSPlanner,
    continue_rollout,
    max_macro_steps,
)
from bfsop_jax.agents.bfsop import EXPLORER
from bfsop_jax.agents.tour import pending_landmarks
from bfsop_jax.config import Preset
from bfsop_jax.env import observe, reset
from bfsop_jax.navigation.distance import distance_field, distance_matrix
from bfsop_jax.navigation.grid import plan_cell_to_xy, true_blocked, xy_to_plan_cell
from bfsop_jax.parallel import mesh_size, place
from bfsop_jax.sop import callback as vns_host
from bfsop_jax.sop.builder import build_instance
from bfsop_jax.world.constants import N_TARGETS, TARGET_NAMES
from bfsop_jax.world.types import House

__all__ = [
    "ABLATIONS",
    "CANDIDATE_METHODS",
    "BASELINES",
    "LABELS",
    "METHODS",
    "Episode",
    "SCORING",
    "HouseSet",
    "evaluate_navigation",
    "make_strategy",
    "optimal_found_length",
    "describe_strategy",
    "protocol_episodes",
    "summarise",
    "target_distances",
    "verification_matrix",
]

METHODS: tuple[str, ...] = ("fbe", "bfs_global", "tfl_reactive", "bfsop_vns", "bfsop_st")
# How episodes are scored: raised whenever L_opt (and so PPL) would come out differently for
# the same rollout. 1: Held-Karp up to 12 found instances, one plain local search above.
# 2: Held-Karp up to 18, an iterated local search above.
SCORING = 2
BASELINES: tuple[str, ...] = ("fbe", "bfs_global", "tfl_reactive")
# Rows run on request only (``--methods``), never a "best baseline": TFL-Reactive with
# BF-SOP's explorer shows how much of BF-SOP's margin is its exploration mode's.
# The scripted policies of the environment's candidate interface (bfsop_jax.env) run as
# extra rows too: what choosing among the posed candidates gives without learning.
CANDIDATE_METHODS: tuple[str, ...] = ("cand_nearest_frontier", "cand_nearest_landmark")
ABLATIONS: tuple[str, ...] = ("tfl_reactive_gain", *CANDIDATE_METHODS)
LABELS: dict[str, str] = {
    "fbe": "FBE",
    "bfs_global": "BFS-Global",
    "tfl_reactive": "TFL-Reactive",
    "bfsop_vns": "BF-SOP (VNS)",
    "bfsop_st": "BF-SOP (Transformer)",
    "tfl_reactive_gain": "TFL-Reactive + gain explorer",
    "cand_nearest_frontier": "Candidates: nearest frontier",
    "cand_nearest_landmark": "Candidates: nearest landmark, else frontier",
}
_START_SALT = 7919  # reset key = fold_in(key(house seed), _START_SALT + category)
_SEGMENT = 32  # macro steps per jitted rollout segment (progress and early stop)


@dataclasses.dataclass(frozen=True)
class Episode:
    """One episode of the protocol: a house (seed or file index) and a target category."""

    house: int
    category: int

    @property
    def key(self) -> jax.Array:
        """PRNG key of the start pose (the same for every method)."""
        return jax.random.fold_in(jax.random.key(self.house), _START_SALT + self.category)


class HouseSet:
    """Houses by id: generated from seeds, or ProcTHOR files indexed 0, 1, ... (cached)."""

    def __init__(self, preset: Preset, procthor_dir: str | os.PathLike | None = None):
        self.preset = preset
        self._cache: dict[int, House] = {}
        self.files: list[Path] | None = None
        if procthor_dir is not None:
            from bfsop_jax.world import load_procthor_house

            folder = Path(procthor_dir)
            files = sorted(folder.glob("*.json")) if folder.is_dir() else []
            if not files:
                raise ValueError(f"--procthor-dir {folder}: no ProcTHOR house *.json files there")
            self.files = files
            self._load = lambda i: load_procthor_house(files[i], preset)
        else:
            from bfsop_jax.world.generator import generate_house

            gen = jax.jit(generate_house, static_argnums=1)
            self._load = lambda seed: gen(jax.random.key(seed), preset)

    def __len__(self) -> int:
        return len(self.files) if self.files is not None else 2**31

    def name(self, house: int) -> str:
        return self.files[house].stem if self.files is not None else str(house)

    def __getitem__(self, house: int) -> House:
        if house not in self._cache:
            self._cache[house] = jax.device_get(self._load(house))
        return self._cache[house]

    def counts(self, house: int) -> np.ndarray:
        """int [N_TARGETS]: instances of each target category in the house."""
        cats = np.asarray(self[house].object_category)
        return np.bincount(cats[(cats >= 0) & (cats < N_TARGETS)], minlength=N_TARGETS)


def protocol_episodes(
    houses: HouseSet, house_ids: Sequence[int], categories: Sequence[int], max_search: int = 200
) -> list[Episode]:
    """Every category in every house; an absent category moves on to the next house.

    The replacement is the next house id after the range (in order) that holds the
    category and was not used for it yet; after ``max_search`` houses without one (or at
    the end of a ProcTHOR folder) that episode is dropped.
    """
    house_ids = list(house_ids)
    if not house_ids:
        raise ValueError("the house range is empty")
    episodes = []
    for c in categories:
        spare = max(house_ids) + 1
        for h in house_ids:
            if houses.counts(h)[c] > 0:
                episodes.append(Episode(h, c))
                continue
            for _ in range(max_search):
                if spare >= len(houses):
                    break
                candidate, spare = spare, spare + 1
                if houses.counts(candidate)[c] > 0:
                    episodes.append(Episode(candidate, c))
                    break
    return episodes


def make_strategy(
    name: str, policy: Any = None, settings: dict[str, dict[str, Any]] | None = None
) -> Any:
    """The strategy behind a method name.

    ``settings`` override config fields: ``{"bfs_global": {...}, "tfl_reactive": {...},
    "bfsop": {...}, "transformer": {...}, "explorer": {...}}`` (``"bfsop"``: the switcher
    of both BF-SOP variants; ``"transformer"``: the decoding options of
    :class:`TransformerPlanner`, e.g. ``{"multi_start": 8, "best_of": 4, "fill": true}``;
    ``"explorer"``: fields of the :class:`FBEConfig` of whichever method runs, on top of
    its own: the baselines explore nearest-frontier first, BF-SOP weighs frontiers by the
    unknown space around them, ``gain_weight_m``). The ablation ``tfl_reactive_gain`` takes
    the ``"tfl_reactive"`` settings and starts from BF-SOP's explorer.
    """
    settings = settings or {}
    switcher = BFSOPConfig(**settings.get("bfsop", {}))
    decoding = settings.get("transformer", {})
    TransformerPlanner(None, **decoding)  # unknown options fail here, whatever the method
    explore = settings.get("explorer", {})
    if name == "fbe":
        return FBE(FBEConfig(**explore))
    if name in CANDIDATE_METHODS:
        from bfsop_jax.agents.candidate import CandidateAgent
        from bfsop_jax.env.candidates import CandidateConfig

        config = CandidateConfig(explorer=FBEConfig(**explore))
        return CandidateAgent(name.removeprefix("cand_"), config)
    if name == "bfs_global":
        strategy = BFSGlobal(BFSGlobalConfig(**settings.get(name, {})))
    elif name == "tfl_reactive":
        strategy = TFLReactive(TFLReactiveConfig(**settings.get(name, {})))
    elif name == "tfl_reactive_gain":  # TFL-Reactive's settings, BF-SOP's explorer
        strategy = TFLReactive(TFLReactiveConfig(**settings.get("tfl_reactive", {})), FBE(EXPLORER))
    elif name == "bfsop_vns":
        strategy = BFSOP(VNSPlanner(seed=0), switcher)
    elif name == "bfsop_st":
        if policy is None:
            raise ValueError("bfsop_st needs a StrategicPolicy")
        strategy = BFSOP(TransformerPlanner(policy, **decoding), switcher)
    else:
        raise ValueError(f"unknown method {name!r}; methods are {', '.join(METHODS + ABLATIONS)}")
    # the overrides apply on top of the method's own explorer (BF-SOP's weighs gain)
    explorer = FBE(dataclasses.replace(strategy.explorer.config, **explore))
    return dataclasses.replace(strategy, explorer=explorer)


def describe_strategy(strategy: Any) -> str:
    """A stable text of a strategy's class, configuration, explorer and planner (a model
    planner's model by its :attr:`~bfsop_jax.policy.StrategicPolicy.fingerprint`), so a
    resumed evaluation can tell whether a method's finished chunks still hold."""
    parts = [type(strategy).__name__, repr(getattr(strategy, "config", None))]
    explorer = getattr(strategy, "explorer", None)
    if explorer is not None:
        parts.append(repr(explorer.config))
    planner = getattr(strategy, "planner", None)
    if planner is not None:
        fields = {f.name: getattr(planner, f.name) for f in dataclasses.fields(planner)}
        if "policy" in fields:
            fields["policy"] = getattr(fields["policy"], "fingerprint", None)
        parts.append(f"{type(planner).__name__}{fields}")
    return " ".join(parts)


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


# -- running episodes --------------------------------------------------------------------


def _stack(trees: Sequence[Any]) -> Any:
    return jax.tree_util.tree_map(lambda *a: jnp.stack(a), *trees)


class _Runner:
    """Jitted, vmapped pieces for one (method, preset), compiled once per batch size."""

    def __init__(self, strategy: Any, preset: Preset, prior: jax.Array):
        self.preset = preset
        self.n_steps = max_macro_steps(preset.budget_m, preset)
        self.reset = jax.jit(jax.vmap(lambda k, h, c, b: reset(k, h, c, preset, prior, b)))
        self.init = jax.jit(jax.vmap(lambda s: strategy.init(observe(s), preset)))
        self.roll = jax.jit(
            jax.vmap(lambda s, m: continue_rollout(s, m, strategy, preset, _SEGMENT))
        )

        self.compile_s = 0.0
        self._compiled: Any = None

    def run(self, states, bar: tqdm | None) -> tuple[Any, Any]:
        """Segments of ``_SEGMENT`` macro steps until every episode has stopped.

        The segment program is compiled ahead of the first call (``compile_s``), so
        callers can time the rollout without compilation.
        """
        memory = self.init(states)
        if self._compiled is None:
            t0 = time.perf_counter()
            self._compiled = self.roll.lower(states, memory).compile()
            self.compile_s = time.perf_counter() - t0
        parts = []
        budget = np.asarray(states.budget)
        for _ in range(math.ceil(self.n_steps / _SEGMENT)):
            states, memory, traj = self._compiled(states, memory)
            traj = jax.device_get(traj)
            parts.append(traj)
            if bar is not None:
                frac = float(np.mean(np.asarray(states.path_length) / budget))
                bar.set_postfix_str(f"budget used {frac:.0%}")
            if not np.asarray(traj.active)[:, -1].any():
                break
        traj = jax.tree_util.tree_map(lambda *a: np.concatenate(a, axis=1), *parts)
        return jax.device_get(states), traj


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


# -- the evaluation ------------------------------------------------------------------------


def _write_json(path: Path, obj: Any) -> None:
    files.write_json(path, obj, sort_keys=False)


def _method_files(folder: Path, method: str, suffix: str) -> list[Path]:
    """A method's files in ``episodes/`` (its numbered chunks in order, then its planner
    latency), ``suffix`` one of ``".json"``, ``".npz"`` or ``"*"``; never another method's
    whose name extends this one's (``tfl_reactive_gain`` for ``tfl_reactive``)."""
    tail = lambda f: f.stem[len(method) + 1 :]
    mine = [
        f for f in folder.glob(f"{method}_*{'' if suffix == '*' else suffix}")
        if tail(f) == "planner" or tail(f).isdigit()
    ]
    chunk = lambda f: int(tail(f)) if tail(f).isdigit() else math.inf  # planner last
    return sorted(mine, key=chunk)


def _finished_chunk(
    done_file: Path, chunk: Sequence[Episode], houses: HouseSet
) -> list[dict[str, Any]] | None:
    """The records of a finished chunk, re-scored first (and saved so) when they come from
    an older :data:`SCORING`; None when the chunk is to run (not finished, or of an older
    scoring without its paths file)."""
    if not done_file.exists():
        return None
    saved = json.loads(done_file.read_text())
    if saved.get("scoring", 1) != SCORING:
        paths_file = done_file.with_suffix(".npz")
        if not paths_file.exists():
            return None
        try:
            with np.load(paths_file) as paths:
                saved["episodes"] = _rescore_chunk(saved["episodes"], paths, chunk, houses)
        except ValueError as err:
            raise ValueError(f"cannot re-score {done_file}: {err}") from None
        saved["scoring"] = SCORING
        _write_json(done_file, saved)
    return saved["episodes"]


def _planner_latency_ms(
    strategy: Any, final: Any, preset: Preset, repeats: int = 8
) -> float | None:
    """Median ms of one planner call (batch 1) on instances posed from final maps.

    The instances are what the agent would plan at the end of its episodes (pending =
    every detected landmark of interest, the strategy's tour budget from a full budget),
    so their size matches the evaluation's.
    """
    planner = getattr(strategy, "planner", None)
    if planner is None:
        return None
    obs = jax.vmap(observe)(final)

    def pose(o):
        pending = pending_landmarks(o, jnp.zeros_like(o.found))
        budget = strategy.tour_budget(o.replace(path_length=jnp.zeros_like(o.path_length)))
        inst, _ = build_instance(
            o.belief, o.pose[:2], budget, pending, o.object_category, o.object_xy,
            o.object_half_extent, o.prior, o.category, preset,
        )  # fmt: skip
        return inst

    instances = jax.jit(jax.vmap(pose))(obs)
    plan = jax.jit(lambda inst: planner(jnp.ones((), bool), inst))
    times = []
    for i in range(min(repeats + 1, instances.set_id.shape[0])):
        inst = jax.tree_util.tree_map(lambda a, i=i: a[i], instances)
        t0 = time.perf_counter()
        jax.block_until_ready(plan(inst))
        times.append(time.perf_counter() - t0)
    return 1000.0 * float(np.median(times[1:] if len(times) > 1 else times))


def evaluate_navigation(
    methods: Sequence[str],
    episodes: Sequence[Episode],
    houses: HouseSet,
    out_dir: str | os.PathLike,
    policy: Any = None,
    settings: dict[str, dict[str, Any]] | None = None,
    batch: int = 30,
    prior: np.ndarray | None = None,
    progress: bool = True,
    protocol: dict[str, Any] | None = None,
    mesh: Any = None,
) -> dict[str, Any]:
    """Run ``methods`` on ``episodes``; write and return ``results.json``'s content.

    Args:
        methods: names from :data:`METHODS`.
        episodes: the protocol (:func:`protocol_episodes`), the same for every method.
        houses: where the episodes' houses come from.
        out_dir: gets ``results.json``, ``protocol.json`` and ``episodes/`` (per-chunk
            records and paths; finished chunks are reused when the run is resumed).
        policy: the Strategic Transformer for ``bfsop_st``.
        settings: baseline config overrides, e.g. ``{"bfs_global": {"fraction": 0.4}}``.
        batch: episodes per vmapped chunk (results do not depend on it).
        protocol: extra description saved in ``protocol.json`` (preset, seeds, ...).
        mesh: a one-axis (``"data"``) mesh of local devices: each chunk's episodes are
            split over them (``batch`` is rounded up to a multiple of the device count).
    """
    preset = houses.preset
    out = Path(out_dir)
    if mesh is not None:
        batch = -(-batch // mesh_size(mesh)) * mesh_size(mesh)
    (out / "episodes").mkdir(parents=True, exist_ok=True)
    if prior is None:
        from bfsop_jax.world.prior import default_prior

        prior = default_prior()
    prior = jnp.asarray(prior, jnp.float32)
    described = {
        "preset": preset.name,
        "budget_m": preset.budget_m,
        "episodes": [[e.house, TARGET_NAMES[e.category]] for e in episodes],
        "settings": settings or {},
        "strategies": {m: describe_strategy(make_strategy(m, policy, settings)) for m in methods},
        "batch": batch,
        **(protocol or {}),
    }
    saved = out / "protocol.json"
    if saved.exists():
        before = json.loads(saved.read_text())
        keys = ("preset", "budget_m", "episodes", "settings", "procthor_dir")
        if any(before.get(k) != described.get(k) for k in keys):
            raise ValueError(
                f"{out} holds a different evaluation (preset, budget, episodes, settings or "
                "house files differ); use another --out directory"
            )
        described["batch"] = before.get("batch", batch)
        batch = described["batch"]
        if mesh is not None and batch % mesh_size(mesh):
            raise ValueError(
                f"{out} runs in chunks of {batch} episodes, which do not split over "
                f"{mesh_size(mesh)} devices; resume it on a device count that divides {batch}"
            )
        # chunks of a method whose strategy changed since (code defaults) are recomputed
        old = before.get("strategies", {})
        for m in methods:
            if m in old and old[m] != described["strategies"][m]:
                for f in _method_files(out / "episodes", m, "*"):
                    f.unlink()
        described["strategies"] = {**old, **described["strategies"]}
    _write_json(saved, described)

    chunks = [list(episodes[i : i + batch]) for i in range(0, len(episodes), batch)]
    all_records: list[dict[str, Any]] = []
    timings: dict[str, dict[str, float]] = {}
    for method in methods:
        strategy = make_strategy(method, policy, settings)
        runner: _Runner | None = None
        bar = tqdm(total=len(episodes), desc=LABELS[method], unit="ep", disable=not progress)
        wall, first_final, moves, ran, j_first = 0.0, None, 0, 0, True
        vns_host.reset_callback_stats()
        method_records: list[dict[str, Any]] = []
        for j, chunk in enumerate(chunks):
            done_file = out / "episodes" / f"{method}_{j:03d}.json"
            reused = _finished_chunk(done_file, chunk, houses)
            if reused is not None:
                method_records.extend(reused)
                bar.update(len(chunk))
                continue
            runner = runner or _Runner(strategy, preset, prior)
            padded = chunk + [chunk[-1]] * (batch - len(chunk))  # one compiled batch size
            size = len(chunk)
            keys = jnp.stack([e.key for e in padded])
            hs = _stack([houses[e.house] for e in padded])
            cats = jnp.asarray([e.category for e in padded], jnp.int32)
            budgets = jnp.full((batch,), preset.budget_m, jnp.float32)
            initial = jax.block_until_ready(runner.reset(keys, hs, cats, budgets))
            if mesh is not None:  # episodes split over the devices
                initial = place(jax.device_get(initial), mesh)
            t0 = time.perf_counter()
            final, traj = runner.run(initial, bar)
            wall += time.perf_counter() - t0 - (runner.compile_s if j_first else 0.0)
            j_first = False
            moves += int(np.asarray(traj.moved[:size]).sum())
            ran += size
            take = lambda tree, n=size: jax.tree_util.tree_map(lambda a: a[:n], tree)
            records, paths = _episode_records(
                method, chunk, houses, take(jax.device_get(initial)), take(final), take(traj),
                runner,
            )  # fmt: skip
            first_final = take(final) if first_final is None else first_final
            files.atomic_write(
                out / "episodes" / f"{method}_{j:03d}.npz",
                lambda f, paths=paths: np.savez_compressed(f, **paths), mode="wb",
            )
            _write_json(done_file, {"episodes": records, "wall_s": wall, "scoring": SCORING})
            method_records.extend(records)
            bar.update(len(chunk))
        bar.close()
        stats = vns_host.callback_stats()
        timings[method] = {
            "rollout_s": wall,  # without compilation; 0 when every chunk was reused
            "compile_s": runner.compile_s if runner is not None else 0.0,
            "motion_steps": moves,
            "motion_steps_per_s": moves / wall if wall > 0 else None,
            "episodes_per_s": ran / wall if wall > 0 else None,
            "vns_rows": stats["rows"],
            "vns_seconds": stats["seconds"],
        }
        # Planner latency at batch 1, measured apart from the rollout (never mixed in).
        latency_file = out / "episodes" / f"{method}_planner.json"
        latency = None  # no planner, or not measured
        if first_final is not None and method.startswith("bfsop"):
            latency = _planner_latency_ms(strategy, first_final, preset)
            _write_json(latency_file, {"planner_ms": latency})
        elif latency_file.exists():
            latency = json.loads(latency_file.read_text())["planner_ms"]
        timings[method]["planner_ms"] = latency
        for r in method_records:
            r["planner_ms"] = latency
        all_records.extend(method_records)
    result = {
        "preset": preset.name,
        "budget_m": preset.budget_m,
        "scoring": SCORING,
        "methods": summarise(all_records, methods),
        "timings": timings,
        "episodes": all_records,
    }
    _write_json(out / "results.json", result)
    return result


def summarise(records: Iterable[dict[str, Any]], methods: Sequence[str]) -> dict[str, Any]:
    """Per-method means with 95 % bootstrap intervals (episodes are the resampled unit)."""
    records = list(records)
    out = {}
    for m in methods:
        rows = [r for r in records if r["method"] == m]
        if not rows:
            continue
        col = lambda k, rows=rows: np.asarray([r[k] for r in rows], float)
        ppl = col("ppl")
        out[m] = {
            "label": LABELS[m],
            "episodes": len(rows),
            "ppl_mean": float(ppl.mean()),
            "ppl_ci95": list(metrics.bootstrap_ci(ppl)),
            "ppl_end_mean": float(col("ppl_end").mean()),
            "progress_mean": float(col("progress").mean()),
            "progress_ci95": list(metrics.bootstrap_ci(col("progress"))),
            "found_all_fraction": float(np.mean(col("found") == col("total"))),
            "path_length_mean": float(col("path_length").mean()),
            "path_length_end_mean": float(col("path_length_end").mean()),
            "switches_mean": float(col("switches").mean()),
            "planner_calls_mean": float(col("planner_calls").mean()),
            "revisit_mean": float(col("revisit").mean()),
            "planner_ms": rows[0].get("planner_ms"),
        }
    return out


def paired(
    records: Sequence[dict[str, Any]], a: str, b: str, by_house: bool = False
) -> tuple[float, float, float]:
    """Paired bootstrap (mean, lo, hi) of PPL(a) - PPL(b) over their shared episodes; with
    ``by_house`` whole houses are resampled (the interval for other houses; needs episodes
    in at least two houses)."""
    key = lambda r: (r["house_seed"], r["category"])
    pa = {key(r): r["ppl"] for r in records if r["method"] == a}
    pb = {key(r): r["ppl"] for r in records if r["method"] == b}
    shared = sorted(set(pa) & set(pb))
    if not shared:
        raise ValueError(f"methods {a} and {b} share no episode")
    groups = [k[0] for k in shared] if by_house else None
    return metrics.paired_bootstrap_ci(
        [pa[k] for k in shared], [pb[k] for k in shared], groups=groups
    )


__all__ += ["paired"]


def _ci(lo_hi: Sequence[float]) -> str:
    return f"[{lo_hi[0]:.3f}, {lo_hi[1]:.3f}]"


def write_table1(result: dict[str, Any], path: str | os.PathLike, header: str = "") -> str:
    """Table I (markdown): mean PPL per method with 95 % bootstrap intervals, and paired
    differences of BF-SOP (Transformer) with the best baseline and with BF-SOP (VNS)."""
    methods = result["methods"]
    lines = [header] if header else []
    lines += [
        "| method | PPL [95% CI] | PPL (episode end) | progress | L (m) | L end (m) | "
        "tours | planner calls | planner ms | revisit | found all |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in methods.values():
        ms = "" if s["planner_ms"] is None else f"{s['planner_ms']:.1f}"
        lines.append(
            f"| {s['label']} | {s['ppl_mean']:.3f} {_ci(s['ppl_ci95'])} | {s['ppl_end_mean']:.3f} "
            f"| {s['progress_mean']:.3f} | {s['path_length_mean']:.1f} "
            f"| {s['path_length_end_mean']:.1f} | {s['switches_mean']:.1f} "
            f"| {s['planner_calls_mean']:.1f} | {ms} | {s['revisit_mean']:.3f} "
            f"| {s['found_all_fraction']:.2f} |"
        )
    episodes = result["episodes"]
    n = max(s["episodes"] for s in methods.values())
    lines += ["", f"{n} episodes per method, the same for every method; preset "
              f"`{result['preset']}`, budget {result['budget_m']:g} m."]  # fmt: skip
    baselines = [m for m in BASELINES if m in methods]
    comparisons = []
    if "bfsop_st" in methods and baselines:
        best = max(baselines, key=lambda m: methods[m]["ppl_mean"])
        comparisons.append(("bfsop_st", best, "best baseline"))
    if "bfsop_st" in methods and "bfsop_vns" in methods:
        comparisons.append(("bfsop_st", "bfsop_vns", "teacher"))
    if "bfsop_vns" in methods and baselines:
        best = max(baselines, key=lambda m: methods[m]["ppl_mean"])
        comparisons.append(("bfsop_vns", best, "best baseline"))
    if "bfsop_st" in methods and "tfl_reactive_gain" in methods:
        comparisons.append(("bfsop_st", "tfl_reactive_gain", "the same explorer"))
    for cand in CANDIDATE_METHODS:
        comparisons += [(cand, b, "scripted candidates") for b in ("fbe", "tfl_reactive")
                        if cand in methods and b in methods]  # fmt: skip
    if comparisons:
        several = len({r["house_seed"] for r in episodes}) > 1
        lines += [
            "", "Paired differences (bootstrap over shared episodes, 95% CI; over houses: "
            "whole houses resampled, the interval for other houses):", "",
            "| comparison | PPL difference [95% CI] | over houses [95% CI] | PPL ratio |",
            "|---|---|---|---|",
        ]  # fmt: skip
        for a, b, what in comparisons:
            d, lo, hi = paired(episodes, a, b)
            house = "-"
            if several:
                _, hlo, hhi = paired(episodes, a, b, by_house=True)
                house = f"[{hlo:+.3f}, {hhi:+.3f}]"
            ratio = methods[a]["ppl_mean"] / max(methods[b]["ppl_mean"], 1e-12)
            lines.append(
                f"| {LABELS[a]} - {LABELS[b]} ({what}) | {d:+.3f} [{lo:+.3f}, {hi:+.3f}] "
                f"| {house} | {ratio:.2f}x |"
            )
    text = "\n".join(lines) + "\n"
    files.write_text(path, text)
    return text


def load_paths(out_dir: str | os.PathLike, method: str) -> list[dict[str, np.ndarray]]:
    """A method's saved paths in episode order: ``[{"xy": [S, 2], "touring": [S], "found":
    [F, 2]}]`` (positions in metres; ``found``: the verified instances)."""
    out = Path(out_dir) / "episodes"
    paths = []
    for f in _method_files(out, method, ".npz"):
        with np.load(f) as z:
            n = len([k for k in z.files if k.endswith("_xy")])
            paths += [
                {"xy": z[f"{i}_xy"], "touring": z[f"{i}_touring"], "found": z[f"{i}_found"]}
                for i in range(n)
            ]
    return paths


__all__ += ["load_paths", "method_colours", "write_table1"]


def method_colours(names: Sequence[str]) -> list[str]:
    """Each method's own colour (its place in :data:`METHODS` then :data:`ABLATIONS`), the
    same in every figure whichever methods ran."""
    from bfsop_jax.viz.style import method_colour

    order = METHODS + ABLATIONS
    return [method_colour(order.index(m)) for m in names]


def write_figures(
    result: dict[str, Any], out_dir: str | os.PathLike, houses: HouseSet
) -> list[Path]:
    """``ppl.png``, ``ppl_per_category.png`` and ``trajectories.png`` (TFL-Reactive and
    BF-SOP (Transformer), or the first and last methods run, in the first episode's house)."""
    from bfsop_jax import viz

    out = Path(out_dir)
    methods = result["methods"]
    names = list(methods)
    written = []
    labels = [methods[m]["label"] for m in names]
    colours = method_colours(names)
    viz.plot_ppl(
        labels, [methods[m]["ppl_mean"] for m in names], [methods[m]["ppl_ci95"] for m in names],
        out / "ppl.png",
        title=f"PPL per method ({result['preset']}, {methods[names[0]]['episodes']} episodes)",
        colours=colours,
    )  # fmt: skip
    written.append(out / "ppl.png")
    episodes = result["episodes"]
    cats = [c for c in TARGET_NAMES if any(r["category"] == c for r in episodes)]
    table = np.zeros((len(names), len(cats)))
    for i, m in enumerate(names):
        for j, c in enumerate(cats):
            vals = [r["ppl"] for r in episodes if r["method"] == m and r["category"] == c]
            table[i, j] = np.mean(vals) if vals else np.nan
    viz.plot_category_ppl(cats, labels, table, out / "ppl_per_category.png",
                          title="PPL per target category", colours=colours)  # fmt: skip
    written.append(out / "ppl_per_category.png")
    pair = [m for m in ("tfl_reactive", "bfsop_st") if m in names]
    if len(pair) < 2:
        pair = [names[0], names[-1]] if len(names) > 1 else names[:1]
    first = [r for r in episodes if r["method"] == pair[0]][0]
    house_id = first["house_seed"]
    house = houses[house_id]
    runs = []
    for m in pair:
        rows = [r for r in episodes if r["method"] == m]
        i = next(k for k, r in enumerate(rows) if (r["house_seed"], r["category"])
                 == (house_id, first["category"]))  # fmt: skip
        p = load_paths(out, m)[i]
        r = rows[i]
        runs.append((f"{LABELS[m]}: found {r['found']}/{r['total']}, PPL {r['ppl']:.2f}",
                     p["xy"], p["touring"], p["found"]))  # fmt: skip
    viz.plot_trajectories_side_by_side(
        house, runs, out / "trajectories.png",
        title=f"{first['category']} in house {first['house']} (first episode of the protocol)",
    )  # fmt: skip
    written.append(out / "trajectories.png")
    return written


__all__ += ["write_figures"]
