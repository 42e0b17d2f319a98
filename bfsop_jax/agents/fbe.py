"""Frontier-based exploration (FBE): head for the nearest frontier.

The strategy sees only what the agent has sensed (the belief map and its pose). Each
macro step it picks the frontier cluster nearest by geodesic distance on the agent's
motion map (:func:`bfsop_jax.navigation.grid.motion_blocked`) and, on arrival, faces the
unknown space next to that frontier (so the frontier is resolved rather than reached
with its unknown side behind the agent's 90 degree field of view). With
``FBEConfig.gain_weight_m`` > 0 the choice weighs information gain too: distance minus
that many metres times the unknown share of the square around the frontier
(:func:`bfsop_jax.navigation.frontiers.unknown_count`; BF-SOP's exploration mode).

A goal that brings no progress (no metre travelled and no newly known cell) for
``FBEConfig.patience`` macro steps in a row is dropped: frontier cells within
``drop_radius`` planning cells of a dropped goal are ignored from then on (a small ring
buffer of the last ``max_dropped`` goals), and the agent picks the next-nearest frontier.
That rule is what guarantees an episode ends only when the budget is spent or no
reachable frontier is left; it fires on frontiers whose unknown cells no scan can
reach (a sliver behind furniture, say).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from bfsop_jax.agents.rollout import Decision, explore_decision
from bfsop_jax.config import Preset
from bfsop_jax.env.types import Action, Observation, StepInfo
from bfsop_jax.navigation.distance import distance_field
from bfsop_jax.navigation.frontiers import (
    cluster_frontier_cells,
    frontier_mask,
    nearest_frontier,
    plan_cell_states,
    unknown_count,
    unknown_side,
)
from bfsop_jax.navigation.grid import (
    motion_blocked,
    plan_cell_to_xy,
    planning_blocked,
    xy_to_plan_cell,
)

__all__ = ["FBE", "FBEConfig", "FBEMemory", "near_dropped"]


@dataclasses.dataclass(frozen=True)
class FBEConfig:
    """Tunable numbers of frontier exploration (static: hashable, sets shapes)."""

    patience: int = 2  # macro steps without progress before the goal is dropped
    drop_radius: int = 3  # planning cells (Chebyshev) around a dropped goal that are ignored
    max_dropped: int = 16  # dropped goals remembered (ring buffer)
    look_radius: int = 2  # planning cells (Chebyshev) searched for the frontier's unknown side
    # > 0: choose the frontier minimising geodesic distance minus this many metres times
    # the unknown share of the (2 gain_radius + 1)^2 planning cells around it (the unseen
    # space a look from there can resolve: a doorway into an unexplored room scores high,
    # a sliver behind furniture low); 0: the nearest frontier
    gain_weight_m: float = 0.0
    gain_radius: int = 10  # planning cells (Chebyshev): 2 m at 0.2 m cells


@struct.dataclass
class FBEMemory:
    """FBE's state between macro steps. G = ``FBEConfig.max_dropped``."""

    goal: jax.Array  # int32 [2]: planning cell of the current goal (-1, -1: none)
    stalled: jax.Array  # int32 []: consecutive macro steps without progress on it
    dropped: jax.Array  # int32 [G, 2]: planning cells of dropped goals
    dropped_valid: jax.Array  # bool [G]
    n_dropped: jax.Array  # int32 []: goals dropped so far (ring position = n % G)


