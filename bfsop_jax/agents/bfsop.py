"""BF-SOP: frontier exploration plus SOP-planned landmark tours.

The heuristic strategy switcher keeps the pending landmarks of interest (detected, not
yet visited; the top ``preset.n_loi`` by reward enter an instance). While exploring, it
estimates an exploitation plan cheaply (:func:`greedy_estimate`: greedy SOP insertion
over the landmark centres with straight-line costs times a detour factor; the same for
every planner) and, whenever the pending set has changed since its last look, switches
to exploitation when

* the plan's reward per metre beats ``yield_weight`` times the recent exploration yield
  (landmark reward discovered per metre explored, an exponential moving average; the
  default weight 0, chosen on validation houses, makes any rewarding plan worth it), or
* the remaining budget is close to the plan's cost, or
* no frontier is reachable, or
* the landmark cap ``preset.n_loi`` is full.

A tour may use at most ``tour_horizon_m`` metres (the SOP budget, 6 m by default) while a
frontier is left, and all that remains once none is (nothing to return to). On
switching, the SOP instance is built on the online map and the *planner* (the VNS
teacher through its host callback, or the Strategic Transformer) computes the tour,
executed as :mod:`bfsop_jax.agents.tour` describes: by default only its prefix with the
best reward per metre (``best_rate_prefix``), with landmark coverage (``cover``) and the
thirds of long landmarks as SOP sets (``parts``) until ``plentiful_after`` (2) targets
are verified, then one visit per whole landmark, a visit that sees it in part going on at
once to a viewpoint within 3 m that sees more (``complete_plentiful``); a tour ends once
the walk to a viewpoint outgrows twice its planned leg plus 1 m (``walk_limit``: the plan
priced it on the optimistic map, and a wall seen on the way can make it much longer).

Exact arithmetic: the estimate's distances come from whole 1/64 m coordinates and the
yield from whole 2^-16 reward units with an explicit rounding per operation, so the
switch decisions do not depend on how XLA fuses the (batched or single) program.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from bfsop_jax.agents.fbe import FBE, FBEConfig
from bfsop_jax.agents.planners import VNSPlanner
from bfsop_jax.agents.tour import TourStrategy, landmark_rewards, pending_within
from bfsop_jax.config import Preset
from bfsop_jax.env.types import Observation, StepInfo
from bfsop_jax.sop.types import Solution, SOPInstance

__all__ = [
    "BFSOP",
    "EXPLORER",
    "BFSOPConfig",
    "SwitchRule",
    "best_rate_prefix",
    "greedy_estimate",
]

_XY_UNITS = 64.0  # estimate coordinates in whole 1/64 m
_REWARD_UNITS = 65536.0  # yield bookkeeping in whole 2^-16 reward units


# BF-SOP's exploration mode: the frontier with the least geodesic distance minus 8 m times
# the unknown share of the 4 m square around it (chosen on validation houses,
# docs/results.md), so the agent heads into unexplored rooms rather than clearing slivers
# near it; the baselines explore nearest-frontier first.
EXPLORER = FBEConfig(gain_weight_m=8.0)


@dataclasses.dataclass(frozen=True)
class BFSOPConfig:
    """Tunable numbers of the strategy switcher.

    The defaults were chosen on validation houses (docs/results.md): a 6 m horizon with
    the best-rate prefix, landmark coverage with part sets, until two targets are found,
    and tours that end when a leg outgrows twice its plan.
    """

    detour: float = 1.3  # geodesic / straight-line ratio assumed by the cheap estimate
    yield_decay: float = 0.9  # per macro step of exploration (about 20 m of memory)
    yield_floor_m: float = 10.0  # the yield's denominator is at least this many metres
    yield_weight: float = 0.0  # exploit when plan reward/metre > this x exploration yield
    budget_margin: float = 1.2  # exploit when the remaining budget is within this factor
    max_attempts: int = 3  # blocked macro steps before a tour viewpoint is skipped
    # the tour ends, its landmark left pending, once the walk to a viewpoint exceeds this
    # many times the planned leg plus 1 m (walls seen on the way); 0: never
    walk_limit: float = 2.0
    # a tour may use at most this many metres (the SOP budget; inf = all that remains)
    # while a frontier is left (with none left it may use all that remains):
    # shorter tours return to exploring sooner and are re-planned on a larger map; a
    # landmark beyond it waits until the agent passes nearer (docs/navigation.md)
    tour_horizon_m: float = 6.0
    # re-plan a tour being executed when a new landmark of interest is detected on the way
    # (the plan covers it and the rest of the old tour); False: tours run to their end
    replan: bool = False
    # execute only the prefix of the planned tour with the best reward per metre (then
    # re-plan on the grown map): a receding horizon; False: the whole tour
    best_rate_prefix: bool = True
    # True: a landmark stays pending until every coverage point of its footprint has been
    # seen (or a visit sees nothing new), each visit completing what it can; False:
    # retired at its first visit
    cover: bool = True
    # with cover: after a visit that leaves the landmark seen in part, go straight on to
    # the nearest viewpoint that sees more of it (False: leave it pending for later tours)
    complete: bool = False
    # with cover: SOP sets are landmark parts (a long footprint's thirds), so one tour can
    # visit a large landmark from several sides (False: one set per landmark)
    parts: bool = True
    # with cover: once this many targets have been verified (the category is plentiful in
    # this house), a landmark seen in part is retired, not gone back to: many targets
    # reward visiting many landmarks once more than covering a few; 0 = never
    plentiful_after: int = 2
    # with plentiful_after: once the category is plentiful, a visit that leaves its
    # landmark seen in part goes straight on to the nearest viewpoint that sees more of it
    # (within 3 m), before the landmark is retired (it is not gone back to later, so what
    # the first viewpoint missed is cheapest to see now); False: retired at once
    complete_plentiful: bool = True
    # > 0: tour only when a pending landmark lies within this many metres of the agent
    # (straight line to its centre), after ``timer_m`` metres explored with landmarks
    # pending, or when the budget or the landmark cap presses (a reactive trigger; the SOP
    # still plans the whole tour from there); 0: whenever the pending set changes
    trigger_m: float = 0.0
    timer_m: float = 40.0  # with trigger_m: metres explored with landmarks pending
    # True: only a newly detected landmark of interest makes the switcher look again; a
    # tour's retirements and partial visits do not, so what a tour left pending (beyond
    # its horizon, or a landmark seen in part) waits for the next tour instead of
    # starting one at once. False: any change of the pending landmarks or their rewards
    new_only: bool = False


@struct.dataclass
class SwitchRule:
    """The switcher's own state. M = object slots."""

    # float32 [M]: each landmark's reward (0 = not pending) at the last evaluation; a
    # landmark seen in part is worth less after a visit, which counts as a change
    considered: jax.Array
    explore_m: jax.Array  # float32 []: decayed metres explored
    explore_reward: jax.Array  # float32 []: decayed landmark reward discovered
    pending_m: jax.Array  # float32 []: metres explored with landmarks pending since a tour
    pending: jax.Array  # bool []: landmarks were pending at the last evaluation


