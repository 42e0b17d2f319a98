"""State, action and step-report pytrees of the navigation environment.

Shapes: H, W = ``preset.grid_shape``; M = ``preset.max_objects``; K = ``preset.micro_steps``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from bfsop_jax.world.types import House


@struct.dataclass
class EnvState:
    """Everything an episode carries between steps (pure data, vmappable)."""

    house: House  # the true world (never shown to planners)
    category: jax.Array  # int32 []: target category of the episode
    prior: jax.Array  # float32 [N_CATEGORIES, N_TARGETS]: co-occurrence prior P(c | landmark)
    belief: jax.Array  # float32 [H, W]: occupancy log-odds, 0 = unknown
    pose: jax.Array  # float32 [3]: x, y (metres), heading (radians)
    path_length: jax.Array  # float32 []: L, metres travelled so far
    budget: jax.Array  # float32 []: B, metres
    found: jax.Array  # bool [M]: verified instances of the target (F_t)
    landmarks_seen: jax.Array  # bool [M]: landmarks of interest detected so far
    receptacles_seen: jax.Array  # bool [M]: receptacles detected so far, whatever the category
    steps: jax.Array  # int32 []: env.step calls so far
    done: jax.Array  # bool []: the budget gate has closed


@struct.dataclass
class Observation:
    """What the agent knows: its map, pose, budget and the objects it has detected.

    Built by :func:`bfsop_jax.env.observe` from the state; strategies and planners see
    only this, never the true house. Object slots the agent has not detected hold
    category -1 and zero geometry, so nothing about an unseen object leaks through.
    """

    belief: jax.Array  # float32 [H, W]: occupancy log-odds, 0 = unknown
    pose: jax.Array  # float32 [3]: x, y (metres), heading (radians)
    path_length: jax.Array  # float32 []: L, metres travelled so far
    budget: jax.Array  # float32 []: B, metres
    category: jax.Array  # int32 []: target category of the episode
    prior: jax.Array  # float32 [N_CATEGORIES, N_TARGETS]: co-occurrence prior (training houses)
    object_seen: jax.Array  # bool [M]: detected (segmented) at least once
    object_category: jax.Array  # int32 [M]: observed category, -1 = not detected
    object_xy: jax.Array  # float32 [M, 2]: observed centre in metres (0 = not detected)
    object_half_extent: jax.Array  # float32 [M, 2]: observed footprint half sizes (metres)
    landmark: jax.Array  # bool [M]: detected landmark of interest for the category
    found: jax.Array  # bool [M]: verified target instances (F_t)
    done: jax.Array  # bool []: the budget gate has closed

    @property
    def remaining(self) -> jax.Array:
        """float32 []: B - L in metres (never negative)."""
        return jnp.maximum(self.budget - self.path_length, 0.0)


@struct.dataclass
class Action:
    """A macro action: follow the optimistic-map path to ``goal_xy``.

    On arrival the agent turns to face ``look_xy`` and senses once more when ``look`` is
    true (viewpoint visits face their landmark).
    """

    goal_xy: jax.Array  # float32 [2], metres
    look_xy: jax.Array  # float32 [2], metres
    look: jax.Array  # bool []


@struct.dataclass
class StepInfo:
    """What happened during one ``step`` (K motion steps)."""

    poses: jax.Array  # float32 [K, 3]: pose after each motion step (repeats when idle)
    moved: jax.Array  # bool [K]: the motion step moved the agent
    travelled: jax.Array  # float32 []: metres travelled during this step (sum of the moves)
    arrived: jax.Array  # bool []: the goal's planning cell was reached
    blocked: jax.Array  # bool []: traversability gate fired (next position not traversable)
    unreachable: jax.Array  # bool []: the goal is unreachable on the optimistic map
    new_found: jax.Array  # int32 []: targets verified during this step
    path_lengths: jax.Array  # float32 [K]: L after each motion step
    found_counts: jax.Array  # int32 [K]: |F_t| after each motion step (before the final look)
    newly_known: jax.Array  # int32 []: belief cells that became known (free or occupied)
