"""Episode metrics: optimal visit length, PPL, revisit share and bootstrap intervals.

Host-side post-processing of recorded episodes, in plain NumPy (no JAX):

* :func:`optimal_visit_length` -- the shortest open path (metres) that leaves the start node
  and visits every target once, without returning: exact Held-Karp dynamic programming up to
  :data:`EXACT_MAX` targets, an iterated local search (2-opt and or-opt moves, double-bridge
  kicks) above.
* :func:`ppl` -- progress weighted by path length, ``P * min(1, l_opt / L)`` with
  ``P = found / total``.
* :func:`revisit_fraction` -- the share of the travelled length spent moving into planning
  cells that were already visited.
* :func:`bootstrap_ci` and :func:`paired_bootstrap_ci` -- seeded percentile bootstrap
  intervals of a mean over episodes, and of a paired difference of means; with ``groups``
  (e.g. the house of each episode) whole groups are resampled (a cluster bootstrap), the
  interval for new groups rather than for new episodes of the same groups.
"""

from __future__ import annotations

import functools

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "EXACT_MAX",
    "EXACT_FORCE_MAX",
    "optimal_visit_length",
    "ppl",
    "revisit_fraction",
    "bootstrap_ci",
    "paired_bootstrap_ci",
    "paired_ratio_ci",
]

EXACT_MAX = 18
"""Largest number of targets F solved exactly by Held-Karp in automatic mode (up to here it
is no slower than the heuristic, about 0.3 s at 18: ``python -m benchmarks.bench_metrics``)."""

EXACT_FORCE_MAX = 20
"""Largest F accepted with ``exact=True`` (the DP table has ``2**F * F`` entries: 168 MB at 20)."""

_OR_OPT_MAX_SEGMENT = 3
_ILS_RESTARTS = 3  # iterated local searches, each from its own start (heuristic above EXACT_MAX)
_ILS_KICKS = 400  # double-bridge kicks at most in each
_ILS_STALL = 150  # ... stopping after this many in a row without a shorter path
_ILS_SEED = 0  # the generator of kicks and starts: a matrix always gives the same length
_BOOT_CHUNK = 4_000_000  # resampled indices held in memory at once


# ---------------------------------------------------------------------------------------------
# Optimal visit length
# ---------------------------------------------------------------------------------------------


def _validate_dist(dist: ArrayLike) -> np.ndarray:
    try:
        d = np.asarray(dist, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"dist must be a numeric matrix: {exc}") from None
    if d.ndim != 2:
        raise ValueError(f"dist must be a 2-D matrix, got {d.ndim} dimension(s)")
    if d.shape[0] != d.shape[1]:
        raise ValueError(f"dist must be square, got shape {d.shape}")
    if d.shape[0] == 0:
        raise ValueError("dist must hold at least the start node (shape [F+1, F+1], F >= 0)")
    if np.isnan(d).any():
        raise ValueError("dist must not contain NaN")
    if (d < 0).any():
        raise ValueError("dist must be non-negative (use +inf for unreachable pairs)")
    return d


def _path_cost(d: np.ndarray, path: np.ndarray) -> float:
    """Length of the open path visiting ``path`` in order (sum of ``d[path[k], path[k+1]]``)."""
    if len(path) < 2:
        return 0.0
    return float(d[path[:-1], path[1:]].sum())


def _held_karp(d: np.ndarray) -> float:
    """Exact shortest open path from node 0 through all other nodes (Held-Karp).

    ``dp[mask, k]`` is the shortest path that starts at node 0, visits exactly the targets in
    ``mask`` (bit ``j`` <-> node ``j + 1``) and ends at target ``k``. Subsets are processed by
    size; within a size, one vectorised update per end target.
    """
    f = d.shape[0] - 1
    if f == 0:
        return 0.0
    start = d[0, 1:]
    inner = d[1:, 1:]
    n_masks = 1 << f
    masks = np.arange(n_masks, dtype=np.int64)
    popcount = np.zeros(n_masks, dtype=np.int64)
    for b in range(f):
        popcount += (masks >> b) & 1
    dp = np.full((n_masks, f), np.inf)
    singles = np.arange(f)
    dp[1 << singles, singles] = start
    for size in range(2, f + 1):
        level = masks[popcount == size]
        for k in range(f):
            bit = 1 << k
            sel = level[(level & bit) != 0]
            prev = sel ^ bit
            # dp[prev, k] is inf (k not in prev), so the diagonal d[k, k] never contributes.
            dp[sel, k] = np.min(dp[prev] + inner[None, :, k], axis=1)
    return float(dp[n_masks - 1].min())


