"""The feasibility rules of the Set Orienteering Problem in JAX, in one place.

The decoder (:mod:`bfsop_jax.model.decode`) and the plan post-processing
(:mod:`bfsop_jax.sop.two_opt`) take their SOP rules from here; the NumPy reference is
:func:`bfsop_jax.sop.types.evaluate`.

* **Blocked sets**: the start node's set, and the end node's set when the instance has an
  end node (a closed tour or a fixed goal), are never rewarding choices.
* **Open nodes**: a node may still be visited when it is not padding (``set_id >= 0``) and
  its set is neither visited nor blocked.
* **Next entry** (:func:`allowed_next`): an open node reachable from the last node (finite
  cost), or END (index N), always allowed; it stops the plan.
* **Budget** (:func:`fits_budget`, on when the model's ``budget_mask`` is): a node stays
  allowed only if going there, and on to the end node, keeps the plan within the budget;
  END is then allowed only when no node is. :func:`next_mask` combines the two.
* **Start and end**: a plan starts at the start node; with an end node it ends there, in
  the first free slot (:func:`close_plan`).
* **Plan value** (:func:`plan_value`): the reward of the sets of the nodes after the start
  and the float32 sum of the edge costs along the plan.

Functions are pure and traceable. Shapes: N nodes, K sets, plans of T slots padded with -1.
:func:`blocked_sets`, :func:`open_nodes` and :func:`plan_end` take one instance or any
leading batch axes; the others take a batch (leading axis B), as the decoder does.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from bfsop_jax.sop.types import SOPInstance

__all__ = [
    "advance",
    "allowed_next",
    "blocked_sets",
    "close_plan",
    "fits_budget",
    "insertion_mask",
    "next_mask",
    "open_nodes",
    "plan_end",
    "plan_reward",
    "plan_value",
    "prefix_states",
]


def blocked_sets(instance: SOPInstance) -> jax.Array:
    """[..., K] bool: the start node's set and, with an end node, the end node's set."""
    k = instance.set_reward.shape[-1]
    sets = jnp.arange(k)
    start = jnp.asarray(instance.start)[..., None]
    end = jnp.asarray(instance.end)[..., None]
    start_set = jnp.take_along_axis(instance.set_id, start, axis=-1)
    end_set = jnp.where(
        end >= 0, jnp.take_along_axis(instance.set_id, jnp.clip(end, 0), axis=-1), -2
    )
    return (sets == start_set) | (sets == end_set)


def open_nodes(set_id: jax.Array, used_sets: jax.Array) -> jax.Array:
    """Nodes that may still be visited: not padding and their set not used.

    Args:
        set_id: [..., N] int32 set of each node (-1 padding).
        used_sets: [..., K] bool, visited (and blocked) sets; same leading axes as
            ``set_id``.

    Returns:
        [..., N] bool.
    """
    used = jnp.take_along_axis(used_sets, jnp.clip(set_id, 0), axis=-1)
    return (set_id >= 0) & ~used


def plan_end(instance: SOPInstance, virtual: int) -> jax.Array:
    """The node a plan ends at: ``instance.end``, or ``virtual`` for an open path ([...])."""
    return jnp.where(instance.end >= 0, instance.end, virtual)


def allowed_next(instance: SOPInstance, visited_sets: jax.Array, last: jax.Array) -> jax.Array:
    """Mask of the next entry for S states per instance.

    Args:
        instance: batch of B instances.
        visited_sets: [B, S, K] bool, sets already used (blocked sets included).
        last: [B, S] int32, the last node of each state.

    Returns:
        [B, S, N+1] bool: allowed nodes, and END (always True) at index N.
    """
    set_id = jnp.broadcast_to(instance.set_id[:, None], last.shape + instance.set_id.shape[-1:])
    reachable = jnp.isfinite(jnp.take_along_axis(instance.cost, last[..., None], axis=1))
    nodes = open_nodes(set_id, visited_sets) & reachable  # [B, S, N]
    return jnp.concatenate([nodes, jnp.ones(last.shape + (1,), bool)], axis=-1)


def fits_budget(
    instance: SOPInstance, allowed: jax.Array, last: jax.Array, travelled: jax.Array
) -> jax.Array:
    """The budget rule applied to a mask from :func:`allowed_next`.

    A node stays allowed only if going there (and on to the end node of a closed tour or
    goal path) keeps the plan within the budget, up to a relative 1e-5; END is allowed
    only when no node is.

    Args:
        instance: batch of B instances.
        allowed: [B, S, N+1] mask (END at index N).
        last: [B, S] int32 last node of each state.
        travelled: [B, S] float32 cost of each state's plan so far (cost units).

    Returns:
        [B, S, N+1] bool.
    """
    n = instance.set_id.shape[-1]
    step = jnp.take_along_axis(instance.cost, last[..., None], axis=1)  # [B, S, N]
    end = jnp.clip(instance.end, 0)
    to_end = jax.vmap(lambda c, e: c[:, e])(instance.cost, end)  # [B, N]: node -> end
    to_end = jnp.where(instance.end[:, None] >= 0, to_end, 0.0)
    left = instance.budget[:, None, None] - travelled[..., None]
    tol = 1e-5 * jnp.maximum(1.0, instance.budget)[:, None, None]
    nodes = allowed[..., :n] & (step + to_end[:, None, :] <= left + tol)
    end_ok = ~jnp.any(nodes, axis=-1, keepdims=True)
    return jnp.concatenate([nodes, end_ok], axis=-1)


def next_mask(
    instance: SOPInstance,
    visited_sets: jax.Array,
    last: jax.Array,
    travelled: jax.Array,
    budget_mask: bool,
) -> jax.Array:
    """The mask of the next entry: :func:`allowed_next`, then :func:`fits_budget` if asked.

    Args:
        instance: batch of B instances.
        visited_sets: [B, S, K] bool, sets already used (blocked sets included).
        last: [B, S] int32, the last node of each state.
        travelled: [B, S] float32 cost of each state's plan so far.
        budget_mask: apply the budget rule (static Python bool).

    Returns:
        [B, S, N+1] bool, END at index N.
    """
    allowed = allowed_next(instance, visited_sets, last)
    if budget_mask:
        allowed = fits_budget(instance, allowed, last, travelled)
    return allowed


def prefix_states(
    instance: SOPInstance, nodes: jax.Array
) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """The state after every prefix of padded plans (for teacher forcing).

    Step ``s`` is the plan ``nodes[:, :s+1]``.

    Args:
        instance: batch of B instances (N nodes, K sets).
        nodes: [B, T] int32 plans, start first, -1 padding.

    Returns:
        ``(last, valid, visited_sets, travelled)``: [B, S] int32 last node (clipped to 0
        where padding), [B, S] bool (the prefix ends at a real node), [B, S, K] bool sets
        used by the prefix (blocked sets included), [B, S] float32 cost of the prefix;
        S = T - 1.
    """
    k = instance.set_reward.shape[-1]
    last = nodes[:, :-1]
    nxt = nodes[:, 1:]
    valid = last >= 0
    safe_last = jnp.clip(last, 0)
    sets = jnp.take_along_axis(instance.set_id, safe_last, axis=1)  # [B, S]
    used = jax.nn.one_hot(jnp.where(valid & (sets >= 0), sets, k), k + 1, dtype=bool)[..., :k]
    visited = jnp.cumsum(used, axis=1) > 0
    visited = visited | blocked_sets(instance)[:, None]
    edge = jax.vmap(lambda c, a, b: c[a, b])(instance.cost, safe_last, jnp.clip(nxt, 0))
    edge = jnp.where(valid & (nxt >= 0), edge, 0.0)
    travelled = jnp.cumsum(edge, axis=1) - edge
    return safe_last, valid, visited, travelled


def advance(
    instance: SOPInstance,
    last: jax.Array,
    visited_sets: jax.Array,
    travelled: jax.Array,
    node: jax.Array,
    stop: jax.Array,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """One decoding step's state update: append ``node`` to every plan that has not stopped.

    Args:
        instance: batch of B instances.
        last: [B] int32 last node of each plan.
        visited_sets: [B, K] bool, sets already used.
        travelled: [B] float32 cost so far.
        node: [B] int32 node appended (-1 where ``stop``).
        stop: [B] bool, plans that end (or ended) instead.

    Returns:
        ``(last, visited_sets, travelled)`` after the step; stopped rows are unchanged.
    """
    k = instance.set_reward.shape[-1]
    rows = jnp.arange(node.shape[0])
    safe = jnp.clip(node, 0)
    node_set = instance.set_id[rows, safe]
    visited_sets = visited_sets | (jax.nn.one_hot(node_set, k, dtype=bool) & ~stop[:, None])
    travelled = travelled + jnp.where(stop, 0.0, instance.cost[rows, last, safe])
    return jnp.where(stop, last, node), visited_sets, travelled


def close_plan(instance: SOPInstance, nodes: jax.Array) -> jax.Array:
    """Put the end node (closed tour or fixed goal) in the first free slot of each plan.

    Args:
        instance: batch of B instances.
        nodes: [B, T] int32 plans, start first, -1 padding (with a free slot left).

    Returns:
        [B, T] int32; open paths are unchanged.
    """
    count = jnp.sum(nodes >= 0, axis=1)
    slot = jnp.arange(nodes.shape[1])[None] == count[:, None]
    return jnp.where(slot & (instance.end[:, None] >= 0), instance.end[:, None], nodes)


def plan_reward(instance: SOPInstance, nodes: jax.Array) -> jax.Array:
    """Reward of padded plans: the set rewards of the nodes after the start.

    Args:
        instance: one instance or a batch (leading axis B).
        nodes: [T] or [B, T] int32 plans (start first, -1 padding).

    Returns:
        [] or [B] float32 (the start and end sets are zero-reward).
    """
    valid = nodes >= 0
    sets = jnp.take_along_axis(instance.set_id, jnp.clip(nodes, 0), axis=-1)
    rewards = jnp.take_along_axis(instance.set_reward, jnp.clip(sets, 0), axis=-1)
    first = jnp.arange(nodes.shape[-1]) == 0
    reward = jnp.sum(jnp.where(valid & ~first & (sets >= 0), rewards, 0.0), axis=-1)
    return reward.astype(jnp.float32)


def plan_value(instance: SOPInstance, nodes: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Reward and cost of padded plans, exactly from the instance.

    Args:
        instance: batch of B instances.
        nodes: [B, T] int32 plans (start first, -1 padding at the end).

    Returns:
        reward [B] (:func:`plan_reward`) and cost [B] (float32 sum of the edge costs along
        the plan, cost units).
    """
    valid = nodes >= 0
    safe = jnp.clip(nodes, 0)
    edge = jax.vmap(lambda c, a, b: c[a, b])(instance.cost, safe[:, :-1], safe[:, 1:])
    cost = jnp.sum(jnp.where(valid[:, :-1] & valid[:, 1:], edge, 0.0), axis=1)
    return plan_reward(instance, nodes), cost.astype(jnp.float32)


