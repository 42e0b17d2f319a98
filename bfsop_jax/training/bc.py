"""Behaviour cloning of the VNS teacher with teacher forcing (docs/design.md §8.3).

Loss: cross-entropy of the teacher's next node (END after its last node) at every step of
every plan, averaged over the valid steps of a minibatch. Optimiser: global-norm clipping
(1.0), then Adam, then the learning rate ``lr * lr_decay ** floor(epoch / decay_period)``
(a staircase step decay, by default x0.5 every third of the run).

The training program is functional: the model is ``nnx.split`` into a graph definition
and a parameter state, and one epoch is a jitted ``lax.scan`` over shuffled minibatches
of a fixed size (the ``D mod batch_size`` instances left over by the shuffle are dropped
for that epoch; a new shuffle drops others the next). Every (seed, learning rate) pair is
a *replica*: replicas share the data and all shapes, so they train side by side in one
``jax.vmap``-ed program. At the end the replica with the lowest validation loss becomes
the run's model.

Dataset format (a dict of NumPy arrays, leading axis D; the table is
:data:`bfsop_jax.data.schema.RECORD_FIELDS`, see :func:`instances_from_dataset`):
``coords [D, N, 2]``, ``cost [D, N, N]``, ``set_id [D, N]``, ``set_reward [D, K]``,
``budget [D]``, ``teacher_nodes [D, K + 1]``; node 0 is the start, paths are open.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import itertools
import math
import os
import signal
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx, struct
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from bfsop_jax import checkpoint as ckpt
from bfsop_jax.data.schema import DATASET_KEYS, check_records, make_records
from bfsop_jax.model.decode import decode, forced_logits, teacher_forced_logits
from bfsop_jax.model.features import node_features, random_symmetry
from bfsop_jax.model.transformer import ModelConfig, StrategicTransformer
from bfsop_jax.parallel import DATA_AXIS, barrier, mesh_size, place, to_host
from bfsop_jax.sop.types import Solution, SOPInstance, plan_length, validate
from bfsop_jax.training.config import Replica, RunConfig, TrainConfig
from bfsop_jax.training.metrics import MetricsLog, imitation_stats

__all__ = [
    "DATASET_KEYS",  # re-exported from bfsop_jax.data.schema
    "Hyper",
    "TRACE_COUNTS",
    "TrainResult",
    "TrainState",
    "TrainingTerminated",
    "dataset_from_instances",
    "dataset_info",
    "evaluate_imitation",
    "init_states",
    "instances_from_dataset",
    "make_evaluate",
    "make_optimizer",
    "learning_rate",
    "lr_factor",
    "make_train_epoch",
    "train",
]


# -- data ------------------------------------------------------------------------------------
def _check_dataset(ds: Mapping[str, Any], name: str = "dataset") -> dict[str, np.ndarray]:
    """Typed copy of the arrays the trainer uses; ValueError naming the problem.

    Keys, dtypes and shapes come from :data:`bfsop_jax.data.schema.RECORD_FIELDS`, the
    instances are checked by :func:`bfsop_jax.sop.types.validate` (start 0, open path), the
    teacher plans here.
    """
    out = check_records(ds, name)
    d, n = out["set_id"].shape
    if d == 0:
        raise ValueError(f"{name} is empty (D = 0)")
    try:
        validate(_dataset_instances(out))
    except ValueError as err:
        raise ValueError(f"{name}: {err}") from None
    teacher = out["teacher_nodes"]
    if (teacher[:, 0] != 0).any():
        raise ValueError(f"{name}: teacher_nodes must start at node 0 (the start)")
    if ((teacher < -1) | (teacher >= n)).any():
        raise ValueError(f"{name}: teacher_nodes outside [-1, {n})")
    return out


def _dataset_instances(data: Mapping[str, np.ndarray]) -> SOPInstance:
    """Batched instances [D] of typed dataset arrays: start node 0, open paths."""
    d = data["set_id"].shape[0]
    return SOPInstance(
        cost=data["cost"],
        set_id=data["set_id"],
        set_reward=data["set_reward"],
        start=np.zeros(d, np.int32),
        end=np.full(d, -1, np.int32),
        budget=data["budget"],
        coords=data["coords"],
    )


def instances_from_dataset(ds: Mapping[str, Any]) -> SOPInstance:
    """Batched :class:`SOPInstance` (NumPy leaves, leading axis D) of a dataset dict.

    Start node 0, open paths (end = -1). Extra keys of ``ds`` are ignored.
    """
    return _dataset_instances(_check_dataset(ds))


def dataset_from_instances(
    instances: Sequence[SOPInstance], solutions: Sequence[Solution]
) -> dict[str, np.ndarray]:
    """Dataset dict (the format above) from single open-path instances and their plans.

    Every instance must have the same N and K, start node 0 and ``end == -1``; a plan is
    start first, then visited nodes (``Solution.nodes`` may be padded with -1).
    """
    if len(instances) != len(solutions) or not instances:
        raise ValueError("need one solution per instance and at least one instance")
    insts = [inst.to_numpy() for inst in instances]
    k = insts[0].num_sets
    for i, inst in enumerate(insts):
        if int(inst.start) != 0 or int(inst.end) != -1:
            raise ValueError(f"instance {i}: the dataset format needs start 0 and an open path")
    teacher = np.stack([np.asarray(sol.padded(plan_length(k)).nodes) for sol in solutions])
    ds = {  # typed by the record table (dtypes and order)
        "coords": np.stack([inst.coords for inst in insts]),
        "cost": np.stack([inst.cost for inst in insts]),
        "set_id": np.stack([inst.set_id for inst in insts]),
        "set_reward": np.stack([inst.set_reward for inst in insts]),
        "budget": np.stack([inst.budget for inst in insts]),
        "teacher_nodes": teacher,
        "teacher_reward": np.asarray([sol.reward for sol in solutions]),
        "teacher_cost": np.asarray([sol.cost for sol in solutions]),
    }
    ds = make_records(ds, complete=False)
    _check_dataset(ds)
    return ds


def _instances(batch: Mapping[str, jax.Array]) -> SOPInstance:
    b = batch["set_id"].shape[0]
    return SOPInstance(
        cost=batch["cost"],
        set_id=batch["set_id"],
        set_reward=batch["set_reward"],
        start=jnp.zeros(b, jnp.int32),
        end=jnp.full(b, -1, jnp.int32),
        budget=batch["budget"],
        coords=batch["coords"],
    )


def dataset_info(ds: Mapping[str, Any]) -> dict[str, int]:
    """Sizes of a dataset: instances D, nodes N, sets K, step-level transitions."""
    data = _check_dataset(ds)
    d, n = data["set_id"].shape
    return {
        "instances": int(d),
        "num_nodes": int(n),
        "num_sets": int(data["set_reward"].shape[1]),
        "transitions": int(np.sum(data["teacher_nodes"] >= 0)),  # m nodes + END each
    }


# -- the functional training program --------------------------------------------------------
@struct.dataclass
class Hyper:
    """One replica's recipe numbers as traced scalars (stacked: a leading replica axis)."""

    lr: Any  # [] float32: base learning rate
    grad_clip: Any  # [] float32: global-norm clipping threshold
    lr_decay: Any  # [] float32: staircase decay factor ...
    decay_every: Any  # [] float32: ... every this many epochs
    warmup_epochs: Any  # [] float32: linear warm-up length (0: none)
    label_smoothing: Any  # [] float32: uniform-target weight over the allowed entries
    augment: Any  # [] bool: show instances under random coordinate symmetries
    on_policy: Any  # [] float32: weight of the loss on the student's own states

    @classmethod
    def of(cls, replica: Replica) -> Hyper:
        f32 = jnp.float32
        return cls(
            lr=f32(replica.lr),
            grad_clip=f32(replica.grad_clip),
            lr_decay=f32(replica.lr_decay),
            decay_every=f32(replica.decay_every),
            warmup_epochs=f32(replica.warmup_epochs),
            label_smoothing=f32(replica.label_smoothing),
            augment=jnp.bool_(replica.augment),
            on_policy=f32(replica.on_policy),
        )


