"""VNS teacher for the Set Orienteering Problem (NumPy, SPEC 8.3).

Follows the published VNS-SOP (Penicka, Faigl & Saska 2019):

* a solution is a permutation of all rewarding sets; its first ``m`` entries are visited in
  order. The node inside each visited set is never searched: for a fixed set order a
  layered min-plus DP (forward table from the start, backward table to the end) picks the
  best node of every set exactly;
* initial solution: greedy insertion by the smallest added length per unit reward;
* basic VNS over two neighbourhoods. Shake 1 moves a random segment of the permutation,
  shake 2 swaps two random segments; then sets are dropped from the end while the tour is
  over budget and the next permutation entries appended while they fit. Local search 1
  relocates a visited set or inserts an unvisited one; local search 2 swaps two visited
  sets or replaces a visited set by an unvisited one. A move is accepted when the reward
  rises, or stays equal with a shorter tour; the VNS accepts a shaken-and-searched solution
  under the same rule;
* stops after ``max_iters`` iterations, ``max_no_improve`` iterations without improvement
  or ``time_limit`` seconds. Deterministic for a seed.

Additions for tight budgets (docs/sop.md): segment reversals in local search 2, and two
intensifications run when the stop rule fires (a success counts as an improvement):
insertion of a set that overshoots the budget followed by an order-only repair
(:func:`_squeeze`), then ruin and recreate of one or two visited sets (:func:`_recreate`).

Vectorisation (why it is not a line-by-line port): instead of drawing n^2 random trials and
evaluating each with a Python-level DP, every move of a neighbourhood is evaluated exactly
in one batched min-plus pass from the DP tables (forward / backward tables, tables of the
tour with one set removed, and a propagation through the unchanged middle of a swap).
The random-trial first-improvement search is then emulated: a uniformly random improving
move is taken (what the first improving random trial would be), and the number of trials
it would have cost is drawn from the matching geometric law and charged to the n^2 trial
budget. With exact costs of all moves at hand, the published lower-bound test that skips
trials which cannot fit is unnecessary: infeasible moves are simply masked.

Independent iterations are batched: iterations that do not improve all start from the same
incumbent, so ``width`` shake + local-search trials run side by side on a leading batch
axis; the best of them is accepted when it improves. Iteration counters advance by
``width`` per batch.

Internal layout: the rewarding sets of an instance are compacted to ``M`` sets with at most
``Q`` (reachable) nodes each; set ``M`` is the start and set ``M + 1`` the end ("END" is a
zero-cost sink for an open path). ``block[s, t]`` is the ``[Q, Q]`` cost matrix between the
node slots of sets ``s`` and ``t`` (inf for padding slots).
"""

from __future__ import annotations

import dataclasses
import functools
import time

import numpy as np

from bfsop_jax.sop.types import Solution, SOPInstance, evaluate, validate

__all__ = ["SetView", "set_view", "solve_vns", "solve_greedy", "greedy_solution", "empty_solution"]

_MAX_BLOCK_BYTES = 2 << 30
RESTART_MAX_SETS = 24  # the intensification restarts from random orders only up to this size


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


# ----------------------------------------------------------------------------------------
# Layered DP on a batch of set orders
#
# Layout: every per-slot table keeps its slot axis first ([Q, ...]) so that the min-plus
# reductions run over the leading axis; NumPy reduces a short trailing axis several times
# slower. ``view.block[a, b, s, t]`` is the cost from slot a of set s to slot b of set t,
# ``view.block_t[b, a, s, t]`` the same numbers with the slot axes swapped.
# ----------------------------------------------------------------------------------------


def _point(q: int) -> np.ndarray:
    """[Q] table of the start / end layer: slot 0 at cost 0, the rest unreachable."""
    v = np.full(q, np.inf)
    v[0] = 0.0
    return v


_lowest = functools.partial(np.minimum.reduce, axis=0)  # min over the leading (slot) axis


def _fwd_step(vec: np.ndarray, mat: np.ndarray) -> np.ndarray:
    """min_a vec[a, ...] + mat[a, b, ...] -> [Q, ...]."""
    return _lowest(vec[:, None] + mat)


def _bwd_step(mat_t: np.ndarray, vec: np.ndarray) -> np.ndarray:
    """min_b mat_t[b, a, ...] + vec[b, ...] -> [Q, ...]."""
    return _lowest(mat_t + vec[:, None])


def _blocks(view: SetView, src: np.ndarray, dst: np.ndarray, swapped: bool = False) -> np.ndarray:
    """[Q, Q, *shape] cost blocks from the sets ``src`` to the sets ``dst`` (broadcast).

    A flat ``np.take`` keeps the result C-contiguous with the slot axes first (fancy
    indexing would leave the slot axes innermost in memory and make the reductions slow).
    """
    flat = np.asarray(src * view.block.shape[2] + dst)
    table = view.block_flat_t if swapped else view.block_flat
    q = view.block.shape[0]
    return table.take(flat.ravel(), axis=1).reshape(q, q, *flat.shape)


def _take(table: np.ndarray, *index: np.ndarray) -> np.ndarray:
    """table[:, *index] for a table [Q, *dims], as a C-contiguous [Q, *shape] array."""
    flat = index[0]
    for size, idx in zip(table.shape[2:], index[1:], strict=True):
        flat = flat * size + idx
    q = table.shape[0]
    return table.reshape(q, -1).take(flat.ravel(), axis=1).reshape(q, *flat.shape)


def _sequences(view: SetView, perm: np.ndarray, m: np.ndarray) -> np.ndarray:
    """[W, L] layer sets: start, the m visited sets, then end (padded with end)."""
    w = perm.shape[0]
    length = int(m.max()) + 2
    seq = np.full((w, length), view.end_set, np.int64)
    seq[:, 0] = view.start_set
    cols = np.arange(1, length - 1)
    inside = cols[None, :] <= m[:, None]
    seq[:, 1:-1] = np.where(inside, perm[:, : length - 2], view.end_set)
    return seq


