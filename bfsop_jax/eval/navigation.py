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

This module holds the protocol, the strategies, the runner and :func:`evaluate_navigation`;
the method names are :mod:`bfsop_jax.eval.methods`', the scoring
:mod:`bfsop_jax.eval.scoring`'s and the tables and figures :mod:`bfsop_jax.eval.tables`'
(all importable from here as well).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from bfsop_jax import files
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
from bfsop_jax.eval.methods import ABLATIONS, BASELINES, CANDIDATE_METHODS, LABELS, METHODS
from bfsop_jax.eval.scoring import (
    SCORING,
    _episode_records,
    _rescore_chunk,
    _stack,
    optimal_found_length,
    target_distances,
    verification_matrix,
)
from bfsop_jax.eval.tables import (
    _method_files,
    load_paths,
    method_colours,
    paired,
    summarise,
    verdict,
    write_figures,
    write_table1,
)
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
    "paired",
    "load_paths",
    "method_colours",
    "verdict",
    "write_table1",
    "write_figures",
]

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


# -- running episodes --------------------------------------------------------------------


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


# -- the evaluation ------------------------------------------------------------------------


def _write_json(path: Path, obj: Any) -> None:
    files.write_json(path, obj, sort_keys=False)


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
