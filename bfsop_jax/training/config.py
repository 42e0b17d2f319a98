"""Configurations of the Strategic Transformer and of behaviour-cloning training.

Both are frozen, hashable dataclasses: a :class:`ModelConfig` fixes every parameter shape,
so it is static under ``jax.jit``; a :class:`TrainConfig` fixes the optimiser recipe and
the minibatch size. Values that are swept inside one compiled program (seeds, learning
rates) are arguments of :func:`bfsop_jax.training.bc.train`, not fields here.

Presets: ``"paper"`` holds the paper's values (d = 128, 6 layers, 8 heads, feed-forward
512; Adam 1e-4, clip 1.0, step decay, 100 epochs); ``"demo"`` is a smaller model and a
shorter schedule that trains in minutes on a 2-core CPU; ``"tiny"`` is for unit tests.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from bfsop_jax.model.transformer import ModelConfig, config_from_dict

__all__ = [
    "ModelConfig",
    "TrainConfig",
    "get_model_config",
    "get_train_config",
    "MODEL_PRESETS",
    "RunConfig",
    "TRAIN_PRESETS",
]


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Behaviour-cloning recipe (SPEC 9.3)."""

    epochs: int = 100  # paper value
    batch_size: int = 64  # instances per minibatch (static; each gives up to K steps)
    grad_clip: float = 1.0  # global-norm clipping threshold
    lr_decay: float = 0.5  # step decay factor ...
    decay_every: int | None = None  # ... every this many epochs (None: a third of the run)
    keep_checkpoints: int = 3  # epoch checkpoints kept on disk
    augment: bool = False  # show each instance under a random coordinate symmetry

    def __post_init__(self) -> None:
        if not isinstance(self.epochs, int) or self.epochs < 1:
            raise ValueError(f"TrainConfig.epochs must be a positive int, got {self.epochs!r}")
        if not isinstance(self.batch_size, int) or self.batch_size < 1:
            raise ValueError(
                f"TrainConfig.batch_size must be a positive int, got {self.batch_size!r}"
            )
        if not self.grad_clip > 0:
            raise ValueError(f"TrainConfig.grad_clip must be positive, got {self.grad_clip}")
        if not 0 < self.lr_decay <= 1:
            raise ValueError(f"TrainConfig.lr_decay must be in (0, 1], got {self.lr_decay}")
        if self.decay_every is not None and self.decay_every < 1:
            raise ValueError(f"TrainConfig.decay_every must be >= 1, got {self.decay_every}")
        if self.keep_checkpoints < 1:
            raise ValueError(
                f"TrainConfig.keep_checkpoints must be >= 1, got {self.keep_checkpoints}"
            )

    @property
    def decay_period(self) -> int:
        """Epochs between two learning-rate halvings (a third of the run by default)."""
        if self.decay_every is not None:
            return self.decay_every
        return max(1, math.ceil(self.epochs / 3))

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainConfig:
        return config_from_dict(cls, data)


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """What a training run needs besides its data: model, recipe and the preset's name.

    ``preset`` names the world preset the data came from (informational, written to
    ``config.json``). Learning rates and seeds are arguments of ``train`` (they are
    vmapped within one program).
    """

    model: ModelConfig = ModelConfig()
    train: TrainConfig = TrainConfig()
    preset: str = "demo"

    def to_dict(self) -> dict[str, Any]:
        return {"model": self.model.to_dict(), "train": self.train.to_dict(), "preset": self.preset}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RunConfig:
        unknown = set(data) - {"model", "train", "preset"}
        if unknown:
            raise ValueError(f"unknown RunConfig keys: {sorted(unknown)}")
        return cls(
            model=ModelConfig.from_dict(data.get("model", {})),
            train=TrainConfig.from_dict(data.get("train", {})),
            preset=str(data.get("preset", "demo")),
        )

    @classmethod
    def named(cls, name: str, preset: str | None = None) -> RunConfig:
        """Model and training preset ``name`` ("paper", "demo", "tiny")."""
        return cls(
            model=get_model_config(name), train=get_train_config(name), preset=preset or name
        )


MODEL_PRESETS: dict[str, ModelConfig] = {
    "paper": ModelConfig(),
    # ~8x fewer FLOPs than the paper model: demo training takes minutes on 2 CPU cores
    "demo": ModelConfig(d_model=64, n_layers=3, n_heads=4, d_ff=256),
    "tiny": ModelConfig(d_model=32, n_layers=2, n_heads=2, d_ff=64),
}

TRAIN_PRESETS: dict[str, TrainConfig] = {
    "paper": TrainConfig(),
    "demo": TrainConfig(epochs=30),
    "tiny": TrainConfig(epochs=6, batch_size=16),
}


def get_model_config(name: str | ModelConfig) -> ModelConfig:
    """Model preset ``"paper"``, ``"demo"`` or ``"tiny"`` (a ModelConfig passes through)."""
    if isinstance(name, ModelConfig):
        return name
    try:
        return MODEL_PRESETS[name]
    except (KeyError, TypeError):
        raise ValueError(
            f"unknown model preset {name!r}; valid: {', '.join(MODEL_PRESETS)}"
        ) from None


def get_train_config(name: str | TrainConfig) -> TrainConfig:
    """Training preset ``"paper"``, ``"demo"`` or ``"tiny"`` (a TrainConfig passes through)."""
    if isinstance(name, TrainConfig):
        return name
    try:
        return TRAIN_PRESETS[name]
    except (KeyError, TypeError):
        raise ValueError(
            f"unknown training preset {name!r}; valid: {', '.join(TRAIN_PRESETS)}"
        ) from None
