"""Explore-or-tour strategies: the machinery BFS-Global, TFL-Reactive and BF-SOP share.

A switching strategy explores with :class:`~bfsop_jax.agents.fbe.FBE` and keeps the
*pending* landmarks of interest (detected, reward > 0 under the co-occurrence prior, not
yet visited). Each macro step its *switch rule* (what tells the three apart) may decide
to exploit: the SOP instance is posed on the online map
(:func:`bfsop_jax.sop.builder.build_instance`, the agent's observation only), its
*planner* returns a tour of viewpoints, and the tour is executed to its end, truncated by
the budget gate; a viewpoint that turns out unreachable, or stays blocked for
``max_attempts`` macro steps, is skipped. The plan prices its legs on the optimistic map
of its time, so walls seen on the way may make one far longer: with ``walk_limit`` > 0 the
tour ends once the walk to a viewpoint exceeds that many times its planned leg plus 1 m,
the landmark staying pending (to be priced again on the grown map). Then the agent
explores again. No mode flip mid-tour.

Visits: by default (``config.cover = False``) a landmark is retired once a viewpoint
of it is reached. A viewpoint sees only part of a large landmark within the
verification distance, so ``config.cover = True`` keeps coverage instead: on arrival the
coverage points the agent sees (within reach and inside its view,
:func:`bfsop_jax.sop.builder.covered_from`) are marked; unless all are seen, or the
visit saw nothing new, the geodesically nearest viewpoint that sees an unseen point
becomes the next goal (:func:`bfsop_jax.sop.builder.completion_viewpoint`) before the
tour goes on. A landmark left seen in part stays pending with the posterior reward of
its unseen part (:func:`landmark_rewards`), and later instances offer only viewpoints
that see an unseen point.

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
import numpy as np
from flax import struct

from bfsop_jax.agents.fbe import FBE, FBEMemory
from bfsop_jax.agents.rollout import Decision
from bfsop_jax.agents.sparse import sparse_cond
from bfsop_jax.config import Preset
from bfsop_jax.env.types import Action, Observation, StepInfo
from bfsop_jax.sop.builder import (
    COVER_POINTS,
    build_instance,
    completion_viewpoint,
    coverage_points,
    covered_from,
    covered_reward,
)
from bfsop_jax.sop.types import Solution, SOPInstance, plan_length

__all__ = [
    "SwitchMemory",
    "TourMemory",
    "TourStrategy",
    "landmark_rewards",
    "pending_landmarks",
    "pending_within",
]


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
    covered: jax.Array  # bool [M, P]: coverage points of each landmark seen on a visit
    arrived_at: jax.Array  # int32 []: landmark whose viewpoint was just reached (-1: none)
    # a completion viewpoint of the landmark just visited, inserted before the next slot
    extra: jax.Array  # bool []: the current goal is the completion viewpoint
    extra_goal: jax.Array  # float32 [2]
    extra_look: jax.Array  # float32 [2]
    extra_landmark: jax.Array  # int32 []: its landmark
    extra_left: jax.Array  # float32 []: metres the walk to it may still take
    leg: jax.Array  # float32 [T]: planned metres to each tour viewpoint from the one before
    leg_walked: jax.Array  # float32 []: metres walked towards the current tour viewpoint


@struct.dataclass
class SwitchMemory:
    """A switching strategy's memory: its tour, its explorer's and its switch rule's."""

    tour: TourMemory
    explore: FBEMemory
    rule: Any  # the switch rule's own state (a pytree; () when it keeps none)
    switches: jax.Array  # int32 []: tours started so far
    finished: jax.Array  # bool []: nothing was left to do (no frontier, no tour): stay idle


