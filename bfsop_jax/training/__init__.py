"""Behaviour-cloning training of the Strategic Transformer: configs, the vmapped training
program, Orbax checkpoints and the epoch log (docs/design.md §8.3)."""

from bfsop_jax.checkpoint import CheckpointStore, export_policy
from bfsop_jax.training.bc import (
    TrainResult,
    TrainState,
    dataset_from_instances,
    dataset_info,
    evaluate_imitation,
    instances_from_dataset,
    train,
)
from bfsop_jax.training.config import (
    ModelConfig,
    Replica,
    RunConfig,
    TrainConfig,
    get_model_config,
    get_train_config,
)

__all__ = [
    "CheckpointStore",
    "ModelConfig",
    "Replica",
    "RunConfig",
    "TrainConfig",
    "TrainResult",
    "TrainState",
    "dataset_from_instances",
    "dataset_info",
    "evaluate_imitation",
    "export_policy",
    "get_model_config",
    "get_train_config",
    "instances_from_dataset",
    "train",
]
