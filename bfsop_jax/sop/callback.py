"""The VNS teacher on batches: a process pool on the host, and a JAX host callback.

``solve_vns_batch`` labels a batch of NumPy instances on all CPU cores; ``vns_callback``
calls it from jitted JAX code through ``jax.pure_callback``; ``vns_masked_callback`` is
the planner form used inside (vmapped) rollouts: it takes a per-row mask and solves only
the rows that ask, so a batch of episodes pays for the teacher only where one switches.
JAX runs its own threads, so worker processes are started with the ``spawn`` method
(never ``fork`` after JAX has started) and the pool is created once and reused across
calls. A batch of one is solved in the calling process.

The VNS options travel as one :class:`~bfsop_jax.sop.vns.VNSConfig` (``config=``; hashable,
and picklable for the spawned workers). The loose keyword options of the old API
(``max_iters=...``) are still accepted: they are folded into the config once, at the entry
point, and override its fields.
"""

from __future__ import annotations

import atexit
import concurrent.futures
import dataclasses
import functools
import multiprocessing
import os
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from bfsop_jax.sop.types import Solution, SOPInstance, plan_length
from bfsop_jax.sop.vns import VNSConfig, solve_vns

__all__ = [
    "callback_stats",
    "reset_callback_stats",
    "shutdown_pool",
    "solve_vns_batch",
    "vns_callback",
    "vns_masked_callback",
]

_FIELDS = dataclasses.fields(SOPInstance)
_POOL: concurrent.futures.ProcessPoolExecutor | None = None
_POOL_SIZE = 0
# Host-side tally of the masked planner callback: calls, rows solved, wall seconds.
_STATS = {"calls": 0, "rows": 0, "seconds": 0.0}


def _pool(processes: int) -> concurrent.futures.ProcessPoolExecutor:
    global _POOL, _POOL_SIZE
    if _POOL is None or _POOL_SIZE != processes:
        shutdown_pool()
        ctx = multiprocessing.get_context("spawn")
        _POOL = concurrent.futures.ProcessPoolExecutor(max_workers=processes, mp_context=ctx)
        _POOL_SIZE = processes
    return _POOL


def shutdown_pool() -> None:
    """Stop the worker processes (they are restarted on the next batch)."""
    global _POOL, _POOL_SIZE
    if _POOL is not None:
        _POOL.shutdown(wait=True, cancel_futures=True)
    _POOL, _POOL_SIZE = None, 0


atexit.register(shutdown_pool)


def _solve_packed(
    item: tuple[dict[str, np.ndarray], int, int, VNSConfig],
) -> tuple[np.ndarray, np.float32, np.float32]:
    """Worker entry point: solve one instance, return padded (nodes, reward, cost)."""
    fields, seed, length, config = item
    sol = solve_vns(SOPInstance(**fields), seed=seed, config=config)
    padded = sol.padded(length)
    return padded.nodes, padded.reward, padded.cost