def greedy_estimate(
    xy: jax.Array,
    reward: jax.Array,
    valid: jax.Array,
    start: jax.Array,
    budget: jax.Array,
    detour: float = 1.3,
) -> tuple[jax.Array, jax.Array]:
    """Greedy SOP insertion on points (open path, straight lines x ``detour``).

    Args: xy [L, 2] landmark centres (metres), reward [L], valid [L] bool, start [2],
    budget [] metres. Returns ``(reward, cost)`` of the plan (cost in metres). Each round
    inserts the point with the best reward per added metre at its cheapest position,
    while the plan fits the budget.

    This is an *estimate* of a tour's value for the strategy switcher, kept apart from
    :func:`bfsop_jax.sop.insertion_fill` (which fills a plan of an SOP instance): one point
    per landmark instead of sets of viewpoints, no end node, distances from whole 1/64 m
    coordinates (exact integer squares, so a batched and a single call give the same bits)
    instead of a cost matrix, a fixed ``L`` rounds (``fori_loop``), and the ratio
    reward / max(added, 1e-3) maximised over candidates at their cheapest position, ties
    going to the lowest landmark index.
    """
    n = xy.shape[0]
    pts = jnp.concatenate([start[None], xy], axis=0)
    q = jnp.round(pts * _XY_UNITS).astype(jnp.int32)
    d = q[:, None] - q[None]
    d2 = (d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]).astype(jnp.float32)  # exact integers
    dist = jnp.sqrt(d2) * np.float32(detour / _XY_UNITS)  # [L+1, L+1]

    def body(_, carry):
        order, length, used, total_r, total_c = carry
        # order: [L+1] node ids (0 = start), first `length` entries are the route.
        pos = jnp.arange(n + 1)
        prev = order  # insertion after position p (0 .. length-1)
        nxt = jnp.roll(order, -1)
        has_next = pos < length - 1
        cand = jnp.arange(1, n + 1)
        added = (
            dist[prev[:, None], cand[None, :]]
            + jnp.where(has_next[:, None], dist[cand[None, :], nxt[:, None]], 0.0)
            - jnp.where(has_next[:, None], dist[prev, nxt][:, None], 0.0)
        )  # [L+1 positions, L candidates]
        added = jnp.where((pos < length)[:, None], added, jnp.inf)
        best_pos = jnp.argmin(added, axis=0)
        best_add = jnp.min(added, axis=0)
        ok = valid & ~used & (total_c + best_add <= budget) & (reward > 0)
        ratio = jnp.where(ok, reward / jnp.maximum(best_add, 1e-3), -jnp.inf)
        k = jnp.argmax(ratio)
        go = jnp.isfinite(ratio[k])
        p = best_pos[k]
        shifted = jnp.where(pos > p + 1, jnp.roll(order, 1), order)
        new_order = jnp.where(pos == p + 1, k + 1, shifted)
        return (
            jnp.where(go, new_order, order),
            length + go.astype(jnp.int32),
            used.at[k].set(used[k] | go),
            total_r + jnp.where(go, reward[k], 0.0),
            total_c + jnp.where(go, best_add[k], 0.0),
        )

    init = (
        jnp.zeros(n + 1, jnp.int32),
        jnp.ones((), jnp.int32),
        jnp.zeros(n, bool),
        jnp.zeros((), jnp.float32),
        jnp.zeros((), jnp.float32),
    )
    _, _, _, total_r, total_c = jax.lax.fori_loop(0, n, body, init)
    return total_r, total_c


