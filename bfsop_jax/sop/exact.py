"""Exact SOP solver: dynamic programming over subsets of sets (docs/design.md §7.4).

State: (subset S of visited sets, last visited node u) -> least cost of a path from the
start through one node of every set of S, ending at u. Subsets are processed by size;
a level holds the subsets that still matter as a sorted array of bit masks and a dense
``[P, n]`` table of costs (``inf`` where u is not a possible last node). The transition
to the next level is a min-plus product with the cost matrix, computed over the finite
entries only.

Pruning keeps the search exact:

* a state whose cost plus the shortest-path cost from u to the end exceeds the budget is
  dropped (no completion fits);
* a reference solution (a quick VNS run unless one is given) gives a reward R0 that the
  optimum reaches. A state that cannot reach R0 is dropped: entering a new set t costs at
  least ``enter[t]`` (its cheapest incoming edge), so the reward still reachable with the
  remaining budget is bounded by a fractional knapsack over the unvisited sets. When R0
  is already the sum of all rewards, the budget in that test shrinks to the reference
  cost, so only tours at least as short survive.

Result: the lexicographic optimum (maximal reward, then minimal cost) over all tours.
Levels are kept as float32 copies for backtracking, so the returned tour's cost can exceed
the optimal cost by float32 rounding (exact for integer costs below 2^24).
Limits: at most ``max_sets`` rewarding sets (default 22: 2^22 subsets) and at most
``max_states`` live (subset, node) states per level; beyond either a ``ValueError`` is
raised. Small instances (<= 16 sets) take milliseconds to a few seconds; 20-22 set
benchmark instances with loose budgets take up to minutes.
"""

from __future__ import annotations

import numpy as np

from bfsop_jax.sop.types import Solution, SOPInstance, evaluate
from bfsop_jax.sop.vns import empty_solution, set_view, solve_vns

__all__ = ["solve_exact"]


