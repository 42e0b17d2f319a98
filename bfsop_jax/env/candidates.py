"""The discrete candidate interface: choose one of K goals posed from the observation.

Each macro step the agent is offered K = 1 + F + L candidates, built from what it has
observed only (its belief map, pose, budget and the objects it has detected):

* slot 0: **stop** (always available; choosing it ends the episode);
* slots 1 .. F: **frontier clusters**
  (:func:`bfsop_jax.navigation.frontiers.cluster_frontier_cells`, largest first), each
  at its representative cell, facing its unknown side on arrival (exactly FBE's goal and
  look, :class:`bfsop_jax.agents.FBE`);
* slots F + 1 .. F + L: **pending landmarks of interest** (detected, prior reward > 0 for
  the category, not yet visited), the L of highest reward
  (:func:`bfsop_jax.sop.builder.select_landmarks`), each at its best viewpoint: of the
  SOP builder's candidate viewpoints around its footprint
  (:func:`bfsop_jax.sop.builder.viewpoint_candidates`), the reachable one on the
  tightest ring around the footprint, nearest the agent among those (at its planning
  cell's centre); on arrival the agent faces the landmark.

A candidate is available (``action_mask``) when it holds a goal the agent can reach on its
motion map; distances are geodesic (one distance field from the agent, the one FBE
computes). Bookkeeping follows FBE, so the interface never offers a goal forever: a
frontier chosen for ``FBEConfig.patience`` macro steps without progress (no metre moved,
no newly known cell) is dropped, and so is the space within ``drop_radius`` around it; a
landmark is retired once its viewpoint is reached, or after ``patience`` macro steps
without progress towards it.

Per-candidate features (``FEATURES``, columns of ``CandidateObservation.features``) are
scaled to order one: kind one-hots, geodesic distance / budget, reachable within what is
left, frontier size (planning cells / 50), unknown share around a frontier, landmark prior
reward, remaining budget / budget, and the goal's offset from the agent (metres / 10).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from bfsop_jax.agents.fbe import FBE, FBEConfig, FBEMemory, near_dropped
from bfsop_jax.agents.tour import pending_landmarks
from bfsop_jax.config import Preset
from bfsop_jax.env.types import Action, Observation, StepInfo
from bfsop_jax.navigation.distance import distance_field
from bfsop_jax.navigation.frontiers import (
    cluster_frontier_cells,
    frontier_mask,
    plan_cell_states,
    unknown_count,
    unknown_side,
)
from bfsop_jax.navigation.grid import (
    motion_blocked,
    plan_cell_to_xy,
    planning_blocked,
    xy_to_plan_cell,
)
from bfsop_jax.sop.builder import inside_map, select_landmarks, viewpoint_candidates

__all__ = [
    "FEATURES",
    "FRONTIER",
    "LANDMARK",
    "STOP",
    "CandidateConfig",
    "CandidateMemory",
    "CandidateObservation",
    "Candidates",
    "candidate_action",
    "candidate_observation",
    "init_candidates",
    "pose_candidates",
    "record_outcome",
    "update_candidates",
]

STOP, FRONTIER, LANDMARK = 0, 1, 2  # candidate kinds

FEATURES: tuple[str, ...] = (
    "is_stop",
    "is_frontier",
    "is_landmark",
    "distance_over_budget",  # geodesic metres / B
    "reachable_in_budget",  # 1 when the distance is within B - L
    "frontier_size_50",  # cluster size in planning cells / 50 (frontiers)
    "unknown_share",  # unknown share of the square around the frontier (frontiers)
    "landmark_reward",  # prior P(target | landmark type) (landmarks)
    "remaining_over_budget",  # (B - L) / B, the same on every row
    "dx_10m",  # goal x - agent x, metres / 10
    "dy_10m",  # goal y - agent y, metres / 10
)


@dataclasses.dataclass(frozen=True)
class CandidateConfig:
    """Static numbers of the candidate interface (they set shapes)."""

    n_frontiers: int | None = None  # F; default preset.max_frontier_clusters
    n_landmarks: int | None = None  # L; default preset.n_loi
    explorer: FBEConfig = FBEConfig()  # patience, dropping and look direction, as FBE

    def sizes(self, preset: Preset) -> tuple[int, int]:
        """(F, L) for ``preset``, checked against its capacities."""
        f = preset.max_frontier_clusters if self.n_frontiers is None else self.n_frontiers
        n = preset.n_loi if self.n_landmarks is None else self.n_landmarks
        if not 0 <= f <= preset.max_frontier_clusters:
            raise ValueError(
                f"n_frontiers must be in 0..{preset.max_frontier_clusters} for preset "
                f"{preset.name!r}, got {f}"
            )
        if not 0 <= n <= preset.max_objects:
            raise ValueError(f"n_landmarks must be in 0..{preset.max_objects}, got {n}")
        return f, n

    def n_candidates(self, preset: Preset) -> int:
        """K = 1 + F + L."""
        f, n = self.sizes(preset)
        return 1 + f + n


@struct.dataclass
class Candidates:
    """The K goals on offer (slot 0 stop, then F frontiers, then L landmarks)."""

    kind: jax.Array  # int32 [K]: STOP, FRONTIER or LANDMARK
    valid: jax.Array  # bool [K]: the goal exists and is reachable (the action mask)
    goal_xy: jax.Array  # float32 [K, 2]: goal (metres; the agent's position for stop/empty)
    look_xy: jax.Array  # float32 [K, 2]: the point faced on arrival
    look: jax.Array  # bool [K]: turn to face look_xy on arrival
    distance: jax.Array  # float32 [K]: geodesic metres from the agent (0 where not valid)
    size: jax.Array  # int32 [K]: frontier cluster size in planning cells (0 otherwise)
    unknown: jax.Array  # float32 [K]: unknown share around the frontier (0 otherwise)
    reward: jax.Array  # float32 [K]: landmark prior reward (0 otherwise)
    landmark: jax.Array  # int32 [K]: object slot of the landmark (-1 otherwise)
    cell: jax.Array  # int32 [K, 2]: planning cell of the goal


@struct.dataclass
class CandidateMemory:
    """What the interface keeps between macro steps. M = object slots."""

    explore: FBEMemory  # dropped frontier goals (FBE's ring buffer) and the stall count
    retired: jax.Array  # bool [M]: landmarks visited or given up
    landmark_goal: jax.Array  # int32 []: landmark slot chosen last (-1: none)
    landmark_stalled: jax.Array  # int32 []: macro steps without progress towards it
    candidates: Candidates  # the candidates posed from the latest observation


@struct.dataclass
class CandidateObservation:
    """The candidate interface's observation (nothing here is read from the true house)."""

    features: jax.Array  # float32 [K, D]: see FEATURES
    action_mask: jax.Array  # bool [K]: which candidates may be chosen (stop always)
    kind: jax.Array  # int32 [K]: STOP, FRONTIER or LANDMARK
    goal_xy: jax.Array  # float32 [K, 2]: each candidate's goal (metres)
    distance: jax.Array  # float32 [K]: geodesic metres from the agent (0 where masked)
    pose: jax.Array  # float32 [3]: x, y (metres), heading (radians)
    remaining: jax.Array  # float32 []: B - L, metres
    budget: jax.Array  # float32 []: B, metres
    found: jax.Array  # int32 []: targets verified so far