@struct.dataclass
class TrainState:
    """One replica's training state (a leading replica axis when stacked)."""

    params: Any  # nnx.State of the model's nnx.Param leaves
    opt_state: Any  # clip + Adam state (moments, counts)
    step: Any  # [] int32: optimiser steps taken
    hyper: Hyper  # this replica's recipe numbers


def make_optimizer(grad_clip: float | jax.Array) -> optax.GradientTransformation:
    """Clip by global norm, then Adam's scaling; the learning rate is applied per replica."""
    return optax.chain(optax.clip_by_global_norm(grad_clip), optax.scale_by_adam())


def lr_factor(step: Any, decay_steps: Any, lr_decay: Any) -> jax.Array:
    """Staircase step decay: ``lr_decay ** floor(step / decay_steps)`` (optimiser steps)."""
    return lr_decay ** jnp.floor(step / decay_steps)


def learning_rate(hyper: Hyper, step: Any, steps_per_epoch: int) -> jax.Array:
    """Learning rate of optimiser step ``step`` (0-based): warm-up, then staircase decay."""
    warm = jnp.minimum(1.0, (step + 1) / jnp.maximum(hyper.warmup_epochs * steps_per_epoch, 1.0))
    warm = jnp.where(hyper.warmup_epochs > 0, warm, 1.0)
    decay = lr_factor(step, hyper.decay_every * steps_per_epoch, hyper.lr_decay)
    return hyper.lr * warm * decay


