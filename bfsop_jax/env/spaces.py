"""Action and observation spaces: small spec objects in gymnax's shape.

Each space says what an array (or a pytree of arrays) looks like: its shape, dtype and
bounds, with ``sample(key)`` (a uniformly random member) and ``contains(x)`` (a bool []
array, so it can run under ``jit``). :class:`Dict` nests spaces by field name and, given
the pytree class it describes (``Observation``, ``Action``), samples instances of it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["Box", "Dict", "Discrete", "Space"]


class Space:
    """Base class: ``sample(key)`` and ``contains(x)``."""

    def sample(self, key: jax.Array) -> Any:
        raise NotImplementedError

    def contains(self, x: Any) -> jax.Array:
        raise NotImplementedError


@dataclasses.dataclass(frozen=True)
class Discrete(Space):
    """Integers ``0 .. n - 1`` (int32 [])."""

    n: int
    dtype: Any = jnp.int32

    @property
    def shape(self) -> tuple[int, ...]:
        return ()

    def sample(self, key: jax.Array) -> jax.Array:
        return jax.random.randint(key, (), 0, self.n, dtype=self.dtype)

    def contains(self, x: Any) -> jax.Array:
        x = jnp.asarray(x)
        integral = jnp.issubdtype(x.dtype, jnp.integer) or x.dtype == jnp.bool_
        return jnp.asarray(integral and x.shape == ()) & (x >= 0) & (x < self.n)


@dataclasses.dataclass(frozen=True)
class Box(Space):
    """Arrays of ``shape`` and ``dtype`` with every entry in ``[low, high]``.

    ``low`` / ``high`` are scalars or arrays broadcastable to ``shape``; infinite bounds
    are allowed (sampling then draws from a unit normal on that side). A bool box has
    bounds 0 and 1 and samples fair coins.
    """

    low: Any
    high: Any
    shape: tuple[int, ...]
    dtype: Any = jnp.float32

    def sample(self, key: jax.Array) -> jax.Array:
        dtype = jnp.dtype(self.dtype)
        if dtype == jnp.bool_:
            return jax.random.bernoulli(key, 0.5, self.shape)
        low = jnp.broadcast_to(jnp.asarray(self.low, jnp.float32), self.shape)
        high = jnp.broadcast_to(jnp.asarray(self.high, jnp.float32), self.shape)
        if jnp.issubdtype(dtype, jnp.integer):
            return jax.random.randint(key, self.shape, low.astype(dtype), high.astype(dtype) + 1)
        k_u, k_n = jax.random.split(key)
        u = jax.random.uniform(k_u, self.shape, jnp.float32)
        n = jnp.abs(jax.random.normal(k_n, self.shape, jnp.float32))
        bounded = low + u * (high - low)
        out = jnp.where(
            jnp.isfinite(low) & jnp.isfinite(high),
            bounded,
            jnp.where(jnp.isfinite(low), low + n, jnp.where(jnp.isfinite(high), high - n, n)),
        )
        return out.astype(dtype)

    def contains(self, x: Any) -> jax.Array:
        x = jnp.asarray(x)
        if x.shape != tuple(self.shape) or (x.dtype == jnp.bool_) != (
            jnp.dtype(self.dtype) == jnp.bool_
        ):
            return jnp.zeros((), bool)
        if x.dtype == jnp.bool_:
            return jnp.ones((), bool)
        xf = x.astype(jnp.float32)
        return jnp.all((xf >= jnp.asarray(self.low)) & (xf <= jnp.asarray(self.high)))


@dataclasses.dataclass(frozen=True)
class Dict(Space):
    """Named sub-spaces; with ``cls`` (a dataclass pytree), samples are ``cls(**fields)``.

    ``contains`` accepts a mapping or an instance of ``cls`` and holds when every field
    is in its sub-space (and no field is missing).
    """

    spaces: Mapping[str, Space]
    cls: Any = None

    def __hash__(self) -> int:
        return hash((tuple(self.spaces.items()), self.cls))

    def sample(self, key: jax.Array) -> Any:
        keys = jax.random.split(key, len(self.spaces))
        out = {name: s.sample(k) for (name, s), k in zip(self.spaces.items(), keys, strict=True)}
        return out if self.cls is None else self.cls(**out)

    def contains(self, x: Any) -> jax.Array:
        if dataclasses.is_dataclass(x):
            x = {f.name: getattr(x, f.name) for f in dataclasses.fields(x)}
        if set(x) != set(self.spaces):
            return jnp.zeros((), bool)
        ok = [s.contains(x[name]) for name, s in self.spaces.items()]
        return jnp.all(jnp.stack(ok))

    def __getitem__(self, name: str) -> Space:
        return self.spaces[name]


def finite_bounds(shape: tuple[int, ...], low: float, high: float) -> Box:
    """A float32 :class:`Box` with the same scalar bounds everywhere."""
    return Box(np.float32(low), np.float32(high), shape, jnp.float32)
