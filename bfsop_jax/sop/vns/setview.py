"""The set view: the rewarding, reachable sets of one instance compacted for the solvers.

The rewarding sets are compacted to ``M`` sets with at most ``Q`` (reachable) nodes each;
set ``M`` is the start and set ``M + 1`` the end ("END" is a zero-cost sink for an open
path). ``block[a, b, s, t]`` is the cost from node slot a of set s to slot b of set t (inf
for padding slots and for transitions that never occur).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from bfsop_jax.sop.types import SOPInstance, validate

__all__ = ["SetView", "set_view"]

_MAX_BLOCK_BYTES = 2 << 30  # the largest ``block`` (both layouts: twice that) the solvers build


@dataclasses.dataclass(frozen=True)
class SetView:
    """The rewarding sets of one instance, compacted for the NumPy solvers.

    ``M`` rewarding sets that have at least one node reachable within the budget; node
    slots padded to ``Q``. Index ``M`` is the start set, ``M + 1`` the end set.
    """

    set_ids: np.ndarray  # [M] int: original set id of each compact set
    reward: np.ndarray  # [M + 2] float64: set rewards (0 for start and end)
    members: np.ndarray  # [M + 2, Q] int: node ids of each set, -1 = empty slot
    block: np.ndarray  # [Q, Q, M + 2, M + 2] float64: slot a of s -> slot b of t, inf = none
    block_t: np.ndarray  # [Q, Q, M + 2, M + 2] float64: block with the slot axes swapped
    cost: np.ndarray  # [N, N] float64: the instance's cost matrix
    dist_from_start: np.ndarray  # [N] float64: shortest-path cost start -> node
    dist_to_end: np.ndarray  # [N] float64: shortest-path cost node -> end (0: open path)
    start: int
    end: int  # -1 = open path
    budget: float

    @property
    def num_sets(self) -> int:
        return int(self.set_ids.shape[0])

    @property
    def block_flat(self) -> np.ndarray:
        """[Q * Q, (M + 2) * (M + 2)] view of ``block`` for flat gathers."""
        q, k = self.block.shape[0], self.block.shape[2]
        return self.block.reshape(q * q, k * k)

    @property
    def block_flat_t(self) -> np.ndarray:
        q, k = self.block.shape[0], self.block.shape[2]
        return self.block_t.reshape(q * q, k * k)

    @property
    def start_set(self) -> int:
        return self.num_sets

    @property
    def end_set(self) -> int:
        return self.num_sets + 1


def _shortest_from(cost: np.ndarray, src: int) -> np.ndarray:
    """Dense Dijkstra: [N] shortest-path costs from ``src`` (cost [N, N], non-negative)."""
    n = cost.shape[0]
    dist = np.full(n, np.inf)
    dist[src] = 0.0
    done = np.zeros(n, bool)
    for _ in range(n):
        cand = np.where(done, np.inf, dist)
        v = int(np.argmin(cand))
        if not np.isfinite(cand[v]):
            break
        done[v] = True
        np.minimum(dist, dist[v] + cost[v], out=dist)
    return dist


def set_view(instance: SOPInstance) -> SetView:
    """Compact the rewarding, reachable sets of a single instance (see :class:`SetView`).

    A node is kept only when start -> node -> end fits the budget along shortest paths
    (a valid bound for every tour), a set only when it keeps a node and has reward > 0.
    """
    inst = instance.to_numpy()
    validate(inst)
    cost = inst.cost.astype(np.float64)
    set_id = inst.set_id
    start, end = int(inst.start), int(inst.end)
    budget = float(inst.budget)
    real = set_id >= 0
    graph = np.where(real[:, None] & real[None, :], cost, np.inf)
    dist_from_start = _shortest_from(graph, start)
    if end >= 0:
        dist_to_end = _shortest_from(graph.T, end)
    else:
        dist_to_end = np.where(real, 0.0, np.inf)
    fixed = {int(set_id[start])}
    if end >= 0:
        fixed.add(int(set_id[end]))
    usable = real & (dist_from_start + dist_to_end <= budget)
    rewards = inst.set_reward.astype(np.float64)
    groups: list[tuple[int, np.ndarray]] = []
    for s in range(rewards.shape[0]):
        if s in fixed or rewards[s] <= 0:
            continue
        nodes = np.flatnonzero(usable & (set_id == s))
        if nodes.size:
            groups.append((s, nodes))
    m = len(groups)
    q = max([1] + [len(g[1]) for g in groups])
    if (m + 2) ** 2 * q * q * 8 > _MAX_BLOCK_BYTES:
        raise ValueError(
            f"instance too large for the NumPy solvers: {m} sets with up to {q} nodes each"
        )
    members = np.full((m + 2, q), -1, np.int64)
    for k, (_, nodes) in enumerate(groups):
        members[k, : len(nodes)] = nodes
    members[m, 0] = start
    members[m + 1, 0] = end  # -1 for an open path: a zero-cost sink
    valid = members >= 0
    safe = np.maximum(members, 0)
    block = cost[safe[:, None, :, None], safe[None, :, None, :]]  # [M+2, M+2, Q, Q]
    block = np.where(valid[:, None, :, None] & valid[None, :, None, :], block, np.inf)
    if end < 0:
        block[:, m + 1] = np.inf
        block[:, m + 1, :, 0] = np.where(valid, 0.0, np.inf)
    block[:, m] = np.inf  # nothing returns into the start layer
    block[m + 1] = np.inf  # nothing leaves the end layer
    idx = np.arange(m + 2)
    block[idx, idx] = np.inf  # a set follows itself never
    reward = np.zeros(m + 2)
    reward[:m] = [rewards[s] for s, _ in groups]
    block_t = np.ascontiguousarray(block.transpose(3, 2, 0, 1))
    block = np.ascontiguousarray(block.transpose(2, 3, 0, 1))
    return SetView(
        set_ids=np.array([s for s, _ in groups], np.int64),
        reward=reward,
        members=members,
        block=block,
        block_t=block_t,
        cost=cost,
        dist_from_start=dist_from_start,
        dist_to_end=dist_to_end,
        start=start,
        end=end,
        budget=budget,
    )
