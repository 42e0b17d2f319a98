"""The navigation environment: pure ``reset`` / ``step`` over :class:`EnvState`.

One ``step`` is a macro action (docs/world.md, "Environment"): the geodesic distance field
from the goal is computed once on the optimistic belief map, then the agent makes up to
``preset.micro_steps`` motion steps along it. A motion step moves from the centre of a
planning cell to the centre of a neighbouring one (0.2 m straight, 0.28 m diagonally),
facing its direction of motion, and senses (mapping + detection) on arrival. Two gates
stop it early:

* budget gate: the last motion step is shortened so that L reaches B exactly, then the
  episode is done;
* traversability gate: when the next cell turns out blocked on the updated belief (an
  obstacle seen during this step) the agent stops (``StepInfo.blocked``); the caller
  replans or drops the goal.

On arrival with ``action.look`` the agent turns to face ``action.look_xy`` and senses once
more (turning is free).

Exact by construction: positions are planning-cell centres, move lengths and headings
come from small tables, headings are whole angle units and every test a decision hinges
on is integer arithmetic or a single rounding of exact values. So an episode is the same
bit for bit alone or inside a ``jax.vmap`` batch (XLA fuses batched programs differently,
which changes the rounding of general float expressions).

Both functions are pure and shape-stable, so ``jax.jit(jax.vmap(step, in_axes=(0, 0, None)),
static_argnums=2)`` compiles once per preset. The caller (an agent strategy) decides when
there is nothing left to do; the environment only closes the budget gate.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from bfsop_jax.config import Preset, get_preset
from bfsop_jax.env.types import Action, EnvState, Observation, StepInfo
from bfsop_jax.navigation.distance import distance_field
from bfsop_jax.navigation.grid import (
    cell_blocked,
    motion_blocked,
    plan_cell_to_xy,
    planning_blocked,
    true_blocked,
    xy_to_plan_cell,
)
from bfsop_jax.navigation.path import NEIGHBOURS, move_headings, move_lengths, next_cell
from bfsop_jax.sensing.detection import landmarks_of_interest, verified_targets
from bfsop_jax.sensing.detection import observe as detect
from bfsop_jax.sensing.mapping import (
    ANGLE_UNITS,
    bearing_units,
    heading_from_units,
    quantised_heading,
    update_belief,
)
from bfsop_jax.world.constants import N_CATEGORIES, N_TARGETS, is_receptacle
from bfsop_jax.world.types import House

__all__ = ["reset", "step", "sense", "observe", "make_action", "sample_start_pose"]


def sense(state: EnvState, pose: jax.Array, preset: Preset, active: jax.Array = True) -> EnvState:
    """Sense from ``pose``: ray-cast mapping, then target verification and LOI detection.

    ``active`` (bool []) masks the whole update, so callers can sense conditionally
    without ``lax.cond`` (which becomes a select under ``vmap`` anyway).
    """
    belief = update_belief(state.belief, state.house.occupied, pose, preset)
    det = detect(state.house, pose, preset)
    found = verified_targets(det, state.house, state.category, preset)
    lois = landmarks_of_interest(det, state.house, state.prior, state.category, preset)
    # Any large enough receptacle, so a partial map can later pose tasks of any category.
    receptacles = (
        det.in_view
        & (det.area_px >= preset.landmark_px)
        & is_receptacle(state.house.object_category)
    )
    active = jnp.asarray(active)
    return state.replace(
        belief=jnp.where(active, belief, state.belief),
        found=state.found | (found & active),
        landmarks_seen=state.landmarks_seen | (lois & active),
        receptacles_seen=state.receptacles_seen | (receptacles & active),
    )


def observe(state: EnvState) -> Observation:
    """The agent's view of ``state``: its map, pose, budget and what it has detected.

    An object slot is visible once the object was detected: a receptacle segmented at
    landmark size, a landmark of interest, or a verified target. Everything else about the
    true house (its occupancy, unseen objects, the number of targets) stays hidden.
    """
    house = state.house
    seen = state.receptacles_seen | state.landmarks_seen | state.found
    return Observation(
        belief=state.belief,
        pose=state.pose,
        path_length=state.path_length,
        budget=state.budget,
        category=state.category,
        prior=state.prior,
        object_seen=seen,
        object_category=jnp.where(seen, house.object_category, -1),
        object_xy=jnp.where(seen[:, None], house.object_xy, 0.0),
        object_half_extent=jnp.where(seen[:, None], house.object_half_extent, 0.0),
        landmark=state.landmarks_seen,
        found=state.found,
        done=state.done,
    )


def sample_start_pose(key: jax.Array, house: House, preset: Preset) -> jax.Array:
    """A uniformly random start pose [3] at the centre of a robot-traversable planning cell.

    Cells whose 3x3 neighbourhood is entirely traversable are preferred, so the start is
    never wedged in a pocket between furniture. The heading is a uniformly random whole
    angle unit. Integer sampling only (no Gumbel trick), so the draw is exact.
    """
    blocked = true_blocked(house.occupied, preset)
    free = ~blocked
    padded = jnp.pad(free, 1, constant_values=False)
    hp, wp = free.shape
    interior = free
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            interior = interior & padded[1 + di : 1 + di + hp, 1 + dj : 1 + dj + wp]
    candidates = jnp.where(interior.any(), interior, free).ravel()
    k_cell, k_heading = jax.random.split(key)
    rank = jax.random.randint(k_cell, (), 0, jnp.maximum(candidates.sum(), 1))
    flat = jnp.argmax(jnp.cumsum(candidates) > rank)
    cell = jnp.stack([flat // wp, flat % wp]).astype(jnp.int32)
    xy = plan_cell_to_xy(cell, preset)
    heading = heading_from_units(jax.random.randint(k_heading, (), 0, ANGLE_UNITS))
    return jnp.concatenate([xy, heading[None]]).astype(jnp.float32)


def reset(
    key: jax.Array,
    house: House,
    category: jax.Array | int,
    preset: Preset | str,
    prior: jax.Array | None = None,
    budget: jax.Array | float | None = None,
) -> EnvState:
    """Start an episode: random start pose, empty belief, then a 360 degree initial look.

    Args:
        key: PRNG key for the start pose.
        house: the true world.
        category: target category id (int32 []; see ``bfsop_jax.world.TARGET_NAMES``).
        preset: preset (static).
        prior: float32 [N_CATEGORIES, N_TARGETS] co-occurrence prior; default: the one
            estimated from training houses (``bfsop_jax.world.prior.default_prior``).
        budget: travel budget B in metres; default ``preset.budget_m``.
    """
    preset = get_preset(preset)
    if prior is None:
        from bfsop_jax.world.prior import default_prior

        prior = default_prior()
    prior = jnp.asarray(prior, jnp.float32)
    if prior.shape[-2:] != (N_CATEGORIES, N_TARGETS):
        raise ValueError(
            f"prior must have shape [{N_CATEGORIES}, {N_TARGETS}], got {tuple(prior.shape)}"
        )
    budget = jnp.asarray(preset.budget_m if budget is None else budget, jnp.float32)
    pose = sample_start_pose(key, house, preset)
    m = house.object_category.shape[-1]
    state = EnvState(
        house=house,
        category=jnp.asarray(category, jnp.int32),
        prior=prior,
        belief=jnp.zeros(house.occupied.shape, jnp.float32),
        pose=pose,
        path_length=jnp.zeros((), jnp.float32),
        budget=budget,
        found=jnp.zeros((m,), bool),
        landmarks_seen=jnp.zeros((m,), bool),
        receptacles_seen=jnp.zeros((m,), bool),
        steps=jnp.zeros((), jnp.int32),
        done=budget <= 0.0,
    )

    def look(state, quarter):
        heading = heading_from_units(quantised_heading(pose[2]) + quarter * (ANGLE_UNITS // 4))
        return sense(state, pose.at[2].set(heading), preset), None

    state, _ = jax.lax.scan(look, state, jnp.arange(4, dtype=jnp.int32))
    return state


def make_action(goal_xy, look_xy=None) -> Action:
    """Build an :class:`Action`; with ``look_xy`` the agent faces that point on arrival."""
    goal_xy = jnp.asarray(goal_xy, jnp.float32)
    if look_xy is None:
        return Action(goal_xy=goal_xy, look_xy=goal_xy, look=jnp.zeros(goal_xy.shape[:-1], bool))
    return Action(
        goal_xy=goal_xy,
        look_xy=jnp.asarray(look_xy, jnp.float32),
        look=jnp.ones(goal_xy.shape[:-1], bool),
    )


def _partial_move_xy(cell: jax.Array, move: jax.Array, fraction: jax.Array, preset: Preset):
    """The point ``fraction`` of the way from ``cell``'s centre along ``move`` (metres [2]).

    The fraction is rounded to 1/256 (0.8 mm at 0.2 m cells) so that
    ``cell + 1/2 + fraction * offset`` is exact in float32; the only rounding is the final
    multiply by the cell size.
    """
    q = jnp.round(jnp.clip(fraction, 0.0, 1.0) * 256.0) * np.float32(1.0 / 256.0)
    off = jnp.asarray(NEIGHBOURS)[jnp.maximum(move, 0)].astype(jnp.float32)
    rc = cell.astype(jnp.float32) + 0.5 + q * off
    return jnp.stack([rc[1], rc[0]]) * np.float32(preset.plan_cell_size)


def _known_count(belief: jax.Array, preset: Preset) -> jax.Array:
    return jnp.sum(jnp.abs(belief) > preset.logodds_known, dtype=jnp.int32)


def step(state: EnvState, action: Action, preset: Preset | str) -> tuple[EnvState, StepInfo]:
    """Execute one macro action (up to ``preset.micro_steps`` motion steps).

    Returns the new state and a :class:`StepInfo`. Path length accumulates the exact
    polyline length moved; the budget gate makes the final step end at L == B exactly.
    """
    preset = get_preset(preset)
    # The map at planning time: the gate refuses only cells that newly seen obstacles
    # block, so it never disagrees with the path the planner allowed.
    planned = planning_blocked(state.belief, preset)
    field = distance_field(
        motion_blocked(state.belief, state.pose[:2], preset, planned), action.goal_xy, preset
    )
    lengths = jnp.asarray(move_lengths(preset))
    headings = jnp.asarray(move_headings())
    found_before = state.found.sum()
    known_before = _known_count(state.belief, preset)

    def motion_step(carry, _):
        state, arrived, blocked, unreachable = carry
        active = ~state.done & ~arrived & ~blocked & ~unreachable
        cell = xy_to_plan_cell(state.pose[:2], preset)
        nxt, move, at_goal, ok = next_cell(field, cell, preset)
        wants_move = active & (move >= 0)
        refused = cell_blocked(state.belief, nxt, preset) & ~planned[nxt[0], nxt[1]]
        moving = wants_move & ~refused
        length = lengths[jnp.maximum(move, 0)]
        remaining = jnp.maximum(state.budget - state.path_length, 0.0)
        # The budget gate: a move longer than what is left stops part way, at L == B.
        at_budget = moving & (length >= remaining)
        xy = jnp.where(
            at_budget,
            _partial_move_xy(cell, move, remaining / length, preset),
            plan_cell_to_xy(nxt, preset),
        )
        heading = heading_from_units(headings[jnp.maximum(move, 0)])
        travelled = jnp.where(at_budget, remaining, length)
        path_length = jnp.where(at_budget, state.budget, state.path_length + length)
        state = state.replace(
            pose=jnp.where(moving, jnp.concatenate([xy, heading[None]]), state.pose),
            path_length=jnp.where(moving, path_length, state.path_length),
        )
        state = sense(state, state.pose, preset, active=moving)
        state = state.replace(done=state.done | (state.path_length >= state.budget))
        entered_goal = moving & ~at_budget & (field[nxt[0], nxt[1]] == 0.0)
        carry = (
            state,
            arrived | (active & at_goal) | entered_goal,
            blocked | (wants_move & refused),
            unreachable | (active & ~ok),
        )
        out = (
            state.pose,
            moving,
            jnp.where(moving, travelled, 0.0),
            state.path_length,
            state.found.sum().astype(jnp.int32),
        )
        return carry, out

    init = (state, jnp.zeros((), bool), jnp.zeros((), bool), jnp.zeros((), bool))
    (state, arrived, blocked, unreachable), micro = jax.lax.scan(
        motion_step, init, None, length=preset.micro_steps
    )
    poses, moved, travelled, path_lengths, found_counts = micro

    # On arrival at a viewpoint: face the landmark and sense once more (turning is free).
    facing = state.pose.at[2].set(
        heading_from_units(bearing_units(action.look_xy - state.pose[:2]))
    )
    do_look = arrived & action.look & ~state.done
    state = sense(state, facing, preset, active=do_look)
    state = state.replace(pose=jnp.where(do_look, facing, state.pose), steps=state.steps + 1)

    info = StepInfo(
        poses=poses,
        moved=moved,
        travelled=travelled.sum(),
        arrived=arrived,
        blocked=blocked,
        unreachable=unreachable,
        new_found=(state.found.sum() - found_before).astype(jnp.int32),
        path_lengths=path_lengths,
        found_counts=found_counts,
        newly_known=_known_count(state.belief, preset) - known_before,
    )
    return state, info