def solve_exact(
    instance: SOPInstance,
    reference: Solution | None = None,
    min_cost: bool = True,
    max_sets: int = 22,
    max_states: int = 60_000_000,
) -> Solution:
    """Optimal solution of a single SOP instance (maximal reward, then minimal cost).

    Args:
        instance: a single (unbatched) instance.
        reference: a feasible solution used for pruning (default: a VNS run).
        min_cost: also minimise the cost among the tours of maximal reward. With False,
            a reference that already collects every reward is returned as it is (its
            reward is optimal, its cost need not be) -- much faster on loose budgets.
        max_sets: refuse instances with more rewarding, reachable sets than this.
        max_states: refuse when a DP level would hold more (subset, node) states.

    Returns:
        A :class:`Solution` with unpadded nodes (start first; end last if any).
    """
    inst = instance.to_numpy()
    view = set_view(inst)
    msets = view.num_sets
    if msets == 0:
        return empty_solution(inst)
    if msets > max_sets:
        raise ValueError(
            f"exact solver handles at most {max_sets} rewarding sets, instance has {msets}"
        )
    if reference is None:
        reference = solve_vns(inst, seed=0, max_iters=1000, max_no_improve=300)
    ref_reward, ref_cost, ref_ok = evaluate(inst, reference.nodes)
    if not ref_ok:
        raise ValueError("reference solution is not feasible for this instance")
    if not min_cost and ref_reward >= view.reward.sum() - 1e-9 * max(1.0, view.reward.sum()):
        return Solution(
            nodes=np.asarray(reference.node_list(), np.int32),
            reward=np.float32(ref_reward),
            cost=np.float32(ref_cost),
        )

    # nodes of the rewarding sets, compacted: node k is view node ids[k] in set sets[k]
    slots = view.members[:msets]
    ids = slots[slots >= 0]
    node_set = np.nonzero(slots >= 0)[0]
    n = ids.size
    cost = view.cost[np.ix_(ids, ids)]
    from_start = view.cost[view.start, ids]
    to_end = view.dist_to_end[ids]  # shortest path: a lower bound on any completion
    close = view.cost[ids, view.end] if view.end >= 0 else np.zeros(n)
    budget = view.budget
    reward = view.reward[:msets]
    total = float(reward.sum())
    eps = 1e-9 * max(1.0, total)
    cost_eps = 1e-9 * max(1.0, budget)
    bits = np.int64(1) << node_set.astype(np.int64)
    # cheapest way into each set: from the start or any node of another set
    into_node = np.minimum(
        np.where(node_set[:, None] == node_set[None, :], np.inf, cost).min(axis=0), from_start
    )
    enter = np.full(msets, np.inf)
    np.minimum.at(enter, node_set, into_node)
    # budget for the knapsack bound: tours matching the full reward must beat the reference
    bound_budget = budget if ref_reward < total - eps else min(budget, ref_cost)
    bound = _KnapsackBound(reward, enter, target=ref_reward - eps)

    levels: list[tuple[np.ndarray, np.ndarray]] = []
    best = (0.0, float(view.cost[view.start, view.end]) if view.end >= 0 else 0.0, 0, -1, -1)
    # level 1: one set visited
    table = np.where(node_set[None, :] == np.arange(msets)[:, None], from_start[None, :], np.inf)
    masks = np.int64(1) << np.arange(msets, dtype=np.int64)
    while masks.size:
        table = _prune(table, masks, to_end, budget, bound, bound_budget)
        keep = np.isfinite(table).any(axis=1)
        masks, table = masks[keep], table[keep]
        if not masks.size:
            break
        levels.append((masks, table.astype(np.float32)))  # float32 copy for backtracking
        finish = (table + close[None, :]).min(axis=1)
        got = _mask_reward(masks, reward)
        for p in np.flatnonzero(finish <= budget):
            r, c = float(got[p]), float(finish[p])
            if r > best[0] + eps or (abs(r - best[0]) <= eps and c < best[1] - cost_eps):
                last = int(np.argmin(table[p] + close))
                best = (r, c, len(levels), p, last)
        masks, table = _next_level(masks, table, cost, node_set, bits, max_states)

    if best[3] < 0:
        return empty_solution(inst)
    order = _backtrack(levels, best, cost, node_set, bits)
    nodes = [view.start] + [int(ids[k]) for k in order]
    if view.end >= 0:
        nodes.append(view.end)
    r, c, ok = evaluate(inst, nodes)
    assert ok, "exact solver produced an infeasible tour"
    return Solution(nodes=np.asarray(nodes, np.int32), reward=np.float32(r), cost=np.float32(c))


class _KnapsackBound:
    """Least budget needed to still collect ``target`` reward from the unvisited sets.

    Fractional knapsack with weights ``enter`` (each unvisited set must at least be
    entered): sets sorted by reward per unit weight, filled greedily.
    """

    def __init__(self, reward: np.ndarray, enter: np.ndarray, target: float) -> None:
        ratio = np.where(enter > 0, reward / np.maximum(enter, 1e-300), np.inf)
        self.set_reward = reward
        self.order = np.argsort(-ratio, kind="stable")
        self.reward = reward[self.order]
        self.enter = enter[self.order]
        self.bits = np.int64(1) << self.order.astype(np.int64)
        self.target = target

    def needed(self, masks: np.ndarray, have: np.ndarray) -> np.ndarray:
        """[P] least extra cost to reach ``target`` from subsets ``masks`` (inf: never)."""
        free = (masks[:, None] & self.bits[None, :]) == 0  # [P, M] in ratio order
        gain = np.where(free, self.reward[None, :], 0.0)
        weight = np.where(free, self.enter[None, :], 0.0)
        missing = self.target - have  # reward still to collect
        cum_gain = np.cumsum(gain, axis=1)
        cum_weight = np.cumsum(weight, axis=1)
        # first item at which the cumulative reward reaches the missing amount
        reach = cum_gain >= missing[:, None]
        idx = np.argmax(reach, axis=1)
        ok = reach[np.arange(masks.size), idx]
        rows = np.arange(masks.size)
        before_gain = cum_gain[rows, idx] - gain[rows, idx]
        before_weight = cum_weight[rows, idx] - weight[rows, idx]
        frac = np.where(
            gain[rows, idx] > 0, (missing - before_gain) / np.maximum(gain[rows, idx], 1e-300), 0
        )
        need = before_weight + np.clip(frac, 0.0, 1.0) * weight[rows, idx]
        need = np.where(ok, need, np.inf)
        return np.where(missing <= 0, 0.0, need)