@dataclasses.dataclass
class _Tables:
    seq: np.ndarray  # [W, L] layer sets
    m: np.ndarray  # [W] visited counts
    step: np.ndarray  # [Q, Q, L-1, W] block from layer l to layer l+1 (block layout)
    step_t: np.ndarray  # [Q, Q, L-1, W] the same, slot axes swapped
    fwd: np.ndarray  # [Q, W, L] best cost start -> slot of layer l
    bwd: np.ndarray  # [Q, W, L] best cost slot of layer l -> end
    length: np.ndarray  # [W] tour cost


def _tables(view: SetView, perm: np.ndarray, m: np.ndarray) -> _Tables:
    seq = _sequences(view, perm, m)
    w, length = seq.shape
    q = view.members.shape[1]
    step = _blocks(view, seq[:, :-1].T, seq[:, 1:].T)
    step_t = _blocks(view, seq[:, :-1].T, seq[:, 1:].T, swapped=True)
    point = np.repeat(_point(q)[:, None], w, axis=1)
    fwd = np.empty((length, q, w))
    fwd[0] = point
    for layer in range(1, length):
        fwd[layer] = _fwd_step(fwd[layer - 1], step[:, :, layer - 1])
    bwd = np.empty((length, q, w))
    bwd[-1] = point
    short = m + 1 < length - 1  # tours that end before the last layer
    for layer in range(length - 2, -1, -1):
        bwd[layer] = _bwd_step(step_t[:, :, layer], bwd[layer + 1])
        if short.any():
            ends = m + 1 == layer
            bwd[layer][:, ends] = point[:, ends]
    total = fwd[m + 1, 0, np.arange(w)]
    return _Tables(
        seq=seq,
        m=m,
        step=step,
        step_t=step_t,
        fwd=np.ascontiguousarray(fwd.transpose(1, 2, 0)),
        bwd=np.ascontiguousarray(bwd.transpose(1, 2, 0)),
        length=total,
    )


def _gap_tables(view: SetView, t: _Tables) -> tuple[np.ndarray, np.ndarray]:
    """Tables for putting a set ``s`` into gap ``j`` (between layers j and j+1).

    into[x, w, j, s]: best cost start -> slot x of set s entered right after layer j.
    out_of[x, w, j, s]: best cost slot x of set s -> end, leaving to layer j + 1.
    Shapes [Q, W, L-1, M].
    """
    sets = np.arange(view.num_sets)[None, None, :]
    blk = _blocks(view, t.seq[:, :-1, None], sets)  # [Q, Q, W, L-1, M]
    into = _lowest(t.fwd[:, None, :, :-1, None] + blk)
    blk = _blocks(view, sets, t.seq[:, 1:, None], swapped=True)
    out_of = _lowest(blk + t.bwd[:, None, :, 1:, None])
    return into, out_of


def _skip_tables(view: SetView, t: _Tables) -> tuple[np.ndarray, np.ndarray]:
    """DP tables of the tour with one visited layer i removed.

    fwd_skip[:, w, i, l]: start -> layer l (l > i) without layer i; bwd_skip[:, w, i, l]:
    layer l (l < i) -> end without layer i. Shapes [Q, W, L, L], inf elsewhere.
    """
    w, length = t.seq.shape
    q = view.members.shape[1]
    fs = np.full((length, q, w, length), np.inf)  # [l, Q, W, i]
    bs = np.full((length, q, w, length), np.inf)
    if length >= 3:
        seq = t.seq
        first = _fwd_step(t.fwd[:, :, :-2], _blocks(view, seq[:, :-2], seq[:, 2:]))
        last = _bwd_step(_blocks(view, seq[:, :-2], seq[:, 2:], swapped=True), t.bwd[:, :, 2:])
        # first[:, w, i-1]: table at layer i+1 without layer i; last[:, w, i-1]: at layer i-1
        for layer in range(2, length):
            fs[layer][:, :, layer - 1] = first[:, :, layer - 2]
            if layer >= 3:
                fs[layer][:, :, 1 : layer - 1] = _fwd_step(
                    fs[layer - 1][:, :, 1 : layer - 1], t.step[:, :, layer - 1, :, None]
                )
        for layer in range(length - 3, -1, -1):
            bs[layer][:, :, layer + 1] = last[:, :, layer]
            if layer + 2 <= length - 2:
                bs[layer][:, :, layer + 2 : length - 1] = _bwd_step(
                    t.step_t[:, :, layer, :, None], bs[layer + 1][:, :, layer + 2 : length - 1]
                )
    return (
        np.ascontiguousarray(fs.transpose(1, 2, 3, 0)),
        np.ascontiguousarray(bs.transpose(1, 2, 3, 0)),
    )


# ----------------------------------------------------------------------------------------
# Neighbourhoods: every move of a batch of solutions at once
# ----------------------------------------------------------------------------------------


@dataclasses.dataclass
class _Moves:
    kind: str
    cost: np.ndarray  # [W, A, B] tour cost after the move
    gain: np.ndarray  # [W, A, B] reward change
    valid: np.ndarray  # [W, A, B] move exists


def _visited_mask(view: SetView, perm: np.ndarray, m: np.ndarray) -> np.ndarray:
    """[W, M] bool: set visited."""
    w, msets = perm.shape
    vis = np.zeros((w, msets), bool)
    pos = np.arange(msets)[None, :] < m[:, None]
    rows = np.repeat(np.arange(w), msets).reshape(w, msets)
    vis[rows, perm] = pos
    return vis


