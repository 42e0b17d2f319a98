"""SOP instances from the agent's online map (docs/design.md §7.1).

Node 0 is the agent's position (its own zero-reward set 0). Set ``k + 1`` holds the
``preset.n_viewpoints`` viewpoints of landmark of interest ``k`` (k < ``preset.n_loi``):
reachable free points ``viewpoint_min_m .. viewpoint_max_m`` beyond the landmark's
footprint, spread in angle around it. The set reward is the co-occurrence prior
P(c | landmark category); costs are geodesic distances on the optimistic belief map;
the budget is what remains of the episode's budget; the path is open (``end = -1``).

Coverage: one viewpoint does not see all of a large footprint (a 2 m counter top, a
bed) within the verification distance. Each footprint carries ``COVER_POINTS`` coverage
points (the centres of its 3 x 3 split); a viewpoint is usable only if it sees a point
not seen yet (within :func:`cover_radius`) and it faces their centroid. A landmark seen
in part keeps the posterior reward of its unseen part (:func:`covered_reward`), so a
tour strategy visits it again from another side when that pays.

Fixed shapes: N = 1 + n_loi * n_viewpoints nodes and K = 1 + n_loi sets. Missing
landmarks and viewpoints that are blocked or unreachable are padding nodes
(``set_id = -1``); a landmark with no usable viewpoint keeps an empty zero-reward set.
So an agent with no pending landmark gets a valid instance whose plan is empty.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from bfsop_jax.config import Preset, require_preset
from bfsop_jax.navigation.distance import distance_field, distance_matrix
from bfsop_jax.navigation.grid import planning_blocked, xy_to_plan_cell
from bfsop_jax.sop.types import SOPInstance

__all__ = [
    "COVER_POINTS",
    "LandmarkChoice",
    "PART_SPLIT_M",
    "build_instance",
    "completion_viewpoint",
    "cover_radius",
    "coverage_points",
    "covered_from",
    "covered_reward",
    "inside_map",
    "part_masks",
    "select_landmarks",
    "viewpoint_candidates",
]

_N_ANGLES = 16  # candidate directions around a landmark
_N_OFFSETS = 3  # candidate clearances between viewpoint_min_m and viewpoint_max_m
_COVER_GRID = np.array([-2.0 / 3.0, 0.0, 2.0 / 3.0], np.float32)  # cell centres of a 3 x 3 split
COVER_POINTS = _COVER_GRID.size**2
"""Coverage points per landmark footprint (the centres of its 3 x 3 split)."""
_CONE_MARGIN_DEG = 5.0  # a covered point lies this far inside the field of view
PART_SPLIT_M = 1.2
"""With ``parts``, footprints longer than this (metres) are split in three along their
long side, one SOP set each."""


@struct.dataclass
class LandmarkChoice:
    """The landmarks of interest behind an instance's sets."""

    index: jax.Array  # int32 [n_loi]: object slot of LOI k (set k + 1), -1 = empty set
    reward: jax.Array  # float32 [n_loi]: its set reward (0 when empty)
    look: Any = None  # float32 [N, 2]: the point each node's viewpoint faces (build_instance)
    part: Any = None  # bool [n_loi, P]: the coverage points set k + 1 stands for (parts=True)


def coverage_points(centre: jax.Array, half_extent: jax.Array) -> jax.Array:
    """float32 [..., P, 2]: the centres of a 3 x 3 split of each footprint (P = 9).

    Args: centre [..., 2], half_extent [..., 2] metres (axis-aligned footprints).
    A target standing on a landmark lies in one of these cells; a point counts as seen
    when a viewpoint had it within :func:`cover_radius` and inside its field of view.
    """
    fx, fy = np.meshgrid(_COVER_GRID, _COVER_GRID, indexing="ij")
    frac = jnp.asarray(np.stack([fx.ravel(), fy.ravel()], axis=-1))  # [P, 2]
    return centre[..., None, :] + half_extent[..., None, :] * frac


def cover_radius(preset: Preset) -> float:
    """Metres within which a coverage point counts as seen: the verification distance
    less one planning cell (a target lies anywhere in its point's cell)."""
    return preset.verify_distance_m - preset.plan_cell_size


