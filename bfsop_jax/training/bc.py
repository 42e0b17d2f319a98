"""Behaviour cloning of the VNS teacher with teacher forcing (SPEC 9.3).

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

Dataset format (a dict of NumPy arrays, leading axis D; see :func:`instances_from_dataset`):
``coords [D, N, 2]``, ``cost [D, N, N]``, ``set_id [D, N]``, ``set_reward [D, K]``,
``budget [D]``, ``teacher_nodes [D, K + 1]``; node 0 is the start, paths are open.
"""

from __future__ import annotations

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

from bfsop_jax.model.decode import teacher_forced_logits
from bfsop_jax.model.features import NUM_SYMMETRIES, node_features, symmetric_features
from bfsop_jax.model.transformer import ModelConfig, StrategicTransformer
from bfsop_jax.sop.types import Solution, SOPInstance, plan_length
from bfsop_jax.training import checkpoint as ckpt
from bfsop_jax.training.config import RunConfig, TrainConfig
from bfsop_jax.training.metrics import MetricsLog, imitation_stats

__all__ = [
    "DATASET_KEYS",
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
    "lr_factor",
    "make_train_epoch",
    "train",
]

DATASET_KEYS = ("coords", "cost", "set_id", "set_reward", "budget", "teacher_nodes")
_DTYPES = {
    "coords": np.float32,
    "cost": np.float32,
    "set_id": np.int32,
    "set_reward": np.float32,
    "budget": np.float32,
    "teacher_nodes": np.int32,
}


# -- data ------------------------------------------------------------------------------------
def _check_dataset(ds: Mapping[str, Any], name: str = "dataset") -> dict[str, np.ndarray]:
    """Typed copy of the arrays the trainer uses; ValueError naming the problem."""
    if not isinstance(ds, Mapping):
        raise ValueError(f"{name} must be a dict of arrays, got {type(ds).__name__}")
    missing = [k for k in DATASET_KEYS if k not in ds]
    if missing:
        raise ValueError(f"{name} lacks the arrays {missing} (needs {list(DATASET_KEYS)})")
    out = {k: np.asarray(ds[k]).astype(_DTYPES[k], copy=False) for k in DATASET_KEYS}
    set_id, reward = out["set_id"], out["set_reward"]
    if set_id.ndim != 2:
        raise ValueError(f"{name}: set_id must be [D, N], got shape {set_id.shape}")
    d, n = set_id.shape
    if reward.ndim != 2 or reward.shape[0] != d:
        raise ValueError(f"{name}: set_reward must be [D, K] with D = {d}, got {reward.shape}")
    k = reward.shape[1]
    expected = {
        "coords": (d, n, 2),
        "cost": (d, n, n),
        "budget": (d,),
        "teacher_nodes": (d, plan_length(k)),
    }
    for key, shape in expected.items():
        if out[key].shape != shape:
            raise ValueError(f"{name}: {key} must have shape {shape}, got {out[key].shape}")
    if d == 0:
        raise ValueError(f"{name} is empty (D = 0)")
    if np.isnan(out["cost"]).any() or (out["cost"] < 0).any():
        raise ValueError(f"{name}: cost contains NaN or negative entries")
    if not np.isfinite(out["coords"]).all() or not np.isfinite(reward).all():
        raise ValueError(f"{name}: coords or set_reward contain NaN or inf")
    if np.isnan(out["budget"]).any() or (out["budget"] < 0).any():
        raise ValueError(f"{name}: budget contains NaN or negative entries")
    if ((set_id < -1) | (set_id >= k)).any():
        raise ValueError(f"{name}: set_id outside [-1, {k})")
    teacher = out["teacher_nodes"]
    if (teacher[:, 0] != 0).any():
        raise ValueError(f"{name}: teacher_nodes must start at node 0 (the start)")
    if ((teacher < -1) | (teacher >= n)).any():
        raise ValueError(f"{name}: teacher_nodes outside [-1, {n})")
    return out