def solve_vns_batch(
    instances: SOPInstance,
    seeds: Any,
    processes: int | None = None,
    config: VNSConfig | None = None,
    **vns_kwargs: Any,
) -> Solution:
    """Solve a batch of instances with :func:`solve_vns`, one process per CPU core.

    Args:
        instances: batched instance, every leaf with a leading batch axis B (NumPy or JAX).
        seeds: [B] integer seeds, one per instance.
        processes: worker processes (default: number of CPU cores, at most B).
        config: the VNS options (default: the reference configuration).
        **vns_kwargs: old-style loose options (``max_iters``, ``time_limit``, ...), still
            accepted; they override the fields of ``config``.

    Returns:
        Batched NumPy :class:`Solution`: ``nodes`` [B, K + 1] int32 padded with -1,
        ``reward`` [B] and ``cost`` [B] float32. Equal to ``solve_vns`` per instance.
    """
    config = VNSConfig.resolve(config, **vns_kwargs)
    inst = instances.to_numpy()
    if inst.set_id.ndim != 2:
        raise ValueError(f"expected a batch of instances, set_id has shape {inst.set_id.shape}")
    batch = inst.set_id.shape[0]
    seeds = np.broadcast_to(np.asarray(seeds, np.int64).reshape(-1), (batch,))
    length = plan_length(inst.num_sets)
    items = [
        ({f.name: getattr(inst, f.name)[b] for f in _FIELDS}, int(seeds[b]), length, config)
        for b in range(batch)
    ]
    workers = min(processes or os.cpu_count() or 1, batch)
    if workers <= 1:
        results = [_solve_packed(item) for item in items]
    else:
        chunk = max(1, batch // (4 * workers))
        results = list(_pool(workers).map(_solve_packed, items, chunksize=chunk))
    nodes, reward, cost = zip(*results, strict=True)
    return Solution(
        nodes=np.stack(nodes).astype(np.int32),
        reward=np.asarray(reward, np.float32),
        cost=np.asarray(cost, np.float32),
    )


def vns_callback(
    instances: SOPInstance,
    seeds: jax.Array,
    config: VNSConfig | None = None,
    **vns_kwargs: Any,
) -> Solution:
    """Label a batch from (jitted) JAX code: ``jax.pure_callback`` to :func:`solve_vns_batch`.

    Args:
        instances: batched instance, leading batch axis B (JAX arrays, may be traced).
        seeds: [B] integer seeds.
        config: the VNS options, static (default: the reference configuration).
        **vns_kwargs: old-style loose options, still accepted; they override ``config``.

    Returns:
        Batched :class:`Solution` of JAX arrays: ``nodes`` [B, K + 1] int32 (-1 padded),
        ``reward`` and ``cost`` [B] float32.
    """
    batch = instances.set_id.shape[0]
    length = plan_length(instances.set_reward.shape[-1])
    shapes = Solution(
        nodes=jax.ShapeDtypeStruct((batch, length), jnp.int32),
        reward=jax.ShapeDtypeStruct((batch,), jnp.float32),
        cost=jax.ShapeDtypeStruct((batch,), jnp.float32),
    )
    host = functools.partial(_host_solve, config=VNSConfig.resolve(config, **vns_kwargs))
    return jax.pure_callback(
        host, shapes, instances, jnp.asarray(seeds, jnp.int32), vmap_method="sequential"
    )


def _host_solve(instances: SOPInstance, seeds: np.ndarray, config: VNSConfig) -> Solution:
    return solve_vns_batch(instances, np.asarray(seeds), config=config)


def callback_stats() -> dict[str, float]:
    """Totals of :func:`vns_masked_callback` since the last reset.

    ``calls`` (host calls that solved at least one row), ``rows`` (instances solved) and
    ``seconds`` (host wall time spent solving them, all workers together).
    """
    return dict(_STATS)


def reset_callback_stats() -> None:
    """Zero the :func:`callback_stats` tally."""
    _STATS.update(calls=0, rows=0, seconds=0.0)


def vns_masked_callback(
    instance: SOPInstance,
    mask: jax.Array,
    seed: int = 0,
    config: VNSConfig | None = None,
    **vns_kwargs: Any,
) -> Solution:
    """The VNS teacher as an in-loop planner: solve ``instance`` only where ``mask`` holds.

    Written for one instance (``set_id`` [N]) and vmappable: under ``jax.vmap`` the host
    receives the whole batch at once with its mask, solves the masked rows on all CPU
    cores (:func:`solve_vns_batch`) and returns an empty plan (start node only, reward
    and cost 0) for the others.

    Args:
        instance: one SOP instance (JAX arrays, may be traced).
        mask: bool [] (per row under ``vmap``).
        seed: VNS seed, the same for every row.
        config: the VNS options, static (default: the reference configuration).
        **vns_kwargs: old-style loose options, still accepted; they override ``config``.

    Returns:
        :class:`Solution` of JAX arrays: ``nodes`` [K + 1] int32 (-1 padded), ``reward``
        and ``cost`` [] float32 (per row under ``vmap``).
    """
    length = plan_length(instance.set_reward.shape[-1])
    shapes = Solution(
        nodes=jax.ShapeDtypeStruct((length,), jnp.int32),
        reward=jax.ShapeDtypeStruct((), jnp.float32),
        cost=jax.ShapeDtypeStruct((), jnp.float32),
    )
    config = VNSConfig.resolve(config, **vns_kwargs)
    host = functools.partial(_host_solve_masked, seed=int(seed), config=config)
    return jax.pure_callback(
        host, shapes, instance, jnp.asarray(mask, bool), vmap_method="broadcast_all"
    )


def _host_solve_masked(
    instance: SOPInstance, mask: np.ndarray, seed: int, config: VNSConfig
) -> Solution:
    mask = np.asarray(mask, bool)
    lead = mask.shape
    n_sets = instance.set_reward.shape[-1]
    flat = jax.tree_util.tree_map(
        lambda a: np.asarray(a).reshape((-1,) + np.shape(a)[len(lead) :]), instance
    )
    rows = np.flatnonzero(mask.reshape(-1))
    length = plan_length(n_sets)
    total = int(np.prod(lead, dtype=np.int64))
    nodes = np.full((total, length), -1, np.int32)
    nodes[:, 0] = np.asarray(flat.start).reshape(total)
    reward = np.zeros(total, np.float32)
    cost = np.zeros(total, np.float32)
    if rows.size:
        t0 = time.perf_counter()
        picked = jax.tree_util.tree_map(lambda a: a[rows], flat)
        sol = solve_vns_batch(picked, np.full(rows.size, seed), config=config)
        _STATS["seconds"] += time.perf_counter() - t0
        _STATS["calls"] += 1
        _STATS["rows"] += int(rows.size)
        nodes[rows], reward[rows], cost[rows] = sol.nodes, sol.reward, sol.cost
    return Solution(
        nodes=nodes.reshape(lead + (length,)),
        reward=reward.reshape(lead),
        cost=cost.reshape(lead),
    )
