"""SOP instances from the agent's online map (docs/design.md §7.1).

Node 0 is the agent's position (its own zero-reward set 0). Set ``k + 1`` holds the
``preset.n_viewpoints`` viewpoints of landmark of interest ``k`` (k < ``preset.n_loi``):
reachable free points ``viewpoint_min_m .. viewpoint_max_m`` beyond the landmark's
footprint, spread in angle around it. The set reward is the co-occurrence prior
P(c | landmark category); costs are geodesic distances on the optimistic belief map;
the budget is what remains of the episode's budget; the path is open (``end = -1``).

Fixed shapes: N = 1 + n_loi * n_viewpoints nodes and K = 1 + n_loi sets. Missing
landmarks and viewpoints that are blocked or unreachable are padding nodes
(``set_id = -1``); a landmark with no usable viewpoint keeps an empty zero-reward set.
So an agent with no pending landmark gets a valid instance whose plan is empty.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from bfsop_jax.config import Preset, require_preset
from bfsop_jax.navigation.distance import distance_field, distance_matrix
from bfsop_jax.navigation.grid import planning_blocked, xy_to_plan_cell
from bfsop_jax.sop.types import SOPInstance

__all__ = ["LandmarkChoice", "build_instance", "select_landmarks", "viewpoint_candidates"]

_N_ANGLES = 16  # candidate directions around a landmark
_N_OFFSETS = 3  # candidate clearances between viewpoint_min_m and viewpoint_max_m


@struct.dataclass
class LandmarkChoice:
    """The landmarks of interest behind an instance's sets."""

    index: jax.Array  # int32 [n_loi]: object slot of LOI k (set k + 1), -1 = empty set
    reward: jax.Array  # float32 [n_loi]: its set reward (0 when empty)


def select_landmarks(
    candidates: jax.Array,
    object_category: jax.Array,
    object_xy: jax.Array,
    agent_xy: jax.Array,
    prior: jax.Array,
    category: jax.Array,
    preset: Preset,
) -> LandmarkChoice:
    """Top ``n_loi`` candidate landmarks by prior reward (nearer first among equals).

    Args:
        candidates: bool [M], landmarks the agent has detected and not yet visited.
        object_category, object_xy: [M], [M, 2] of the detected objects.
        agent_xy: [2] metres.
        prior: float32 [N_CATEGORIES, N_TARGETS].
        category: int32 [] target category.
    """
    reward = prior[jnp.maximum(object_category, 0), category]
    ok = candidates & (object_category >= 0) & (reward > 0)
    dist = jnp.linalg.norm(object_xy - agent_xy, axis=-1)
    # Rewards are probabilities in [0, 1]; the distance term only breaks ties.
    score = jnp.where(ok, reward - 1e-6 * dist, -jnp.inf)
    n = min(preset.n_loi, candidates.shape[-1])
    top, idx = jax.lax.top_k(score, n)
    valid = jnp.isfinite(top)
    idx = jnp.where(valid, idx, -1).astype(jnp.int32)
    rew = jnp.where(valid, reward[jnp.maximum(idx, 0)], 0.0)
    if n < preset.n_loi:  # fewer object slots than LOI slots (tiny hand-made houses)
        pad = preset.n_loi - n
        idx = jnp.concatenate([idx, jnp.full(pad, -1, jnp.int32)])
        rew = jnp.concatenate([rew, jnp.zeros(pad, rew.dtype)])
    return LandmarkChoice(index=idx, reward=rew.astype(jnp.float32))


def _candidate_offsets(preset: Preset) -> tuple[np.ndarray, np.ndarray]:
    angles = np.arange(_N_ANGLES) * (2 * math.pi / _N_ANGLES)
    offsets = np.linspace(preset.viewpoint_min_m, preset.viewpoint_max_m, _N_OFFSETS)
    a, o = np.meshgrid(angles, offsets, indexing="ij")  # [A, R]
    return a.ravel().astype(np.float32), o.ravel().astype(np.float32)


