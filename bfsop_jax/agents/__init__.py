"""Agent strategies (SPEC 7) and episode rollouts."""

from bfsop_jax.agents.fbe import fbe_action
from bfsop_jax.agents.rollout import Trajectory, rollout

__all__ = ["Trajectory", "fbe_action", "rollout"]