def init_candidates(obs: Observation, preset: Preset, config: CandidateConfig) -> CandidateMemory:
    """Fresh bookkeeping for a new episode, with the candidates posed from ``obs``."""
    memory = CandidateMemory(
        explore=FBE(config.explorer).init(obs, preset),
        retired=jnp.zeros(obs.found.shape, bool),
        landmark_goal=jnp.full((), -1, jnp.int32),
        landmark_stalled=jnp.zeros((), jnp.int32),
        candidates=None,
    )
    return memory.replace(candidates=pose_candidates(memory, obs, preset, config))


def pose_candidates(
    memory: CandidateMemory, obs: Observation, preset: Preset, config: CandidateConfig
) -> Candidates:
    """The K candidates of ``obs`` (module docstring): one distance field from the agent,
    the frontier clusters and the pending landmarks' viewpoints."""
    n_front, n_lm = config.sizes(preset)
    cfg = config.explorer
    blocked = planning_blocked(obs.belief, preset)
    free, unknown = plan_cell_states(obs.belief, preset)
    motion = motion_blocked(obs.belief, obs.pose[:2], preset, blocked)
    field = distance_field(motion, obs.pose[:2], preset)
    agent_xy = obs.pose[:2]

    # frontiers: FBE's clusters, goals and look directions
    cells = frontier_mask(free, unknown, blocked) & ~near_dropped(memory.explore, cfg, preset)
    front = cluster_frontier_cells(cells, preset)
    f_xy, f_size = front.xy[:n_front], front.size[:n_front]
    f_cell = xy_to_plan_cell(f_xy, preset)
    f_dist = field[f_cell[:, 0], f_cell[:, 1]]
    f_valid = front.valid[:n_front] & jnp.isfinite(f_dist)
    side = unknown_side(unknown, f_cell, cfg.look_radius)
    f_look_xy = plan_cell_to_xy(f_cell + side, preset)
    f_look = jnp.any(side != 0, axis=-1)
    area = (2 * cfg.gain_radius + 1) ** 2
    f_unknown = unknown_count(unknown, f_cell, cfg.gain_radius).astype(jnp.float32)
    f_unknown = f_unknown * np.float32(1.0 / area)

    # landmarks: the L pending ones of highest reward, each at its nearest free viewpoint
    pending = pending_landmarks(obs, memory.retired)
    choice = select_landmarks(
        pending, obs.object_category, obs.object_xy, agent_xy, obs.prior, obs.category,
        preset, count=n_lm,
    )  # fmt: skip
    slot = jnp.maximum(choice.index, 0)
    centre, half = obs.object_xy[slot], obs.object_half_extent[slot]
    vp_xy, _, clearance = jax.vmap(viewpoint_candidates, in_axes=(0, 0, None))(
        centre, half, preset
    )  # [L, C, 2], [L, C] metres from the footprint
    vp_cell = xy_to_plan_cell(vp_xy, preset)  # [L, C, 2]
    reach = field[vp_cell[..., 0], vp_cell[..., 1]]
    usable = inside_map(vp_xy, preset) & ~blocked[vp_cell[..., 0], vp_cell[..., 1]]
    usable = usable & jnp.isfinite(reach) & (choice.index >= 0)[:, None]
    # the tightest ring with a usable viewpoint, then the nearest on it: targets are
    # verified within 1 m, so a viewpoint close to the footprint sees more of it
    ring = jnp.where(usable, clearance, jnp.inf)
    tight = usable & (clearance <= jnp.min(ring, axis=-1, keepdims=True))
    best = jnp.argmin(jnp.where(tight, reach, jnp.inf), axis=-1)  # [L]
    rows = jnp.arange(best.shape[0])
    l_valid = usable[rows, best]
    # the centre of the viewpoint's planning cell (where the agent stops): exact, so a
    # batched row and its single run offer the same goal to the last bit
    l_xy = plan_cell_to_xy(vp_cell[rows, best], preset)
    l_dist = reach[rows, best]

    here = xy_to_plan_cell(agent_xy, preset)
    valid = jnp.concatenate([jnp.ones(1, bool), f_valid, l_valid])
    goal_xy = jnp.concatenate([agent_xy[None], f_xy, l_xy])  # stop: where the agent is
    goal_xy = jnp.where(valid[:, None], goal_xy, agent_xy)
    look_xy = jnp.concatenate([agent_xy[None], f_look_xy, centre])
    kind = np.concatenate([[STOP], np.full(n_front, FRONTIER), np.full(n_lm, LANDMARK)])
    zeros_f, zeros_l = jnp.zeros(n_front), jnp.zeros(n_lm)
    return Candidates(
        kind=jnp.asarray(kind, jnp.int32),
        valid=valid,
        goal_xy=goal_xy,
        look_xy=jnp.where(valid[:, None], look_xy, agent_xy),
        look=valid & jnp.concatenate([jnp.zeros(1, bool), f_look, jnp.ones(n_lm, bool)]),
        distance=jnp.where(valid, jnp.concatenate([jnp.zeros(1), f_dist, l_dist]), 0.0),
        size=jnp.where(valid, jnp.concatenate([jnp.zeros(1, jnp.int32), f_size,
                                               jnp.zeros(n_lm, jnp.int32)]), 0),  # fmt: skip
        unknown=jnp.where(valid, jnp.concatenate([jnp.zeros(1), f_unknown, zeros_l]), 0.0),
        reward=jnp.where(valid, jnp.concatenate([jnp.zeros(1), zeros_f, choice.reward]), 0.0),
        landmark=jnp.where(
            valid, jnp.concatenate([jnp.full(1 + n_front, -1, jnp.int32), choice.index]), -1
        ),
        cell=jnp.where(valid[:, None], xy_to_plan_cell(goal_xy, preset), here),
    )