def instances_from_dataset(ds: Mapping[str, Any]) -> SOPInstance:
    """Batched :class:`SOPInstance` (NumPy leaves, leading axis D) of a dataset dict.

    Start node 0, open paths (end = -1). Extra keys of ``ds`` are ignored.
    """
    data = _check_dataset(ds)
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
    ds = {
        "coords": np.stack([inst.coords for inst in insts]),
        "cost": np.stack([inst.cost for inst in insts]),
        "set_id": np.stack([inst.set_id for inst in insts]),
        "set_reward": np.stack([inst.set_reward for inst in insts]),
        "budget": np.stack([inst.budget for inst in insts]),
        "teacher_nodes": teacher.astype(np.int32),
        "teacher_reward": np.asarray([sol.reward for sol in solutions], np.float32),
        "teacher_cost": np.asarray([sol.cost for sol in solutions], np.float32),
    }
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
class TrainState:
    """One replica's training state (a leading replica axis when stacked)."""

    params: Any  # nnx.State of the model's nnx.Param leaves
    opt_state: Any  # clip + Adam state (moments, counts)
    step: Any  # [] int32: optimiser steps taken
    lr: Any  # [] float32: base learning rate of this replica


def make_optimizer(grad_clip: float | jax.Array) -> optax.GradientTransformation:
    """Clip by global norm, then Adam's scaling; the learning rate is applied per replica."""
    return optax.chain(optax.clip_by_global_norm(grad_clip), optax.scale_by_adam())


def lr_factor(step: Any, decay_steps: Any, lr_decay: Any) -> jax.Array:
    """Staircase step decay: ``lr_decay ** floor(step / decay_steps)`` (optimiser steps)."""
    return lr_decay ** jnp.floor(step / decay_steps)


def init_states(
    model_config: ModelConfig,
    train_config: TrainConfig,
    seeds: Sequence[int],
    lrs: Sequence[float],
) -> tuple[nnx.GraphDef, TrainState]:
    """Graph definition and stacked initial states of the replicas ``zip(seeds, lrs)``."""
    tx = make_optimizer(train_config.grad_clip)
    graphdef, states = None, []
    for seed, lr in zip(seeds, lrs, strict=True):
        model = StrategicTransformer(model_config, rngs=nnx.Rngs(params=_init_key(seed)))
        graphdef, params = nnx.split(model, nnx.Param)
        states.append(
            TrainState(
                params=params,
                opt_state=tx.init(params),
                step=jnp.int32(0),
                lr=jnp.float32(lr),
            )
        )
    stacked = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *states)
    return graphdef, _committed(stacked)


def _committed(tree: Any) -> Any:
    """Place arrays on the default device explicitly: jit caches committed and uncommitted
    inputs separately, and the epoch's outputs are committed."""
    return jax.device_put(tree, jax.devices()[0])


def _init_key(seed: int) -> jax.Array:
    return jax.random.fold_in(jax.random.key(seed), 0)


def _epoch_key(seed: int, epoch: int) -> jax.Array:
    """Shuffle key of an epoch: a function of (seed, epoch) only, so a resume is exact."""
    return jax.random.fold_in(jax.random.fold_in(jax.random.key(seed), 1), epoch)


def _batch_stats(
    graphdef: nnx.GraphDef,
    params: Any,
    batch: Mapping[str, jax.Array],
    weight=None,
    key: jax.Array | None = None,
):
    """Summed imitation stats of a minibatch; with ``key``, every instance is seen under
    a random one of the 8 coordinate symmetries (training augmentation)."""
    model = nnx.merge(graphdef, params)
    inst = _instances(batch)
    features = None
    if key is not None:
        features = node_features(inst)
        variants = symmetric_features(features).nodes  # [8, B, N, F]
        pick = jax.random.randint(key, (variants.shape[1],), 0, NUM_SYMMETRIES)
        features = features.replace(nodes=variants[pick, jnp.arange(variants.shape[1])])
    tf = teacher_forced_logits(model, inst, batch["teacher_nodes"], features)
    return imitation_stats(tf, weight)


