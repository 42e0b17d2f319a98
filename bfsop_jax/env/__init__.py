"""The navigation environment: ``reset`` and ``step`` are pure and vmappable."""

from bfsop_jax.env.env import make_action, reset, sample_start_pose, sense, step
from bfsop_jax.env.types import Action, EnvState, StepInfo

__all__ = [
    "Action",
    "EnvState",
    "StepInfo",
    "make_action",
    "reset",
    "sample_start_pose",
    "sense",
    "step",
]
