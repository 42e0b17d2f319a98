"""Local search and the intensifications of the VNS (all on batches of solutions).

* :func:`_local_search`: random first-improvement local search 1 or 2, emulated from the
  exact costs of all moves (a uniformly random improving move is taken, the trials it
  would have cost are drawn from the matching geometric law);
* order-only repair of over-budget tours (:func:`_reorder`, :func:`_tighten`,
  :func:`_shortest_order`, :func:`_repair`);
* greedy insertion with an optional budget overshoot (:func:`_fill`, the greedy start);
* the two intensifications run when the stop rule fires: :func:`_squeeze` (insert a set
  that overshoots the budget, then repair the order) and :func:`_recreate` (ruin and
  recreate of one or two visited sets).
"""

from __future__ import annotations

import time

import numpy as np

from bfsop_jax.sop.vns.dp import (
    _gap_tables,
    _lowest,
    _score,
    _tables,
    _tolerances,
    _visited_mask,
)
from bfsop_jax.sop.vns.moves import _apply, _neighbourhood
from bfsop_jax.sop.vns.setview import SetView

__all__ = ["RESTART_MAX_SETS"]

RESTART_MAX_SETS = 24  # the intensification restarts from random orders only up to this size


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
    if m == 0:  # nothing visited, nothing to ruin: the incumbent as it is
        rew, cost = _score(view, perm[None], np.array([m]))
        return perm, m, float(rew[0]), float(cost[0])
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