def make_train_epoch(
    graphdef: nnx.GraphDef, config: TrainConfig, num_instances: int
) -> Callable[[TrainState, dict[str, jax.Array], jax.Array], tuple[TrainState, jax.Array]]:
    """Jitted ``train_epoch(states, data, keys) -> (states, stats)`` over stacked replicas.

    ``states``: :class:`TrainState` with a leading replica axis R; ``data``: dataset dict of
    device arrays (shared by the replicas); ``keys``: [R] shuffle keys. ``stats`` [R, 3]:
    summed NLL, correct arg-max steps, valid steps over the epoch. The program is compiled
    once per (model graph, batch size, D, replica count): the recipe's numbers (clip, decay)
    are traced values, so runs that differ only in them, or in epochs, share it.
    """
    batch_size = min(config.batch_size, num_instances)
    steps = num_instances // batch_size
    recipe = jnp.asarray(
        [config.grad_clip, config.lr_decay, steps * config.decay_period], jnp.float32
    )
    return functools.partial(
        _train_epoch,
        recipe=recipe,
        graphdef=graphdef,
        batch_size=batch_size,
        num_instances=num_instances,
        augment=config.augment,
    )


@functools.partial(jax.jit, static_argnames=("graphdef", "batch_size", "num_instances", "augment"))
def _train_epoch(
    states, data, keys, recipe, *, graphdef, batch_size: int, num_instances: int, augment: bool
):
    num_batches = num_instances // batch_size
    grad_clip, lr_decay, decay_steps = recipe[0], recipe[1], recipe[2]
    tx = make_optimizer(grad_clip)

    def loss(params, batch, key):
        stats = _batch_stats(graphdef, params, batch, key=key if augment else None)
        return stats[0] / jnp.maximum(stats[2], 1.0), stats

    def epoch(state: TrainState, key: jax.Array):
        shuffle, sym = jax.random.split(key)
        order = jax.random.permutation(shuffle, num_instances)[: num_batches * batch_size]
        sym_keys = jax.random.split(sym, num_batches)

        def minibatch(state: TrainState, xs):
            idx, sym_key = xs
            batch = jax.tree_util.tree_map(lambda x: x[idx], data)
            grads, stats = jax.grad(loss, has_aux=True)(state.params, batch, sym_key)
            updates, opt_state = tx.update(grads, state.opt_state, state.params)
            lr = state.lr * lr_factor(state.step, decay_steps, lr_decay)
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


@functools.partial(jax.jit, static_argnames=("graphdef", "batch_size", "num_instances"))
def _evaluate(params, data, *, graphdef, batch_size: int, num_instances: int):
    batch_size = min(batch_size, num_instances)
    num_batches = math.ceil(num_instances / batch_size)
    slots = np.arange(num_batches * batch_size)
    index = jnp.asarray((slots % num_instances).reshape(num_batches, batch_size), jnp.int32)
    weight = jnp.asarray((slots < num_instances).reshape(num_batches, batch_size), jnp.float32)

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
    return _committed({k: jnp.asarray(v) for k, v in _check_dataset(ds).items()})


# -- the run --------------------------------------------------------------------------------
class TrainingTerminated(Exception):
    """Raised in the training loop when the process receives SIGTERM."""


@dataclasses.dataclass
class TrainResult:
    """What :func:`train` returns."""

    model: StrategicTransformer  # the chosen replica (the current best if incomplete)
    best_replica: int  # index into ``replicas``
    replicas: list[dict[str, Any]]  # [{"seed": s, "lr": lr}] in replica order
    states: TrainState  # final states of every replica (leading replica axis)
    epochs_done: int
    complete: bool  # all configured epochs done (the model was saved to run_dir/model)
    history: list[dict[str, Any]]  # the metrics rows
    run_dir: Path