def init_states(
    model_config: ModelConfig,
    train_config: TrainConfig,
    seeds: Sequence[int] = (),
    lrs: Sequence[float] = (),
    *,
    replicas: Sequence[Replica] | None = None,
    init_params: Any = None,
) -> tuple[nnx.GraphDef, TrainState]:
    """Graph definition and stacked initial states of the replicas.

    The replicas are ``replicas`` when given, otherwise ``zip(seeds, lrs)`` with the
    recipe's other numbers. ``init_params`` (the ``nnx.Param`` state of a model of the
    same config) starts every replica from those weights with a fresh optimiser
    (fine-tuning, DAgger rounds) instead of a seeded initialisation.
    """
    if replicas is None:
        replicas = [Replica.of(train_config, s, lr) for s, lr in zip(seeds, lrs, strict=True)]
    if not replicas:
        raise ValueError("init_states needs at least one replica")
    graphdef, states = None, []
    for rep in replicas:
        model = StrategicTransformer(model_config, rngs=nnx.Rngs(params=_init_key(rep.seed)))
        graphdef, params = nnx.split(model, nnx.Param)
        if init_params is not None:
            try:
                params = jax.tree_util.tree_map(
                    lambda fresh, given: jnp.asarray(given, fresh.dtype).reshape(fresh.shape),
                    params, init_params,
                )  # fmt: skip
            except (ValueError, TypeError) as err:
                raise ValueError(f"init_params do not match the model config: {err}") from None
        states.append(
            TrainState(
                params=params,
                opt_state=make_optimizer(rep.grad_clip).init(params),
                step=jnp.int32(0),
                hyper=Hyper.of(rep),
            )
        )
    stacked = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *states)
    return graphdef, _committed(stacked)


def _committed(tree: Any) -> Any:
    """Place arrays on the default device explicitly: jit caches committed and uncommitted
    inputs separately, and the epoch's outputs are committed."""
    return place(tree, None)


def _init_key(seed: int) -> jax.Array:
    return jax.random.fold_in(jax.random.key(seed), 0)


def _epoch_key(seed: int, epoch: int) -> jax.Array:
    """Shuffle key of an epoch: a function of (seed, epoch) only, so a resume is exact."""
    return jax.random.fold_in(jax.random.fold_in(jax.random.key(seed), 1), epoch)


def _teacher_forcing(
    graphdef: nnx.GraphDef,
    params: Any,
    batch: Mapping[str, jax.Array],
    key: jax.Array | None = None,
    features: Any = None,
):
    """Teacher-forced decoder outputs on a minibatch, with its ``features`` (e.g. from
    :func:`_augmented`; None: the plain ones); with ``key`` an insertion decoder sees the
    teacher's nodes enter in a random order drawn from it (without: a fixed order)."""
    model = nnx.merge(graphdef, params)
    order_key = None if key is None else jax.random.fold_in(key, 1)
    return teacher_forced_logits(model, _instances(batch), batch["teacher_nodes"], features,
                                 order_key)  # fmt: skip


def _augmented(batch: Mapping[str, jax.Array], key: jax.Array, augment: Any):
    """Every instance's features under a random one of the 8 coordinate symmetries drawn
    from ``key`` (``augment`` traced false: the identity)."""
    return random_symmetry(node_features(_instances(batch)), key, augment)


def _student_forcing(graphdef: nnx.GraphDef, params: Any, batch: Mapping[str, jax.Array],
                     features, key: jax.Array):  # fmt: skip
    """The insertion decoder on its own states: half the minibatch's plans greedy, half
    sampled (temperature 1) by the current parameters (no gradient through the plans),
    each state labelled by the teacher's nodes it still allows (DAgger at the level of
    decoding steps, with the teacher's plan as the oracle)."""
    inst = _instances(batch)
    rows = inst.set_id.shape[0]
    frozen = nnx.merge(graphdef, jax.lax.stop_gradient(params))
    trace = decode(frozen, inst, key, greedy=jnp.arange(rows) % 2 == 0, features=features)
    model = nnx.merge(graphdef, params)
    return forced_logits(model, inst, trace.choices, features, teacher_nodes=batch["teacher_nodes"])


def _batch_stats(graphdef: nnx.GraphDef, params: Any, batch: Mapping[str, jax.Array], weight=None):
    """Summed imitation stats [3] of a minibatch (see ``imitation_stats``)."""
    return imitation_stats(_teacher_forcing(graphdef, params, batch), weight)


