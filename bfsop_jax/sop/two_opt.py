"""Bounded SOP 2-opt and the budget gate (JAX, docs/design.md §7.5).

``two_opt`` improves a plan without changing which sets it visits:

1. intra-set exchange: for the current set order, a layered min-plus DP over the padded
   ``[N, N]`` cost matrix picks the best node of every visited set exactly;
2. inter-set reordering: every segment reversal (2-opt) of the visited set order is
   scored with the current nodes in O(1) from prefix sums of the forward and backward
   edge costs; the best improving one is applied and step 1 runs again.

It stops after ``max_iters`` reversals or when none improves (``lax.while_loop``); a step
is kept only if it lowers the cost, so the cost never increases and the visited sets,
hence the reward, stay the same. ``budget_gate`` then drops sets from the end of the plan
until its cost fits the budget (that one may lower the reward).

Both functions take a single instance and solution, or a batch (leading batch axis on
every leaf, ``jax.vmap`` inside); both are jitted. Shapes are static: N nodes, T =
``solution.nodes.shape[-1]`` plan slots (padded with -1). Internally a route holds T + 1
positions: the start, the visited nodes, then the end node, or a virtual node N whose
incoming edges cost 0 for an open path; later positions repeat that virtual node.

The SOP rules (blocked and open sets, the plan's end, its reward) come from
:mod:`bfsop_jax.sop.rules`; costs are summed along the route with the virtual node.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from bfsop_jax import ops
from bfsop_jax.sop.rules import blocked_sets, open_nodes, plan_end, plan_reward
from bfsop_jax.sop.types import Solution, SOPInstance

__all__ = [
    "two_opt",
    "budget_gate",
    "insert_after",
    "insertion_costs",
    "insertion_fill",
    "plan_route",
    "refine_route",
]


def _batched(fn):
    """Apply ``fn(instance, solution, ...)`` to one item or vmap it over a leading axis."""

    @functools.wraps(fn)
    def wrapper(instance: SOPInstance, solution: Solution, *args):
        if instance.cost.ndim == 3:
            return jax.vmap(lambda i, s: fn(i, s, *args))(instance, solution)
        return fn(instance, solution, *args)

    return wrapper


def _extended_cost(instance: SOPInstance) -> jax.Array:
    """[N+1, N+1] float32 costs with a virtual node N: free to enter, free to stay."""
    n = instance.cost.shape[-1]
    ext = jnp.full((n + 1, n + 1), jnp.inf, jnp.float32)
    ext = ext.at[:n, :n].set(instance.cost.astype(jnp.float32))
    return ext.at[:, n].set(0.0)


def _route(instance: SOPInstance, nodes: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Route [T+1] (start, visited, end or virtual) and the visited count m."""
    t = nodes.shape[0]
    n = instance.cost.shape[-1]
    has_end = instance.end >= 0
    count = jnp.sum(nodes >= 0)
    m = jnp.maximum(count - 1 - has_end.astype(count.dtype), 0)
    pos = jnp.arange(t + 1)
    padded = jnp.concatenate([nodes, jnp.full((1,), -1, nodes.dtype)])
    last = plan_end(instance, n)
    route = jnp.where(pos <= m, padded, jnp.where(pos == m + 1, last, n))
    route = route.at[0].set(instance.start)
    return route.astype(jnp.int32), m


def _route_cost(cx: jax.Array, route: jax.Array) -> jax.Array:
    return jnp.sum(cx[route[:-1], route[1:]])


def _to_solution(instance: SOPInstance, cx: jax.Array, route: jax.Array, m: jax.Array) -> Solution:
    """Pack a route into a padded Solution (nodes [T])."""
    t = route.shape[0] - 1
    n = instance.cost.shape[-1]
    pos = jnp.arange(t)
    keep = (pos <= m) | ((pos == m + 1) & (route[:t] < n))
    nodes = jnp.where(keep, route[:t], -1).astype(jnp.int32)
    return Solution(nodes=nodes, reward=plan_reward(instance, nodes), cost=_route_cost(cx, route))