def landmark_rewards(obs: Observation, covered: jax.Array | None = None) -> jax.Array:
    """float32 [M]: P(target | landmark type) of each detected object (0 if undetected).

    With ``covered`` (bool [M, P], coverage points seen on visits) a landmark seen in part
    is worth the posterior of its unseen part (:func:`bfsop_jax.sop.builder.covered_reward`).
    """
    cat = obs.object_category
    reward = jnp.where(cat >= 0, obs.prior[jnp.maximum(cat, 0), obs.category], 0.0)
    return reward if covered is None else covered_reward(reward, covered)


def pending_landmarks(obs: Observation, retired: jax.Array) -> jax.Array:
    """bool [M]: detected landmarks of interest with a positive reward, not yet retired."""
    return obs.landmark & ~retired & (landmark_rewards(obs) > 0)


def pending_within(obs: Observation, pending: jax.Array, radius_m: float) -> jax.Array:
    """bool []: a pending landmark's centre lies within ``radius_m`` metres of the agent.

    Straight-line distance, compared as exact integer squares of whole 1/64 m
    coordinates (so batched and single calls agree). ``pending`` bool [M].
    """
    q = jnp.round(obs.object_xy * 64.0).astype(jnp.int32)
    p = jnp.round(obs.pose[:2] * 64.0).astype(jnp.int32)
    d = q - p
    d2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]
    r = int(round(radius_m * 64.0))
    return jnp.any(pending & (d2 <= r * r))


def _empty_plan(preset: Preset) -> tuple[SOPInstance, Solution, jax.Array, jax.Array]:
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
    return inst, plan, jnp.full((preset.n_loi,), -1, jnp.int32), jnp.zeros((n, 2), jnp.float32)


def _fold_arrival(
    tour: TourMemory, obs: Observation, preset: Preset, complete: bool | jax.Array = True
) -> TourMemory:
    """Mark the coverage points seen from the viewpoint just reached (``tour.arrived_at``).

    The landmark is retired when all are seen or the visit saw nothing new; otherwise, with
    ``complete`` (bool, or a bool [] array), the nearest viewpoint that sees an unseen point
    becomes the next goal (``tour.extra``), so a large landmark is covered in one visit,
    side after side, before the tour goes on.
    """
    complete = jnp.asarray(complete, bool)
    lm = tour.arrived_at
    arrived = lm >= 0
    slot = jnp.maximum(lm, 0)
    centre, half = obs.object_xy[slot], obs.object_half_extent[slot]
    seen = covered_from(coverage_points(centre, half), obs.pose, preset) & arrived
    before = tour.covered[slot]
    after = before | seen
    done = arrived & (jnp.all(after) | ~jnp.any(seen & ~before))
    ok, goal, look, metres = sparse_cond(
        arrived & ~done & complete,
        lambda _, obs, c, h, a: completion_viewpoint(obs.belief, obs.pose[:2], c, h, a, preset),
        lambda *_: (
            jnp.zeros((), bool), jnp.zeros(2, jnp.float32), jnp.zeros(2, jnp.float32),
            jnp.zeros((), jnp.float32),
        ),
        obs, centre, half, after,
    )  # fmt: skip
    ok = ok & (metres <= np.float32(COMPLETE_MAX_M))
    extra = arrived & ~done & ok
    return tour.replace(
        covered=tour.covered.at[slot].set(jnp.where(arrived, after, before)),
        retired=tour.retired.at[slot].max(done | (arrived & ~ok & complete)),
        arrived_at=jnp.full((), -1, jnp.int32),
        touring=tour.touring | extra,
        extra=tour.extra | extra,
        extra_goal=jnp.where(extra, goal, tour.extra_goal),
        extra_look=jnp.where(extra, look, tour.extra_look),
        extra_landmark=jnp.where(extra, lm, tour.extra_landmark),
        # the walk to it may grow as the map fills in: given up past twice the estimate
        extra_left=jnp.where(extra, 2.0 * metres + 1.0, tour.extra_left),
    )