def _neighbourhood(
    view: SetView, perm: np.ndarray, m: np.ndarray, t: _Tables, which: int, reversals: bool = False
) -> list[_Moves]:
    """Exact costs of every move of local search ``which`` (1 or 2) for the batch.

    Index conventions: layer i = 1..m is the i-th visited set; gap j lies between layers
    j and j + 1 (j = 0..m); sets s are compact set ids.
    """
    seq, length = t.seq, t.seq.shape[1]
    w = seq.shape[0]
    clip = view.num_sets - 1
    rows = np.arange(w)[:, None, None]
    into, out_of = _gap_tables(view, t)
    unvisited = ~_visited_mask(view, perm, m)  # [W, M]
    layer = np.arange(length)
    mm = t.m[:, None, None]
    reward = view.reward
    moves: list[_Moves] = []
    if which == 1:
        # insertion of an unvisited set s into gap j: [W, j, s]
        cost = _lowest(into + out_of)
        valid = (layer[None, :-1, None] <= mm) & unvisited[:, None, :]
        gain = np.broadcast_to(reward[None, None, : view.num_sets], cost.shape)
        moves.append(_Moves("insert", cost, gain, valid))
        # relocation of visited layer i into gap j: [W, i, j]
        fwd_skip, bwd_skip = _skip_tables(view, t)
        li, gaps = layer[None, :, None], layer[None, None, :-1]
        s_raw = seq[:, :, None]
        s_i = np.minimum(s_raw, clip)
        # earlier (j <= i - 2): ..., j, s_i, j+1, ..., i-1, i+1, ...
        blk = _blocks(view, s_raw, seq[:, None, 1:], swapped=True)  # s_i -> layer j+1
        after = _lowest(blk + bwd_skip[:, None, :, :, 1:])
        earlier = _lowest(_take(into, rows, gaps, s_i) + after)
        # later (j >= i + 1): ..., i-1, i+1, ..., j, s_i, j+1, ...
        blk = _blocks(view, seq[:, None, :-1], s_raw)  # layer j -> s_i
        before = _lowest(fwd_skip[:, None, :, :, :-1] + blk)
        later = _lowest(before + _take(out_of, rows, gaps, s_i))
        cost = np.where(gaps <= li - 2, earlier, later)
        valid = (li >= 1) & (li <= mm) & ((gaps <= li - 2) | ((gaps >= li + 1) & (gaps <= mm)))
        moves.append(_Moves("relocate", cost, np.zeros_like(cost), valid))
    else:
        # replacement of visited layer i by an unvisited set s: [W, i - 1, s]
        cost = _lowest(into[:, :, :-1] + out_of[:, :, 1:])
        valid = (layer[None, 1:-1, None] <= mm) & unvisited[:, None, :]
        lost = reward[np.minimum(seq[:, 1:-1], clip)][..., None]
        gain = reward[None, None, : view.num_sets] - lost
        moves.append(_Moves("replace", cost, gain, valid))
        moves.append(_swap_moves(view, t, into, out_of))
        if reversals:
            moves.append(_reversal_moves(view, t))
    return moves


def _swap_moves(view: SetView, t: _Tables, into: np.ndarray, out_of: np.ndarray) -> _Moves:
    """Swap of visited layers i < k: [W, i, k]."""
    seq, length = t.seq, t.seq.shape[1]
    w = seq.shape[0]
    clip = view.num_sets - 1
    rows = np.arange(w)[:, None, None]
    layer = np.arange(length)
    li, lk = layer[None, :, None], layer[None, None, :]
    cost = np.full((w, length, length), np.inf)
    valid = (li >= 1) & (lk > li) & (lk <= t.m[:, None, None])
    if length >= 4:
        # adjacent k = i + 1: ..., i-1, s_k, s_i, k+1, ...
        i = np.arange(1, length - 2)[None, :]
        r = np.arange(w)[:, None]
        left = _take(into, r, i - 1, np.minimum(seq[:, i[0] + 1], clip))  # [Q, W, L-3]
        right = _take(out_of, r, i + 1, np.minimum(seq[:, i[0]], clip))
        mid = _blocks(view, seq[:, i[0] + 1], seq[:, i[0]])  # [Q, Q, W, L-3]
        cost[:, i[0], i[0] + 1] = _lowest(_fwd_step(left, mid) + right)
    if length >= 5:
        # k >= i + 2: ..., i-1, s_k, i+1, ..., k-1, s_i, k+1, ...; the middle is unchanged,
        # so one table per pair is carried through it layer by layer
        s_i = np.minimum(seq[:, :, None], clip)  # [W, L, 1]
        s_k = np.minimum(seq[:, None, :], clip)  # [W, 1, L]
        head = _take(into, rows, np.clip(li - 1, 0, length - 2), s_k)  # s_k in layer i
        nxt = seq[:, np.clip(layer + 1, 0, length - 1)][:, :, None]  # set at layer i+1
        vec = _fwd_step(head, _blocks(view, seq[:, None, :], nxt))  # at layer i+1
        for mid in range(3, length - 2):
            # pairs with i + 1 <= mid - 1 and mid <= k - 1 move from layer mid-1 to mid
            vec[:, :, 1 : mid - 1, mid + 1 :] = _fwd_step(
                vec[:, :, 1 : mid - 1, mid + 1 :], t.step[:, :, mid - 1, :, None, None]
            )
        prev = seq[:, np.clip(layer - 1, 0, length - 1)][:, None, :]  # set at layer k-1
        tail = _fwd_step(vec, _blocks(view, prev, seq[:, :, None]))  # s_i in layer k
        far = _lowest(tail + _take(out_of, rows, np.clip(lk, 0, length - 2), s_i))
        cost = np.where(lk >= li + 2, far, cost)
    return _Moves("swap", cost, np.zeros_like(cost), valid)


