"""A training run's directory: preparing it, resuming checks, replicas' models, epoch meta.

:func:`bfsop_jax.training.bc.train` writes ``config.json`` before its first epoch
(refusing a directory that holds another run unless it resumes the same one), each
checkpoint's meta (the selection losses and the best replica), and at the end every
replica's own run directory; :func:`latest_best_params` reads the best replica of the last
checkpoint back. The layout is :mod:`bfsop_jax.checkpoint`'s. Importable from
:mod:`bfsop_jax.training.bc` too.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import jax
import numpy as np

from bfsop_jax import checkpoint as ckpt
from bfsop_jax.model.transformer import ModelConfig
from bfsop_jax.training.config import Replica, TrainConfig
from bfsop_jax.training.program import init_states

__all__ = ["latest_best_params"]


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