def _nearest_neighbour(w: np.ndarray) -> np.ndarray:
    n = w.shape[0]
    path = np.zeros(n, dtype=np.int64)
    visited = np.zeros(n, dtype=bool)
    visited[0] = True
    cur = 0
    for step in range(1, n):
        row = np.where(visited, np.inf, w[cur])
        cur = int(np.argmin(row))
        visited[cur] = True
        path[step] = cur
    return path


def _prefix_costs(path: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Prefix sums ``[n]`` of the path's edge costs walked forward and walked backward."""
    fwd = w[path[:-1], path[1:]]
    bwd = w[path[1:], path[:-1]]
    return np.concatenate(([0.0], np.cumsum(fwd))), np.concatenate(([0.0], np.cumsum(bwd)))


@functools.cache
def _two_opt_moves(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Every 2-opt move ``(i, j)``, ``1 <= i < j <= n-1``, of an open path of ``n`` nodes."""
    ii, jj = np.triu_indices(n - 1, k=1)
    return ii + 1, jj + 1


def _best_two_opt(
    path: np.ndarray, w: np.ndarray, cf: np.ndarray, cb: np.ndarray
) -> tuple[float, tuple[int, int]]:
    """Best 2-opt move for an open path with a fixed first node: ``(delta, (i, j))``.

    Move ``(i, j)``, ``1 <= i < j <= n-1``, reverses ``path[i..j]``. Costs may be asymmetric:
    the reversed inner edges are charged in the backward direction (the prefix sums ``cf``,
    ``cb`` of :func:`_prefix_costs` give every move's delta in one vectorised evaluation).
    """
    n = len(path)
    ii, jj = _two_opt_moves(n)
    a, b, c = path[ii - 1], path[ii], path[jj]
    e = path[np.minimum(jj + 1, n - 1)]
    delta = (w[a, c] - w[a, b]) + (cb[jj] - cb[ii]) - (cf[jj] - cf[ii])
    delta = delta + np.where(jj < n - 1, w[b, e] - w[c, e], 0.0)
    m = int(np.argmin(delta))
    return float(delta[m]), (int(ii[m]), int(jj[m]))


def _best_or_opt(
    path: np.ndarray, w: np.ndarray, cf: np.ndarray, cb: np.ndarray
) -> tuple[float, tuple[int, int, int, bool]]:
    """Best or-opt move: ``(delta, (i, s, t, reverse))`` moves the segment ``path[i:i+s]``
    (1..3 nodes, ``i >= 1``), reversed or not, to just after ``path[t]`` (``t = n-1``
    appends it at the end). Every segment and insertion point is evaluated at once."""
    n = len(path)
    t = np.arange(n)
    has_next = t < n - 1
    nxt = path[np.minimum(t + 1, n - 1)]
    opened = np.where(has_next, w[path, nxt], 0.0)  # [n] edge cut at each insertion point
    best: tuple[float, tuple[int, int, int, bool]] = (np.inf, (0, 0, 0, False))
    for s in range(1, min(_OR_OPT_MAX_SEGMENT, n - 2) + 1):
        i = np.arange(1, n - s + 1)  # [m] segment starts
        j = i + s - 1  # segment ends
        after = path[np.minimum(j + 1, n - 1)]
        closed = np.where(j < n - 1, w[path[i - 1], after] - w[path[j], after], 0.0)
        removal = closed - w[path[i - 1], path[i]]  # [m]
        head, tail = path[i][:, None], path[j][:, None]
        a, b = path[None, :], nxt[None, :]
        legal = (t[None] <= (i - 2)[:, None]) | (t[None] >= (j + 1)[:, None])  # [m, n]
        variants = [(False, w[a, head] + np.where(has_next, w[tail, b], 0.0))]
        if s > 1:
            turned = (cb[j] - cb[i]) - (cf[j] - cf[i])
            variants.append((True, w[a, tail] + np.where(has_next, w[head, b], 0.0)
                             + turned[:, None]))  # fmt: skip
        for reverse, insert in variants:
            delta = np.where(legal, removal[:, None] + insert - opened[None], np.inf)
            k = int(np.argmin(delta))
            if delta.flat[k] < best[0]:
                best = (float(delta.flat[k]), (int(i[k // n]), s, k % n, reverse))
    return best


def _apply_or_opt(path: np.ndarray, move: tuple[int, int, int, bool]) -> np.ndarray:
    i, s, t, reverse = move
    seg = path[i : i + s][::-1] if reverse else path[i : i + s]
    rest = np.concatenate((path[:i], path[i + s :]))
    at = t + 1 if t < i else t + 1 - s  # just after the old path[t] in ``rest``
    return np.concatenate((rest[:at], seg, rest[at:]))


def _local_search(path: np.ndarray, w: np.ndarray, tol: float) -> np.ndarray:
    """Apply the best 2-opt or or-opt move while one shortens the path by more than ``tol``."""
    if len(path) < 3:
        return path
    for _ in range(10 * len(path) ** 2):  # a bound only: each move shortens the path
        cf, cb = _prefix_costs(path, w)
        gain2, (i, j) = _best_two_opt(path, w, cf, cb)
        gain3, move = _best_or_opt(path, w, cf, cb)
        if min(gain2, gain3) >= -tol:
            break
        if gain2 <= gain3:
            path = np.concatenate((path[:i], path[i : j + 1][::-1], path[j + 1 :]))
        else:
            path = _apply_or_opt(path, move)
    return path


def _kicked_search(
    path: np.ndarray, w: np.ndarray, tol: float, rng: np.random.Generator
) -> tuple[np.ndarray, float]:
    """Local search from ``path``, then double-bridge kicks of the best path so far, each
    followed by local search and kept when shorter: ``(best path, its cost under w)``.

    A kick swaps two consecutive segments (three cut points drawn from ``rng``); up to
    ``_ILS_KICKS`` kicks, stopping after ``_ILS_STALL`` in a row that do not improve.
    """
    n = len(path)
    best = _local_search(path, w, tol)
    best_cost = _path_cost(w, best)
    stall = 0
    for _ in range(_ILS_KICKS):
        a, b, c = np.sort(rng.choice(np.arange(1, n + 1), size=3, replace=False))
        path = _local_search(np.concatenate((best[:a], best[b:c], best[a:b], best[c:])), w, tol)
        cost = _path_cost(w, path)
        stall += 1
        if cost < best_cost - tol:
            best, best_cost, stall = path, cost, 0
        if stall >= _ILS_STALL:
            break
    return best, best_cost


def _heuristic(d: np.ndarray) -> float:
    """Iterated local search over 2-opt and or-opt moves with double-bridge kicks, run
    ``_ILS_RESTARTS`` times: from the nearest-neighbour path from node 0, then from random
    orders. The generator has a fixed seed, so a matrix always gives the same length.

    Unreachable (+inf) pairs are replaced by a finite penalty larger than any all-finite path
    while searching, so the moves stay well defined; the returned value is the length of the
    shortest path found under the original matrix (+inf if it needs such a pair).
    """
    n = d.shape[0]
    if n <= 2:
        return _path_cost(d, np.arange(n))
    finite = np.isfinite(d)
    max_finite = float(d[finite].max()) if finite.any() else 0.0
    w = np.where(finite, d, (n + 1) * (max_finite + 1.0))
    tol = 1e-9 * max(max_finite, np.finfo(np.float64).tiny)
    if n < 4:  # two orders at most: the local search tries both
        return _path_cost(d, _local_search(_nearest_neighbour(w), w, tol))
    rng = np.random.default_rng(_ILS_SEED)
    best, best_cost = _kicked_search(_nearest_neighbour(w), w, tol, rng)
    for _ in range(_ILS_RESTARTS - 1):
        order = np.concatenate(([0], 1 + rng.permutation(n - 1)))
        path, cost = _kicked_search(order, w, tol, rng)
        if cost < best_cost - tol:
            best, best_cost = path, cost
    return _path_cost(d, best)


def optimal_visit_length(dist: ArrayLike, *, exact: bool | None = None) -> float:
    """Length (metres) of the shortest open path from node 0 through every other node once.

    Args:
      dist: ``[F+1, F+1]`` distances in metres (e.g. geodesic); node 0 is the start and nodes
        ``1..F`` are the targets. ``dist[i, j]`` is the cost of going from ``i`` to ``j``
        (asymmetric matrices are allowed); ``+inf`` marks an unreachable pair; the diagonal is
        ignored. The path does not return to the start.
      exact: ``None`` (automatic): Held-Karp for ``F <= EXACT_MAX``, the heuristic above.
        ``True``: always Held-Karp (``ValueError`` for ``F > EXACT_FORCE_MAX``). ``False``:
        always the heuristic.

    Returns:
      The path length in metres; ``0.0`` for ``F = 0``; ``inf`` when every (found) path needs
      an unreachable pair. The heuristic -- nearest-neighbour construction from the start,
      best-improvement local search over 2-opt and or-opt moves (segments of 1..3 nodes,
      either direction) for open paths, then up to 400 double-bridge kicks, each followed by
      the local search and kept when shorter; three such runs, the second and third from
      random orders -- returns the length of a real path, so it is never below the exact
      optimum; it is deterministic (a fixed seed).

    Raises:
      ValueError: ``dist`` is not a square 2-D matrix of non-negative numbers or ``+inf``, or
        ``exact=True`` with more than ``EXACT_FORCE_MAX`` targets.
    """
    d = _validate_dist(dist)
    if exact is not None and not isinstance(exact, (bool, np.bool_)):
        raise ValueError(f"exact must be True, False or None, got {exact!r}")
    f = d.shape[0] - 1
    if f == 0:
        return 0.0
    if exact is None:
        exact = f <= EXACT_MAX
    if exact:
        if f > EXACT_FORCE_MAX:
            raise ValueError(f"exact=True supports at most {EXACT_FORCE_MAX} targets, got {f}")
        return _held_karp(d)
    return _heuristic(d)


# ---------------------------------------------------------------------------------------------
# PPL
# ---------------------------------------------------------------------------------------------


def ppl(
    found: ArrayLike, total: ArrayLike, path_length: ArrayLike, l_opt: ArrayLike
) -> float | np.ndarray:
    """Progress weighted by path length: ``P * min(1, l_opt / L)`` with ``P = found / total``.

    Args:
      found: number of targets found (scalar or array, broadcast with the others).
      total: number of targets in the episode.
      path_length: ``L``, metres the agent travelled (up to the caller's chosen cut-off).
      l_opt: metres of the optimal visit path (:func:`optimal_visit_length`); may be ``+inf``.

    Returns:
      A float for scalar inputs, else an array of the broadcast shape. The result is 0 where
      ``found == 0`` or ``total == 0``; where ``found > 0`` and ``L <= 0`` (targets verified
      at the start without moving) the efficiency term is 1.

    Raises:
      ValueError: a negative or NaN input, an infinite ``found``/``total``/``path_length``,
        ``found > total``, or shapes that do not broadcast.
    """
    arrs = [np.asarray(x, dtype=np.float64) for x in (found, total, path_length, l_opt)]
    try:
        fo, to, pl, lo = np.broadcast_arrays(*arrs)
    except ValueError as exc:
        raise ValueError(f"ppl inputs do not broadcast: {exc}") from None
    names = ("found", "total", "path_length", "l_opt")
    for name, x in zip(names, (fo, to, pl, lo), strict=True):
        if np.isnan(x).any():
            raise ValueError(f"{name} must not contain NaN")
        if (x < 0).any():
            raise ValueError(f"{name} must be non-negative")
    for name, x in zip(names[:3], (fo, to, pl), strict=True):
        if np.isinf(x).any():
            raise ValueError(f"{name} must be finite")
    if (fo > to).any():
        raise ValueError("found must not exceed total")
    progress = np.divide(fo, to, out=np.zeros_like(fo), where=to > 0)
    moved = pl > 0
    ratio = np.divide(lo, pl, out=np.ones_like(lo), where=moved)
    eff = np.where(moved, np.minimum(1.0, ratio), 1.0)
    out = np.where(fo > 0, progress * eff, 0.0)
    if out.ndim == 0:
        return float(out)
    return out


# ---------------------------------------------------------------------------------------------
# Revisits
# ---------------------------------------------------------------------------------------------


def revisit_fraction(start_cell: ArrayLike, cells: ArrayLike, lengths: ArrayLike) -> float:
    """Share of the travelled length spent on moves into already visited planning cells.

    Args:
      start_cell: int ``[2]``, (row, col) planning cell of the agent before the first motion
        step; it counts as visited.
      cells: int ``[S, 2]``, (row, col) planning cell of the agent after each motion step, in
        order.
      lengths: float ``[S]``, metres travelled by each motion step.

    Returns:
      ``sum(lengths[step enters a cell seen before]) / sum(lengths)``, in ``[0, 1]``. A step
      that ends in the cell it started from counts as a revisit. ``0.0`` for an empty path or
      zero total length.

    Raises:
      ValueError: wrong shapes, or negative / non-finite lengths.
    """
    start = np.asarray(start_cell)
    c = np.asarray(cells)
    ln = np.asarray(lengths, dtype=np.float64)
    if start.shape != (2,):
        raise ValueError(f"start_cell must have shape [2], got {start.shape}")
    if c.size == 0:
        c = c.reshape(0, 2)
    if c.ndim != 2 or c.shape[1] != 2:
        raise ValueError(f"cells must have shape [S, 2], got {c.shape}")
    if ln.shape != (c.shape[0],):
        raise ValueError(f"lengths must have shape [{c.shape[0]}], got {ln.shape}")
    if not np.isfinite(ln).all() or (ln < 0).any():
        raise ValueError("lengths must be finite and non-negative")
    total = float(ln.sum())
    if c.shape[0] == 0 or total <= 0.0:
        return 0.0
    seq = np.concatenate((start[None, :], c), axis=0)
    _, first, inverse = np.unique(seq, axis=0, return_index=True, return_inverse=True)
    inverse = np.asarray(inverse).reshape(-1)
    position = np.arange(1, seq.shape[0])
    revisit = first[inverse[1:]] < position
    return float(ln[revisit].sum() / total)


# ---------------------------------------------------------------------------------------------
# Bootstrap intervals
# ---------------------------------------------------------------------------------------------


def _validate_boot(values: ArrayLike, n_boot: int, level: float, name: str) -> np.ndarray:
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got shape {v.shape}")
    if v.size == 0:
        raise ValueError(f"{name} must not be empty")
    if not np.isfinite(v).all():
        raise ValueError(f"{name} must be finite")
    if int(n_boot) != n_boot or n_boot < 1:
        raise ValueError(f"n_boot must be a positive integer, got {n_boot!r}")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must lie in (0, 1), got {level!r}")
    return v


def _validate_groups(groups: ArrayLike | None, n: int) -> np.ndarray | None:
    """Group labels ``[N]`` -> group index ``[N]`` in ``0..G-1`` (None passes through)."""
    if groups is None:
        return None
    g = np.asarray(groups).reshape(-1) if np.ndim(groups) else np.asarray([groups])
    if g.size != n:
        raise ValueError(f"groups must give one label per value: {g.size} labels, {n} values")
    _, index = np.unique(g, return_inverse=True)
    if index.max() < 1:
        raise ValueError("groups must hold at least two distinct labels to resample groups")
    return index.reshape(-1)


def _boot_interval(
    v: np.ndarray, n_boot: int, level: float, seed: int, groups: np.ndarray | None = None
) -> tuple[float, float]:
    if np.all(v == v[0]):
        x = float(v[0])
        return x, x
    rng = np.random.default_rng(seed)
    if groups is not None:  # per-group sums and sizes; a resample draws whole groups
        sums = np.bincount(groups, weights=v)
        counts = np.bincount(groups).astype(np.float64)
    n = v.size if groups is None else sums.size
    rows = max(1, _BOOT_CHUNK // n)
    means = np.empty(n_boot)
    for s in range(0, n_boot, rows):
        e = min(n_boot, s + rows)
        idx = rng.integers(0, n, size=(e - s, n))
        if groups is None:
            means[s:e] = v[idx].mean(axis=1)
        else:
            means[s:e] = sums[idx].sum(axis=1) / counts[idx].sum(axis=1)
    alpha = (1.0 - level) / 2.0
    lo, hi = np.quantile(means, [alpha, 1.0 - alpha])
    return float(lo), float(hi)


def _validate_pair(
    a: ArrayLike, b: ArrayLike, n_boot: int, level: float
) -> tuple[np.ndarray, np.ndarray]:
    """Two methods' per-episode values on the same episodes, checked (same length)."""
    av = _validate_boot(a, n_boot, level, "a")
    bv = _validate_boot(b, n_boot, level, "b")
    if av.shape != bv.shape:
        raise ValueError(f"a and b must have the same length, got {av.size} and {bv.size}")
    return av, bv


def paired_ratio_ci(
    a: ArrayLike,
    b: ArrayLike,
    n_boot: int = 2000,
    level: float = 0.95,
    seed: int = 0,
    groups: ArrayLike | None = None,
) -> tuple[float, float, float]:
    """Ratio of means ``mean(a) / mean(b)`` of two methods on the same episodes, with a
    paired percentile bootstrap interval (each resample draws the same episodes, or with
    ``groups`` the same whole groups, for both methods).

    Args:
      a, b: ``[N]`` per-episode values (``b``'s mean must be positive).
      n_boot, level, seed, groups: as in :func:`bootstrap_ci`.

    Returns:
      ``(ratio, lo, hi)``, dimensionless. Resamples whose ``b`` sums to zero are left out.

    Raises:
      ValueError: as :func:`paired_bootstrap_ci`, or ``mean(b) <= 0``.
    """
    av, bv = _validate_pair(a, b, n_boot, level)
    if bv.mean() <= 0:
        raise ValueError(f"the ratio needs a positive mean of b, got {bv.mean()}")
    g = _validate_groups(groups, av.size)
    if g is not None:  # per-group sums: a resample draws whole groups
        av, bv = np.bincount(g, weights=av), np.bincount(g, weights=bv)
    rng = np.random.default_rng(seed)
    n = av.size
    rows = max(1, _BOOT_CHUNK // n)
    ratios = np.empty(n_boot)
    for s in range(0, n_boot, rows):
        e = min(n_boot, s + rows)
        idx = rng.integers(0, n, size=(e - s, n))
        den = bv[idx].sum(axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratios[s:e] = np.where(den > 0, av[idx].sum(axis=1) / den, np.nan)
    alpha = (1.0 - level) / 2.0
    lo, hi = np.nanquantile(ratios, [alpha, 1.0 - alpha])
    return float(av.sum() / bv.sum()), float(lo), float(hi)


def bootstrap_ci(
    values: ArrayLike,
    n_boot: int = 2000,
    level: float = 0.95,
    seed: int = 0,
    groups: ArrayLike | None = None,
) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean over episodes.

    Args:
      values: ``[N]`` per-episode values.
      n_boot: number of bootstrap resamples (episodes drawn with replacement, N per resample).
      level: coverage of the interval, in (0, 1).
      seed: seed of ``np.random.default_rng``; the result is deterministic for a seed.
      groups: optional ``[N]`` label of each episode's group (e.g. its house). Then the G
        groups are drawn with replacement (G per resample) and each resample's statistic is
        the mean over all episodes of its drawn groups: a cluster bootstrap, whose interval
        holds for new groups, not only for new episodes of the same groups (wider when
        episodes of one group are alike). Needs at least two groups.

    Returns:
      ``(lo, hi)`` in the units of ``values``; ``(v, v)`` when all values equal ``v`` (in
      particular for a single value).

    Raises:
      ValueError: empty, non-1-D or non-finite ``values``; bad ``n_boot`` or ``level``;
        ``groups`` not one label per value or with fewer than two labels.
    """
    v = _validate_boot(values, n_boot, level, "values")
    g = _validate_groups(groups, v.size)
    return _boot_interval(v, int(n_boot), float(level), seed, g)


def paired_bootstrap_ci(
    a: ArrayLike,
    b: ArrayLike,
    n_boot: int = 2000,
    level: float = 0.95,
    seed: int = 0,
    groups: ArrayLike | None = None,
) -> tuple[float, float, float]:
    """Paired difference of means ``mean(a - b)`` with a percentile bootstrap interval.

    Episodes are resampled with the same index for ``a`` and ``b`` (the interval is the
    bootstrap interval of the mean of ``a - b``).

    Args:
      a, b: ``[N]`` per-episode values of two methods on the same episodes.
      n_boot, level, seed, groups: as in :func:`bootstrap_ci` (with ``groups`` whole groups
        of paired episodes are resampled).

    Returns:
      ``(mean_diff, lo, hi)`` in the units of the inputs. When ``a - b`` is constant the three
      values equal that constant exactly.

    Raises:
      ValueError: lengths differ, or an input is empty, non-1-D or non-finite; bad ``groups``.
    """
    av, bv = _validate_pair(a, b, n_boot, level)
    g = _validate_groups(groups, av.size)
    diff = av - bv
    if np.all(diff == diff[0]):
        x = float(diff[0])
        return x, x, x
    lo, hi = _boot_interval(diff, int(n_boot), float(level), seed, g)
    return float(diff.mean()), lo, hi