def _smoothing_nll(tf) -> jax.Array:
    """Summed cross-entropy of the uniform distribution over each valid step's allowed
    entries (the label-smoothing term)."""
    allowed = tf.allowed
    count = jnp.maximum(jnp.sum(allowed, axis=-1), 1)
    uniform = -jnp.sum(jnp.where(allowed, tf.log_probs, 0.0), axis=-1) / count
    return jnp.sum(jnp.where(tf.valid, uniform, 0.0))


TRACE_COUNTS: collections.Counter[str] = collections.Counter()
"""How often each training program was traced (a test that a sweep group compiles once)."""


def make_train_epoch(
    graphdef: nnx.GraphDef,
    config: TrainConfig,
    num_instances: int,
    *,
    augment: bool | None = None,
    smoothing: bool | None = None,
    on_policy: bool | None = None,
    mesh: Mesh | None = None,
    shard: str = "replicas",
) -> Callable[[TrainState, dict[str, jax.Array], jax.Array], tuple[TrainState, jax.Array]]:
    """Jitted ``train_epoch(states, data, keys) -> (states, stats)`` over stacked replicas.

    ``states``: :class:`TrainState` with a leading replica axis R; ``data``: dataset dict of
    device arrays (shared by the replicas); ``keys``: [R] shuffle keys. ``stats`` [R, 3]:
    summed NLL, correct arg-max steps, valid steps over the epoch. The program is compiled
    once per (model graph, batch size, D, replica count, the two flags below, placement):
    every recipe number lives in ``states.hyper``, so replicas that differ only in them, or
    runs that differ in epochs, share it.

    ``augment`` / ``smoothing`` / ``on_policy``: compile the symmetry augmentation / the
    label-smoothing term / the loss on the student's own states (insertion decoder) in
    (default: the recipe's setting); each replica's ``hyper`` then says whether it
    augments, how much it smooths and what weight its own states get. ``mesh`` with
    ``shard="batch"``: every minibatch is split over the mesh's ``data`` axis
    (``shard="replicas"`` needs nothing inside the program: the placement of ``states``
    decides).
    """
    batch_size = min(config.batch_size, num_instances)
    return functools.partial(
        _train_epoch,
        graphdef=graphdef,
        batch_size=batch_size,
        num_instances=num_instances,
        augment=config.augment if augment is None else bool(augment),
        smoothing=config.label_smoothing > 0 if smoothing is None else bool(smoothing),
        on_policy=config.on_policy > 0 if on_policy is None else bool(on_policy),
        batch_mesh=mesh if shard == "batch" else None,
    )


@functools.partial(
    jax.jit,
    static_argnames=(
        "graphdef", "batch_size", "num_instances", "augment", "smoothing", "on_policy",
        "batch_mesh",
    ),
)  # fmt: skip
def _train_epoch(
    states,
    data,
    keys,
    *,
    graphdef,
    batch_size: int,
    num_instances: int,
    augment: bool,
    smoothing: bool,
    on_policy: bool,
    batch_mesh: Mesh | None,
):
    TRACE_COUNTS["train_epoch"] += 1
    num_batches = num_instances // batch_size

    def loss(params, batch, key, hyper: Hyper):
        # one symmetry per instance for both losses (left out of the program unless some
        # replica augments); the key also draws an insertion decoder's order of entry
        features = _augmented(batch, key, hyper.augment) if augment else None
        tf = _teacher_forcing(graphdef, params, batch, key=key, features=features)
        stats = imitation_stats(tf)
        total, steps = stats[0], stats[2]
        if smoothing:
            eps = hyper.label_smoothing
            total = (1.0 - eps) * total + eps * _smoothing_nll(tf)
        if on_policy:  # the student's own states join with weight hyper.on_policy
            own = imitation_stats(
                _student_forcing(graphdef, params, batch, features, jax.random.fold_in(key, 2))
            )
            total = total + hyper.on_policy * own[0]
            steps = steps + hyper.on_policy * own[2]
        return total / jnp.maximum(steps, 1.0), stats

    def epoch(state: TrainState, key: jax.Array):
        shuffle, sym = jax.random.split(key)
        order = jax.random.permutation(shuffle, num_instances)[: num_batches * batch_size]
        sym_keys = jax.random.split(sym, num_batches)
        tx = make_optimizer(state.hyper.grad_clip)

        def minibatch(state: TrainState, xs):
            idx, sym_key = xs
            batch = jax.tree_util.tree_map(lambda x: x[idx], data)
            if batch_mesh is not None:
                batch = jax.lax.with_sharding_constraint(
                    batch, NamedSharding(batch_mesh, PartitionSpec(DATA_AXIS))
                )
            grads, stats = jax.grad(loss, has_aux=True)(state.params, batch, sym_key, state.hyper)
            updates, opt_state = tx.update(grads, state.opt_state, state.params)
            lr = learning_rate(state.hyper, state.step, num_batches)
            updates = jax.tree_util.tree_map(lambda u: -lr * u, updates)
            params = optax.apply_updates(state.params, updates)
            return state.replace(params=params, opt_state=opt_state, step=state.step + 1), stats

        state, stats = jax.lax.scan(
            minibatch, state, (order.reshape(num_batches, batch_size), sym_keys)
        )
        return state, jnp.sum(stats, axis=0)

    return jax.vmap(epoch)(states, keys)


