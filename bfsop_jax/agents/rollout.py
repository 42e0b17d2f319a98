"""Run a strategy for a fixed number of macro steps with ``lax.scan``."""

from __future__ import annotations

import math
from typing import Any, Protocol

import jax
import jax.numpy as jnp
from flax import struct

from bfsop_jax.config import Preset
from bfsop_jax.env.env import step
from bfsop_jax.env.types import Action, EnvState, StepInfo

__all__ = ["Strategy", "Trajectory", "continue_rollout", "max_macro_steps", "rollout"]


class Strategy(Protocol):
    """A navigation strategy: pure functions over its own memory pytree.

    Implementations are hashable (frozen dataclasses), so a jitted rollout takes them as
    static arguments; their tunable numbers are fields of their config.
    """

    def init(self, state: EnvState, preset: Preset) -> Any: ...

    def act(self, memory: Any, state: EnvState, preset: Preset) -> tuple[Action, jax.Array, Any]:
        """``(action, has_goal, memory)``; no goal means the strategy has nothing left to do."""
        ...

    def update(self, memory: Any, before: EnvState, after: EnvState, info: StepInfo) -> Any: ...


@struct.dataclass
class Trajectory:
    """Per-macro-step record of an episode. T = number of macro steps, K = micro steps."""

    poses: jax.Array  # float32 [T, K, 3]: pose after every motion step
    moved: jax.Array  # bool [T, K]
    path_length: jax.Array  # float32 [T]: L after the step
    found_count: jax.Array  # int32 [T]: |F_t| after the step
    active: jax.Array  # bool [T]: the strategy had a goal and the episode was running


def max_macro_steps(budget_m: float, preset: Preset, slack: float = 3.0) -> int:
    """A static number of macro steps that lets an episode of ``budget_m`` metres finish.

    A macro step that runs its course moves ``micro_steps`` cells (at least
    ``micro_steps * plan_cell_size`` metres); ``slack`` covers the shorter ones (arrivals,
    looks, refused moves).
    """
    return math.ceil(slack * budget_m / (preset.micro_steps * preset.plan_cell_size))


def rollout(
    state: EnvState, strategy: Strategy, preset: Preset, n_steps: int
) -> tuple[EnvState, Trajectory]:
    """Apply ``strategy`` for ``n_steps`` macro steps (static), stopping once it has no goal.

    Pure and vmappable over ``state``; a finished episode just repeats its last state.
    """
    state, _, traj = continue_rollout(
        state, strategy.init(state, preset), strategy, preset, n_steps
    )
    return state, traj


def continue_rollout(
    state: EnvState, memory: Any, strategy: Strategy, preset: Preset, n_steps: int
) -> tuple[EnvState, Any, Trajectory]:
    """:func:`rollout` from a given strategy memory, returning it too (to run in chunks)."""

    def body(carry, _):
        state, memory = carry
        action, has_goal, memory = strategy.act(memory, state, preset)
        active = has_goal & ~state.done
        new_state, info = step(state, action, preset)
        new_memory = strategy.update(memory, state, new_state, info)
        keep = lambda a, b: jnp.where(active, a, b)
        state = jax.tree_util.tree_map(keep, new_state, state)
        memory = jax.tree_util.tree_map(keep, new_memory, memory)
        record = Trajectory(
            poses=info.poses,
            moved=info.moved & active,
            path_length=state.path_length,
            found_count=state.found.sum().astype(jnp.int32),
            active=active,
        )
        return (state, memory), record

    (state, memory), traj = jax.lax.scan(body, (state, memory), None, length=n_steps)
    return state, memory, traj
