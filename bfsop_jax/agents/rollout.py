"""Run a policy for a fixed number of macro steps with ``lax.scan``."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from flax import struct

from bfsop_jax.config import Preset
from bfsop_jax.env.env import step
from bfsop_jax.env.types import Action, EnvState


@struct.dataclass
class Trajectory:
    """Per-macro-step record of an episode. T = number of macro steps, K = micro steps."""

    poses: jax.Array  # float32 [T, K, 3]: pose after every motion step
    moved: jax.Array  # bool [T, K]
    path_length: jax.Array  # float32 [T]: L after the step
    found_count: jax.Array  # int32 [T]: |F_t| after the step
    active: jax.Array  # bool [T]: the policy had a goal and the episode was running


Policy = Callable[[EnvState, Preset], tuple[Action, jax.Array]]


def rollout(
    state: EnvState, policy: Policy, preset: Preset, n_steps: int
) -> tuple[EnvState, Trajectory]:
    """Apply ``policy`` for ``n_steps`` macro steps (static), stopping once it has no goal.

    Pure and vmappable over ``state``; a finished episode just repeats its last state.
    """

    def body(state, _):
        action, has_goal = policy(state, preset)
        active = has_goal & ~state.done
        new_state, info = step(state, action, preset)
        state = jax.tree_util.tree_map(lambda a, b: jnp.where(active, a, b), new_state, state)
        record = Trajectory(
            poses=info.poses,
            moved=info.moved & active,
            path_length=state.path_length,
            found_count=state.found.sum().astype(jnp.int32),
            active=active,
        )
        return state, record

    return jax.lax.scan(body, state, None, length=n_steps)