def make_evaluate(
    graphdef: nnx.GraphDef, batch_size: int, num_instances: int
) -> Callable[[Any, dict[str, jax.Array]], jax.Array]:
    """Jitted ``evaluate(params, data) -> stats [R, 3]`` over every instance of ``data``.

    The last minibatch is padded with repeated instances of weight 0, so all count once.
    """
    return functools.partial(
        _evaluate, graphdef=graphdef, batch_size=batch_size, num_instances=num_instances
    )


def padded_batches(num_instances: int, batch_size: int) -> tuple[jax.Array, jax.Array]:
    """Minibatches covering every instance once: index [M, batch] int32 (the last batch
    padded with repeated instances) and weight [M, batch] float32 (0 on the padding)."""
    num_batches = math.ceil(num_instances / batch_size)
    slots = np.arange(num_batches * batch_size)
    index = jnp.asarray((slots % num_instances).reshape(num_batches, batch_size), jnp.int32)
    weight = jnp.asarray((slots < num_instances).reshape(num_batches, batch_size), jnp.float32)
    return index, weight


@functools.partial(jax.jit, static_argnames=("graphdef", "batch_size", "num_instances"))
def _evaluate(params, data, *, graphdef, batch_size: int, num_instances: int):
    index, weight = padded_batches(num_instances, min(batch_size, num_instances))

    def evaluate(params):
        def minibatch(total, xs):
            idx, w = xs
            batch = jax.tree_util.tree_map(lambda x: x[idx], data)
            return total + _batch_stats(graphdef, params, batch, w), None

        total, _ = jax.lax.scan(minibatch, jnp.zeros(3, jnp.float32), (index, weight))
        return total

    return jax.vmap(evaluate)(params)


def evaluate_imitation(
    model: StrategicTransformer, ds: Mapping[str, Any], batch_size: int = 64
) -> dict[str, float]:
    """Teacher-forced loss and next-node accuracy of one model on a dataset."""
    data = _device_data(ds)
    graphdef, params = nnx.split(model, nnx.Param)
    fn = make_evaluate(graphdef, batch_size, data["set_id"].shape[0])
    stats = np.asarray(fn(jax.tree_util.tree_map(lambda x: x[None], params), data))[0]
    return {"loss": float(stats[0] / max(stats[2], 1)), "acc": float(stats[1] / max(stats[2], 1))}


def _device_data(ds: Mapping[str, Any]) -> dict[str, jax.Array]:
    return place(_check_dataset(ds), None)


# -- the run --------------------------------------------------------------------------------
class TrainingTerminated(Exception):
    """Raised in the training loop when the process receives SIGTERM."""


@dataclasses.dataclass
class TrainResult:
    """What :func:`train` returns."""

    model: StrategicTransformer  # the chosen replica (the current best if incomplete)
    best_replica: int  # index into ``replicas``
    replicas: list[dict[str, Any]]  # Replica.to_dict() of every replica, in order
    states: TrainState  # final states of every replica (leading replica axis)
    epochs_done: int
    complete: bool  # all configured epochs done (the models were saved)
    history: list[dict[str, Any]]  # the metrics rows
    run_dir: Path
    replica_dirs: list[Path] = dataclasses.field(default_factory=list)  # one per replica
    losses: list[float] = dataclasses.field(default_factory=list)  # last selection loss each


def _stats_row(stats: np.ndarray) -> tuple[float, float]:
    steps = max(float(stats[2]), 1.0)
    return float(stats[0]) / steps, float(stats[1]) / steps


def _replica_list(
    recipe: TrainConfig,
    seeds: Sequence[int],
    lrs: Sequence[float],
    replicas: Sequence[Replica] | None,
) -> list[Replica]:
    if replicas is not None:
        if not replicas or not all(isinstance(r, Replica) for r in replicas):
            raise ValueError("replicas must be a non-empty list of Replica")
        return list(replicas)
    if not seeds or not lrs:
        raise ValueError("train needs at least one seed and one learning rate")
    if any(not (isinstance(lr, int | float) and lr > 0) for lr in lrs):
        raise ValueError(f"learning rates must be positive numbers, got {list(lrs)}")
    return [Replica.of(recipe, s, lr) for s, lr in itertools.product(seeds, lrs)]