def _best_slots(t: _Tables) -> np.ndarray:
    """[W, L] slot of a best node of every layer: argmin of forward + backward tables.

    (With ties the slots may mix two optimal tours; scores built on them stay upper
    bounds, which is all the reversal moves need.)
    """
    slots = np.argmin(t.fwd + t.bwd, axis=0)  # [W, L]
    layer = np.arange(t.seq.shape[1])[None, :]
    return np.where((layer >= 1) & (layer <= t.m[:, None]), slots, 0)


def _reversal_moves(view: SetView, t: _Tables) -> _Moves:
    """Reversal of visited layers i..k (k >= i + 2): [W, i, k], scored with the current nodes.

    The score is the cost of the reversed tour with every node kept, an upper bound of its
    exact cost (the DP may pick better nodes afterwards), so an improving score is a true
    improvement. Computed in O(1) per pair from prefix sums of forward and backward edges.
    """
    seq, length = t.seq, t.seq.shape[1]
    w = seq.shape[0]
    q, k_sets = view.block.shape[0], view.block.shape[2]
    flat = view.block.reshape(-1)
    slots = _best_slots(t)

    def edge(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
        """Cost from layer ``src`` to layer ``dst`` with the current nodes (per element)."""
        rows = np.arange(w).reshape((w,) + (1,) * (src.ndim - 1))
        a, b = slots[rows, src], slots[rows, dst]
        return flat[((a * q + b) * k_sets + seq[rows, src]) * k_sets + seq[rows, dst]]

    def prefix(e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Finite sums and inf counts apart, so that inf - inf never happens."""
        z = np.zeros((w, 1))
        finite = np.cumsum(np.where(np.isinf(e), 0.0, e), axis=1)
        return np.concatenate([z, finite], 1), np.concatenate([z, np.cumsum(np.isinf(e), 1)], 1)

    layer = np.arange(length)
    step = np.broadcast_to(layer[None, :-1], (w, length - 1))
    f_sum, f_inf = prefix(edge(step, step + 1))  # edge l -> l+1
    b_sum, b_inf = prefix(edge(step + 1, step))  # edge l+1 -> l
    i = np.broadcast_to(layer[None, :, None], (w, length, length))
    k = np.broadcast_to(layer[None, None, :], (w, length, length))
    im1, kp1 = np.clip(i - 1, 0, length - 1), np.clip(k + 1, 0, length - 1)
    rows = np.arange(w)[:, None, None]

    def span(sums: np.ndarray, infs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Kept edges before i-1 and after k+1, plus the reversed middle i..k."""
        return (
            sums[rows, im1] + sums[:, -1:, None] - sums[rows, kp1],
            infs[rows, im1] + infs[:, -1:, None] - infs[rows, kp1],
        )

    kept, kept_inf = span(f_sum, f_inf)
    mid = b_sum[rows, k] - b_sum[rows, i]
    mid_inf = b_inf[rows, k] - b_inf[rows, i]
    links = edge(im1, k) + edge(i, kp1)
    cost = np.where(kept_inf + mid_inf > 0, np.inf, kept + mid + links)
    valid = (i >= 1) & (k >= i + 2) & (k <= t.m[:, None, None])
    return _Moves("reverse", cost, np.zeros_like(cost), valid)


# ----------------------------------------------------------------------------------------
# Applying moves, shakes and the budget fit
# ----------------------------------------------------------------------------------------


def _apply(perm: np.ndarray, m: int, kind: str, a: int, b: int) -> tuple[np.ndarray, int]:
    """Perform one move on a single permutation (indices as in _neighbourhood)."""
    vis, tail = list(perm[:m]), list(perm[m:])
    if kind == "insert":  # gap a, set b
        tail.remove(b)
        vis.insert(a, b)
        return np.array(vis + tail), m + 1
    if kind == "replace":  # layer a + 1, set b
        tail[tail.index(b)] = vis[a]
        vis[a] = b
        return np.array(vis + tail), m
    if kind == "relocate":  # layer a into gap b
        s = vis.pop(a - 1)
        vis.insert(b if b < a else b - 1, s)
        return np.array(vis + tail), m
    if kind == "swap":  # layers a < b
        vis[a - 1], vis[b - 1] = vis[b - 1], vis[a - 1]
        return np.array(vis + tail), m
    if kind == "reverse":  # layers a..b
        vis[a - 1 : b] = vis[a - 1 : b][::-1]
        return np.array(vis + tail), m
    raise AssertionError(kind)


def _prefix_costs(view: SetView, perm: np.ndarray) -> np.ndarray:
    """[W, M+1] cost of the tour visiting the first p permutation entries, p = 0..M."""
    w, msets = perm.shape
    q = view.members.shape[1]
    fwd = np.repeat(_point(q)[:, None], w, axis=1)  # [Q, W]
    out = np.empty((w, msets + 1))
    layers = np.concatenate([np.full((w, 1), view.start_set), perm], axis=1).T  # [M+1, W]
    steps = _blocks(view, layers[:-1], layers[1:])  # [Q, Q, M, W]
    close = _blocks(view, layers, view.end_set)[:, 0]  # [Q, M+1, W]: slot -> end
    out[:, 0] = _lowest(fwd + close[:, 0])
    for p in range(msets):
        fwd = _fwd_step(fwd, steps[:, :, p])
        out[:, p + 1] = _lowest(fwd + close[:, p + 1])
    return out


def _fit(view: SetView, perm: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Drop sets from the end while over budget, then append the next ones while they fit."""
    close = _prefix_costs(view, perm)
    fits = close <= view.budget
    out = m.copy()
    for w in range(perm.shape[0]):
        p = int(m[w])
        while p > 0 and not fits[w, p]:
            p -= 1
        while p < perm.shape[1] and fits[w, p + 1]:
            p += 1
        out[w] = p
    return out


def _shakes(
    perm: np.ndarray, m: int, which: int, width: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """``width`` random segment moves (1) or segment exchanges (2) of one permutation.

    Returns permutations [W, M] and visited counts [W]. Moved entries count as visited
    when they land inside the visited prefix and as unvisited otherwise; the new visited
    prefix is the leading run of visited entries. Entries are reordered by sorting keys:
    a moved segment gets keys just below the position it lands before.
    """
    n = perm.shape[0]
    perms = np.broadcast_to(perm, (width, n))
    if n < 2 + which:
        return perms.copy(), np.full(width, m)
    cuts = np.sort(np.argsort(rng.random((width, n)), axis=1)[:, : 2 + which], axis=1)
    pos = np.arange(n)[None, :]
    visited = np.broadcast_to(pos < m, (width, n))
    step = 1.0 / (n + 1)  # keeps a moved segment in order between two integer keys
    if which == 1:
        a, b, c = (cuts[:, i : i + 1] for i in range(3))
        up = rng.random((width, 1)) < 0.5
        # up: [a, b] moves before position c; down: [b, c] moves to position a
        seg = np.where(up, (pos >= a) & (pos <= b), (pos >= b) & (pos <= c))
        lands = np.where(up, c, a)
        first = np.where(up, a, b)
        key = np.where(seg, lands - 1 + (pos - first + 1) * step, pos)
        tag = np.where(seg, lands < m, visited)
    else:
        a, b, c, d = (cuts[:, i : i + 1] for i in range(4))
        low, high = (pos >= a) & (pos <= b), (pos >= c) & (pos <= d)
        key = np.where(high, a - 1 + (pos - c + 1) * step, pos)
        key = np.where(low, c - 1 + (pos - a + 1) * step, key)
        tag = np.where(high, a < m, np.where(low, c < m, visited))
    order = np.argsort(key, axis=1, kind="stable")
    new_tag = np.take_along_axis(tag, order, axis=1)
    run = np.where(new_tag.all(axis=1), n, np.argmin(new_tag, axis=1))
    return np.take_along_axis(perms, order, axis=1), run


# ----------------------------------------------------------------------------------------
# Local search and the VNS loop
# ----------------------------------------------------------------------------------------


def _tolerances(view: SetView) -> tuple[float, float]:
    return 1e-9 * max(1.0, float(view.reward.sum())), 1e-9 * max(1.0, view.budget)


def _local_search(
    view: SetView,
    perm: np.ndarray,
    m: np.ndarray,
    which: int,
    rng: np.random.Generator,
    trades: bool = False,
    reversals: bool = False,
    order_only: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Random first-improvement local search ``which`` on a batch, n^2 trials each.

    With ``trades``, as in the published code, a replacement is also taken when it
    shortens the tour while lowering the reward; the set it removes may not come back
    during the same search, which rules out trade / re-insert cycles.

    With ``order_only`` only the moves that keep the visited sets (relocate, swap,
    reversal) are tried, the budget is ignored and the search runs to a local minimum of
    the tour cost (used to repair a tour that is slightly over budget).
    """
    w = perm.shape[0]
    trials_left = np.full(w, np.inf if order_only else float(view.num_sets) ** 2)
    budget = np.inf if order_only else view.budget
    active = np.ones(w, bool)
    banned = np.zeros((w, view.num_sets), bool)
    eps_r, eps_l = _tolerances(view)
    perm, m = perm.copy(), m.copy()
    while active.any():
        idx = np.flatnonzero(active)
        t = _tables(view, perm[idx], m[idx])
        moves = _neighbourhood(view, perm[idx], m[idx], t, which, reversals)
        for mv in moves:
            if mv.kind in ("insert", "replace"):
                mv.valid = mv.valid & ~banned[idx, None, :] & (not order_only)
        cost = np.concatenate([mv.cost.reshape(len(idx), -1) for mv in moves], axis=1)
        gain = np.concatenate([mv.gain.reshape(len(idx), -1) for mv in moves], axis=1)
        valid = np.concatenate([mv.valid.reshape(len(idx), -1) for mv in moves], axis=1)
        trade = np.concatenate(
            [np.full(mv.cost[0].size, trades and mv.kind == "replace") for mv in moves]
        )
        shorter = cost < t.length[:, None] - eps_l
        better = valid & (cost <= budget)
        better &= (gain > eps_r) | (((np.abs(gain) <= eps_r) | trade[None, :]) & shorter)
        n_valid = valid.sum(axis=1)
        n_better = better.sum(axis=1)
        # a uniformly random improving move: what the first improving random trial would be
        target = np.floor(rng.random(len(idx)) * n_better)
        pick = np.argmax(np.cumsum(better, axis=1) > target[:, None], axis=1)
        p = np.where(n_better > 0, n_better / np.maximum(n_valid, 1), 1.0)
        cost_trials = rng.geometric(p)
        sizes = np.cumsum([0] + [mv.cost[0].size for mv in moves])
        kinds = (np.searchsorted(sizes, pick, side="right") - 1).tolist()
        pick, gain_pick = pick.tolist(), gain[np.arange(len(idx)), pick].tolist()
        for r, wi in enumerate(idx.tolist()):
            if n_better[r] == 0 or cost_trials[r] > trials_left[wi]:
                active[wi] = False
                continue
            trials_left[wi] -= cost_trials[r]
            mv = moves[kinds[r]]
            a, b = divmod(pick[r] - int(sizes[kinds[r]]), mv.cost.shape[2])
            if mv.kind == "replace" and gain_pick[r] < -eps_r:
                banned[wi, perm[wi][a]] = True
            perm[wi], m[wi] = _apply(perm[wi], int(m[wi]), mv.kind, a, b)
    return perm, m


def _reorder(
    view: SetView, perm: np.ndarray, m: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Both local searches with order-only moves (budget ignored) on a batch."""
    for which in (1, 2):
        perm, m = _local_search(view, perm, m, which, rng, reversals=True, order_only=True)
    return perm, m


def _tighten(
    view: SetView, perm: np.ndarray, m: int, rng: np.random.Generator
) -> tuple[np.ndarray, int]:
    """Shorten the tour of one solution with order-only moves until no move helps."""
    batch, ms = perm[None].copy(), np.array([m])
    length = float(_score(view, batch, ms)[1][0])
    while True:
        batch, ms = _reorder(view, batch, ms, rng)
        new = float(_score(view, batch, ms)[1][0])
        if not new < length - _tolerances(view)[1]:
            return batch[0], int(ms[0])
        length = new


def _shortest_order(
    view: SetView,
    perm: np.ndarray,
    m: int,
    rng: np.random.Generator,
    restarts: int,
    deadline: float = np.inf,
) -> tuple[np.ndarray, int, float]:
    """A short tour through the visited sets of ``perm``: order-only local search from the
    given order and from ``restarts`` random orders of the same sets (no new start after
    ``deadline``, a ``time.perf_counter`` value); the shortest wins."""
    starts = [perm]
    for _ in range(restarts if m <= RESTART_MAX_SETS else 0):
        starts.append(np.concatenate([rng.permutation(perm[:m]), perm[m:]]))
    best = None
    for r, order in enumerate(starts):
        if r > 0 and time.perf_counter() > deadline:
            break
        cand, cm = _tighten(view, order, m, rng)
        length = float(_score(view, cand[None], np.array([cm]))[1][0])
        if best is None or length < best[2]:
            best = (cand, cm, length)
        if length <= view.budget:
            break
    return best


def _squeeze(
    view: SetView,
    perm: np.ndarray,
    m: int,
    rng: np.random.Generator,
    slack: float,
    tries: int,
    restarts: int = 3,
    ejections: int = 2,
    deadline: float = np.inf,
) -> tuple[np.ndarray, int] | None:
    """Intensification for tight budgets: a better set selection that needs a new order.

    The budget-respecting neighbourhoods cannot reach a better solution whose tour needs
    a reordering *and* another set at once. For each of the ``tries`` unvisited sets with
    the cheapest insertion that overshoots the budget by at most ``slack``: insert it and
    search a short order for the enlarged selection (order-only local search from the
    current order and ``restarts`` random ones); if it still does not fit, eject one of
    the ``ejections`` lower-reward visited sets whose removal shortens that tour most and
    search again. Returns the first feasible selection with more reward, or None (also
    when ``deadline``, a ``time.perf_counter`` value, has passed).
    """
    t = _tables(view, perm[None], np.array([m]))
    into, out_of = _gap_tables(view, t)
    cost = _lowest(into + out_of)[0]  # [L-1, M]
    unvisited = ~_visited_mask(view, perm[None], np.array([m]))[0]
    ok = unvisited[None, :] & (np.arange(cost.shape[0])[:, None] <= m)
    ok &= (cost > view.budget) & (cost <= view.budget * (1.0 + slack))
    cand = np.where(ok, cost, np.inf)
    best_gap = np.argmin(cand, axis=0)  # the cheapest gap of every set
    best = cand[best_gap, np.arange(cand.shape[1])]
    reward = view.reward
    for s in np.argsort(best, kind="stable")[:tries]:
        if not np.isfinite(best[s]) or time.perf_counter() > deadline:
            break
        trial, tm = _apply(perm, m, "insert", int(best_gap[s]), int(s))
        trial, tm, length = _shortest_order(view, trial, tm, rng, restarts, deadline)
        if length <= view.budget:
            return trial, tm
        others = [i for i in range(tm) if trial[i] != s and reward[trial[i]] < reward[s]]
        if not others:
            continue
        ejected = np.stack([np.append(np.delete(trial, i), trial[i]) for i in others])
        _, shorter = _score(view, ejected, np.full(len(others), tm - 1))
        for j in np.argsort(shorter, kind="stable")[:ejections]:
            if time.perf_counter() > deadline:
                return None
            out, om, length = _shortest_order(view, ejected[j], tm - 1, rng, restarts, deadline)
            if length <= view.budget:
                return out, om
    return None


def _repair(
    view: SetView,
    perm: np.ndarray,
    m: np.ndarray,
    rng: np.random.Generator,
    restarts: int,
    restart_rows: int = 32,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Shorten a batch of over-budget tours with order-only local search from the given
    orders; the ``restart_rows`` rows that still overshoot least (and visit at most
    ``RESTART_MAX_SETS`` sets) search again from ``restarts`` random orders of the same
    sets, side by side. Returns the shortest (perm, m) per row and whether it fits."""
    perm, m = _reorder(view, perm, m, rng)
    length = _score(view, perm, m)[1]
    retry = np.flatnonzero((length > view.budget) & (m <= RESTART_MAX_SETS))
    retry = retry[np.argsort(length[retry], kind="stable")[:restart_rows]]
    if restarts and retry.size:
        n, msets = retry.size, perm.shape[1]
        pos = np.arange(msets)[None, :]
        pm = np.tile(m[retry], restarts)
        keys = np.where(pos < pm[:, None], rng.random((restarts * n, msets)), 1.0 + pos)
        base = np.tile(perm[retry], (restarts, 1))
        p = np.take_along_axis(base, np.argsort(keys, axis=1), axis=1)
        p, pm = _reorder(view, p, pm, rng)
        found = _score(view, p, pm)[1].reshape(restarts, n)
        best = np.argmin(found, axis=0)
        better = found[best, np.arange(n)] < length[retry]
        take = best * n + np.arange(n)
        perm, m, length = perm.copy(), m.copy(), length.copy()
        perm[retry[better]] = p[take[better]]
        m[retry[better]] = pm[take[better]]
        length[retry[better]] = found[best, np.arange(n)][better]
    return perm, m, length <= view.budget


def _fill(
    view: SetView,
    perm: np.ndarray,
    m: np.ndarray,
    banned: np.ndarray,
    rng: np.random.Generator | None = None,
    slack: float = 0.0,
    restarts: int = 3,
) -> tuple[np.ndarray, np.ndarray]:
    """Greedy insertion on a batch (the rule of :func:`greedy_solution`) until nothing
    fits; the sets marked in ``banned`` [W, M] are never inserted.

    With ``slack`` an insertion may overshoot the budget by that fraction: the tour is then
    shortened with order-only moves (random, ``rng`` needed; see :func:`_repair`) and the
    insertion undone (and the set banned for that row) when it still does not fit.
    """
    perm, m, banned = perm.copy(), m.copy(), banned.copy()
    gaps = np.arange(view.num_sets + 1)
    active = np.ones(perm.shape[0], bool)
    while active.any():
        idx = np.flatnonzero(active)
        t = _tables(view, perm[idx], m[idx])
        into, out_of = _gap_tables(view, t)
        cost = _lowest(into + out_of)  # [W, L-1, M]
        ok = cost <= view.budget * (1.0 + slack)
        ok &= gaps[None, : cost.shape[1], None] <= t.m[:, None, None]
        ok &= ~(_visited_mask(view, perm[idx], m[idx]) | banned[idx])[:, None, :]
        with np.errstate(invalid="ignore"):  # inf - inf: a ruined tour cut off by inf edges
            ratio = (cost - t.length[:, None, None]) / view.reward[None, None, : view.num_sets]
        ratio = np.where(ok, ratio, np.inf).reshape(len(idx), -1)
        pick = np.argmin(ratio, axis=1)
        found = np.isfinite(ratio[np.arange(len(idx)), pick])
        over = cost.reshape(len(idx), -1)[np.arange(len(idx)), pick] > view.budget
        active[idx[~found]] = False
        idx, pick, over = idx[found], pick[found], over[found]
        before, before_m = perm[idx].copy(), m[idx].copy()
        for w, flat in zip(idx.tolist(), pick.tolist(), strict=True):
            gap, s = divmod(flat, view.num_sets)
            perm[w], m[w] = _apply(perm[w], int(m[w]), "insert", gap, s)
        if over.any():
            rows = idx[over]
            p, pm, fits = _repair(view, perm[rows], m[rows], rng, restarts)
            perm[rows] = np.where(fits[:, None], p, before[over])
            m[rows] = np.where(fits, pm, before_m[over])
            failed = rows[~fits]
            for w, flat in zip(failed.tolist(), pick[over][~fits].tolist(), strict=True):
                banned[w, flat % view.num_sets] = True
    return perm, m


def _recreate(
    view: SetView,
    perm: np.ndarray,
    m: int,
    rng: np.random.Generator,
    slack: float,
    rows: int = 256,
    restarts: int = 3,
) -> tuple[np.ndarray, int, float, float]:
    """Ruin and recreate: compound selection changes that no single move reaches.

    Removes every visited set and every pair of visited sets (a random sample of at most
    ``rows`` of them), refills each tour greedily without the removed sets, polishes it
    with both local searches and returns the best result (permutation, m, reward, cost).
    """
    ruins = [(i,) for i in range(m)] + [(i, j) for i in range(m) for j in range(i + 1, m)]
    if len(ruins) > rows:
        ruins = [ruins[i] for i in np.sort(rng.choice(len(ruins), rows, replace=False))]
    perms = np.empty((len(ruins), perm.shape[0]), perm.dtype)
    banned = np.zeros((len(ruins), view.num_sets), bool)
    for r, out in enumerate(ruins):
        gone = perm[list(out)]
        perms[r] = np.concatenate([np.delete(perm[:m], out), gone, perm[m:]])
        banned[r, gone] = True
    ms = np.array([m - len(out) for out in ruins])
    perms, ms = _reorder(view, perms, ms, rng)
    perms, ms = _fill(view, perms, ms, banned, rng, slack, restarts)
    for which in (1, 2):
        perms, ms = _local_search(view, perms, ms, which, rng, reversals=True)
    rew, cost = _score(view, perms, ms)
    j = int(np.lexsort((cost, -rew))[0])
    return perms[j], int(ms[j]), float(rew[j]), float(cost[j])


def _better(r1: float, c1: float, r0: float, c0: float, view: SetView) -> bool:
    eps_r, eps_l = _tolerances(view)
    return r1 > r0 + eps_r or (abs(r1 - r0) <= eps_r and c1 < c0 - eps_l)


def _score(view: SetView, perm: np.ndarray, m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[W] reward and cost of a batch of solutions."""
    t = _tables(view, perm, m)
    vis = _visited_mask(view, perm, m)
    return (vis * view.reward[None, : view.num_sets]).sum(axis=1), t.length


def greedy_solution(view: SetView) -> tuple[np.ndarray, int]:
    """Greedy insertion by the smallest added length per unit reward: (permutation, m)."""
    msets = view.num_sets
    perm, m = _fill(view, np.arange(msets)[None], np.zeros(1, int), np.zeros((1, msets), bool))
    return perm[0], int(m[0])


def _plan(view: SetView, perm: np.ndarray, m: int) -> list[int]:
    """Node ids of the best node choice for the set order perm[:m] (start ... end)."""
    t = _tables(view, perm[None], np.array([m]))
    seq, fwd = t.seq[0], t.fwd[:, 0, :].T
    slots = [0] * (m + 2)
    nxt = 0
    for layer in range(m, 0, -1):
        blk = view.block[:, nxt, seq[layer], seq[layer + 1]]
        nxt = int(np.argmin(fwd[layer] + blk))
        slots[layer] = nxt
    nodes = [view.start] + [int(view.members[seq[i], slots[i]]) for i in range(1, m + 1)]
    if view.end >= 0:
        nodes.append(view.end)
    return nodes


def _solution(instance: SOPInstance, nodes: list[int]) -> Solution:
    reward, cost, _ = evaluate(instance, nodes)
    return Solution(
        nodes=np.asarray(nodes, np.int32), reward=np.float32(reward), cost=np.float32(cost)
    )


def empty_solution(instance: SOPInstance) -> Solution:
    """The plan that visits nothing: [start] (open path) or [start, end]."""
    inst = instance.to_numpy()
    nodes = [int(inst.start)] + ([int(inst.end)] if int(inst.end) >= 0 else [])
    return _solution(inst, nodes)


def solve_greedy(instance: SOPInstance) -> Solution:
    """Greedy insertion plan (the VNS start): cheapest added length per unit reward.

    Deterministic and fast (one batched insertion evaluation per added set); unpadded nodes.
    """
    inst = instance.to_numpy()
    view = set_view(inst)
    if view.num_sets == 0:
        return empty_solution(inst)
    perm, m = greedy_solution(view)
    return _solution(inst, _plan(view, perm, m))


def solve_vns(
    instance: SOPInstance,
    seed: int = 0,
    max_iters: int = 2000,
    max_no_improve: int = 1000,
    time_limit: float | None = None,
    width: int | None = None,
    trades: bool = False,
    reversals: bool = True,
    squeeze: float = 0.3,
    squeeze_tries: int = 3,
    recreate: bool = True,
    return_greedy: bool = False,
) -> Solution | tuple[Solution, Solution]:
    """Solve one SOP instance with the VNS teacher (NumPy).

    Args:
        instance: a single (unbatched) instance, NumPy or JAX leaves.
        seed: seed of the ``np.random.Generator``; equal seeds give equal solutions.
        max_iters: VNS iterations (reference config 2000).
        max_no_improve: stop after this many iterations without improvement (1000).
        time_limit: optional wall-clock limit in seconds (checked between batches).
        width: iterations evaluated side by side (default: from the instance size).
        trades: let local search 2 replace a set by a cheaper, lower-reward one when that
            shortens the tour (the published code's rule; see docs/sop.md).
        reversals: add segment reversals (2-opt) of the visited order to local search 2,
            scored with the current nodes (an addition to the published method that
            helps on tight budgets; see docs/sop.md).
        squeeze: when the search stagnates, insert one more set even though the tour
            then overshoots the budget by at most this fraction, shorten it with
            order-only moves and keep it if it fits (0 disables; see docs/sop.md). The
            same slack bounds the insertions of ``recreate``.
        squeeze_tries: how many of the cheapest overshooting insertions are tried (random
            order restarts only for selections of at most ``RESTART_MAX_SETS`` sets, where
            a random order is quick to repair; ``time_limit`` also bounds it).
        recreate: when the search stagnates and ``squeeze`` finds nothing, try ruin and
            recreate: remove every visited set and pair of visited sets, refill greedily
            without them and keep the best result if it improves (see docs/sop.md).
        return_greedy: also return the greedy initial solution.

    Returns:
        A feasible :class:`Solution` (unpadded nodes: start first; end last when the
        instance has one). An instance with nothing reachable gives the start-only plan.
    """
    inst = instance.to_numpy()
    view = set_view(inst)
    rng = np.random.default_rng(seed)
    if view.num_sets == 0:
        sol = empty_solution(inst)
        return (sol, sol) if return_greedy else sol
    perm, m = greedy_solution(view)
    greedy = _solution(inst, _plan(view, perm, m))
    q = view.members.shape[1]
    if width is None:
        width = int(np.clip(24000 // (view.num_sets * q * q), 1, 48))
    best_r, best_c = (float(x[0]) for x in _score(view, perm[None], np.array([m])))
    t0 = time.perf_counter()
    it, last = 0, 0
    while it < max_iters and it - last < max_no_improve:
        if time_limit is not None and time.perf_counter() - t0 > time_limit:
            break
        k = 1
        while k <= 2:
            batch, ms = _shakes(perm, m, k, width, rng)
            ms = _fit(view, batch, ms)
            batch, ms = _local_search(view, batch, ms, k, rng, trades, reversals)
            rew, cost = _score(view, batch, ms)
            order = np.lexsort((cost, -rew))
            j = int(order[0])
            if _better(float(rew[j]), float(cost[j]), best_r, best_c, view):
                perm, m, best_r, best_c = batch[j], int(ms[j]), float(rew[j]), float(cost[j])
                last = it + width
                k = 1
            else:
                k += 1
        it += width
        if it >= max_iters or it - last >= max_no_improve:
            # stagnation: before stopping, try the budget-overshoot intensification once
            # per incumbent; a success resets the no-improvement count
            deadline = np.inf if time_limit is None else t0 + time_limit
            squeezed = None
            if squeeze:
                squeezed = _squeeze(view, perm, m, rng, squeeze, squeeze_tries, deadline=deadline)
            if squeezed is None and recreate and time.perf_counter() < deadline:
                p2, m2, r2, c2 = _recreate(view, perm, m, rng, squeeze)
                if _better(r2, c2, best_r, best_c, view):
                    squeezed = p2, m2
            if squeezed is not None and it < max_iters:
                perm, m = squeezed
                best_r, best_c = (float(x[0]) for x in _score(view, perm[None], np.array([m])))
                last = it
            elif squeezed is not None:
                perm, m = squeezed
    sol = _solution(inst, _plan(view, perm, m))
    return (sol, greedy) if return_greedy else sol