def covered_from(points: jax.Array, pose: jax.Array, preset: Preset) -> jax.Array:
    """bool [..., P]: points within :func:`cover_radius` of ``pose`` and inside its view.

    Args: points [..., P, 2] metres, pose [3] (x, y metres, heading radians). Positions
    and the heading's direction are compared in whole 1/64 m units (exact integers), so
    a batched and a single call decide alike.
    """
    q = jnp.round(points * 64.0).astype(jnp.int32) - jnp.round(pose[:2] * 64.0).astype(jnp.int32)
    d2 = q[..., 0] * q[..., 0] + q[..., 1] * q[..., 1]
    r = int(round(cover_radius(preset) * 64.0))
    h = jnp.round(jnp.stack([jnp.cos(pose[2]), jnp.sin(pose[2])]) * 64.0).astype(jnp.int32)
    dot = q[..., 0] * h[0] + q[..., 1] * h[1]  # |q| <= r: no overflow
    half = math.radians(preset.fov_deg / 2.0 - _CONE_MARGIN_DEG)
    c2 = np.float32(math.cos(half) ** 2)
    h2 = (h[0] * h[0] + h[1] * h[1]).astype(jnp.float32)
    dotf = dot.astype(jnp.float32)
    in_cone = (dot >= 0) & (dotf * dotf >= d2.astype(jnp.float32) * h2 * c2)
    return (d2 <= r * r) & (in_cone | (d2 == 0))


def covered_reward(reward: jax.Array, covered: jax.Array) -> jax.Array:
    """float32 [...]: P(target on the landmark's unseen part | none seen on the rest).

    ``reward`` [...] is the prior P(target | landmark type), ``covered`` [..., P] bool the
    coverage points already seen. With a share ``u`` unseen and targets spread evenly over
    the footprint, Bayes gives ``p u / (1 - p (1 - u))``: 0 once all is seen, ``p`` before.
    """
    p = jnp.asarray(reward, jnp.float32)
    n = covered.shape[-1]
    u = (n - covered.sum(-1)).astype(jnp.float32) / np.float32(n)
    seen = jax.lax.optimization_barrier(p * (1.0 - u))  # no fused multiply-add below
    return jnp.where(u >= 1.0, p, p * u / (1.0 - seen))