def train(
    config: RunConfig,
    train_ds: Mapping[str, Any],
    val_ds: Mapping[str, Any] | None,
    out_dir: str | os.PathLike,
    seeds: Sequence[int] = (0,),
    lrs: Sequence[float] = (1e-4,),
    resume: bool = False,
    progress: bool = True,
    max_epochs_this_call: int | None = None,
    on_epoch: Callable[[list[dict[str, Any]]], None] | None = None,
    dataset_meta: dict[str, Any] | None = None,
    *,
    replicas: Sequence[Replica] | None = None,
    replica_dirs: Sequence[str | os.PathLike] | None = None,
    mesh: Mesh | None = None,
    init_params: Any = None,
) -> TrainResult:
    """Train every replica as one vmapped program; checkpoint after every epoch.

    Args:
        config: model, recipe and preset name.
        train_ds, val_ds: dataset dicts (``val_ds`` may be None: the training loss then
            picks the best replica).
        out_dir: run directory (see :mod:`bfsop_jax.checkpoint` for its layout).
        seeds, lrs: without ``replicas``, the replicas are their Cartesian product
            (seed-major) with the recipe's other numbers.
        resume: continue from the last checkpoint in ``out_dir`` (same config required).
            Without it, a directory that already holds checkpoints is refused.
        progress: show a tqdm bar over epochs.
        max_epochs_this_call: stop (checkpointed) after this many epochs of this call.
        on_epoch: called with the metric rows after each epoch, before its checkpoint.
        dataset_meta: extra JSON-able description of the data, stored in ``config.json``.
        replicas: the members of the program, each with its own seed and recipe numbers.
        replica_dirs: where each replica's final model goes (``config.json`` + ``model/``,
            loadable by ``StrategicPolicy.load``); default ``out_dir/replicas/<i>`` when
            there are several (one replica is ``out_dir/model`` itself).
        mesh: a one-axis (``"data"``) device mesh to spread the program over: the
            replicas when their count divides by the mesh size, otherwise every
            minibatch (the batch size must then divide by it). None: the default device.
        init_params: start every replica from these model parameters (``nnx.Param``
            state of the same model config), e.g. the previous DAgger round's model.

    Returns:
        A :class:`TrainResult`. On KeyboardInterrupt or SIGTERM the last completed epoch is
        checkpointed, then the exception propagates (resume with ``resume=True``). The
        best replica (lowest validation loss) also goes to ``out_dir/model``.
    """
    if not isinstance(config, RunConfig):
        raise ValueError(f"config must be a RunConfig, got {type(config).__name__}")
    tcfg = config.train
    members = _replica_list(tcfg, seeds, lrs, replicas)
    if any(r.on_policy > 0 for r in members) and config.model.decoder != "insertion":
        raise ValueError("on_policy training needs the insertion decoder (model.decoder)")
    if max_epochs_this_call is not None and max_epochs_this_call < 1:
        raise ValueError(f"max_epochs_this_call must be >= 1, got {max_epochs_this_call}")
    run_dir = Path(out_dir)
    if replica_dirs is not None:
        dirs = [Path(d) for d in replica_dirs]
    elif len(members) > 1:
        dirs = [run_dir / "replicas" / f"{i:03d}" for i in range(len(members))]
    else:  # one replica: run_dir/model is that replica
        dirs = []
    if dirs and len(dirs) != len(members):
        raise ValueError(f"{len(members)} replicas but {len(dirs)} replica directories")
    info = {"train": dataset_info(train_ds)}
    if val_ds is not None:
        info["val"] = dataset_info(val_ds)
        for key in ("num_nodes", "num_sets"):
            if info["val"][key] != info["train"][key]:
                raise ValueError(f"train and val datasets differ in {key}")
    num_train = info["train"]["instances"]
    batch_size = min(tcfg.batch_size, num_train)
    shard = _shard_mode(mesh, len(members), batch_size)
    replica_dicts = [r.to_dict() for r in members]
    run_config = {
        "run": config.to_dict(),
        "replicas": replica_dicts,
        "dataset": {
            "num_nodes": info["train"]["num_nodes"],
            "num_sets": info["train"]["num_sets"],
            **info,
            "meta": dataset_meta or {},
        },
    }
    _prepare_run_dir(run_dir, run_config, resume)
    barrier("train:prepared")

    graphdef, states = init_states(config.model, tcfg, replicas=members, init_params=init_params)
    lead = shard == "replicas"
    states = place(to_host(states), mesh, leading=lead)
    train_data = place(_check_dataset(train_ds), mesh, leading=False)
    val_data = place(_check_dataset(val_ds), mesh, leading=False) if val_ds is not None else None
    train_epoch = make_train_epoch(
        graphdef, tcfg, num_train, augment=any(r.augment for r in members),
        smoothing=any(r.label_smoothing > 0 for r in members),
        on_policy=any(r.on_policy > 0 for r in members), mesh=mesh, shard=shard,
    )  # fmt: skip
    evaluate = (
        make_evaluate(graphdef, tcfg.batch_size, info["val"]["instances"]) if val_data else None
    )
    steps = num_train // batch_size  # optimiser steps per epoch

    store = ckpt.CheckpointStore(run_dir, max_to_keep=tcfg.keep_checkpoints)
    start = 0
    if resume and store.latest_epoch() is not None:
        states, meta = store.restore(states)
        states = place(to_host(states), mesh, leading=lead)
        start = int(meta["epoch"])
    log = MetricsLog(run_dir, keep_until_epoch=start)
    last_losses = _last_losses(log.rows, len(members), start)
    stop = (
        tcfg.epochs
        if max_epochs_this_call is None
        else min(tcfg.epochs, start + max_epochs_this_call)
    )

    done, saved = start, start
    previous = _install_sigterm()
    bar = _progress(progress, start, tcfg.epochs)
    try:
        for epoch in range(start + 1, stop + 1):
            t0 = time.perf_counter()
            keys = place(
                jnp.stack([_epoch_key(r.seed, epoch) for r in members]), mesh, leading=lead
            )
            new_states, train_stats = train_epoch(states, train_data, keys)
            train_stats = to_host(train_stats)
            val_stats = to_host(evaluate(new_states.params, val_data)) if evaluate else None
            seconds = time.perf_counter() - t0
            rows = []
            for i, rep in enumerate(members):
                train_loss, train_acc = _stats_row(train_stats[i])
                val_loss, val_acc = (
                    _stats_row(val_stats[i]) if val_stats is not None else (None, None)
                )
                lr = learning_rate(Hyper.of(rep), epoch * steps - 1, steps)
                rows.append(
                    {
                        "epoch": epoch,
                        "replica": i,
                        "seed": rep.seed,
                        "base_lr": rep.lr,
                        "lr": float(lr),
                        "train_loss": train_loss,
                        "train_acc": train_acc,
                        "val_loss": val_loss,
                        "val_acc": val_acc,
                        "seconds": seconds,
                    }
                )
            last_losses = [
                r["val_loss"] if r["val_loss"] is not None else r["train_loss"] for r in rows
            ]
            log.append(rows)
            # the epoch counts as done (and is saved on an interrupt) once its rows are
            # logged: an interrupt before that runs it again on resume, with its own rows
            states, done = new_states, epoch
            if not np.isfinite(np.asarray(last_losses, float)).any():
                raise ValueError(
                    f"training diverged: no replica has a finite loss at epoch {epoch} "
                    "(try a lower learning rate)"
                )
            if bar is not None:
                best = int(np.nanargmin(last_losses))
                bar.set_postfix(
                    loss=f"{rows[best]['train_loss']:.3f}", sel=f"{last_losses[best]:.3f}"
                )
                bar.update(1)
            if on_epoch is not None:
                on_epoch(rows)
            store.save(epoch, states, _meta(epoch, last_losses))
            saved = epoch
    except (KeyboardInterrupt, TrainingTerminated):
        if done > saved:  # the epoch finished but its checkpoint was not written yet
            store.save(done, states, _meta(done, last_losses))
        raise
    finally:
        _restore_sigterm(previous)
        if bar is not None:
            bar.close()
        store.close()

    host_states = to_host(states)
    best = int(np.nanargmin(last_losses)) if last_losses else 0
    params = jax.tree_util.tree_map(lambda x: x[best], host_states.params)
    complete = done >= tcfg.epochs
    if complete:  # every process takes part in the (collective) saves
        ckpt.save_model(run_dir, params)
        summary = dict(run_config)
        summary["result"] = {
            "best_replica": best,
            **replica_dicts[best],
            "selection_loss": last_losses[best] if last_losses else None,
            "epochs": done,
        }
        ckpt.write_config(run_dir, summary)
        for i, rep_dir in enumerate(dirs):
            _save_replica(
                rep_dir, run_config, replica_dicts[i], i, last_losses, done, host_states.params
            )
    return TrainResult(
        model=nnx.merge(graphdef, params),
        best_replica=best,
        replicas=replica_dicts,
        states=host_states,
        epochs_done=done,
        complete=complete,
        history=list(log.rows),
        run_dir=run_dir,
        replica_dirs=dirs,
        losses=list(last_losses),
    )


