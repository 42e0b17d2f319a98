"""The one timing helper of the benchmark scripts.

``time_calls(fn, *args, repeats=R, inner=I)`` calls ``fn(*args)`` once (compilation and
first run, timed apart), then ``R`` rounds of ``I`` back-to-back calls, blocking on the
result at the end of each round. Times are wall-clock seconds per call.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

import jax
import numpy as np

__all__ = ["Timing", "machine", "time_calls"]


def machine() -> str:
    """The machine line of a benchmark's output: CPU, backend and its device, geodesic
    solver (``bfsop_jax.navigation.distance.geodesic_method``) and JAX version."""
    import os
    import platform

    from bfsop_jax.navigation.distance import geodesic_method

    device = jax.devices()[0]
    return (
        f"{platform.machine()} {os.cpu_count()} cores, {jax.default_backend()} "
        f"({device.device_kind}), geodesics={geodesic_method()}, jax {jax.__version__}"
    )


@dataclasses.dataclass(frozen=True)
class Timing:
    """First call (compile + run) and the steady-state seconds per call of every round."""

    first_s: float
    per_call_s: tuple[float, ...]

    @property
    def best(self) -> float:
        return float(min(self.per_call_s))

    @property
    def median(self) -> float:
        return float(np.median(self.per_call_s))

    @property
    def ms(self) -> list[float]:
        return [1e3 * t for t in self.per_call_s]


def time_calls(fn: Callable[..., Any], *args: Any, repeats: int = 5, inner: int = 1) -> Timing:
    """Time ``fn(*args)``: the first call alone, then ``repeats`` rounds of ``inner`` calls."""
    if repeats < 1 or inner < 1:
        raise ValueError(f"repeats and inner must be >= 1, got {repeats} and {inner}")
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    first = time.perf_counter() - t0
    rounds = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(inner):
            out = fn(*args)
        jax.block_until_ready(out)
        rounds.append((time.perf_counter() - t0) / inner)
    return Timing(first, tuple(rounds))
