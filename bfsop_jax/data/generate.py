"""Teacher-labelled SOP datasets from training houses (docs/design.md §8.2).

Two sources (docs/design.md §8.2): *on-trajectory* decisions, i.e. every switch to exploitation of
a BF-SOP agent planning with the VNS teacher, and *retrospective virtual tasks* (the
paper's teacher-student symmetry): an exploration run in a training house leaves a
*partial* belief map and the receptacles seen on the way.
That map is reused to pose many new SOP tasks (other start positions, remaining budgets,
target categories and subsets of the pending landmarks); the instance is built on the
partial, optimistic map exactly as the online agent would build it
(:func:`bfsop_jax.sop.builder.build_instance`), never on the true house, and labelled by
the VNS teacher through the batched host callback from inside the jitted function.

One record per instance, fixed shapes per preset (N nodes, K sets, T = K + 1):
``coords [N, 2]``, ``cost [N, N]``, ``set_id [N]``, ``set_reward [K]``, ``budget []``,
``teacher_nodes [T]`` (start first, -1 padded), ``teacher_reward []``,
``teacher_cost []``, plus provenance ``house_seed``, ``category``, ``source``
(0 = virtual task, 1 = on-trajectory decision, 2 = a decision of the student's own
episode, labelled afterwards: the DAgger rows of :func:`student_records`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from bfsop_jax.agents import BFSOP, FBE, VNSPlanner, max_macro_steps, rollout
from bfsop_jax.agents.record import belief_states
from bfsop_jax.config import EVAL_SEED_START, Preset, get_preset
from bfsop_jax.data.schema import make_records
from bfsop_jax.data.shards import ShardStore
from bfsop_jax.env import observe, reset
from bfsop_jax.env.types import EnvState
from bfsop_jax.navigation.distance import distance_field
from bfsop_jax.navigation.grid import plan_cell_to_xy, planning_blocked
from bfsop_jax.sensing.mapping import known_free
from bfsop_jax.sop.builder import build_instance
from bfsop_jax.sop.callback import vns_callback
from bfsop_jax.sop.types import Solution, SOPInstance
from bfsop_jax.sop.vns import VNSConfig
from bfsop_jax.world.constants import N_TARGETS
from bfsop_jax.world.generator import generate_house
from bfsop_jax.world.prior import default_prior

__all__ = [
    "DataConfig",
    "SOURCE_ON_TRAJECTORY",
    "SOURCE_STUDENT",
    "SOURCE_VIRTUAL",
    "explore",
    "generate_dataset",
    "label_virtual_tasks",
    "pose_tasks",
    "prior_digest",
    "shard_records",
    "student_records",
    "virtual_tasks",
]

SOURCE_VIRTUAL = 0
SOURCE_ON_TRAJECTORY = 1
SOURCE_STUDENT = 2  # DAgger: the decisions of a BF-SOP episode planned by the student


@dataclasses.dataclass(frozen=True)
class DataConfig:
    """What a dataset is made of; equal configs give equal datasets (the cache key)."""

    preset: str = "demo"
    houses: int = 48  # training houses
    seed_start: int = 0  # first training house seed (all below EVAL_SEED_START)
    houses_per_shard: int = 4
    tasks_per_house: int = 24  # retrospective virtual tasks per exploration run
    explore_budget: tuple[float, float] = (0.3, 1.0)  # fraction of B spent exploring
    task_budget: tuple[float, float] = (0.1, 0.6)  # remaining budget of a task, fraction of B
    keep_landmark: float = 0.8  # chance that a seen landmark is pending in a task
    vns_iters: int = 2000  # the labelling VNS run (see vns_config)
    vns_no_improve: int = 1000
    on_trajectory: bool = True  # also record the decisions of a BF-SOP (VNS) episode per house

    def __post_init__(self):
        if self.seed_start < 0 or self.seed_start + self.houses > EVAL_SEED_START:
            raise ValueError(
                f"training house seeds {self.seed_start}..{self.seed_start + self.houses - 1} "
                f"must lie in [0, {EVAL_SEED_START}) (evaluation seeds start there)"
            )
        if self.houses < 1 or self.houses_per_shard < 1 or self.tasks_per_house < 1:
            raise ValueError("houses, houses_per_shard and tasks_per_house must be >= 1")

    @property
    def n_shards(self) -> int:
        return math.ceil(self.houses / self.houses_per_shard)

    @property
    def vns_config(self) -> VNSConfig:
        """How the teacher labels this dataset: the reference VNS options with
        ``vns_iters`` iterations and ``vns_no_improve`` iterations without improvement."""
        return VNSConfig.labelling(self.vns_iters, self.vns_no_improve)


def explore(
    keys: jax.Array, houses, budgets: jax.Array, prior: jax.Array, preset: Preset
) -> EnvState:
    """Frontier-exploration runs (batched over houses) until each budget is spent."""
    n_steps = max_macro_steps(preset.budget_m, preset)

    def one(key, house, budget):
        state = reset(key, house, 0, preset, prior, budget)
        return rollout(state, FBE(), preset, n_steps)[0]

    return jax.vmap(one)(keys, houses, budgets)


def virtual_tasks(
    key: jax.Array, state: EnvState, n_tasks: int, preset: Preset, config: DataConfig
) -> tuple[SOPInstance, jax.Array]:
    """``n_tasks`` SOP instances posed on the final partial map of one exploration run.

    Start positions are drawn among known-free, traversable cells reachable from where the
    run ended; categories uniformly among the nine targets; each seen landmark with a
    positive prior is pending with probability ``config.keep_landmark``.
    Returns ``(instances [n_tasks], categories [n_tasks])``.
    """
    blocked = planning_blocked(state.belief, preset)
    hp, wp = preset.plan_shape
    f = preset.plan_factor
    free_fine = known_free(state.belief, preset)
    h, w = free_fine.shape
    free_fine = jnp.pad(free_fine, ((0, hp * f - h), (0, wp * f - w)))
    known = free_fine.reshape(hp, f, wp, f).all(axis=(1, 3))
    reach = jnp.isfinite(distance_field(blocked, state.pose[:2], preset))
    starts_ok = (known & ~blocked & reach).ravel()

    k_start, k_cat, k_bud, k_keep = jax.random.split(key, 4)
    logits = jnp.where(starts_ok, 0.0, -jnp.inf)
    cells = jax.random.categorical(k_start, logits, shape=(n_tasks,))
    cells = jnp.stack([cells // wp, cells % wp], axis=-1)
    starts = plan_cell_to_xy(cells, preset)
    starts = jnp.where(starts_ok.any(), starts, state.pose[None, :2])
    categories = jax.random.randint(k_cat, (n_tasks,), 0, N_TARGETS)
    lo, hi = config.task_budget
    budgets = preset.budget_m * jax.random.uniform(k_bud, (n_tasks,), minval=lo, maxval=hi)
    keep = jax.random.bernoulli(
        k_keep, config.keep_landmark, (n_tasks,) + state.receptacles_seen.shape
    )
    obs = observe(state)  # the run's detections only, never the true house

    def one(start, budget, category, keep):
        candidates = state.receptacles_seen & keep
        inst, _ = build_instance(
            obs.belief, start, budget, candidates, obs.object_category, obs.object_xy,
            obs.object_half_extent, obs.prior, category, preset,
        )  # fmt: skip
        return inst

    return jax.vmap(one)(starts, budgets, categories, keep), categories


def label_virtual_tasks(
    key: jax.Array, state: EnvState, seeds: jax.Array, preset: Preset, config: DataConfig
) -> tuple[SOPInstance, jax.Array, Solution]:
    """Pose virtual tasks on one final map and label them with the VNS host callback."""
    instances, categories = virtual_tasks(key, state, seeds.shape[0], preset, config)
    labels = vns_callback(instances, seeds, config=config.vns_config)
    return instances, categories, labels


def on_trajectory_decisions(
    key: jax.Array,
    house,
    category: jax.Array,
    prior: jax.Array,
    preset: Preset,
    config: DataConfig,
) -> tuple[SOPInstance, Solution, jax.Array]:
    """Run one BF-SOP episode with the VNS planner; return every step's decision record.

    Returns ``(instances [S], plans [S], planned [S])`` for S macro steps; the records
    with ``planned`` are the exploitation decisions (instance on the online map at that
    moment, the teacher's tour).
    """  # fmt: skip
    n_steps = max_macro_steps(preset.budget_m, preset)
    state = reset(key, house, category, preset, prior)
    planner = VNSPlanner(seed=0, config=config.vns_config)
    _, traj = rollout(state, BFSOP(planner=planner, record=True), preset, n_steps)
    instances, plans = traj.record
    return instances, plans, traj.planned


# one jitted function for every call (a fresh vmap each call would be traced and
# compiled again each time)
_generate_houses = jax.jit(jax.vmap(generate_house, in_axes=(0, None)), static_argnums=1)


def _present_categories(houses, j: int) -> np.ndarray:
    """The target categories present in house ``j`` of a batch (host-side, sorted)."""
    cats = np.asarray(houses.object_category[j])
    return np.unique(cats[(cats >= 0) & (cats < N_TARGETS)])


def _present_category(houses, j: int, key: jax.Array) -> int:
    """A random target category present in house ``j`` of a batch (host-side)."""
    present = _present_categories(houses, j)
    if len(present) == 0:
        return 0
    return int(present[int(jax.random.randint(key, (), 0, len(present)))])


def _selected_steps(tree, sel: np.ndarray):
    """Leaves [E, S, ...] -> [E * S, ...] as NumPy, keeping the rows where ``sel`` [E * S]."""
    return jax.tree_util.tree_map(
        lambda a: np.asarray(a).reshape((-1,) + np.shape(a)[2:])[sel], tree
    )


def _records(instances, categories, labels, house_seeds, source) -> dict[str, np.ndarray]:
    """Dataset records (:data:`bfsop_jax.data.schema.RECORD_FIELDS`) of a batch [B].

    ``instances`` [B] and their teacher ``labels`` [B], ``categories`` [B], ``house_seeds``
    [B], ``source`` (one constant); instances without any rewarding set are dropped.
    """
    inst = jax.device_get(instances)
    lab = jax.device_get(labels)
    useful = (np.asarray(inst.set_reward) > 0).any(axis=-1)  # something to plan for
    rec = make_records(
        {
            "coords": inst.coords,
            "cost": inst.cost,
            "set_id": inst.set_id,
            "set_reward": inst.set_reward,
            "budget": inst.budget,
            "teacher_nodes": lab.nodes,
            "teacher_reward": lab.reward,
            "teacher_cost": lab.cost,
            "house_seed": house_seeds,
            "category": categories,
            "source": np.full(len(useful), source),
        }
    )  # typed by the record table (bfsop_jax.data.schema)
    return {k: v[useful] for k, v in rec.items()}


def _explored(seeds, preset: Preset, config: DataConfig, prior, gen, run):
    """Houses of ``seeds`` and their exploration runs: ``(keys, houses, final states)``."""
    keys = jax.vmap(jax.random.key)(jnp.asarray(seeds))
    houses = gen(keys, preset)
    frac = jax.vmap(lambda k: jax.random.uniform(jax.random.fold_in(k, 1)))(keys)
    lo_b, hi_b = config.explore_budget
    states = run(keys, houses, preset.budget_m * (lo_b + (hi_b - lo_b) * frac), prior, preset)
    return keys, houses, states


def pose_tasks(
    house_seeds: np.ndarray | list[int],
    config: DataConfig,
    batch: int = 4,
    progress: bool = True,
    maps: bool = False,
) -> tuple[SOPInstance, np.ndarray] | tuple[SOPInstance, np.ndarray, dict[int, np.ndarray]]:
    """Unlabelled virtual tasks posed on the partial maps of exploration runs (evaluation).

    The same recipe as the training data (exploration run, then ``config.tasks_per_house``
    tasks on the final partial map), for any house seeds, e.g. held-out evaluation seeds
    (``>= EVAL_SEED_START``). Instances without a rewarding set are dropped.

    Returns:
        ``(instances [I], house_seed [I])`` as NumPy arrays; with ``maps`` also the map
        every task of a house was posed on: house seed -> int8 [H, W] cell states of the
        run's final belief map (-1 known free, 0 unknown, 1 known occupied, on the 0.1 m
        grid: :func:`bfsop_jax.agents.record.belief_states`), for pictures of the tours.
        The instances are the same either way.
    """
    preset = get_preset(config.preset)
    seeds = np.asarray(house_seeds, np.int64).ravel()
    if seeds.size == 0:
        raise ValueError("pose_tasks needs at least one house seed")
    prior = jnp.asarray(default_prior())
    gen = _generate_houses
    run = jax.jit(explore, static_argnums=4)
    pose = jax.jit(virtual_tasks, static_argnums=(2, 3, 4))
    parts, owners, house_maps = [], [], {}
    bar = tqdm(total=len(seeds), desc="evaluation tasks", unit="house", disable=not progress)
    for lo in range(0, len(seeds), batch):
        chunk = seeds[lo : lo + batch]
        keys, _, states = _explored(chunk, preset, config, prior, gen, run)
        for j, seed in enumerate(chunk):
            state = jax.tree_util.tree_map(lambda a, j=j: a[j], states)
            inst, _ = pose(jax.random.fold_in(keys[j], 2), state, config.tasks_per_house,
                           preset, config)  # fmt: skip
            inst = jax.device_get(inst)
            useful = (np.asarray(inst.set_reward) > 0).any(axis=-1)
            parts.append(jax.tree_util.tree_map(lambda a, u=useful: np.asarray(a)[u], inst))
            owners.append(np.full(int(useful.sum()), seed, np.int64))
            if maps:
                house_maps[int(seed)] = np.asarray(belief_states(state.belief, preset))
            bar.update(1)
    bar.close()
    instances = jax.tree_util.tree_map(lambda *a: np.concatenate(a), *parts)
    if maps:
        return instances, np.concatenate(owners), house_maps
    return instances, np.concatenate(owners)


def generate_dataset(
    out_dir: str | Path,
    config: DataConfig,
    shard: tuple[int, int] = (0, 1),
    progress: bool = True,
) -> ShardStore:
    """Generate (or resume, or reuse) a dataset; returns its :class:`ShardStore`.

    ``shard = (i, n)`` makes this process generate only the shards with index % n == i,
    so several processes or hosts can split the seed range.
    """
    preset = get_preset(config.preset)
    _grow(out_dir, config)
    store = ShardStore(out_dir, dataclasses.asdict(config))
    i_shard, n_proc = shard
    if not (0 <= i_shard < n_proc):
        raise ValueError(f"shard must be i/n with 0 <= i < n, got {i_shard}/{n_proc}")
    prior_np = np.asarray(default_prior(), np.float32)
    labelled = {
        "prior": prior_digest(prior_np),
        "vns_config": json.loads(json.dumps(config.vns_config.to_dict())),
    }
    _refuse_other_labels(store, labelled)
    todo = [s for s in range(config.n_shards) if s % n_proc == i_shard]
    todo = [s for s in todo if not store.is_complete(s)]
    if not todo:
        return store

    prior = jnp.asarray(prior_np)
    bar = tqdm(total=len(todo) * config.houses_per_shard, desc="dataset", unit="house",
               disable=not progress)  # fmt: skip
    for s in todo:
        lo = config.seed_start + s * config.houses_per_shard
        seeds = np.arange(lo, min(lo + config.houses_per_shard, config.seed_start + config.houses))
        arrays = shard_records(seeds, preset, config, prior)
        # how the shard was labelled: the teacher and the prior behind the set rewards
        info = {"house_seeds": [int(seeds[0]), int(seeds[-1])], **labelled}
        store.write(s, arrays, info)
        bar.update(len(seeds))
    bar.close()
    return store


def prior_digest(prior) -> str:
    """16 hex digits naming a co-occurrence prior (float32 [C, T] values), recorded with
    the records it labelled."""
    return hashlib.sha256(np.asarray(prior, np.float32).tobytes()).hexdigest()[:16]


def _refuse_other_labels(store: ShardStore, labelled: dict) -> None:
    """ValueError when a shard of ``store`` was labelled with another co-occurrence prior
    or teacher configuration than ``labelled`` (shards written before these were recorded
    are taken as they are)."""
    for index, info in store.meta["shards"].items():
        for key, value in labelled.items():
            if key in info and info[key] != value:
                what = "co-occurrence prior" if key == "prior" else "VNS teacher configuration"
                raise ValueError(
                    f"dataset directory {store.root}: shard {index} was labelled with another "
                    f"{what}; use another --data-dir (or remove it to label it again)"
                )


def _grow(out_dir: str | Path, config: DataConfig) -> None:
    """Let ``out_dir`` grow to ``config.houses``: a dataset made with the same
    configuration but fewer houses keeps its full shards (shard ``s`` always holds the
    houses ``seed_start + s * houses_per_shard ...``, so their records do not depend on
    the house count) and its ``meta.json`` takes the new configuration; a partial last
    shard is dropped and generated again. Anything else is left to :class:`ShardStore`,
    which refuses a directory made with another configuration."""
    meta_path = Path(out_dir) / "meta.json"
    if not meta_path.exists():
        return
    try:
        meta = json.loads(meta_path.read_text())
    except json.JSONDecodeError:
        return  # ShardStore names the corrupt file
    old, new = meta.get("config") or {}, json.loads(json.dumps(dataclasses.asdict(config)))
    houses = old.get("houses")
    grows = isinstance(houses, int) and houses < new["houses"]
    if not grows or {**old, "houses": new["houses"]} != new:
        return
    per = config.houses_per_shard
    kept = [int(k) for k in meta.get("shards", {}) if (int(k) + 1) * per <= houses]
    ShardStore.open(out_dir).reconfigure(new, kept)
    print(f"dataset {out_dir}: grows from {houses} to {new['houses']} houses "
          f"({len(kept)} full shards kept)")  # fmt: skip


# jitted once per (preset, config): the whole shard's houses in one program per stage
_explore_jit = jax.jit(explore, static_argnums=4)


def _label_houses(
    keys: jax.Array, states: EnvState, seeds: jax.Array, preset: Preset, config: DataConfig
) -> tuple[SOPInstance, jax.Array, Solution]:
    """Virtual tasks of H final maps (``seeds`` [H, T]), labelled by one callback of H*T rows."""
    h, t = seeds.shape
    instances, categories = jax.vmap(virtual_tasks, in_axes=(0, 0, None, None, None))(
        keys, states, t, preset, config
    )
    instances = jax.tree_util.tree_map(lambda a: a.reshape((h * t,) + a.shape[2:]), instances)
    labels = vns_callback(instances, seeds.reshape(-1), config=config.vns_config)
    return instances, categories.reshape(-1), labels


_label_jit = jax.jit(_label_houses, static_argnums=(3, 4))
_decide_jit = jax.jit(
    jax.vmap(on_trajectory_decisions, in_axes=(0, 0, 0, None, None, None)), static_argnums=(4, 5)
)


def shard_records(
    seeds: np.ndarray,
    preset: Preset,
    config: DataConfig,
    prior: jax.Array,
    timings: dict[str, float] | None = None,
) -> dict[str, np.ndarray]:
    """The dataset records of the houses ``seeds`` [H], every stage batched over them.

    Stages: house generation and exploration runs (one vmapped program), virtual tasks
    posed on all H final maps and labelled by one VNS callback over all H * tasks rows,
    then (``config.on_trajectory``) H BF-SOP (VNS) episodes side by side, the teacher
    solving only the rows that switch to exploitation at a step. ``timings``, if given,
    receives the wall seconds of each stage (``explore``, ``virtual``, ``on_trajectory``).
    """
    clock = time.perf_counter()

    def lap(name: str, value):
        nonlocal clock
        jax.block_until_ready(value)
        now = time.perf_counter()
        if timings is not None:
            timings[name] = timings.get(name, 0.0) + now - clock
        clock = now
        return value

    seeds = np.asarray(seeds, np.int64)
    keys, houses, states = lap(
        "explore", _explored(seeds, preset, config, prior, _generate_houses, _explore_jit)
    )
    task_keys = jax.vmap(lambda k: jax.random.fold_in(k, 2))(keys)
    vns_seeds = (
        np.arange(config.tasks_per_house, dtype=np.int32)[None] + seeds[:, None].astype(np.int32)
        * 1000
    )  # fmt: skip
    inst, cats, labels = lap(
        "virtual", _label_jit(task_keys, states, jnp.asarray(vns_seeds), preset, config)
    )
    owner = np.repeat(seeds, config.tasks_per_house)
    parts = [_records(inst, cats, labels, owner, SOURCE_VIRTUAL)]
    if config.on_trajectory:
        cat = np.array([
            _present_category(houses, j, jax.random.fold_in(keys[j], 3))
            for j in range(len(seeds))
        ], np.int32)  # fmt: skip
        inst, plans, switched = lap(
            "on_trajectory",
            _decide_jit(keys, states.house, jnp.asarray(cat), prior, preset, config),
        )
        sel = np.asarray(switched).reshape(-1)  # [H * steps]: the exploitation decisions
        steps = np.shape(switched)[1]
        inst, plans = _selected_steps((inst, plans), sel)
        parts.append(
            _records(inst, np.repeat(cat, steps)[sel], plans, np.repeat(seeds, steps)[sel],
                     SOURCE_ON_TRAJECTORY)
        )  # fmt: skip
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _student_episodes(keys, houses, categories, prior, preset: Preset, planner):
    """BF-SOP episodes planned by ``planner`` (batched): ``(instances [E, S], planned [E, S])``."""
    n_steps = max_macro_steps(preset.budget_m, preset)

    def one(key, house, category):
        state = reset(key, house, category, preset, prior)
        _, traj = rollout(state, BFSOP(planner=planner, record=True), preset, n_steps)
        return traj.record[0], traj.planned

    return jax.vmap(one)(keys, houses, categories)


_student_jit = jax.jit(_student_episodes, static_argnums=(4, 5))


def student_records(
    seeds: np.ndarray,
    planner,
    preset: Preset,
    config: DataConfig,
    prior: jax.Array,
    episode_salt: int = 0,
    categories_per_house: int = 3,
    timings: dict[str, float] | None = None,
) -> dict[str, np.ndarray]:
    """DAgger records: the student plans BF-SOP episodes, the teacher labels its decisions.

    For every house of ``seeds`` [H], up to ``categories_per_house`` target categories
    present in it (drawn at random) give one episode each, all run side by side with
    ``planner`` (e.g. :class:`~bfsop_jax.agents.TransformerPlanner` of the current
    student) choosing the tours. Every instance the student planned on its own online
    map is then labelled by the VNS (``config.vns_config``, on all CPU cores, host-side:
    only these rows pay for the teacher). ``episode_salt`` varies the start poses, so
    rounds see new situations in the same training houses.

    Returns:
        Dataset records with ``source`` :data:`SOURCE_STUDENT`.
    """
    from bfsop_jax.sop.callback import solve_vns_batch  # host-side labelling

    clock = time.perf_counter()
    seeds = np.asarray(seeds, np.int64)
    keys = jax.vmap(jax.random.key)(jnp.asarray(seeds))
    houses = _generate_houses(keys, preset)
    pairs = []
    for j, seed in enumerate(seeds):
        present = _present_categories(houses, j)
        rng = np.random.default_rng([int(seed), int(episode_salt)])
        for cat in rng.permutation(present)[:categories_per_house]:
            pairs.append((j, int(cat)))
    if not pairs:
        raise ValueError(f"houses {seeds.tolist()} hold no target category")
    rows = np.array([p[0] for p in pairs])
    cats = np.array([p[1] for p in pairs], np.int32)
    ep_keys = jax.vmap(
        lambda k, c: jax.random.fold_in(jax.random.fold_in(k, 100 + episode_salt), c)
    )(keys[rows], jnp.asarray(cats))
    ep_houses = jax.tree_util.tree_map(lambda a: a[rows], houses)
    inst, planned = _student_jit(ep_keys, ep_houses, jnp.asarray(cats), prior, preset, planner)
    jax.block_until_ready(planned)
    now = time.perf_counter()
    if timings is not None:
        timings["student_episodes"] = timings.get("student_episodes", 0.0) + now - clock
    sel = np.asarray(planned).reshape(-1)
    if not sel.any():
        raise ValueError(
            f"the student planned no tour in houses {seeds.tolist()} (nothing to label); "
            "drive it in more houses or for more categories"
        )
    steps = np.shape(planned)[1]
    inst = _selected_steps(inst, sel)
    vns_seeds = np.flatnonzero(sel).astype(np.int64) + 7919 * int(episode_salt)
    labels = solve_vns_batch(inst, vns_seeds, config=config.vns_config)
    if timings is not None:
        timings["labelling"] = timings.get("labelling", 0.0) + time.perf_counter() - now
    return _records(inst, np.repeat(cats, steps)[sel], labels,
                    np.repeat(seeds[rows], steps)[sel], SOURCE_STUDENT)  # fmt: skip
