"""Small array operations that XLA compiles poorly on a CPU, written another way.

``jnp.argmin``/``jnp.argmax`` lower to a variadic (value, index) reduction that XLA:CPU
does not vectorise: on the planner's [17, 17, 77] arrays it takes 2-4x the time of a
plain ``min``. :func:`argmin` and :func:`argmax` give the same answer (the first index of
the extreme value; the first NaN if there is one) with two plain reductions
(``python -m benchmarks.bench_policy`` shows what the planner gains).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

__all__ = ["argmax", "argmin"]


def argmin(x: jax.Array, axis: int | None = None) -> jax.Array:
    """``jnp.argmin(x, axis)`` (int32; flattened when ``axis`` is None)."""
    return _arg_first(x, jnp.min, axis)


def argmax(x: jax.Array, axis: int | None = None) -> jax.Array:
    """``jnp.argmax(x, axis)`` (int32; flattened when ``axis`` is None)."""
    return _arg_first(x, jnp.max, axis)


def _arg_first(x: jax.Array, reduce: Callable[..., jax.Array], axis: int | None) -> jax.Array:
    x = jnp.asarray(x)
    if axis is None:
        x, axis = x.reshape(-1), 0
    axis = axis % x.ndim
    hit = x == reduce(x, axis=axis, keepdims=True)
    if jnp.issubdtype(x.dtype, jnp.inexact):
        hit = hit | jnp.isnan(x)  # NaN is the extreme, as in jnp.argmin/argmax
    index = jax.lax.broadcasted_iota(jnp.int32, x.shape, axis)
    return jnp.min(jnp.where(hit, index, x.shape[axis]), axis=axis)
