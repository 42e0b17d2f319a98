"""Tour planners for the switching strategies: ``plan(mask, instance) -> Solution``.

A planner turns one SOP instance (posed on the agent's online map by
:func:`bfsop_jax.sop.builder.build_instance`) into a tour: node ids in visiting order,
start first, -1 padded. ``mask`` (bool []) says whether the row really asked for a plan;
it matters only to host-side planners under ``jax.vmap``
(:func:`bfsop_jax.agents.sparse.sparse_cond` passes the batch's mask), which then skip
the rows that did not. All planners are frozen dataclasses (hashable, static under
``jit``).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from bfsop_jax.policy import check_decoding
from bfsop_jax.sop.callback import vns_masked_callback
from bfsop_jax.sop.types import Solution, SOPInstance, plan_length
from bfsop_jax.sop.vns import REFERENCE, VNSConfig

__all__ = ["NearestNeighbourPlanner", "TransformerPlanner", "VNSPlanner", "nearest_neighbour_plan"]


def nearest_neighbour_plan(instance: SOPInstance, max_sets: int = 0) -> Solution:
    """Visit rewarding sets in nearest-neighbour order (geodesic costs), ignoring the budget.

    From the start, repeatedly go to the nearest node (by ``instance.cost`` from the last
    node) of a rewarding set not visited yet, up to ``max_sets`` sets (0: all of them).
    The reactive baselines plan this way; their tours are cut by the budget gate during
    execution. One instance (``set_id`` [N]); vmappable.
    """
    k = instance.set_reward.shape[-1]
    length = plan_length(k)
    steps = (k - 1) if max_sets <= 0 else min(max_sets, k - 1)
    sets = jnp.maximum(instance.set_id, 0)
    eligible = (instance.set_id >= 1) & (instance.set_reward[sets] > 0)

    def body(carry, _):
        last, visited = carry
        open_ = eligible & ~visited[sets] & jnp.isfinite(instance.cost[last])
        d = jnp.where(open_, instance.cost[last], jnp.inf)
        nxt = jnp.argmin(d).astype(jnp.int32)
        go = open_[nxt]
        visited = visited.at[sets[nxt]].set(visited[sets[nxt]] | go)
        return (jnp.where(go, nxt, last), visited), (jnp.where(go, nxt, -1), d[nxt])

    init = (instance.start.astype(jnp.int32), jnp.zeros(k, bool))
    _, (picked, legs) = jax.lax.scan(body, init, None, length=steps)
    go = picked >= 0
    # Chosen nodes are contiguous from the front: once nothing is left, nothing follows.
    nodes = jnp.full((length,), -1, jnp.int32).at[0].set(instance.start)
    nodes = nodes.at[1 : 1 + steps].set(picked)
    reward = jnp.sum(jnp.where(go, instance.set_reward[sets[jnp.maximum(picked, 0)]], 0.0))
    cost = jnp.sum(jnp.where(go, legs, 0.0))
    return Solution(nodes=nodes, reward=reward.astype(jnp.float32), cost=cost.astype(jnp.float32))


@dataclasses.dataclass(frozen=True)
class NearestNeighbourPlanner:
    """:func:`nearest_neighbour_plan` as a planner (``max_sets`` 0 = every pending set)."""

    max_sets: int = 0
    name: str = "nearest_neighbour"

    def __call__(self, mask: jax.Array, instance: SOPInstance) -> Solution:
        return nearest_neighbour_plan(instance, self.max_sets)


@dataclasses.dataclass(frozen=True)
class VNSPlanner:
    """The VNS teacher through the masked host callback (solves only rows that ask).

    ``config`` holds the VNS options (:class:`~bfsop_jax.sop.vns.VNSConfig`, default the
    reference configuration). The old keywords ``max_iters`` / ``max_no_improve`` are still
    accepted (None: keep ``config``'s value); they are folded into ``config`` on
    construction, so ``VNSPlanner(0, max_iters=100)`` equals
    ``VNSPlanner(0, config=VNSConfig(max_iters=100))`` (same hash, same ``jit`` cache).
    """

    seed: int = 0
    config: VNSConfig = REFERENCE
    name: str = "vns"
    max_iters: dataclasses.InitVar[int | None] = None  # old keyword: overrides config
    max_no_improve: dataclasses.InitVar[int | None] = None  # old keyword: overrides config

    def __post_init__(self, max_iters: int | None, max_no_improve: int | None) -> None:
        overrides = {"max_iters": max_iters, "max_no_improve": max_no_improve}
        overrides = {k: v for k, v in overrides.items() if v is not None}
        object.__setattr__(self, "config", VNSConfig.resolve(self.config, **overrides))

    def __call__(self, mask: jax.Array, instance: SOPInstance) -> Solution:
        return vns_masked_callback(instance, mask, self.seed, config=self.config)


@dataclasses.dataclass(frozen=True, eq=False)
class TransformerPlanner:
    """The Strategic Transformer (greedy decoding, bounded 2-opt, budget gate) in JAX.

    ``policy`` is a :class:`bfsop_jax.policy.StrategicPolicy`; under ``jax.vmap`` the
    whole batch is planned in one forward pass. Hashed by identity (the policy's weights).
    The options are those of :meth:`~bfsop_jax.policy.StrategicPolicy.plan`.
    """

    policy: Any
    two_opt: bool = True
    augment: bool = False
    best_of: int = 1
    fill: bool = False
    multi_start: bool | int = False
    name: str = "transformer"

    def __post_init__(self) -> None:
        check_decoding(self.best_of, self.multi_start)

    def __call__(self, mask: jax.Array, instance: SOPInstance) -> Solution:
        return self.policy.plan_traced(
            instance, two_opt=self.two_opt, augment=self.augment, best_of=self.best_of,
            fill=self.fill, multi_start=self.multi_start,
        )  # fmt: skip
