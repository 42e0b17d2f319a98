"""Configurations of the Strategic Transformer and of behaviour-cloning training.

Both are frozen, hashable dataclasses: a :class:`ModelConfig` fixes every parameter shape,
so it is static under ``jax.jit``; a :class:`TrainConfig` fixes the run length, the
minibatch size and the default optimiser recipe. A :class:`Replica` is one member of a
vmapped training program: its seed and every number of the recipe that changes no array
shape (learning rate, clip, decay, warm-up, label smoothing, augmentation) can differ from
the other replicas' and is a traced value, so replicas that differ only in them share one
compiled program (:func:`bfsop_jax.training.bc.train`).

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
    "Replica",
    "RunConfig",
    "TRAIN_PRESETS",
]


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Behaviour-cloning recipe (docs/design.md §8.3)."""

    epochs: int = 100  # paper value
    batch_size: int = 64  # instances per minibatch (static; each gives up to K steps)
    grad_clip: float = 1.0  # global-norm clipping threshold
    lr_decay: float = 0.5  # step decay factor ...
    decay_every: int | None = None  # ... every this many epochs (None: a third of the run)
    keep_checkpoints: int = 3  # epoch checkpoints kept on disk
    augment: bool = False  # show each instance under a random coordinate symmetry
    warmup_epochs: float = 0.0  # linear learning-rate warm-up over this many epochs
    label_smoothing: float = 0.0  # weight of the uniform target over the allowed entries
    # insertion decoder: weight of the loss on the student's own states (its greedy and
    # sampled plans of each minibatch, labelled by the teacher's nodes still allowed)
    on_policy: float = 0.0

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
        if self.warmup_epochs < 0:
            raise ValueError(f"TrainConfig.warmup_epochs must be >= 0, got {self.warmup_epochs}")
        if not 0 <= self.label_smoothing < 1:
            raise ValueError(
                f"TrainConfig.label_smoothing must be in [0, 1), got {self.label_smoothing}"
            )
        if not self.on_policy >= 0:
            raise ValueError(f"TrainConfig.on_policy must be >= 0, got {self.on_policy}")
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
class Replica:
    """One member of a vmapped training program: a seed and its recipe numbers.

    Every field is a per-replica value of the compiled program (no field changes a shape),
    so a program trains any list of replicas side by side. ``decay_every`` and
    ``warmup_epochs`` are in epochs; the learning rate at optimiser step ``t`` (``S`` steps
    per epoch) is ``lr * min(1, (t + 1) / (warmup_epochs * S)) * lr_decay **
    floor(t / (decay_every * S))``.
    """

    seed: int = 0
    lr: float = 1e-4
    grad_clip: float = 1.0
    lr_decay: float = 0.5
    decay_every: int = 1
    warmup_epochs: float = 0.0
    label_smoothing: float = 0.0
    augment: bool = False
    on_policy: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.seed, int) or isinstance(self.seed, bool):
            raise ValueError(f"Replica.seed must be an int, got {self.seed!r}")
        if not self.lr > 0:
            raise ValueError(f"Replica.lr must be positive, got {self.lr}")
        # the remaining numbers obey the recipe's rules
        TrainConfig(
            grad_clip=self.grad_clip,
            lr_decay=self.lr_decay,
            decay_every=self.decay_every,
            warmup_epochs=self.warmup_epochs,
            label_smoothing=self.label_smoothing,
            on_policy=self.on_policy,
        )

    @classmethod
    def of(cls, recipe: TrainConfig, seed: int = 0, lr: float = 1e-4, **overrides) -> Replica:
        """The replica ``(seed, lr)`` with the recipe's other numbers (and ``overrides``)."""
        values = {
            "grad_clip": recipe.grad_clip,
            "lr_decay": recipe.lr_decay,
            "decay_every": recipe.decay_period,
            "warmup_epochs": recipe.warmup_epochs,
            "label_smoothing": recipe.label_smoothing,
            "augment": recipe.augment,
            "on_policy": recipe.on_policy,
        }
        unknown = set(overrides) - set(values)
        if unknown:
            raise ValueError(f"unknown replica fields {sorted(unknown)}")
        values.update(overrides)
        return cls(seed=int(seed), lr=float(lr), **values)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any], recipe: TrainConfig | None = None) -> Replica:
        """From ``to_dict``; missing fields (older run files list only seed and lr) take
        the recipe's values."""
        data = dict(data)
        return cls.of(recipe or TrainConfig(), data.pop("seed", 0), data.pop("lr", 1e-4), **data)


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
