"""The navigation environment: ``reset`` and ``step`` are pure and vmappable."""

from bfsop_jax.env.env import make_action, observe, reset, sample_start_pose, sense, step
from bfsop_jax.env.types import Action, EnvState, Observation, StepInfo

__all__ = [
    "Action",
    "EnvState",
    "Observation",
    "StepInfo",
    "make_action",
    "observe",
    "reset",
    "sample_start_pose",
    "sense",
    "step",
]