def _shard_mode(mesh: Mesh | None, num_replicas: int, batch_size: int) -> str:
    """How a mesh splits the program: "replicas" (also without a mesh) or "batch"."""
    if mesh is None:
        return "replicas"
    n = mesh_size(mesh)
    if num_replicas % n == 0:
        return "replicas"
    if batch_size % n == 0:
        return "batch"
    raise ValueError(
        f"cannot spread {num_replicas} replicas with minibatches of {batch_size} over {n} "
        "devices: one of the two must divide by the device count"
    )


def _save_replica(
    rep_dir: Path,
    run_config: dict[str, Any],
    replica: dict[str, Any],
    index: int,
    losses: list[float],
    epochs: int,
    params: Any,
) -> None:
    """A replica's own run directory: ``config.json`` (one replica) and ``model/``."""
    rep_dir.mkdir(parents=True, exist_ok=True)
    ckpt.save_model(rep_dir, jax.tree_util.tree_map(lambda x: x[index], params))
    summary = {**run_config, "replicas": [replica]}
    summary["result"] = {
        "best_replica": 0,
        **replica,
        "selection_loss": losses[index] if losses else None,
        "epochs": epochs,
    }
    ckpt.write_config(rep_dir, summary)


def latest_best_params(
    run_dir: str | os.PathLike, config: dict[str, Any], model_config: ModelConfig
) -> Any:
    """Parameters of the best replica in the last epoch checkpoint of a run directory
    (``config``: its ``config.json``); ValueError when there is none."""
    run_dir = Path(run_dir)
    replicas = config.get("replicas") or []
    if not replicas:
        raise ValueError(f"{run_dir / ckpt.CONFIG_FILE} lists no replicas")
    train_config = TrainConfig.from_dict(config["run"]["train"])
    members = [Replica.from_dict(r, train_config) for r in replicas]
    states = jax.eval_shape(lambda: init_states(model_config, train_config, replicas=members)[1])
    with ckpt.CheckpointStore(run_dir, read_only=True) as store:
        if store.latest_epoch() is None:
            raise ValueError(f"no checkpoint in {run_dir} (neither model/ nor an epoch checkpoint)")
        state, meta = store.restore(states)
    best = int(meta.get("best_replica", 0))
    return jax.tree_util.tree_map(lambda x: x[best], state.params)


