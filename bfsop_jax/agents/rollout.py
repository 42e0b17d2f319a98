"""One ``lax.scan`` rollout for every strategy, and the records it returns.

A strategy is a frozen dataclass (its tunable numbers are fields of its config) with
three pure functions over its own memory pytree:

* ``init(obs, preset) -> memory``
* ``act(memory, obs, preset) -> (action, decision, memory)``
* ``update(memory, before, after, info) -> memory`` (``before``/``after``: observations)

It sees only :class:`~bfsop_jax.env.types.Observation` (built by
:func:`bfsop_jax.env.observe`), never the true house. :func:`rollout` runs any strategy
and returns the same :class:`Trajectory` record for all of them.
"""

from __future__ import annotations

import math
from typing import Any, Protocol

import jax
import jax.numpy as jnp
from flax import struct

from bfsop_jax.config import Preset
from bfsop_jax.env.env import observe, step
from bfsop_jax.env.types import Action, EnvState, Observation, StepInfo

__all__ = [
    "Decision",
    "Strategy",
    "Trajectory",
    "continue_rollout",
    "explore_decision",
    "max_macro_steps",
    "rollout",
]


@struct.dataclass
class Decision:
    """What a strategy decided this macro step (besides the action itself)."""

    has_goal: jax.Array  # bool []: false = nothing left to do (the episode ends)
    touring: jax.Array  # bool []: the step executes a landmark tour (else: exploring)
    switched: jax.Array  # bool []: a tour started this step (explore -> exploit)
    planned: jax.Array  # bool []: a planner was called this step
    record: Any = None  # strategy-specific pytree (e.g. the SOP posed at a planner call)


def explore_decision(has_goal: jax.Array) -> Decision:
    """The decision of a pure explorer: never tours, never plans."""
    no = jnp.zeros((), bool)
    return Decision(has_goal=jnp.asarray(has_goal, bool), touring=no, switched=no, planned=no)


class Strategy(Protocol):
    """A navigation strategy: pure functions over its own memory pytree.

    Implementations are hashable (frozen dataclasses), so a jitted rollout takes them as
    static arguments; their tunable numbers are fields of their config.
    """

    def init(self, obs: Observation, preset: Preset) -> Any: ...

    def act(self, memory: Any, obs: Observation, preset: Preset) -> tuple[Action, Decision, Any]:
        """``(action, decision, memory)``; ``decision.has_goal`` false ends the episode."""
        ...

    def update(self, memory: Any, before: Observation, after: Observation, info: StepInfo) -> Any:
        """Fold the outcome of the step into the memory."""
        ...


@struct.dataclass
class Trajectory:
    """Per-macro-step record of an episode. T = macro steps, K = motion steps per macro step."""

    poses: jax.Array  # float32 [T, K, 3]: pose after every motion step
    moved: jax.Array  # bool [T, K]: the motion step moved the agent
    micro_length: jax.Array  # float32 [T, K]: L after every motion step
    micro_found: jax.Array  # int32 [T, K]: |F_t| after every motion step
    path_length: jax.Array  # float32 [T]: L after the macro step
    found_count: jax.Array  # int32 [T]: |F_t| after the macro step (its final look included)
    active: jax.Array  # bool [T]: the strategy had a goal and the episode was running
    touring: jax.Array  # bool [T]: the step executed a tour (mode: exploit), else explore
    switched: jax.Array  # bool [T]: a tour started at this step
    planned: jax.Array  # bool [T]: a planner was called at this step
    record: Any = None  # the strategy's per-step records, stacked over T


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
    memory = strategy.init(observe(state), preset)
    state, _, traj = continue_rollout(state, memory, strategy, preset, n_steps)
    return state, traj


def continue_rollout(
    state: EnvState, memory: Any, strategy: Strategy, preset: Preset, n_steps: int
) -> tuple[EnvState, Any, Trajectory]:
    """:func:`rollout` from a given strategy memory, returning it too (to run in chunks)."""

    def body(carry, _):
        state, memory = carry
        obs = observe(state)
        action, decision, memory = strategy.act(memory, obs, preset)
        active = decision.has_goal & ~state.done
        new_state, info = step(state, action, preset)
        new_memory = strategy.update(memory, obs, observe(new_state), info)
        keep = lambda a, b: jnp.where(active, a, b)
        state = jax.tree_util.tree_map(keep, new_state, state)
        memory = jax.tree_util.tree_map(keep, new_memory, memory)
        record = Trajectory(
            poses=info.poses,
            moved=info.moved & active,
            micro_length=jnp.where(active, info.path_lengths, state.path_length),
            micro_found=jnp.where(active, info.found_counts, state.found.sum()).astype(jnp.int32),
            path_length=state.path_length,
            found_count=state.found.sum().astype(jnp.int32),
            active=active,
            touring=decision.touring & active,
            switched=decision.switched & active,
            planned=decision.planned,
            record=decision.record,
        )
        return (state, memory), record

    (state, memory), traj = jax.lax.scan(body, (state, memory), None, length=n_steps)
    return state, memory, traj
