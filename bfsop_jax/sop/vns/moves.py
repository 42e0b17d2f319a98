"""Moves of the VNS: exact costs of whole neighbourhoods, applying a move, shakes, budget fit.

Every move of a neighbourhood is evaluated exactly in one batched min-plus pass from the DP
tables (:mod:`bfsop_jax.sop.vns.dp`): insertion and relocation (local search 1),
replacement, swap and segment reversal (local search 2). Index conventions: layer i = 1..m
is the i-th visited set; gap j lies between layers j and j + 1 (j = 0..m); sets s are
compact set ids.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from bfsop_jax.sop.vns.dp import (
    _blocks,
    _fwd_step,
    _gap_tables,
    _lowest,
    _point,
    _skip_tables,
    _Tables,
    _take,
    _visited_mask,
)
from bfsop_jax.sop.vns.setview import SetView

__all__: list[str] = []


# ----------------------------------------------------------------------------------------
# Neighbourhoods: every move of a batch of solutions at once
# ----------------------------------------------------------------------------------------


@dataclasses.dataclass
class _Moves:
    kind: str
    cost: np.ndarray  # [W, A, B] tour cost after the move
    gain: np.ndarray  # [W, A, B] reward change
    valid: np.ndarray  # [W, A, B] move exists


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