def _meta(epoch: int, losses: list[float]) -> dict[str, Any]:
    best = int(np.nanargmin(losses)) if losses else 0
    return {"epoch": epoch, "selection_loss": losses, "best_replica": best}


def _last_losses(rows: list[dict[str, Any]], replicas: int, epoch: int) -> list[float]:
    mine = [r for r in rows if r["epoch"] == epoch]
    if len(mine) != replicas:
        return []
    mine.sort(key=lambda r: r["replica"])
    return [r["val_loss"] if r.get("val_loss") is not None else r["train_loss"] for r in mine]


def _prepare_run_dir(run_dir: Path, run_config: dict[str, Any], resume: bool) -> None:
    run_dir.mkdir(parents=True, exist_ok=True)
    has_checkpoints = (run_dir / ckpt.CHECKPOINT_DIR).is_dir() and any(
        p.name.isdigit() for p in (run_dir / ckpt.CHECKPOINT_DIR).iterdir()
    )
    if (run_dir / ckpt.CONFIG_FILE).exists() and has_checkpoints:
        if not resume:
            raise ValueError(
                f"{run_dir} already holds a training run; pass resume=True to continue it "
                "or choose a new directory"
            )
        old = ckpt.read_config(run_dir)
        for key in ("run", "replicas"):
            if old.get(key) != run_config[key]:
                raise ValueError(
                    f"cannot resume {run_dir}: its {key} differs from this call "
                    f"({old.get(key)} != {run_config[key]})"
                )
        for key in ("num_nodes", "num_sets", "train"):
            if old.get("dataset", {}).get(key) != run_config["dataset"][key]:
                raise ValueError(f"cannot resume {run_dir}: the training data differ ({key})")
        return
    ckpt.write_config(run_dir, run_config)


def _install_sigterm():
    if threading.current_thread() is not threading.main_thread():
        return None

    def handler(signum, frame):
        raise TrainingTerminated("SIGTERM received during training")

    return signal.signal(signal.SIGTERM, handler)


def _restore_sigterm(previous) -> None:
    if previous is not None:
        signal.signal(signal.SIGTERM, previous)


def _progress(enabled: bool, start: int, total: int):
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=start, desc="training", unit="epoch")
