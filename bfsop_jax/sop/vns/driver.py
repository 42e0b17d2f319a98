"""The VNS driver: :func:`solve_vns`, basic VNS over two neighbourhoods plus intensification.

Independent iterations are batched: iterations that do not improve all start from the same
incumbent, so ``width`` shake + local-search trials run side by side on a leading batch
axis; the best of them is accepted when it improves. Iteration counters advance by
``width`` per batch.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from bfsop_jax.sop.types import Solution, SOPInstance
from bfsop_jax.sop.vns.config import VNSConfig
from bfsop_jax.sop.vns.dp import _better, _plan, _score
from bfsop_jax.sop.vns.greedy import _solution, empty_solution, greedy_solution
from bfsop_jax.sop.vns.moves import _fit, _shakes
from bfsop_jax.sop.vns.search import _local_search, _recreate, _squeeze
from bfsop_jax.sop.vns.setview import set_view

__all__ = ["solve_vns"]


def solve_vns(
    instance: SOPInstance,
    seed: int = 0,
    config: VNSConfig | Mapping[str, Any] | None = None,
    *,
    return_greedy: bool = False,
    **overrides: Any,
) -> Solution | tuple[Solution, Solution]:
    """Solve one SOP instance with the VNS teacher (NumPy).

    Args:
        instance: a single (unbatched) instance, NumPy or JAX leaves.
        seed: seed of the ``np.random.Generator``; equal seeds and configs give equal
            solutions (unless ``config.time_limit`` cuts the run).
        config: the options (:class:`VNSConfig`, or a dict as written by
            :meth:`VNSConfig.to_dict`); None: the reference configuration
            (:data:`bfsop_jax.sop.vns.REFERENCE`).
        return_greedy: also return the greedy initial solution.
        **overrides: the loose keyword options of the old API (``max_iters``,
            ``max_no_improve``, ``time_limit``, ``width``, ``trades``, ``reversals``,
            ``squeeze``, ``squeeze_tries``, ``recreate``; see :class:`VNSConfig`), still
            accepted: they override the fields of ``config``. An unknown name raises
            ``TypeError``.

    Returns:
        A feasible :class:`Solution` (unpadded nodes: start first; end last when the
        instance has one), or ``(solution, greedy)`` with ``return_greedy``. An instance
        with nothing reachable gives the start-only plan.
    """
    cfg = VNSConfig.resolve(config, **overrides)
    cost_shape = np.shape(instance.cost)
    if len(cost_shape) != 2:
        raise ValueError(
            f"solve_vns takes one instance (cost [N, N]), got cost of shape {cost_shape}; "
            "solve a batch with bfsop_jax.sop.callback.solve_vns_batch"
        )
    max_iters, max_no_improve, time_limit = cfg.max_iters, cfg.max_no_improve, cfg.time_limit
    squeeze = cfg.squeeze
    inst = instance.to_numpy()
    view = set_view(inst)
    rng = np.random.default_rng(seed)
    if view.num_sets == 0:
        sol = empty_solution(inst)
        return (sol, sol) if return_greedy else sol
    perm, m = greedy_solution(view)
    greedy = _solution(inst, _plan(view, perm, m))
    q = view.members.shape[1]
    width = cfg.width
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
            batch, ms = _local_search(view, batch, ms, k, rng, cfg.trades, cfg.reversals)
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
                squeezed = _squeeze(
                    view, perm, m, rng, squeeze, cfg.squeeze_tries, deadline=deadline
                )
            if squeezed is None and cfg.recreate and time.perf_counter() < deadline:
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