def candidate_observation(cands: Candidates, obs: Observation) -> CandidateObservation:
    """The agent's view of the candidates (features scaled as in ``FEATURES``)."""
    # products with one reciprocal, never divisions: XLA may turn a division into a
    # multiply by the reciprocal in one program and not in another, and a batched row
    # must equal its single run bit for bit
    per_budget = 1.0 / jnp.maximum(obs.budget, 1e-6)
    remaining = obs.remaining
    n = cands.kind.shape[0]
    offset = (cands.goal_xy - obs.pose[:2]) * np.float32(0.1)
    columns = [
        cands.kind == STOP,
        cands.kind == FRONTIER,
        cands.kind == LANDMARK,
        cands.distance * per_budget,
        cands.distance <= remaining,
        cands.size.astype(jnp.float32) * np.float32(0.02),
        cands.unknown,
        cands.reward,
        jnp.broadcast_to(remaining * per_budget, (n,)),
        offset[:, 0],
        offset[:, 1],
    ]
    features = jnp.stack([jnp.asarray(c, jnp.float32) for c in columns], axis=-1)
    features = jnp.where(cands.valid[:, None], features, 0.0)
    return CandidateObservation(
        features=features,
        action_mask=cands.valid,
        kind=cands.kind,
        goal_xy=cands.goal_xy,
        distance=cands.distance,
        pose=obs.pose,
        remaining=remaining,
        budget=obs.budget,
        found=obs.found.sum().astype(jnp.int32),
    )


