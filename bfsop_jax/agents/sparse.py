"""A ``lax.cond`` that stays a branch under ``jax.vmap``: pay for a planner only when needed.

Under ``vmap`` a ``lax.cond`` with a batched predicate turns into a select: both branches
run for every row, every step. For a strategy that plans rarely (an SOP tour once every
few dozen macro steps) that means building an instance and calling the planner at every
step of every episode. :func:`sparse_cond` keeps the branch: batched, it gathers the rows
that need it into small fixed-size sub-batches, runs the expensive branch on those only
(vectorised; no round at all when nobody asks) and scatters the results back, handing
the branch a per-row mask so a host-side planner (the VNS callback) skips padding.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

__all__ = ["SPARSE_CAPACITY", "default_capacity", "sparse_cond"]

# Rows per sub-batch of the true branch, by backend: a CPU core runs few rows at a time
# best; an accelerator runs a round of many rows in about the time of one, and the rounds
# are sequential.
SPARSE_CAPACITY = {"cpu": 8, "accelerator": 128}


def default_capacity() -> int:
    """Sub-batch rows for the current backend (``jax.default_backend()`` at trace time)."""
    return SPARSE_CAPACITY["cpu" if jax.default_backend() == "cpu" else "accelerator"]


def sparse_cond(
    pred: jax.Array,
    true_fn: Callable[..., Any],
    false_fn: Callable[..., Any],
    *operands: Any,
    capacity: int | None = None,
) -> Any:
    """``true_fn(pred, *operands)`` where ``pred`` holds, else ``false_fn(*operands)``.

    Unbatched this is ``lax.cond``. Under ``jax.vmap`` the rows whose ``pred`` holds are
    gathered into sub-batches of ``capacity`` rows and only those run the true branch
    (as many rounds as needed; none when no row asks), so the cost follows the number of
    rows that ask rather than the batch size. The true branch gets a per-row mask (false
    on the padding of the last sub-batch) so host callbacks can skip padded rows. Both
    functions must return the same pytree structure and shapes, and must not close over
    traced values: pass everything dynamic through ``operands``.

    Args:
        pred: bool [] (per row under ``vmap``).
        true_fn: ``(mask, *operands) -> out``; ``mask`` is true for a real row.
        false_fn: ``(*operands) -> out``, the cheap result.
        *operands: pytrees of arrays.
        capacity: rows per sub-batch of the true branch (static; default
            :func:`default_capacity`: 8 on a CPU, 128 on accelerators). It changes how
            many rounds run, never what a row computes.
    """
    capacity = default_capacity() if capacity is None else int(capacity)
    if capacity < 1:
        raise ValueError(f"capacity must be >= 1, got {capacity}")

    @jax.custom_batching.custom_vmap
    def run(pred, operands):
        hit = lambda ops: true_fn(pred, *ops)
        return jax.lax.cond(pred, hit, lambda ops: false_fn(*ops), operands)

    @run.def_vmap
    def _batched(axis_size, in_batched, pred, operands):
        pred_batched, ops_batched = in_batched
        if not pred_batched:
            pred = jnp.broadcast_to(pred, (axis_size,))
        axes = jax.tree_util.tree_map(lambda b: 0 if b else None, ops_batched)
        cheap = jax.vmap(lambda ops: false_fn(*ops), in_axes=(axes,), axis_size=axis_size)
        size = min(capacity, axis_size)
        dear = jax.vmap(lambda p, ops: true_fn(p, *ops), in_axes=(0, axes), axis_size=size)
        count = jnp.sum(pred, dtype=jnp.int32)
        order = jnp.nonzero(pred, size=axis_size, fill_value=0)[0].astype(jnp.int32)
        order = jnp.concatenate([order, jnp.zeros(size, jnp.int32)])  # room for the last slice

        def one_round(r, out):
            rows = jax.lax.dynamic_slice(order, (r * size,), (size,))
            real = r * size + jnp.arange(size) < count
            sub = jax.tree_util.tree_map(
                lambda x, b: x[rows] if b else x, operands, ops_batched
            )
            got = dear(real, sub)
            into = jnp.where(real, rows, axis_size)  # padding rows are dropped
            return jax.tree_util.tree_map(
                lambda o, g: o.at[into].set(g, mode="drop"), out, got
            )

        rounds = (count + size - 1) // size
        # inside a cond, so XLA cannot hoist the loop-invariant part of the expensive
        # branch out of the loop and run it on every call (a house generator's constant
        # tables, say) when no row asks
        out = jax.lax.cond(
            count > 0,
            lambda ops: jax.lax.fori_loop(0, rounds, one_round, cheap(ops)),
            cheap,
            operands,
        )
        return out, jax.tree_util.tree_map(lambda _: True, out)

    return run(jnp.asarray(pred, bool), operands)
