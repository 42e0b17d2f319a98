"""Agent strategies and episode rollouts."""

from bfsop_jax.agents.fbe import FBE, FBEConfig, FBEMemory
from bfsop_jax.agents.rollout import (
    Strategy,
    Trajectory,
    continue_rollout,
    max_macro_steps,
    rollout,
)

__all__ = [
    "FBE",
    "FBEConfig",
    "FBEMemory",
    "Strategy",
    "Trajectory",
    "continue_rollout",
    "max_macro_steps",
    "rollout",
]
