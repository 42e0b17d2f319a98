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

The pieces live in their own modules, all importable from here: the datasets and their
batches in :mod:`bfsop_jax.training.dataset`, the training program (optimiser, losses,
epoch and evaluation programs) in :mod:`bfsop_jax.training.program`, the run directory's
bookkeeping in :mod:`bfsop_jax.training.run_dir`; this module runs the training loop
(:func:`train`).
"""

from __future__ import annotations

import dataclasses
import itertools
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
from flax import nnx
from jax.sharding import Mesh

from bfsop_jax import checkpoint as ckpt
from bfsop_jax.data.schema import DATASET_KEYS
from bfsop_jax.model.transformer import StrategicTransformer
from bfsop_jax.parallel import barrier, mesh_size, place, to_host
from bfsop_jax.training.config import Replica, RunConfig, TrainConfig
from bfsop_jax.training.dataset import (
    _check_dataset,
    dataset_from_instances,
    dataset_info,
    instances_from_dataset,
)
from bfsop_jax.training.dataset import padded_batches as padded_batches
from bfsop_jax.training.metrics import MetricsLog
from bfsop_jax.training.program import (
    TRACE_COUNTS,
    Hyper,
    TrainState,
    _epoch_key,
    evaluate_imitation,
    init_states,
    learning_rate,
    lr_factor,
    make_evaluate,
    make_optimizer,
    make_train_epoch,
)
from bfsop_jax.training.program import _student_forcing as _student_forcing
from bfsop_jax.training.run_dir import (
    _last_losses,
    _meta,
    _prepare_run_dir,
    _save_replica,
)
from bfsop_jax.training.run_dir import latest_best_params as latest_best_params

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
