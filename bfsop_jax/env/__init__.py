"""The navigation environment.

* ``reset`` / ``step``: the pure, vmappable simulator over :class:`EnvState` (one macro
  action per step), which the project's strategies drive.
* ``make``: the same simulator as a gymnax-style environment (``env.reset(key, params)``,
  ``env.step(key, state, action, params)`` with reward, terminated and truncated, spaces),
  with a native and a discrete candidate action interface (:mod:`bfsop_jax.env.environment`,
  :mod:`bfsop_jax.env.candidates`); wrappers in :mod:`bfsop_jax.env.wrappers`.
"""

from __future__ import annotations

import importlib
from typing import Any

from bfsop_jax.env.env import make_action, observe, reset, sample_start_pose, sense, step
from bfsop_jax.env.types import Action, EnvState, Observation, StepInfo

# The user-facing environment poses candidates with the strategies' own pieces (FBE's
# frontier bookkeeping), and the strategies import the simulator above: loaded on first
# use, so either side can be imported first.
_LAZY = {
    "CandidateConfig": "bfsop_jax.env.candidates",
    "CandidateObservation": "bfsop_jax.env.candidates",
    "EnvParams": "bfsop_jax.env.environment",
    "NavigationEnv": "bfsop_jax.env.environment",
    "TaskState": "bfsop_jax.env.environment",
    "make": "bfsop_jax.env.environment",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "Action",
    "CandidateConfig",
    "CandidateObservation",
    "EnvParams",
    "EnvState",
    "NavigationEnv",
    "Observation",
    "StepInfo",
    "TaskState",
    "make",
    "make_action",
    "observe",
    "reset",
    "sample_start_pose",
    "sense",
    "step",
]
