"""Scripted policies on the discrete candidate interface, and any such policy as a strategy.

A candidate policy maps a :class:`~bfsop_jax.env.candidates.CandidateObservation` to the
index of the candidate it chooses (int32 []; 0 is stop). Two scripted ones:

* :func:`nearest_frontier`: the geodesically nearest frontier (FBE on the candidates:
  the same goals, looks and bookkeeping, so the same episodes as :class:`FBE`);
* :func:`nearest_landmark`: the nearest pending landmark's best viewpoint while one is
  on offer, else the nearest frontier.

:class:`CandidateAgent` runs a candidate policy as a strategy (``init`` / ``act`` /
``update`` over the :class:`~bfsop_jax.env.types.Observation`), so the navigation
benchmark can put it on the same episodes as every other method.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp
from flax import struct

from bfsop_jax.agents.fbe import FBE
from bfsop_jax.agents.rollout import Decision, explore_decision
from bfsop_jax.config import Preset
from bfsop_jax.env.candidates import (
    FRONTIER,
    LANDMARK,
    STOP,
    CandidateConfig,
    CandidateMemory,
    CandidateObservation,
    candidate_action,
    candidate_observation,
    init_candidates,
    pose_candidates,
    record_outcome,
)
from bfsop_jax.env.types import Action, Observation, StepInfo

__all__ = ["CANDIDATE_POLICIES", "CandidateAgent", "nearest_frontier", "nearest_landmark"]


def _nearest(obs: CandidateObservation, kind: int) -> tuple[jax.Array, jax.Array]:
    """(index int32 [], any bool []): the nearest available candidate of ``kind``."""
    ok = obs.action_mask & (obs.kind == kind)
    index = jnp.argmin(jnp.where(ok, obs.distance, jnp.inf)).astype(jnp.int32)
    return index, jnp.any(ok)


def nearest_frontier(obs: CandidateObservation) -> jax.Array:
    """The nearest frontier (ties: the larger cluster), or stop when none is left."""
    index, ok = _nearest(obs, FRONTIER)
    return jnp.where(ok, index, STOP).astype(jnp.int32)


def nearest_landmark(obs: CandidateObservation) -> jax.Array:
    """The nearest pending landmark, else the nearest frontier, else stop."""
    lm, has_lm = _nearest(obs, LANDMARK)
    return jnp.where(has_lm, lm, nearest_frontier(obs)).astype(jnp.int32)


CANDIDATE_POLICIES: dict[str, Callable[[CandidateObservation], jax.Array]] = {
    "nearest_frontier": nearest_frontier,
    "nearest_landmark": nearest_landmark,
}


@struct.dataclass
class CandidateAgentMemory:
    candidates: CandidateMemory  # the interface's bookkeeping and the last candidates
    choice: jax.Array  # int32 []: the candidate chosen at the last act


@dataclasses.dataclass(frozen=True)
class CandidateAgent:
    """A candidate policy (by name in :data:`CANDIDATE_POLICIES`) as a strategy.

    Choosing a landmark counts as touring (a one-landmark tour), so trajectories colour
    those steps as the tour strategies' are; a switch is a landmark chosen after a
    frontier.
    """

    policy: str = "nearest_frontier"
    config: CandidateConfig = CandidateConfig()

    def __post_init__(self):
        if self.policy not in CANDIDATE_POLICIES:
            names = ", ".join(CANDIDATE_POLICIES)
            raise ValueError(f"unknown candidate policy {self.policy!r}; policies are {names}")

    @property
    def explorer(self) -> FBE:
        """The frontier bookkeeping's numbers, as the other strategies' explorer."""
        return FBE(self.config.explorer)

    def init(self, obs: Observation, preset: Preset) -> CandidateAgentMemory:
        memory = init_candidates(obs, preset, self.config)
        return CandidateAgentMemory(memory, jnp.zeros((), jnp.int32))

    def act(
        self, memory: CandidateAgentMemory, obs: Observation, preset: Preset
    ) -> tuple[Action, Decision, CandidateAgentMemory]:
        cands = pose_candidates(memory.candidates, obs, preset, self.config)
        choice = CANDIDATE_POLICIES[self.policy](candidate_observation(cands, obs))
        touring = cands.kind[choice] == LANDMARK
        was_touring = memory.candidates.candidates.kind[memory.choice] == LANDMARK
        decision = explore_decision(choice != STOP).replace(
            touring=touring, switched=touring & ~was_touring
        )
        memory = CandidateAgentMemory(memory.candidates.replace(candidates=cands), choice)
        return candidate_action(cands, choice), decision, memory

    def update(
        self, memory: CandidateAgentMemory, before: Observation, after: Observation,
        info: StepInfo,
    ) -> CandidateAgentMemory:  # fmt: skip
        return memory.replace(
            candidates=record_outcome(memory.candidates, memory.choice, info, self.config)
        )
