"""Layered min-plus DP on batches of set orders, and the scores built on it.

For a fixed order of the visited sets a forward table (best cost from the start to every
node slot of every layer) and a backward table (best cost from a slot to the end) pick the
best node of every set exactly; the tables of the tour with one set inserted
(:func:`_gap_tables`) or removed (:func:`_skip_tables`) score whole neighbourhoods in one
batched pass (:mod:`bfsop_jax.sop.vns.moves`).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from bfsop_jax.sop.vns.setview import SetView

__all__: list[str] = []


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


def _visited_mask(view: SetView, perm: np.ndarray, m: np.ndarray) -> np.ndarray:
    """[W, M] bool: set visited."""
    w, msets = perm.shape
    vis = np.zeros((w, msets), bool)
    pos = np.arange(msets)[None, :] < m[:, None]
    rows = np.repeat(np.arange(w), msets).reshape(w, msets)
    vis[rows, perm] = pos
    return vis


def _tolerances(view: SetView) -> tuple[float, float]:
    return 1e-9 * max(1.0, float(view.reward.sum())), 1e-9 * max(1.0, view.budget)


def _better(r1: float, c1: float, r0: float, c0: float, view: SetView) -> bool:
    eps_r, eps_l = _tolerances(view)
    return r1 > r0 + eps_r or (abs(r1 - r0) <= eps_r and c1 < c0 - eps_l)


def _score(view: SetView, perm: np.ndarray, m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[W] reward and cost of a batch of solutions."""
    t = _tables(view, perm, m)
    vis = _visited_mask(view, perm, m)
    return (vis * view.reward[None, : view.num_sets]).sum(axis=1), t.length


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
