"""Frontier-based exploration (FBE, SPEC 7.1): always head for the nearest frontier."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from bfsop_jax.config import Preset
from bfsop_jax.env.env import make_action
from bfsop_jax.env.types import Action, EnvState
from bfsop_jax.navigation.distance import distance_field
from bfsop_jax.navigation.frontiers import frontier_clusters, nearest_frontier
from bfsop_jax.navigation.grid import planning_blocked


def fbe_action(state: EnvState, preset: Preset) -> tuple[Action, jax.Array]:
    """The nearest frontier (by geodesic distance on the optimistic map) as the goal.

    Returns ``(action, has_goal)``; ``has_goal`` is false when no frontier is reachable,
    in which case the action keeps the agent where it is.
    """
    field = distance_field(planning_blocked(state.belief, preset), state.pose[:2], preset)
    frontiers = frontier_clusters(state.belief, preset)
    index, _ = nearest_frontier(frontiers, field, preset)
    has_goal = index >= 0
    goal = jnp.where(has_goal, frontiers.xy[jnp.maximum(index, 0)], state.pose[:2])
    return make_action(goal), has_goal