def _best_nodes(instance: SOPInstance, cx: jax.Array, route: jax.Array, m: jax.Array) -> jax.Array:
    """Same set order, best node of every visited set (layered min-plus DP + backtrack)."""
    t1 = route.shape[0]
    n = instance.cost.shape[-1]
    cost = cx[:n, :n]
    order = instance.set_id[jnp.clip(route, 0, n - 1)]  # set of each route position
    close = cx[:n, route[jnp.clip(m + 1, 0, t1 - 1)]]  # [N] cost to the end (0 if open)
    table0 = jnp.where(jnp.arange(n) == instance.start, 0.0, jnp.inf)

    def layer(table, pos):
        cand = table[:, None] + cost  # [from, to]
        best = jnp.min(cand, axis=0)
        back = ops.argmin(cand, axis=0).astype(jnp.int32)
        allowed = instance.set_id == order[pos]
        active = pos <= m
        new = jnp.where(allowed, best, jnp.inf)
        stay = jnp.arange(n, dtype=jnp.int32)  # layers past the plan keep every node
        return jnp.where(active, new, table), jnp.where(active, back, stay)

    table, back = jax.lax.scan(layer, table0, jnp.arange(1, t1))
    last = ops.argmin(table + close).astype(jnp.int32)

    def trace(node, ptr):
        return ptr[node], node

    _, chosen = jax.lax.scan(trace, last, back, reverse=True)  # chosen[l-1]: node of layer l
    pos = jnp.arange(t1)
    inner = (pos >= 1) & (pos <= m)
    return jnp.where(inner, jnp.concatenate([route[:1], chosen])[pos], route)


def _reversal_costs(cx: jax.Array, route: jax.Array, m: jax.Array) -> jax.Array:
    """[T+1, T+1] cost after reversing route[i..k] (1 <= i < k <= m), inf elsewhere."""
    t1 = route.shape[0]
    fwd = cx[route[:-1], route[1:]]  # edge p -> p+1
    bwd = cx[route[1:], route[:-1]]  # edge p+1 -> p

    def prefix(e):  # cumulative finite sums and inf counts, so segment sums never see inf-inf
        z = jnp.zeros((1,), e.dtype)
        finite = jnp.concatenate([z, jnp.cumsum(jnp.where(jnp.isinf(e), 0.0, e))])
        infs = jnp.concatenate([z, jnp.cumsum(jnp.isinf(e).astype(e.dtype))])
        return finite, infs

    f_sum, f_inf = prefix(fwd)
    b_sum, b_inf = prefix(bwd)
    i = jnp.arange(t1)[:, None]
    k = jnp.arange(t1)[None, :]
    im1 = jnp.clip(i - 1, 0, t1 - 1)
    kp1 = jnp.clip(k + 1, 0, t1 - 1)
    kk = jnp.clip(k, 0, t1 - 1)
    # before: edges 0..i-2; middle reversed: edges i..k-1 backwards; after: edges k+1..T-1
    finite = f_sum[im1] + (b_sum[kk] - b_sum[i]) + (f_sum[t1 - 1] - f_sum[kp1])
    infs = f_inf[im1] + (b_inf[kk] - b_inf[i]) + (f_inf[t1 - 1] - f_inf[kp1])
    links = cx[route[im1], route[kk]] + cx[route[i], route[kp1]]
    total = jnp.where(infs > 0, jnp.inf, finite + links)
    valid = (i >= 1) & (k > i) & (k <= m)
    return jnp.where(valid, total, jnp.inf)