def best_rate_prefix(instance: SOPInstance, nodes: jax.Array) -> jax.Array:
    """int32 []: the length of the plan's prefix with the most reward per metre.

    ``nodes`` int32 [T + 1]: start node, then viewpoints (-1 padded, contiguous). Each
    prefix's reward (its sets' rewards) and cost (its legs) are summed in visiting order,
    one add at a time, so batched and single calls agree bit for bit. Ties go to the
    longer prefix; 0 when the plan has no viewpoint.
    """
    sets = jnp.maximum(instance.set_id[jnp.maximum(nodes, 0)], 0)
    rate_best = jnp.full((), -1.0, jnp.float32)
    best = jnp.zeros((), jnp.int32)
    cum_r = jnp.zeros((), jnp.float32)
    cum_c = jnp.zeros((), jnp.float32)
    for i in range(1, nodes.shape[0]):
        ok = nodes[i] > 0
        leg = instance.cost[jnp.maximum(nodes[i - 1], 0), jnp.maximum(nodes[i], 0)]
        cum_r = cum_r + jnp.where(ok, instance.set_reward[sets[i]], 0.0)
        cum_c = cum_c + jnp.where(ok, leg, 0.0)
        rate = cum_r / jnp.maximum(cum_c, np.float32(1e-3))
        take = ok & (rate >= rate_best)
        rate_best = jnp.where(take, rate, rate_best)
        best = jnp.where(take, i, best)
    return best


def _decayed(decay: float, value: jax.Array, added: jax.Array) -> jax.Array:
    """``decay * value + added`` with both roundings explicit (never a fused multiply-add)."""
    return jax.lax.optimization_barrier(np.float32(decay) * value) + added


