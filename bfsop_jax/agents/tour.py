"""Explore-or-tour strategies: the machinery BFS-Global, TFL-Reactive and BF-SOP share.

A switching strategy explores with :class:`~bfsop_jax.agents.fbe.FBE` and keeps the
*pending* landmarks of interest (detected, reward > 0 under the co-occurrence prior, not
yet visited). Each macro step its *switch rule* (what tells the three apart) may decide
to exploit: the SOP instance is posed on the online map
(:func:`bfsop_jax.sop.builder.build_instance`, the agent's observation only), its
*planner* returns a tour of viewpoints, and the tour is executed to its end, truncated by
the budget gate; a viewpoint that turns out unreachable, or stays blocked for
``max_attempts`` macro steps, is skipped. Visited landmarks are retired; then the agent
explores again. No mode flip mid-tour.

Common rules: a strategy with nothing left to explore exploits whatever is pending, and a
chosen landmark without a single reachable viewpoint is retired at once (so no rule can
ask for it forever). The instance and planner run under
:func:`~bfsop_jax.agents.sparse.sparse_cond`, so a vmapped batch of episodes pays for
them only on steps where some episode switches.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from bfsop_jax.agents.fbe import FBE, FBEMemory
from bfsop_jax.agents.rollout import Decision
from bfsop_jax.agents.sparse import sparse_cond
from bfsop_jax.config import Preset
from bfsop_jax.env.types import Action, Observation, StepInfo
from bfsop_jax.sop.builder import build_instance
from bfsop_jax.sop.types import Solution, SOPInstance, plan_length

__all__ = ["SwitchMemory", "TourMemory", "TourStrategy", "landmark_rewards", "pending_landmarks"]


@struct.dataclass
class TourMemory:
    """The tour being executed. T = ``preset.n_loi`` slots, M = object slots."""

    touring: jax.Array  # bool []
    goal: jax.Array  # float32 [T, 2]: viewpoints in visiting order (metres)
    look: jax.Array  # float32 [T, 2]: the landmark centre each viewpoint faces
    landmark: jax.Array  # int32 [T]: object slot of each viewpoint's landmark
    length: jax.Array  # int32 []: viewpoints in the tour
    position: jax.Array  # int32 []: next viewpoint
    attempts: jax.Array  # int32 []: blocked macro steps on the current viewpoint
    retired: jax.Array  # bool [M]: landmarks visited or given up


@struct.dataclass
class SwitchMemory:
    """A switching strategy's memory: its tour, its explorer's and its switch rule's."""

    tour: TourMemory
    explore: FBEMemory
    rule: Any  # the switch rule's own state (a pytree; () when it keeps none)
    switches: jax.Array  # int32 []: tours started so far
    finished: jax.Array  # bool []: nothing was left to do (no frontier, no tour): stay idle


def landmark_rewards(obs: Observation) -> jax.Array:
    """float32 [M]: P(target | landmark type) of each detected object (0 if undetected)."""
    cat = obs.object_category
    return jnp.where(cat >= 0, obs.prior[jnp.maximum(cat, 0), obs.category], 0.0)


def pending_landmarks(obs: Observation, retired: jax.Array) -> jax.Array:
    """bool [M]: detected landmarks of interest with a positive reward, not yet retired."""
    return obs.landmark & ~retired & (landmark_rewards(obs) > 0)


def _empty_plan(preset: Preset) -> tuple[SOPInstance, Solution, jax.Array]:
    n, k = preset.n_sop_nodes, preset.n_loi + 1
    inst = SOPInstance(
        cost=jnp.zeros((n, n), jnp.float32),
        set_id=jnp.full((n,), -1, jnp.int32),
        set_reward=jnp.zeros((k,), jnp.float32),
        start=jnp.zeros((), jnp.int32),
        end=jnp.full((), -1, jnp.int32),
        budget=jnp.zeros((), jnp.float32),
        coords=jnp.zeros((n, 2), jnp.float32),
    )
    plan = Solution(
        nodes=jnp.full((plan_length(k),), -1, jnp.int32),
        reward=jnp.zeros((), jnp.float32),
        cost=jnp.zeros((), jnp.float32),
    )
    return inst, plan, jnp.full((preset.n_loi,), -1, jnp.int32)


