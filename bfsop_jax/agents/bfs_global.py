"""BFS-Global: explore first, exploit late, blind to scene structure.

Explore (FBE) until a fixed fraction of the budget is spent; from then on, whenever
landmarks of interest are pending, visit them all in nearest-neighbour order (geodesic,
on the online map), then go back to exploring. With nothing left to explore it exploits
earlier (the common rule of :mod:`bfsop_jax.agents.tour`).
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from bfsop_jax.agents.fbe import FBE
from bfsop_jax.agents.planners import nearest_neighbour_plan
from bfsop_jax.agents.tour import TourStrategy
from bfsop_jax.sop.types import Solution, SOPInstance

__all__ = ["BFSGlobal", "BFSGlobalConfig"]


@dataclasses.dataclass(frozen=True)
class BFSGlobalConfig:
    """Tunable numbers of BFS-Global."""

    fraction: float = 0.1  # share of B explored before any tour (validation scan: 0.1)
    max_attempts: int = 3  # blocked macro steps before a tour viewpoint is skipped
    # True: a landmark stays pending until every coverage point of its footprint has been
    # seen (or a visit sees nothing new), each visit completing what it can; False (the
    # default, chosen on validation houses): retired at its first visit
    cover: bool = False
    # with cover: after a visit that leaves the landmark seen in part, go straight on to
    # the nearest viewpoint that sees more of it (False: leave it pending for later tours)
    complete: bool = True


@dataclasses.dataclass(frozen=True)
class BFSGlobal(TourStrategy):
    """BFS-Global as a strategy (``init`` / ``act`` / ``update``)."""

    config: BFSGlobalConfig = BFSGlobalConfig()
    explorer: FBE = FBE()
    record: bool = False

    def wants_tour(self, rule, obs, pending, reward, has_frontier, touring, preset):
        late = obs.path_length >= np.float32(self.config.fraction) * obs.budget
        return late, rule

    def plan(self, mask: jax.Array, instance: SOPInstance) -> Solution:
        return nearest_neighbour_plan(instance)