def _best_reversal(
    cx: jax.Array, route: jax.Array, m: jax.Array, cost: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """The route after its best segment reversal, and whether that lowers ``cost`` (the
    route's cost) by more than a relative 1e-6."""
    t1 = route.shape[0]
    scores = _reversal_costs(cx, route, m)
    flat = ops.argmin(scores)
    i, k = flat // t1, flat % t1
    tol = 1e-6 * jnp.maximum(1.0, jnp.abs(cost))
    pos = jnp.arange(t1)
    inside = (pos >= i) & (pos <= k)
    flipped = jnp.where(inside, route[jnp.clip(i + k - pos, 0, t1 - 1)], route)
    return flipped, scores.reshape(-1)[flat] < cost - tol


def refine_route(
    instance: SOPInstance, route: jax.Array, m: jax.Array, reversals: int = 2, sweeps: int = 2
) -> jax.Array:
    """A cheap improvement of one route (single instance; what the insertion decoder does
    after every insertion, so the budget it frees is there for the next choices).

    First up to ``reversals`` best segment reversals (2-opt), each kept only when it lowers
    the cost; then ``sweeps`` passes in which every visited position takes the node of its
    set that is cheapest between its two neighbours (odd positions, then even ones, so no
    two changed positions are adjacent). The visited sets stay the same and the cost never
    increases; the exact intra-set DP of :func:`two_opt` is left out (it costs a scan over
    the route per call).

    Args:
        instance: one instance (N nodes).
        route: [T+1] int32, :func:`plan_route` layout.
        m: [] int32 visited nodes on the route.
        reversals, sweeps: static counts (0 skips that part).

    Returns:
        [T+1] int32, the improved route (same layout and m).
    """
    cx = _extended_cost(instance)
    n = instance.cost.shape[-1]
    t1 = route.shape[0]
    pos = jnp.arange(t1)

    def reverse(_, route):
        flipped, improves = _best_reversal(cx, route, m, _route_cost(cx, route))
        return jnp.where(improves, flipped, route)

    route = jax.lax.fori_loop(0, reversals, reverse, route)
    same_set = instance.set_id[None, :] == instance.set_id[jnp.clip(route, 0, n - 1)][:, None]
    for _ in range(sweeps):
        for parity in (1, 0):
            prev = route[jnp.clip(pos - 1, 0, t1 - 1)]
            nxt = route[jnp.clip(pos + 1, 0, t1 - 1)]
            detour = jnp.where(same_set, cx[prev, :n] + cx[:n, nxt].T, jnp.inf)  # [T+1, N]
            best = ops.argmin(detour, axis=1).astype(route.dtype)
            now = cx[prev, route] + cx[route, nxt]
            move = (pos >= 1) & (pos <= m) & (pos % 2 == parity)
            move = move & (jnp.min(detour, axis=1) < now)
            route = jnp.where(move, best, route)
    return route


def _two_opt_single(instance: SOPInstance, solution: Solution, max_iters: int) -> Solution:
    cx = _extended_cost(instance)
    route, m = _route(instance, solution.nodes)
    cost0 = _route_cost(cx, route)
    # intra-set exchange on the given order first
    first = _best_nodes(instance, cx, route, m)
    cost1 = _route_cost(cx, first)
    route, cost = jax.lax.cond(cost1 < cost0, lambda: (first, cost1), lambda: (route, cost0))

    def cond(state):
        _, _, it, done = state
        return (it < max_iters) & ~done

    def body(state):
        route, cost, it, _ = state
        flipped, improves = _best_reversal(cx, route, m, cost)
        better = _best_nodes(instance, cx, flipped, m)
        new_cost = _route_cost(cx, better)
        take = improves & (new_cost < cost)
        return (
            jnp.where(take, better, route),
            jnp.where(take, new_cost, cost),
            it + 1,
            ~take,
        )

    route, _, _, _ = jax.lax.while_loop(cond, body, (route, cost, jnp.int32(0), jnp.bool_(False)))
    return _to_solution(instance, cx, route, m)


def _budget_gate_single(instance: SOPInstance, solution: Solution) -> Solution:
    cx = _extended_cost(instance)
    route, m = _route(instance, solution.nodes)
    t1 = route.shape[0]
    n = instance.cost.shape[-1]
    end = plan_end(instance, n)
    edges = cx[route[:-1], route[1:]]
    prefix = jnp.concatenate([jnp.zeros((1,), edges.dtype), jnp.cumsum(edges)])  # cost to p
    total = prefix + cx[route, end]  # plan keeping positions 0..p, then the end
    pos = jnp.arange(t1)
    fits = (pos <= m) & (total <= instance.budget)
    keep = jnp.max(jnp.where(fits, pos, 0))
    cut = jnp.where(pos <= keep, route, jnp.where(pos == keep + 1, end, n)).astype(jnp.int32)
    return _to_solution(instance, cx, cut, keep)


@functools.partial(jax.jit, static_argnames=("max_iters",))
def two_opt(instance: SOPInstance, solution: Solution, max_iters: int = 100) -> Solution:
    """Bounded SOP 2-opt with exact intra-set node choice; never increases the cost.

    Args:
        instance: one instance, or a batch with a leading batch axis on every leaf.
        solution: matching plan(s), ``nodes`` [T] or [B, T] padded with -1.
        max_iters: most segment reversals applied (static).

    Returns:
        Solution(s) with the same visited sets (same reward) and cost <= the input cost.
        ``cost`` is the float32 sum along the plan.
    """
    return _batched(_two_opt_single)(instance, solution, max_iters)


@jax.jit
def budget_gate(instance: SOPInstance, solution: Solution) -> Solution:
    """Drop sets from the end of the plan until its cost fits the budget.

    Keeps the longest prefix of the visited nodes whose cost, plus the return to the end
    node of a closed tour, is within ``instance.budget``. Single or batched like
    :func:`two_opt`.
    """
    return _batched(_budget_gate_single)(instance, solution)


def _insertion_deltas(cx: jax.Array, route: jax.Array, m: jax.Array) -> jax.Array:
    """[T+1, N] added cost of putting node j right after ``route[p]`` (p <= m), inf elsewhere.

    ``cx`` from :func:`_extended_cost`: after the last visited node comes the end node, or
    the free virtual node of an open path, so appending to an open path costs c(last, j).
    """
    t1 = route.shape[0]
    n = cx.shape[0] - 1
    pos = jnp.arange(t1)
    nxt = route[jnp.clip(pos + 1, 0, t1 - 1)]
    here = cx[route, nxt]
    delta = cx[route][:, :n] + cx[:n, nxt].T - here[:, None]
    ok = (pos <= m)[:, None] & jnp.isfinite(here)[:, None] & ~jnp.isnan(delta)
    return jnp.where(ok, delta, jnp.inf)


def plan_route(instance: SOPInstance, nodes: jax.Array) -> tuple[jax.Array, jax.Array]:
    """One plan as a route for insertion (single instance).

    Args:
        instance: one instance (N nodes).
        nodes: [T] plan (start, visited nodes, the end node of a closed tour), -1 padding.

    Returns:
        ``(route, m)``: route [T+1] int32 = start, the m visited nodes, the end node (or the
        virtual node N of an open path), then N; m the visited count.
    """
    return _route(instance, nodes)


def insert_after(route: jax.Array, after: jax.Array, node: jax.Array) -> jax.Array:
    """``route`` [..., T+1] with ``node`` put right after position ``after`` (both
    broadcast against the leading axes, e.g. [B, 1]); later entries move one slot on."""
    slot = jnp.arange(route.shape[-1])
    moved = jnp.roll(route, 1, axis=-1)  # slot i holds route[i - 1] (slot 0 is never used)
    return jnp.where(slot <= after, route, jnp.where(slot == after + 1, node, moved))


def insertion_costs(
    instance: SOPInstance, route: jax.Array, m: jax.Array
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Cheapest insertion of every node into one route (single instance, cost units).

    Args:
        instance: one instance (N nodes).
        route: [T+1] int32 from :func:`plan_route` (or the same layout).
        m: [] int32 visited nodes on the route.

    Returns:
        ``(delta, after, cost)``: delta [N] float32, the least added cost of putting node j
        into the route (inf when no position is reachable); after [N] int32, the route
        position it goes right after; cost [] float32, the route's cost (to the end node of
        a closed tour). Which nodes may be inserted (sets, budget) is the caller's rule.
    """
    cx = _extended_cost(instance)
    deltas = _insertion_deltas(cx, route, m)
    after = ops.argmin(deltas, axis=0).astype(jnp.int32)
    return jnp.min(deltas, axis=0), after, _route_cost(cx, route)


def _insertion_fill_single(instance: SOPInstance, solution: Solution) -> Solution:
    cx = _extended_cost(instance)
    route, m = _route(instance, solution.nodes)
    t1 = route.shape[0]
    n = instance.cost.shape[-1]
    k = instance.set_reward.shape[-1]
    set_id = instance.set_id
    reward = instance.set_reward[jnp.clip(set_id, 0)]  # [N] reward of each node's set
    end = plan_end(instance, n)
    blocked = blocked_sets(instance)
    pos = jnp.arange(t1)

    def step(state):
        route, m, cost, _ = state
        on_route = (pos >= 1) & (pos <= m)
        used = (
            jnp.zeros((k,), bool).at[jnp.clip(set_id[jnp.clip(route, 0, n - 1)], 0)].max(on_route)
        )
        free = open_nodes(set_id, used | blocked) & (reward > 0)
        delta = _insertion_deltas(cx, route, m)  # [T+1, N]
        ok = free[None, :] & (cost + delta <= instance.budget)
        ok = ok & (m + 2 < t1)  # a slot is left for the end
        score = jnp.where(ok, jnp.maximum(delta, 0.0) / reward[None, :], jnp.inf)
        flat = ops.argmin(score)
        p, j = flat // n, flat % n
        found = jnp.isfinite(score.reshape(-1)[flat])
        shifted = insert_after(route, p, j)
        new_route = jnp.where(found, shifted, route).astype(jnp.int32)
        return new_route, m + found, cost + jnp.where(found, delta[p, j], 0.0), found

    def cond(state):
        return state[3]

    cost0 = _route_cost(cx, route)
    route, m, _, _ = jax.lax.while_loop(cond, step, (route, m, cost0, jnp.bool_(True)))
    route = jnp.where(pos == m + 1, end, route)  # the end (or virtual node) after the plan
    return _to_solution(instance, cx, route, m)


@jax.jit
def insertion_fill(instance: SOPInstance, solution: Solution) -> Solution:
    """Spend budget the plan leaves unused: greedy cheapest insertion of unvisited sets.

    Repeatedly inserts the node of an unvisited rewarding set, at the position of the
    plan, with the smallest added cost per unit reward among those that keep the plan
    within the budget (the VNS's greedy rule); stops when nothing fits. Never lowers the
    reward; the input should already fit the budget (e.g. after :func:`budget_gate`).
    Single or batched like :func:`two_opt`.

    Unlike the switcher's estimate :func:`bfsop_jax.agents.bfsop.greedy_estimate` (points on
    integer coordinates, no plan), this works on the instance's cost matrix and sets (one
    node per unvisited open set, :func:`bfsop_jax.sop.rules.open_nodes`), keeps the end
    node, scores max(added cost, 0) / reward over every (position, node) pair (ties to the
    earliest position, then the lowest node) and returns the filled plan.
    """
    return _batched(_insertion_fill_single)(instance, solution)
