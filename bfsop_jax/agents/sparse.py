"""A ``lax.cond`` that stays a branch under ``jax.vmap``: pay for a planner only when needed.

Under ``vmap`` a ``lax.cond`` with a batched predicate turns into a select: both branches
run for every row, every step. For a strategy that plans rarely (an SOP tour once every
few dozen macro steps) that means building an instance and calling the planner at every
step of every episode. :func:`sparse_cond` keeps the branch: batched, it runs the
expensive branch (for the whole batch, vectorised) only on steps where *some* row needs
it, and hands that branch the per-row mask so a host-side planner (the VNS callback)
solves only the rows that asked.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

__all__ = ["sparse_cond"]


def sparse_cond(
    pred: jax.Array,
    true_fn: Callable[..., Any],
    false_fn: Callable[..., Any],
    *operands: Any,
) -> Any:
    """``true_fn(pred, *operands)`` where ``pred`` holds, else ``false_fn(*operands)``.

    Unbatched this is ``lax.cond``. Under ``jax.vmap`` the true branch runs (vmapped over
    the batch, with ``pred`` as its per-row mask) only when ``pred`` holds for at least one
    row, and rows whose ``pred`` is false take ``false_fn``'s result. Both functions must
    return the same pytree structure and shapes, and must not close over traced values:
    pass everything dynamic through ``operands``.

    Args:
        pred: bool [] (per row under ``vmap``).
        true_fn: ``(mask, *operands) -> out``; ``mask`` is ``pred`` (true when unbatched).
        false_fn: ``(*operands) -> out``, the cheap result.
        *operands: pytrees of arrays.
    """

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
        dear = jax.vmap(lambda p, ops: true_fn(p, *ops), in_axes=(0, axes), axis_size=axis_size)

        def both(ops):
            hit, miss = dear(pred, ops), cheap(ops)
            pick = lambda a, b: jnp.where(pred.reshape((-1,) + (1,) * (a.ndim - 1)), a, b)
            return jax.tree_util.tree_map(pick, hit, miss)

        out = jax.lax.cond(jnp.any(pred), both, cheap, operands)
        return out, jax.tree_util.tree_map(lambda _: True, out)

    return run(jnp.asarray(pred, bool), operands)