def candidate_action(cands: Candidates, index: jax.Array) -> Action:
    """The native :class:`Action` of candidate ``index`` (int32 []); a masked index or
    stop keeps the agent where it is."""
    index = jnp.asarray(index, jnp.int32)
    ok = cands.valid[index] & (cands.kind[index] != STOP)
    here = cands.goal_xy[0]
    return Action(
        goal_xy=jnp.where(ok, cands.goal_xy[index], here),
        look_xy=jnp.where(ok, cands.look_xy[index], here),
        look=ok & cands.look[index],
    )


def record_outcome(
    memory: CandidateMemory, index: jax.Array, info: StepInfo, config: CandidateConfig
) -> CandidateMemory:
    """Fold the outcome of the step that executed candidate ``index`` (int32 [], of
    ``memory.candidates``) into the bookkeeping: drop a stalled frontier, retire a visited
    or stalled landmark. The candidates are left as they were (pose new ones next)."""
    cands = memory.candidates
    index = jnp.asarray(index, jnp.int32)
    chosen = cands.valid[index]
    kind = jnp.where(chosen, cands.kind[index], STOP)
    # frontiers: FBE's rule on the chosen goal cell (its stall count restarts on a new goal)
    explore = memory.explore
    goal = jnp.where(kind == FRONTIER, cands.cell[index], -1)
    same = jnp.all(goal == explore.goal)
    explore = explore.replace(goal=goal, stalled=jnp.where(same, explore.stalled, 0))
    explore = FBE(config.explorer).update(explore, None, None, info)
    # landmarks: retired on arrival, or after `patience` macro steps without progress
    progress = (info.travelled > 0.0) | (info.newly_known > 0)
    lm = jnp.where(kind == LANDMARK, cands.landmark[index], -1)
    same_lm = lm == memory.landmark_goal
    stalled = jnp.where(same_lm, memory.landmark_stalled, 0) + jnp.where(progress, 0, 1)
    give_up = info.arrived | info.unreachable | (stalled >= config.explorer.patience)
    retire = (lm >= 0) & give_up
    return memory.replace(
        explore=explore,
        retired=memory.retired.at[jnp.maximum(lm, 0)].max(retire),
        landmark_goal=jnp.where(retire, -1, lm),
        landmark_stalled=jnp.where(retire | (lm < 0), 0, stalled),
    )


def update_candidates(
    memory: CandidateMemory,
    index: jax.Array,
    info: StepInfo,
    after: Observation,
    preset: Preset,
    config: CandidateConfig,
) -> CandidateMemory:
    """:func:`record_outcome`, then the next candidates posed from ``after``."""
    memory = record_outcome(memory, index, info, config)
    return memory.replace(candidates=pose_candidates(memory, after, preset, config))