def viewpoint_candidates(
    centre: jax.Array, half_extent: jax.Array, preset: Preset
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Candidate viewpoints around one landmark footprint.

    Returns ``(xy [C, 2], angle [C], offset [C])`` with C = 16 directions x 3 clearances:
    the point in direction ``angle`` from the centre whose Euclidean distance to the
    axis-aligned footprint is exactly ``offset`` metres (a rounded-rectangle ring).
    """
    angle, offset = _candidate_offsets(preset)
    direction = jnp.stack([jnp.cos(angle), jnp.sin(angle)], axis=-1)

    def clearance(t):  # distance from centre + t * direction to the footprint, [C]
        gap = jnp.abs(t[:, None] * direction) - half_extent
        return jnp.linalg.norm(jnp.maximum(gap, 0.0), axis=-1)

    # clearance(t) is monotone in t: bisect for clearance(t) == offset.
    def bisect(_, bounds):
        lo, hi = bounds
        mid = 0.5 * (lo + hi)
        short = clearance(mid) < offset
        return jnp.where(short, mid, lo), jnp.where(short, hi, mid)

    hi = jnp.full(angle.shape, 1.0) * (jnp.linalg.norm(half_extent) + offset)
    lo, hi = jax.lax.fori_loop(0, 24, bisect, (jnp.zeros_like(hi), hi))
    xy = centre + direction * hi[:, None]
    return xy, jnp.asarray(angle), jnp.asarray(offset)


def _choose_spread(
    usable: jax.Array, angle: jax.Array, offset: jax.Array, k: int
) -> tuple[jax.Array, jax.Array]:
    """Greedily pick ``k`` usable candidates spread in angle (closest clearance first).

    Returns ``(index [k], valid [k])``.
    """
    preference = -offset  # tight viewpoints see the landmark's surface best

    def pick(carry, _):
        taken, picked_angles, n_picked = carry
        diff = jnp.abs(angle[:, None] - picked_angles[None, :])
        diff = jnp.minimum(diff, 2 * math.pi - diff)
        slot_used = jnp.arange(k)[None, :] < n_picked
        spread = jnp.min(jnp.where(slot_used, diff, math.pi), axis=1)
        score = jnp.where(usable & ~taken, spread + 0.1 * preference, -jnp.inf)
        i = jnp.argmax(score)
        ok = jnp.isfinite(score[i])
        taken = taken.at[i].set(taken[i] | ok)
        picked_angles = picked_angles.at[n_picked].set(jnp.where(ok, angle[i], 0.0))
        return (taken, picked_angles, n_picked + ok.astype(jnp.int32)), (i, ok)

    init = (jnp.zeros_like(usable), jnp.zeros(k, jnp.float32), jnp.zeros((), jnp.int32))
    _, (index, valid) = jax.lax.scan(pick, init, None, length=k)
    return index.astype(jnp.int32), valid


def build_instance(
    belief: jax.Array,
    agent_xy: jax.Array,
    remaining_budget: jax.Array,
    candidates: jax.Array,
    object_category: jax.Array,
    object_xy: jax.Array,
    object_half_extent: jax.Array,
    prior: jax.Array,
    category: jax.Array,
    preset: Preset,
) -> tuple[SOPInstance, LandmarkChoice]:
    """The SOP instance of the current exploitation decision (jit/vmap-able).

    Args:
        belief: float32 [H, W] occupancy log-odds (the online map).
        agent_xy: float32 [2], the start node.
        remaining_budget: float32 [], B - L in metres.
        candidates: bool [M], detected, not yet visited landmarks of interest.
        object_category, object_xy, object_half_extent: [M], [M, 2], [M, 2] of the
            detected landmarks (their observed type, position and footprint).
        prior: float32 [N_CATEGORIES, N_TARGETS] co-occurrence prior.
        category: int32 [] target category.

    Returns ``(instance, landmarks)``: N = 1 + n_loi * n_viewpoints, K = 1 + n_loi.
    """
    preset = require_preset(preset)
    agent_xy = jnp.asarray(agent_xy, jnp.float32)
    blocked = planning_blocked(belief, preset)
    choice = select_landmarks(
        candidates, object_category, object_xy, agent_xy, prior, category, preset
    )
    lm = jnp.maximum(choice.index, 0)
    has_lm = choice.index >= 0

    xy, angle, offset = jax.vmap(viewpoint_candidates, in_axes=(0, 0, None))(
        object_xy[lm], object_half_extent[lm], preset
    )  # [L, C, 2], [L, C], [L, C]
    hp, wp = preset.plan_shape
    cells = xy_to_plan_cell(xy, preset)
    inside = (
        (xy[..., 0] >= 0)
        & (xy[..., 1] >= 0)
        & (xy[..., 0] < wp * preset.plan_cell_size)
        & (xy[..., 1] < hp * preset.plan_cell_size)
    )
    from_agent = distance_field(blocked, agent_xy, preset)
    reach = from_agent[cells[..., 0], cells[..., 1]]
    usable = inside & ~blocked[cells[..., 0], cells[..., 1]] & jnp.isfinite(reach)
    usable = usable & has_lm[:, None]

    pick, pick_ok = jax.vmap(_choose_spread, in_axes=(0, 0, 0, None))(
        usable, angle, offset, preset.n_viewpoints
    )  # [L, V]
    vp_xy = jnp.take_along_axis(xy, pick[..., None], axis=1)  # [L, V, 2]

    n_nodes = preset.n_sop_nodes
    coords = jnp.concatenate([agent_xy[None], vp_xy.reshape(-1, 2)], axis=0)
    vp_valid = pick_ok.reshape(-1)
    valid = jnp.concatenate([jnp.ones(1, bool), vp_valid])
    set_of_vp = jnp.repeat(jnp.arange(1, preset.n_loi + 1, dtype=jnp.int32), preset.n_viewpoints)
    set_id = jnp.concatenate([jnp.zeros(1, jnp.int32), jnp.where(vp_valid, set_of_vp, -1)])
    coords = jnp.where(valid[:, None], coords, agent_xy[None])
    cost = distance_matrix(blocked, coords, valid, preset)

    set_has_node = pick_ok.any(axis=1)
    set_reward = jnp.concatenate(
        [jnp.zeros(1, jnp.float32), jnp.where(set_has_node, choice.reward, 0.0)]
    )
    instance = SOPInstance(
        cost=cost,
        set_id=set_id,
        set_reward=set_reward,
        start=jnp.zeros((), jnp.int32),
        end=jnp.full((), -1, jnp.int32),
        budget=jnp.maximum(jnp.asarray(remaining_budget, jnp.float32), 0.0),
        coords=coords,
    )
    assert coords.shape == (n_nodes, 2)
    return instance, choice.replace(reward=set_reward[1:])