def insertion_mask(
    instance: SOPInstance,
    visited_sets: jax.Array,
    delta: jax.Array,
    travelled: jax.Array,
    budget_mask: bool,
) -> jax.Array:
    """The mask of an insertion step (the chosen node goes where it adds the least cost).

    A node may be inserted when it is open (:func:`open_nodes`) and has a reachable
    position (finite ``delta``); with ``budget_mask`` also only if the plan stays within
    the budget (up to a relative 1e-5) and END is allowed only when no node is.

    Args:
        instance: batch of B instances.
        visited_sets: [B, S, K] bool, sets already used (blocked sets included).
        delta: [B, S, N] float32 added cost of each node's cheapest insertion.
        travelled: [B, S] float32 cost of each state's plan (to the end node of a closed
            tour).
        budget_mask: apply the budget rule (static Python bool).

    Returns:
        [B, S, N+1] bool, END at index N.
    """
    set_id = jnp.broadcast_to(instance.set_id[:, None], delta.shape)
    nodes = open_nodes(set_id, visited_sets) & jnp.isfinite(delta)
    end_ok = jnp.ones(delta.shape[:-1] + (1,), bool)
    if budget_mask:
        tol = 1e-5 * jnp.maximum(1.0, instance.budget)[:, None, None]
        left = instance.budget[:, None, None] - travelled[..., None]
        nodes = nodes & (delta <= left + tol)
        end_ok = ~jnp.any(nodes, axis=-1, keepdims=True)
    return jnp.concatenate([nodes, end_ok], axis=-1)