class TourStrategy:
    """Mixin: ``init`` / ``act`` / ``update`` of an explore-or-tour strategy.

    A subclass (a frozen dataclass with fields ``config`` (holding ``max_attempts``),
    ``explorer`` and ``record``) supplies the switch rule and the planner:

    * ``rule_init(obs, preset) -> rule``
    * ``wants_tour(rule, obs, pending, has_frontier, touring, preset) -> (bool [], rule)``
    * ``rule_update(rule, before, after, info, exploring) -> rule``
    * ``plan(mask, instance) -> Solution``
    """

    config: Any
    explorer: FBE
    record: bool

    @property
    def max_attempts(self) -> int:
        """Blocked macro steps before a tour viewpoint is skipped."""
        return self.config.max_attempts

    @property
    def replans(self) -> bool:
        """Whether ``wants_tour`` may replace a tour being executed (default: no; a tour
        runs to its end). A replacement plan starts from the agent's position over what
        is still pending, the rest of the old tour included."""
        return bool(getattr(self.config, "replan", False))

    # -- hooks (overridden) ------------------------------------------------------------
    def rule_init(self, obs: Observation, preset: Preset) -> Any:
        return ()

    def wants_tour(
        self, rule: Any, obs: Observation, pending: jax.Array, has_frontier: jax.Array,
        touring: jax.Array, preset: Preset,
    ) -> tuple[jax.Array, Any]:  # fmt: skip
        raise NotImplementedError

    def rule_update(
        self, rule: Any, before: Observation, after: Observation, info: StepInfo,
        exploring: jax.Array,
    ) -> Any:  # fmt: skip
        return rule

    def plan(self, mask: jax.Array, instance: SOPInstance) -> Solution:
        raise NotImplementedError

    def tour_budget(self, obs: Observation) -> jax.Array:
        """Metres a tour may use (the SOP budget): by default all that remains."""
        return obs.remaining

    # -- the strategy ------------------------------------------------------------------
    def init(self, obs: Observation, preset: Preset) -> SwitchMemory:
        t, m = preset.n_loi, obs.found.shape[-1]
        tour = TourMemory(
            touring=jnp.zeros((), bool),
            goal=jnp.zeros((t, 2), jnp.float32),
            look=jnp.zeros((t, 2), jnp.float32),
            landmark=jnp.full((t,), -1, jnp.int32),
            length=jnp.zeros((), jnp.int32),
            position=jnp.zeros((), jnp.int32),
            attempts=jnp.zeros((), jnp.int32),
            retired=jnp.zeros((m,), bool),
        )
        return SwitchMemory(
            tour=tour,
            explore=self.explorer.init(obs, preset),
            rule=self.rule_init(obs, preset),
            switches=jnp.zeros((), jnp.int32),
            finished=jnp.zeros((), bool),
        )

    def act(
        self, memory: SwitchMemory, obs: Observation, preset: Preset
    ) -> tuple[Action, Decision, SwitchMemory]:
        tour = memory.tour
        explore_action, has_frontier, explore_memory = self.explorer.explore(
            memory.explore, obs, preset
        )
        pending = pending_landmarks(obs, tour.retired)
        want, rule = self.wants_tour(
            memory.rule, obs, pending, has_frontier, tour.touring, preset
        )
        can = ~obs.done & ~memory.finished & jnp.any(pending)
        switch = can & ~tour.touring & (want | ~has_frontier)
        if self.replans:
            switch = switch | (can & tour.touring & want)

        def posed(mask, obs, pending):
            inst, choice = build_instance(
                obs.belief, obs.pose[:2], self.tour_budget(obs), pending, obs.object_category,
                obs.object_xy, obs.object_half_extent, obs.prior, obs.category, preset,
            )  # fmt: skip
            return inst, self.plan(mask, inst), choice.index

        inst, plan, loi_index = sparse_cond(
            switch, posed, lambda obs, pending: _empty_plan(preset), obs, pending
        )

        # Tour slots from the plan: the start node first, then viewpoints.
        nodes = plan.nodes[1 : preset.n_loi + 1]
        is_vp = nodes > 0
        sets = inst.set_id[jnp.maximum(nodes, 0)]
        landmark = jnp.where(is_vp, loi_index[jnp.maximum(sets - 1, 0)], -1)
        goal = inst.coords[jnp.maximum(nodes, 0)]
        look = obs.object_xy[jnp.maximum(landmark, 0)]
        length = is_vp.sum().astype(jnp.int32)
        started = switch & (length > 0)
        # A chosen landmark with no reachable viewpoint cannot be toured: retire it.
        hopeless = switch & (loi_index >= 0) & (inst.set_reward[1:] <= 0)
        retired = tour.retired.at[jnp.maximum(loi_index, 0)].max(hopeless)
        tour = tour.replace(
            touring=tour.touring | started,
            goal=jnp.where(started, goal, tour.goal),
            look=jnp.where(started, look, tour.look),
            landmark=jnp.where(started, landmark, tour.landmark),
            length=jnp.where(started, length, tour.length),
            position=jnp.where(started, 0, tour.position),
            attempts=jnp.where(started, 0, tour.attempts),
            retired=retired,
        )
        explore_memory = jax.tree_util.tree_map(
            lambda a, b: jnp.where(memory.tour.touring, a, b), memory.explore, explore_memory
        )
        has_goal = tour.touring | has_frontier
        memory = memory.replace(
            tour=tour,
            explore=explore_memory,
            rule=rule,
            switches=memory.switches + started.astype(jnp.int32),
            finished=memory.finished | ~has_goal,
        )
        pos = jnp.minimum(tour.position, preset.n_loi - 1)
        tour_action = Action(
            goal_xy=tour.goal[pos], look_xy=tour.look[pos], look=jnp.ones((), bool)
        )
        action = jax.tree_util.tree_map(
            lambda a, b: jnp.where(tour.touring, a, b), tour_action, explore_action
        )
        decision = Decision(
            has_goal=has_goal,
            touring=tour.touring,
            switched=started,
            planned=switch,
            record=(inst, plan) if self.record else None,
        )
        return action, decision, memory

    def update(
        self, memory: SwitchMemory, before: Observation, after: Observation, info: StepInfo
    ) -> SwitchMemory:
        tour = memory.tour
        pos = jnp.minimum(tour.position, tour.landmark.shape[0] - 1)
        attempts = tour.attempts + info.blocked.astype(jnp.int32)
        done_vp = tour.touring & (info.arrived | info.unreachable | (attempts >= self.max_attempts))
        lm = tour.landmark[pos]
        retired = tour.retired.at[jnp.maximum(lm, 0)].max(done_vp & (lm >= 0))
        position = tour.position + done_vp.astype(jnp.int32)
        exploring = ~tour.touring
        explore = self.explorer.update(memory.explore, before, after, info)
        return memory.replace(
            tour=tour.replace(
                touring=tour.touring & (position < tour.length),
                position=position,
                attempts=jnp.where(done_vp, 0, attempts),
                retired=retired,
            ),
            explore=jax.tree_util.tree_map(
                lambda a, b: jnp.where(exploring, a, b), explore, memory.explore
            ),
            rule=self.rule_update(memory.rule, before, after, info, exploring),
        )