@dataclasses.dataclass(frozen=True)
class FBE:
    """Frontier-based exploration as a strategy: ``init`` / ``act`` / ``update``."""

    config: FBEConfig = FBEConfig()

    def init(self, obs: Observation, preset: Preset) -> FBEMemory:
        g = self.config.max_dropped
        return FBEMemory(
            goal=jnp.full((2,), -1, jnp.int32),
            stalled=jnp.zeros((), jnp.int32),
            dropped=jnp.zeros((g, 2), jnp.int32),
            dropped_valid=jnp.zeros((g,), bool),
            n_dropped=jnp.zeros((), jnp.int32),
        )

    def act(
        self, memory: FBEMemory, obs: Observation, preset: Preset
    ) -> tuple[Action, Decision, FBEMemory]:
        """The nearest frontier not dropped, as an action facing its unknown side.

        Returns ``(action, decision, memory)``; ``decision.has_goal`` is false when no
        frontier is reachable, in which case the action keeps the agent where it is.
        """
        action, has_goal, memory = self.explore(memory, obs, preset)
        return action, explore_decision(has_goal), memory

    def explore(
        self, memory: FBEMemory, obs: Observation, preset: Preset
    ) -> tuple[Action, jax.Array, FBEMemory]:
        """:meth:`act` with a bare ``has_goal`` (bool []), for strategies built on FBE."""
        cfg = self.config
        # One planning map and one pass over the planning-cell states serve the motion
        # map, the frontier cells and the look direction.
        blocked = planning_blocked(obs.belief, preset)
        free, unknown = plan_cell_states(obs.belief, preset)
        motion = motion_blocked(obs.belief, obs.pose[:2], preset, blocked)
        field = distance_field(motion, obs.pose[:2], preset)
        cells = frontier_mask(free, unknown, blocked) & ~near_dropped(memory, cfg, preset)
        frontiers = cluster_frontier_cells(cells, preset)
        bonus = None
        if cfg.gain_weight_m > 0:
            count = unknown_count(unknown, xy_to_plan_cell(frontiers.xy, preset), cfg.gain_radius)
            area = (2 * cfg.gain_radius + 1) ** 2
            bonus = count.astype(jnp.float32) * np.float32(cfg.gain_weight_m / area)
        index, _ = nearest_frontier(frontiers, field, preset, bonus)
        has_goal = index >= 0
        goal_xy = jnp.where(has_goal, frontiers.xy[jnp.maximum(index, 0)], obs.pose[:2])
        goal = xy_to_plan_cell(goal_xy, preset)
        side = unknown_side(unknown, goal, cfg.look_radius)
        look = has_goal & jnp.any(side != 0)
        action = Action(goal_xy=goal_xy, look_xy=plan_cell_to_xy(goal + side, preset), look=look)
        same = jnp.all(goal == memory.goal)
        goal = jnp.where(has_goal, goal, -1)
        memory = memory.replace(goal=goal, stalled=jnp.where(same, memory.stalled, 0))
        return action, has_goal, memory

    def update(
        self, memory: FBEMemory, before: Observation, after: Observation, info: StepInfo
    ) -> FBEMemory:
        """Count macro steps without progress; drop the goal after ``patience`` of them."""
        cfg = self.config
        progress = (info.travelled > 0.0) | (info.newly_known > 0)
        stalled = jnp.where(progress, 0, memory.stalled + 1)
        drop = (stalled >= cfg.patience) & (memory.goal[0] >= 0)
        slot = memory.n_dropped % cfg.max_dropped
        return memory.replace(
            stalled=jnp.where(drop, 0, stalled),
            dropped=jnp.where(drop, memory.dropped.at[slot].set(memory.goal), memory.dropped),
            dropped_valid=memory.dropped_valid | (drop & (jnp.arange(cfg.max_dropped) == slot)),
            n_dropped=memory.n_dropped + drop.astype(jnp.int32),
        )


def near_dropped(memory: FBEMemory, cfg: FBEConfig, preset: Preset) -> jax.Array:
    """[Hp, Wp] bool: planning cells within ``drop_radius`` of a dropped goal."""
    hp, wp = preset.plan_shape
    r = cfg.drop_radius
    rows = jnp.abs(jnp.arange(hp)[None, :] - memory.dropped[:, :1]) <= r  # [G, Hp]
    cols = jnp.abs(jnp.arange(wp)[None, :] - memory.dropped[:, 1:]) <= r  # [G, Wp]
    rows = rows & memory.dropped_valid[:, None]
    return jnp.any(rows[:, :, None] & cols[:, None, :], axis=0)
