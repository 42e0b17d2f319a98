"""TFL-Reactive: explore, and detour to a landmark as soon as one is close (ping-pong).

While exploring, switch to the nearest pending landmark of interest (geodesic, via its
nearest viewpoint) whenever one lies within ``radius_m`` of the agent (straight-line
distance to its centre), or when ``timer_m`` metres have been explored since the last
visit while landmarks were pending; visit that one landmark, then explore again.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from bfsop_jax.agents.fbe import FBE
from bfsop_jax.agents.planners import nearest_neighbour_plan
from bfsop_jax.agents.tour import TourStrategy, pending_within
from bfsop_jax.config import Preset
from bfsop_jax.env.types import Observation, StepInfo
from bfsop_jax.sop.types import Solution, SOPInstance

__all__ = ["TFLReactive", "TFLReactiveConfig"]


@dataclasses.dataclass(frozen=True)
class TFLReactiveConfig:
    """Tunable numbers of TFL-Reactive."""

    radius_m: float = 4.0  # trigger radius around the agent (metres, straight line)
    timer_m: float = 40.0  # metres explored with landmarks pending before a forced visit
    max_attempts: int = 3  # blocked macro steps before a tour viewpoint is skipped
    # the tour ends, its landmark left pending, once the walk to a viewpoint exceeds this
    # many times the planned leg plus 1 m (walls seen on the way); 0: never
    walk_limit: float = 0.0
    # True: a landmark stays pending until every coverage point of its footprint has been
    # seen (or a visit sees nothing new), each visit completing what it can; False (the
    # default, chosen on validation houses): retired at its first visit
    cover: bool = False
    # with cover: after a visit that leaves the landmark seen in part, go straight on to
    # the nearest viewpoint that sees more of it (False: leave it pending for later tours)
    complete: bool = True


@dataclasses.dataclass(frozen=True)
class TFLReactive(TourStrategy):
    """TFL-Reactive as a strategy (``init`` / ``act`` / ``update``)."""

    config: TFLReactiveConfig = TFLReactiveConfig()
    explorer: FBE = FBE()
    record: bool = False

    def rule_init(self, obs: Observation, preset: Preset) -> tuple[jax.Array, jax.Array]:
        # (metres explored with landmarks pending since the last visit, pending now)
        return jnp.zeros((), jnp.float32), jnp.zeros((), bool)

    def wants_tour(self, rule, obs, pending, reward, has_frontier, touring, preset):
        near = pending_within(obs, pending, self.config.radius_m)
        metres, _ = rule
        timer = metres >= np.float32(self.config.timer_m)
        return near | timer, (metres, jnp.any(pending))

    def rule_update(self, rule, before, after, info: StepInfo, exploring):
        metres, pending = rule
        metres = jnp.where(exploring, metres + jnp.where(pending, info.travelled, 0.0), 0.0)
        return metres, pending

    def plan(self, mask: jax.Array, instance: SOPInstance) -> Solution:
        return nearest_neighbour_plan(instance, max_sets=1)