def _mask_reward(masks: np.ndarray, reward: np.ndarray) -> np.ndarray:
    bits = (masks[:, None] >> np.arange(reward.size, dtype=np.int64)[None, :]) & 1
    return bits @ reward


def _prune(
    table: np.ndarray,
    masks: np.ndarray,
    to_end: np.ndarray,
    budget: float,
    bound: _KnapsackBound,
    bound_budget: float,
) -> np.ndarray:
    """Drop states that cannot finish within the budget or cannot reach the reference."""
    need = bound.needed(masks, _mask_reward(masks, bound.set_reward))
    dead = table + to_end[None, :] > budget
    dead |= table + need[:, None] > bound_budget
    return np.where(dead, np.inf, table)


def _next_level(
    masks: np.ndarray,
    table: np.ndarray,
    cost: np.ndarray,
    node_set: np.ndarray,
    bits: np.ndarray,
    max_states: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Extend every state by one node of an unvisited set; returns the next level."""
    n = cost.shape[0]
    out_rows, out_vals = [], []
    chunk = max(1, (1 << 22) // max(n, 1))
    rows, cols = np.nonzero(np.isfinite(table))
    for lo in range(0, rows.size, chunk):
        r, c = rows[lo : lo + chunk], cols[lo : lo + chunk]
        vals = table[r, c][:, None] + cost[c]  # [entries, n]
        starts = np.flatnonzero(np.r_[True, r[1:] != r[:-1]])
        best = np.minimum.reduceat(vals, starts, axis=0)  # [rows in chunk, n]
        out_rows.append(r[starts])
        out_vals.append(best)
    if not out_rows:
        return masks[:0], table[:0]
    src = np.concatenate(out_rows)
    vals = np.concatenate(out_vals)
    # a chunk boundary may split a row: combine duplicates
    if src.size > 1 and (src[1:] == src[:-1]).any():
        uniq, first = np.unique(src, return_index=True)
        vals = np.minimum.reduceat(vals, first, axis=0)
        src = uniq
    vals[(masks[src][:, None] & bits[None, :]) != 0] = np.inf  # set already visited
    r, u = np.nonzero(np.isfinite(vals))
    new = masks[src][r] | bits[u]
    uniq, where = np.unique(new, return_inverse=True)
    if uniq.size * n > max_states:
        raise ValueError(
            f"exact solver: {uniq.size} subsets x {n} nodes exceed max_states={max_states}"
        )
    out = np.full((uniq.size, n), np.inf)
    out[where, u] = vals[r, u]  # (new mask, u) comes from exactly one (old mask, u)
    return uniq, out


def _backtrack(
    levels: list[tuple[np.ndarray, np.ndarray]],
    best: tuple[float, float, int, int, int],
    cost: np.ndarray,
    node_set: np.ndarray,
    bits: np.ndarray,
) -> list[int]:
    """Compact node indices of the optimal tour, first visited first."""
    _, _, level, row, last = best
    mask = int(levels[level - 1][0][row])
    order = [last]
    value = float(levels[level - 1][1][row, last])
    for lvl in range(level - 1, 0, -1):
        mask ^= int(bits[order[-1]])
        masks, table = levels[lvl - 1]
        p = int(np.searchsorted(masks, mask))
        cand = table[p].astype(np.float64) + cost[:, order[-1]]
        prev = int(np.argmin(np.abs(cand - value)))
        value = float(table[p, prev])
        order.append(prev)
    return order[::-1]