@dataclasses.dataclass(frozen=True, eq=False)
class BFSOP(TourStrategy):
    """BF-SOP with a given planner: ``VNSPlanner()`` (teacher) or ``TransformerPlanner``.

    ``record`` keeps every planner call's (instance, plan) in the trajectory (the
    on-trajectory decisions of the dataset). Hashed by identity.
    """

    planner: Any = VNSPlanner()
    config: BFSOPConfig = BFSOPConfig()
    explorer: FBE = FBE(EXPLORER)
    record: bool = False

    def plan(self, mask: jax.Array, instance: SOPInstance) -> Solution:
        return self.planner(mask, instance)

    def tour_length(self, instance: SOPInstance, nodes: jax.Array) -> jax.Array:
        if self.config.best_rate_prefix:
            return best_rate_prefix(instance, nodes)
        return super().tour_length(instance, nodes)

    def tour_budget(self, obs: Observation) -> jax.Array:
        return jnp.minimum(obs.remaining, np.float32(self.config.tour_horizon_m))

    def rule_init(self, obs: Observation, preset: Preset) -> SwitchRule:
        return SwitchRule(
            considered=jnp.zeros(obs.found.shape, jnp.float32),
            explore_m=jnp.zeros((), jnp.float32),
            explore_reward=jnp.zeros((), jnp.float32),
            pending_m=jnp.zeros((), jnp.float32),
            pending=jnp.zeros((), bool),
        )

    def wants_tour(self, rule, obs, pending, reward, has_frontier, touring, preset):
        cfg = self.config
        remaining = obs.budget - obs.path_length
        horizon = self.tour_budget(obs)
        top_r, top_i = jax.lax.top_k(reward, min(preset.n_loi, reward.shape[0]))
        est_r, est_c = greedy_estimate(
            obs.object_xy[top_i], top_r, top_r > 0, obs.pose[:2], horizon, cfg.detour
        )
        yield_rate = rule.explore_reward / jnp.maximum(rule.explore_m, cfg.yield_floor_m)
        yield_rate = np.float32(cfg.yield_weight) * yield_rate
        worth = est_r / jnp.maximum(est_c, 1e-3) > yield_rate
        presses = (remaining <= np.float32(cfg.budget_margin) * est_c) | (
            pending.sum() >= preset.n_loi
        )
        # While exploring: any change of the pending landmarks or their rewards. While
        # touring (re-planning), only a newly detected landmark: the tour's own visits
        # shrink the set as planned.
        new = jnp.any((reward > 0) & (rule.considered <= 0))
        changed = new if cfg.new_only else jnp.any(reward != rule.considered)
        changed = jnp.where(touring, new, changed)
        if cfg.trigger_m > 0:
            near = pending_within(obs, pending, cfg.trigger_m)
            timer = rule.pending_m >= np.float32(cfg.timer_m)
            fire = jnp.where(touring, changed, near | timer | (presses & changed))
        else:
            fire = (worth | presses) & changed
        want = (est_r > 0) & fire
        # An evaluation is not repeated until something changes (with nothing left to
        # explore, the tour strategy switches regardless); a tour's visits change it.
        keep = touring & ~(new & np.bool_(cfg.replan))
        considered = jnp.where(keep, rule.considered, reward)
        return want, rule.replace(considered=considered, pending=jnp.any(pending))

    def rule_update(self, rule, before, after, info: StepInfo, exploring):
        cfg = self.config
        new = after.landmark & ~before.landmark
        units = jnp.round(landmark_rewards(after) * _REWARD_UNITS).astype(jnp.int32)
        found = jnp.sum(jnp.where(new & exploring, units, 0)).astype(jnp.float32)
        pending_m = rule.pending_m + jnp.where(rule.pending, info.travelled, 0.0)
        return rule.replace(
            pending_m=jnp.where(exploring, pending_m, 0.0),
            explore_m=jnp.where(
                exploring, _decayed(cfg.yield_decay, rule.explore_m, info.travelled), rule.explore_m
            ),
            explore_reward=jnp.where(
                exploring,
                _decayed(cfg.yield_decay, rule.explore_reward, found / np.float32(_REWARD_UNITS)),
                rule.explore_reward,
            ),
        )