def part_masks(half_extent: jax.Array) -> jax.Array:
    """bool [..., 3, P]: the coverage points of each of a footprint's three parts.

    Args: half_extent [..., 2] metres. A footprint longer than :data:`PART_SPLIT_M` is
    split across its long side into three thirds of three points each; a shorter one is
    one part (all points), and its other two parts are empty.
    """
    n = _COVER_GRID.size
    idx = np.arange(COVER_POINTS)
    along_x = np.stack([idx // n == k for k in range(n)])  # [3, P]
    along_y = np.stack([idx % n == k for k in range(n)])
    whole = np.stack([idx >= 0, idx < 0, idx < 0])
    long_x = (half_extent[..., 0] >= half_extent[..., 1])[..., None, None]
    split = (2.0 * jnp.max(half_extent, axis=-1) > PART_SPLIT_M)[..., None, None]
    thirds = jnp.where(long_x, jnp.asarray(along_x), jnp.asarray(along_y))
    return jnp.where(split, thirds, jnp.asarray(whole))


def select_landmarks(
    candidates: jax.Array,
    object_category: jax.Array,
    object_xy: jax.Array,
    agent_xy: jax.Array,
    prior: jax.Array,
    category: jax.Array,
    preset: Preset,
    covered: jax.Array | None = None,
    object_half_extent: jax.Array | None = None,
    count: int | None = None,
) -> LandmarkChoice:
    """Top ``n_loi`` candidate landmarks by reward (nearer first among equals).

    Args:
        candidates: bool [M], landmarks the agent has detected and not yet visited.
        object_category, object_xy: [M], [M, 2] of the detected objects.
        agent_xy: [2] metres.
        prior: float32 [N_CATEGORIES, N_TARGETS].
        category: int32 [] target category.
        covered: optional bool [M, P] coverage points already seen: the reward is then
            :func:`covered_reward` of the prior (a landmark seen in part is worth less).
        object_half_extent: with ``covered``, optional [M, 2] footprints: the sets are then
            landmark *parts* (:func:`part_masks`), each worth its share of the
            landmark's reward by unseen points, and ``part`` says which points each
            set stands for.
        count: how many to return (static; default ``preset.n_loi``; whole landmarks
            only).
    """
    reward = prior[jnp.maximum(object_category, 0), category]
    if covered is not None:
        reward = covered_reward(reward, covered)
    if covered is not None and object_half_extent is not None:
        if count is not None:
            raise ValueError("select_landmarks: count applies to whole landmarks, not parts")
        return _select_parts(candidates, object_category, object_xy, agent_xy, reward,
                             covered, object_half_extent, preset)  # fmt: skip
    ok = candidates & (object_category >= 0) & (reward > 0)
    dist = jnp.linalg.norm(object_xy - agent_xy, axis=-1)
    # Rewards are probabilities in [0, 1]; the distance term only breaks ties.
    score = jnp.where(ok, reward - 1e-6 * dist, -jnp.inf)
    slots = preset.n_loi if count is None else count
    n = min(slots, candidates.shape[-1])
    top, idx = jax.lax.top_k(score, n)
    valid = jnp.isfinite(top)
    idx = jnp.where(valid, idx, -1).astype(jnp.int32)
    rew = jnp.where(valid, reward[jnp.maximum(idx, 0)], 0.0)
    if n < slots:  # fewer object slots than LOI slots (tiny hand-made houses)
        pad = slots - n
        idx = jnp.concatenate([idx, jnp.full(pad, -1, jnp.int32)])
        rew = jnp.concatenate([rew, jnp.zeros(pad, rew.dtype)])
    return LandmarkChoice(index=idx, reward=rew.astype(jnp.float32))


def _select_parts(
    candidates: jax.Array,
    object_category: jax.Array,
    object_xy: jax.Array,
    agent_xy: jax.Array,
    reward: jax.Array,
    covered: jax.Array,
    half_extent: jax.Array,
    preset: Preset,
) -> LandmarkChoice:
    """:func:`select_landmarks` over landmark parts: the top ``n_loi`` (landmark, part)."""
    masks = part_masks(half_extent)  # [M, 3, P]
    unseen = masks & ~covered[:, None, :]
    n_part = unseen.sum(-1).astype(jnp.float32)  # [M, 3]
    n_all = jnp.maximum((~covered).sum(-1), 1).astype(jnp.float32)  # [M]
    part_reward = reward[:, None] * n_part / n_all[:, None]  # sums to the landmark's
    ok = candidates[:, None] & (object_category >= 0)[:, None] & (part_reward > 0)
    dist = jnp.linalg.norm(object_xy - agent_xy, axis=-1)
    score = jnp.where(ok, part_reward - 1e-6 * dist[:, None], -jnp.inf).reshape(-1)
    n = min(preset.n_loi, score.shape[-1])
    top, pair = jax.lax.top_k(score, n)
    valid = jnp.isfinite(top)
    m, k = pair // 3, pair % 3
    idx = jnp.where(valid, m, -1).astype(jnp.int32)
    rew = jnp.where(valid, part_reward.reshape(-1)[pair], 0.0)
    part = masks[m, k] & valid[:, None]
    if n < preset.n_loi:
        pad = preset.n_loi - n
        idx = jnp.concatenate([idx, jnp.full(pad, -1, jnp.int32)])
        rew = jnp.concatenate([rew, jnp.zeros(pad, rew.dtype)])
        part = jnp.concatenate([part, jnp.zeros((pad, COVER_POINTS), bool)])
    return LandmarkChoice(index=idx, reward=rew.astype(jnp.float32), part=part)


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

    # clearance(t) is monotone in t: bisect for clearance(t) == offset. Unrolled: the same
    # arithmetic (bit for bit), but one fused kernel instead of 24 loop iterations of
    # small ones, which cost the candidate interface a quarter of its step time
    def bisect(_, bounds):
        lo, hi = bounds
        mid = 0.5 * (lo + hi)
        short = clearance(mid) < offset
        return jnp.where(short, mid, lo), jnp.where(short, hi, mid)

    hi = jnp.full(angle.shape, 1.0) * (jnp.linalg.norm(half_extent) + offset)
    lo, hi = jax.lax.fori_loop(0, 24, bisect, (jnp.zeros_like(hi), hi), unroll=True)
    xy = centre + direction * hi[:, None]
    return xy, jnp.asarray(angle), jnp.asarray(offset)


def inside_map(xy: jax.Array, preset: Preset) -> jax.Array:
    """bool [...]: the points ``xy`` [..., 2] (metres) lie on the planning grid."""
    hp, wp = preset.plan_shape
    return (
        (xy[..., 0] >= 0)
        & (xy[..., 1] >= 0)
        & (xy[..., 0] < wp * preset.plan_cell_size)
        & (xy[..., 1] < hp * preset.plan_cell_size)
    )


def _viewpoint_coverage(
    xy: jax.Array, points: jax.Array, unseen: jax.Array, centre: jax.Array, preset: Preset
) -> tuple[jax.Array, jax.Array]:
    """What a visit to each candidate viewpoint would mark, and where it looks.

    Args: xy [C, 2] candidate viewpoints, points [P, 2] a landmark's coverage points,
    unseen [P] bool, centre [2] the landmark's centre (metres). A viewpoint faces the
    centroid of the unseen points within :func:`cover_radius` (the centre when there is
    none) and marks those of them :func:`covered_from` accepts from there: the test made
    on arrival, so a viewpoint is offered only if it really sees something new.
    Returns ``(sees [C, P] bool, look [C, 2])``.
    """
    gap = xy[:, None, :] - points[None, :, :]  # [C, P, 2]
    near = (jnp.sum(gap * gap, axis=-1) <= cover_radius(preset) ** 2) & unseen[None, :]
    n_near = near.sum(-1)
    centroid = jnp.sum(jnp.where(near[..., None], points[None], 0.0), axis=1)
    look = jnp.where(
        (n_near > 0)[:, None],
        centroid / jnp.maximum(n_near, 1)[:, None].astype(jnp.float32),
        centre[None, :],
    )
    facing = jnp.arctan2(look[:, 1] - xy[:, 1], look[:, 0] - xy[:, 0])
    pose = jnp.concatenate([xy, facing[:, None]], axis=-1)  # [C, 3]
    sees = jax.vmap(lambda p: covered_from(points, p, preset))(pose) & unseen[None, :]
    return sees, look


def completion_viewpoint(
    belief: jax.Array,
    agent_xy: jax.Array,
    centre: jax.Array,
    half_extent: jax.Array,
    covered: jax.Array,
    preset: Preset,
) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """The next viewpoint that completes the coverage of a landmark just visited.

    Args: belief [H, W] log-odds (the agent's map), agent_xy [2], centre [2] and
    half_extent [2] of the landmark (metres), covered [P] bool its coverage points seen.
    Among the candidate viewpoints (:func:`viewpoint_candidates`) on free planning cells
    that see an unseen point, the one nearest the agent (geodesic, optimistic map).
    Returns ``(ok bool [], xy [2], look [2], metres [])``: ``ok`` is false when none is
    left; ``metres`` is its geodesic distance on the optimistic map.
    """
    xy, _, _ = viewpoint_candidates(centre, half_extent, preset)  # [C, 2]
    points = coverage_points(centre, half_extent)  # [P, 2]
    sees, look = _viewpoint_coverage(xy, points, ~covered, centre, preset)
    cells = xy_to_plan_cell(xy, preset)
    inside = inside_map(xy, preset)
    blocked = planning_blocked(belief, preset)
    reach = distance_field(blocked, agent_xy, preset)[cells[:, 0], cells[:, 1]]
    usable = inside & ~blocked[cells[:, 0], cells[:, 1]] & jnp.any(sees, axis=-1)
    usable = usable & jnp.isfinite(reach)
    best = jnp.argmin(jnp.where(usable, reach, jnp.inf))
    return usable[best], xy[best], look[best], jnp.where(usable[best], reach[best], 0.0)


def _choose_spread(
    usable: jax.Array, angle: jax.Array, offset: jax.Array, k: int, seen: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """Greedily pick ``k`` usable candidates spread in angle (closest clearance first).

    ``seen`` [C] is the share of the landmark each candidate would cover (0 without
    coverage); among candidates equally spread, those that cover more come first.
    Returns ``(index [k], valid [k])``.
    """
    # tight viewpoints see the landmark's surface best; covering viewpoints see more of it
    preference = 10.0 * seen - offset

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
    covered: jax.Array | None = None,
    parts: bool = False,
    split: jax.Array | bool = True,
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
        covered: optional bool [M, P] coverage points of each landmark already seen
            (:func:`coverage_points`); default None: no coverage, every viewpoint faces the
            landmark's centre. With it, a viewpoint is usable only if it sees an unseen
            point (:func:`covered_from`), and faces the centroid of those within reach.
        parts: with ``covered``, the sets are landmark parts (:func:`select_landmarks`):
            a set's viewpoints must see an unseen point of its part.
        split: with ``parts``, bool [] (may be traced): False makes every footprint one
            part, so each set is a whole landmark again.

    Returns ``(instance, landmarks)``: N = 1 + n_loi * n_viewpoints, K = 1 + n_loi;
    ``landmarks.look`` [N, 2] is the point each node's viewpoint faces.
    """
    preset = require_preset(preset)
    agent_xy = jnp.asarray(agent_xy, jnp.float32)
    blocked = planning_blocked(belief, preset)
    if parts and covered is None:
        raise ValueError("build_instance: parts=True needs covered (the coverage points seen)")
    choice = select_landmarks(
        candidates, object_category, object_xy, agent_xy, prior, category, preset, covered,
        jnp.where(split, object_half_extent, 0.0) if parts else None,
    )  # fmt: skip
    lm = jnp.maximum(choice.index, 0)
    has_lm = choice.index >= 0

    xy, angle, offset = jax.vmap(viewpoint_candidates, in_axes=(0, 0, None))(
        object_xy[lm], object_half_extent[lm], preset
    )  # [L, C, 2], [L, C], [L, C]
    cells = xy_to_plan_cell(xy, preset)
    inside = inside_map(xy, preset)
    from_agent = distance_field(blocked, agent_xy, preset)
    reach = from_agent[cells[..., 0], cells[..., 1]]
    usable = inside & ~blocked[cells[..., 0], cells[..., 1]] & jnp.isfinite(reach)
    usable = usable & has_lm[:, None]
    if covered is None:  # every viewpoint faces the landmark's centre
        look_c = jnp.broadcast_to(object_xy[lm][:, None, :], xy.shape)
        share = jnp.zeros(xy.shape[:-1], jnp.float32)
    else:  # a viewpoint must see a coverage point not seen yet, and faces their centroid
        points = coverage_points(object_xy[lm], object_half_extent[lm])  # [L, P, 2]
        unseen = ~covered[lm] if choice.part is None else ~covered[lm] & choice.part
        sees, look_c = jax.vmap(_viewpoint_coverage, in_axes=(0, 0, 0, 0, None))(
            xy, points, unseen, object_xy[lm], preset
        )  # [L, C, P], [L, C, 2]
        usable = usable & jnp.any(sees, axis=-1)
        share = sees.sum(-1).astype(jnp.float32) / np.float32(COVER_POINTS)

    pick, pick_ok = jax.vmap(_choose_spread, in_axes=(0, 0, 0, None, 0))(
        usable, angle, offset, preset.n_viewpoints, share
    )  # [L, V]
    vp_xy = jnp.take_along_axis(xy, pick[..., None], axis=1)  # [L, V, 2]
    vp_look = jnp.take_along_axis(look_c, pick[..., None], axis=1)  # [L, V, 2]

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
    look = jnp.concatenate([agent_xy[None], vp_look.reshape(-1, 2)], axis=0)
    return instance, choice.replace(reward=set_reward[1:], look=look)