def _stats_row(stats: np.ndarray) -> tuple[float, float]:
    steps = max(float(stats[2]), 1.0)
    return float(stats[0]) / steps, float(stats[1]) / steps


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
) -> TrainResult:
    """Train every (seed, lr) pair as one vmapped program; checkpoint after every epoch.

    Args:
        config: model, recipe and preset name.
        train_ds, val_ds: dataset dicts (``val_ds`` may be None: the training loss then
            picks the best replica).
        out_dir: run directory (see :mod:`bfsop_jax.training.checkpoint` for its layout).
        seeds, lrs: the replicas are their Cartesian product (seed-major).
        resume: continue from the last checkpoint in ``out_dir`` (same config required).
            Without it, a directory that already holds checkpoints is refused.
        progress: show a tqdm bar over epochs.
        max_epochs_this_call: stop (checkpointed) after this many epochs of this call.
        on_epoch: called with the metric rows after each epoch, before its checkpoint.
        dataset_meta: extra JSON-able description of the data, stored in ``config.json``.

    Returns:
        A :class:`TrainResult`. On KeyboardInterrupt or SIGTERM the last completed epoch is
        checkpointed, then the exception propagates (resume with ``resume=True``).
    """
    if not isinstance(config, RunConfig):
        raise ValueError(f"config must be a RunConfig, got {type(config).__name__}")
    if not seeds or not lrs:
        raise ValueError("train needs at least one seed and one learning rate")
    if any(not (isinstance(lr, int | float) and lr > 0) for lr in lrs):
        raise ValueError(f"learning rates must be positive numbers, got {list(lrs)}")
    if max_epochs_this_call is not None and max_epochs_this_call < 1:
        raise ValueError(f"max_epochs_this_call must be >= 1, got {max_epochs_this_call}")
    train_data = _device_data(train_ds)
    val_data = _device_data(val_ds) if val_ds is not None else None
    info = {"train": dataset_info(train_ds)}
    if val_ds is not None:
        info["val"] = dataset_info(val_ds)
        for key in ("num_nodes", "num_sets"):
            if info["val"][key] != info["train"][key]:
                raise ValueError(f"train and val datasets differ in {key}")
    replicas = [{"seed": int(s), "lr": float(lr)} for s, lr in itertools.product(seeds, lrs)]
    run_config = {
        "run": config.to_dict(),
        "replicas": replicas,
        "dataset": {
            "num_nodes": info["train"]["num_nodes"],
            "num_sets": info["train"]["num_sets"],
            **info,
            "meta": dataset_meta or {},
        },
    }
    run_dir = Path(out_dir)
    _prepare_run_dir(run_dir, run_config, resume)

    tcfg = config.train
    graphdef, states = init_states(
        config.model, tcfg, [r["seed"] for r in replicas], [r["lr"] for r in replicas]
    )
    num_train = info["train"]["instances"]
    train_epoch = make_train_epoch(graphdef, tcfg, num_train)
    evaluate = (
        make_evaluate(graphdef, tcfg.batch_size, info["val"]["instances"]) if val_data else None
    )
    steps = num_train // min(tcfg.batch_size, num_train)  # optimiser steps per epoch
    decay_steps, decay = steps * tcfg.decay_period, tcfg.lr_decay

    store = ckpt.CheckpointStore(run_dir, max_to_keep=tcfg.keep_checkpoints)
    start = 0
    if resume and store.latest_epoch() is not None:
        states, meta = store.restore(states)
        states = _committed(states)
        start = int(meta["epoch"])
    log = MetricsLog(run_dir, keep_until_epoch=start)
    last_losses = _last_losses(log.rows, len(replicas), start)
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
            keys = jnp.stack([_epoch_key(r["seed"], epoch) for r in replicas])
            new_states, train_stats = train_epoch(states, train_data, keys)
            train_stats = np.asarray(train_stats)
            val_stats = np.asarray(evaluate(new_states.params, val_data)) if evaluate else None
            seconds = time.perf_counter() - t0
            states, done = new_states, epoch
            rows = []
            for i, rep in enumerate(replicas):
                train_loss, train_acc = _stats_row(train_stats[i])
                val_loss, val_acc = (
                    _stats_row(val_stats[i]) if val_stats is not None else (None, None)
                )
                rows.append(
                    {
                        "epoch": epoch,
                        "replica": i,
                        "seed": rep["seed"],
                        "base_lr": rep["lr"],
                        "lr": rep["lr"] * float(lr_factor(epoch * steps - 1, decay_steps, decay)),
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

    best = int(np.nanargmin(last_losses)) if last_losses else 0
    params = jax.tree_util.tree_map(lambda x: x[best], states.params)
    complete = done >= tcfg.epochs
    if complete:
        ckpt.save_model(run_dir, params)
        summary = dict(run_config)
        summary["result"] = {
            "best_replica": best,
            **replicas[best],
            "selection_loss": last_losses[best] if last_losses else None,
            "epochs": done,
        }
        ckpt.write_config(run_dir, summary)
    return TrainResult(
        model=nnx.merge(graphdef, params),
        best_replica=best,
        replicas=replicas,
        states=states,
        epochs_done=done,
        complete=complete,
        history=list(log.rows),
        run_dir=run_dir,
    )


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