def _skip_retired(tour: TourMemory) -> TourMemory:
    """Move past the tour's slots whose landmark was retired meanwhile (a landmark with
    several slots, one per part, is retired once a visit has seen all of it)."""
    idx = jnp.arange(tour.landmark.shape[0])
    lm = tour.landmark
    live = (idx >= tour.position) & (idx < tour.length) & ~tour.retired[jnp.maximum(lm, 0)]
    nxt = jnp.where(jnp.any(live), jnp.argmax(live), tour.length).astype(jnp.int32)
    moving = tour.touring & ~tour.extra
    position = jnp.where(moving, nxt, tour.position)
    return tour.replace(
        position=position,
        attempts=jnp.where(moving & (position != tour.position), 0, tour.attempts),
        leg_walked=jnp.where(moving & (position != tour.position), 0.0, tour.leg_walked),
        touring=tour.touring & (tour.extra | (position < tour.length)),
    )


COMPLETE_MAX_M = 3.0
"""A completion viewpoint is taken only this close (metres, geodesic on the optimistic map)."""


class TourStrategy:
    """Mixin: ``init`` / ``act`` / ``update`` of an explore-or-tour strategy.

    A subclass (a frozen dataclass with fields ``config`` (holding ``max_attempts``),
    ``explorer`` and ``record``) supplies the switch rule and the planner:

    * ``rule_init(obs, preset) -> rule``
    * ``wants_tour(rule, obs, pending, reward, has_frontier, touring, preset)
      -> (bool [], rule)`` (``reward`` float32 [M]: each landmark's current reward)
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
    def walk_limit(self) -> float:
        """The tour ends (the landmark it was walking to stays pending) once the walk to a
        viewpoint exceeds this many times the planned leg, plus 1 m; 0: never."""
        return float(getattr(self.config, "walk_limit", 0.0))

    @property
    def replans(self) -> bool:
        """Whether ``wants_tour`` may replace a tour being executed (default: no; a tour
        runs to its end). A replacement plan starts from the agent's position over what
        is still pending, the rest of the old tour included."""
        return bool(getattr(self.config, "replan", False))

    @property
    def parts(self) -> bool:
        """With coverage: whether SOP sets are landmark parts rather than landmarks."""
        return bool(getattr(self.config, "parts", False))

    @property
    def completes(self) -> bool:
        """With coverage: whether a visit seen in part goes on to a completion viewpoint."""
        return bool(getattr(self.config, "complete", True))

    @property
    def completes_plentiful(self) -> bool:
        """With coverage and ``plentiful_after``: whether, once the category is plentiful, a
        visit seen in part goes on to a completion viewpoint (within ``COMPLETE_MAX_M``)
        before the landmark is retired."""
        return bool(getattr(self.config, "complete_plentiful", False))

    @property
    def plentiful_after(self) -> int:
        """With coverage: once this many targets are verified, a landmark seen in part is
        retired (each landmark is visited once again); 0: never."""
        return int(getattr(self.config, "plentiful_after", 0))

    def _plentiful(self, obs: Observation) -> jax.Array:
        """bool []: ``plentiful_after`` targets verified (never when it is 0)."""
        k = self.plentiful_after
        return (obs.found.sum() >= k) if k > 0 else jnp.zeros((), bool)

    @property
    def covers(self) -> bool:
        """Whether a landmark stays pending until its coverage points are seen, rather than
        being retired at its first visit (the default)."""
        return bool(getattr(self.config, "cover", False))

    def tour_length(self, instance: SOPInstance, nodes: jax.Array) -> jax.Array:
        """int32 []: how many viewpoints of the plan to execute (all, by default).

        ``nodes`` int32 [n_loi + 1]: the plan's start node, then viewpoints (-1 padded).
        """
        return (nodes[1:] > 0).sum().astype(jnp.int32)

    # -- hooks (overridden) ------------------------------------------------------------
    def rule_init(self, obs: Observation, preset: Preset) -> Any:
        return ()

    def wants_tour(
        self, rule: Any, obs: Observation, pending: jax.Array, reward: jax.Array,
        has_frontier: jax.Array, touring: jax.Array, preset: Preset,
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
        """Metres a tour may use while a frontier is left (the SOP budget): by default all
        that remains. With no reachable frontier a tour may always use all that remains."""
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
            covered=jnp.zeros((m, COVER_POINTS), bool),
            arrived_at=jnp.full((), -1, jnp.int32),
            extra=jnp.zeros((), bool),
            extra_goal=jnp.zeros((2,), jnp.float32),
            extra_look=jnp.zeros((2,), jnp.float32),
            extra_landmark=jnp.full((), -1, jnp.int32),
            extra_left=jnp.zeros((), jnp.float32),
            leg=jnp.zeros((t,), jnp.float32),
            leg_walked=jnp.zeros((), jnp.float32),
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
        if self.covers:
            plentiful = self._plentiful(obs)
            complete = self.completes
            if self.completes_plentiful:
                complete = complete | plentiful
            tour = _fold_arrival(tour, obs, preset, complete)
            if self.plentiful_after > 0:
                # the category is plentiful here: breadth over depth, so a landmark seen
                # (in part) on a visit is not gone back to (beyond a completion viewpoint
                # on the spot, with ``complete_plentiful``), and sets are whole landmarks
                slots = jnp.arange(tour.retired.shape[0])
                completing = tour.extra & (slots == tour.extra_landmark)
                seen = tour.covered.any(-1) & ~completing
                tour = tour.replace(retired=tour.retired | (plentiful & seen))
            tour = _skip_retired(tour)
        explore_action, has_frontier, explore_memory = self.explorer.explore(
            memory.explore, obs, preset
        )
        pending = pending_landmarks(obs, tour.retired)
        reward = jnp.where(
            pending, landmark_rewards(obs, tour.covered if self.covers else None), 0.0
        )
        want, rule = self.wants_tour(
            memory.rule, obs, pending, reward, has_frontier, tour.touring, preset
        )
        can = ~obs.done & ~memory.finished & jnp.any(pending)
        switch = can & ~tour.touring & (want | ~has_frontier)
        if self.replans:
            switch = switch | (can & tour.touring & want)

        parts = self.covers and self.parts

        def posed(mask, obs, pending, covered, budget):
            inst, choice = build_instance(
                obs.belief, obs.pose[:2], budget, pending, obs.object_category,
                obs.object_xy, obs.object_half_extent, obs.prior, obs.category, preset,
                covered if self.covers else None, parts, ~self._plentiful(obs),
            )  # fmt: skip
            part = choice.part if parts else jnp.zeros((preset.n_loi, COVER_POINTS), bool)
            return inst, self.plan(mask, inst), choice.index, choice.look, part

        def unposed(*_):
            return *_empty_plan(preset), jnp.zeros((preset.n_loi, COVER_POINTS), bool)

        # With nothing left to explore a tour may use all that remains: a horizon only
        # serves to return to exploring sooner.
        budget = jnp.where(has_frontier, self.tour_budget(obs), obs.remaining)
        inst, plan, loi_index, node_look, set_part = sparse_cond(
            switch, posed, unposed, obs, pending, tour.covered, budget
        )

        # Tour slots from the plan: the start node first, then viewpoints.
        nodes = plan.nodes[1 : preset.n_loi + 1]
        is_vp = nodes > 0
        sets = inst.set_id[jnp.maximum(nodes, 0)]
        landmark = jnp.where(is_vp, loi_index[jnp.maximum(sets - 1, 0)], -1)
        goal = inst.coords[jnp.maximum(nodes, 0)]
        prev = plan.nodes[: preset.n_loi]
        leg = jnp.where(is_vp, inst.cost[jnp.maximum(prev, 0), jnp.maximum(nodes, 0)], 0.0)
        look = node_look[jnp.maximum(nodes, 0)]
        length = self.tour_length(inst, plan.nodes[: preset.n_loi + 1])
        started = switch & (length > 0)
        # A chosen landmark with no reachable viewpoint cannot be toured: retire it (with
        # parts: give up that part's points, and retire the landmark once none is left).
        hopeless = switch & (loi_index >= 0) & (inst.set_reward[1:] <= 0)
        slot = jnp.maximum(loi_index, 0)
        if parts:
            gone = (hopeless[:, None] & set_part).astype(jnp.int32)
            covered = tour.covered.astype(jnp.int32).at[slot].max(gone).astype(bool)
            retired = tour.retired.at[slot].max(hopeless & jnp.all(covered[slot], axis=-1))
            tour = tour.replace(covered=covered)
        else:
            retired = tour.retired.at[slot].max(hopeless)
        tour = tour.replace(
            touring=tour.touring | started,
            goal=jnp.where(started, goal, tour.goal),
            look=jnp.where(started, look, tour.look),
            landmark=jnp.where(started, landmark, tour.landmark),
            length=jnp.where(started, length, tour.length),
            position=jnp.where(started, 0, tour.position),
            attempts=jnp.where(started, 0, tour.attempts),
            leg=jnp.where(started, leg, tour.leg),
            leg_walked=jnp.where(started, 0.0, tour.leg_walked),
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
            goal_xy=jnp.where(tour.extra, tour.extra_goal, tour.goal[pos]),
            look_xy=jnp.where(tour.extra, tour.extra_look, tour.look[pos]),
            look=jnp.ones((), bool),
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
        ended = info.arrived | info.unreachable | (attempts >= self.max_attempts)
        lm = tour.landmark[pos]
        slot_walk = tour.touring & ~tour.extra
        leg_walked = tour.leg_walked + jnp.where(slot_walk, info.travelled, 0.0)
        # The plan priced the walk on the map of its time (unknown cells free); walls seen
        # on the way may make it far longer. Past the limit the tour ends there and the
        # landmark stays pending, to be priced again on the grown map.
        too_far = slot_walk & np.bool_(self.walk_limit > 0) & ~ended & (
            leg_walked > np.float32(self.walk_limit) * tour.leg[pos] + np.float32(1.0)
        )
        done_vp = (slot_walk & ended) | too_far  # a tour slot
        extra_left = tour.extra_left - jnp.where(tour.extra, info.travelled, 0.0)
        done_x = tour.touring & tour.extra & (ended | (extra_left < 0))  # a completion
        # An arrival is judged by what the agent sees there, at the next act (_fold_arrival).
        judged = done_vp & (lm >= 0) & info.arrived & np.bool_(self.covers)
        retired = tour.retired.at[jnp.maximum(lm, 0)].max(
            done_vp & (lm >= 0) & ~judged & ~too_far
        )
        xlm = tour.extra_landmark  # a failed completion leaves its landmark pending
        arrived_at = jnp.where(judged, lm, tour.arrived_at)
        arrived_at = jnp.where(done_x & info.arrived, xlm, arrived_at)
        position = tour.position + done_vp.astype(jnp.int32)
        # the rest of the plan assumed that viewpoint reached: the tour ends there
        position = jnp.where(too_far, tour.length, position)
        extra = tour.extra & ~done_x
        exploring = ~tour.touring
        explore = self.explorer.update(memory.explore, before, after, info)
        return memory.replace(
            tour=tour.replace(
                touring=tour.touring & ((position < tour.length) | extra),
                position=position,
                attempts=jnp.where(done_vp | done_x, 0, attempts),
                leg_walked=jnp.where(done_vp, 0.0, leg_walked),
                retired=retired,
                arrived_at=arrived_at,
                extra=extra,
                extra_left=extra_left,
            ),
            explore=jax.tree_util.tree_map(
                lambda a, b: jnp.where(exploring, a, b), explore, memory.explore
            ),
            rule=self.rule_update(memory.rule, before, after, info, exploring),
        )
