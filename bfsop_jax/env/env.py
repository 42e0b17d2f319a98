"""The navigation environment: pure ``reset`` / ``step`` over :class:`EnvState`.

One ``step`` is a macro action (SPEC 5): the geodesic distance field from the goal is
computed once on the optimistic belief map, then the agent makes ``preset.micro_steps``
motion steps of ``preset.move_step_m`` along it, turning to face its direction of motion
and sensing (mapping + detection) after every step. Two gates stop it early:

* budget gate: the last motion step is shortened so that L reaches B exactly, then the
  episode is done;
* traversability gate: when the next position turns out not traversable on the updated
  belief the agent stops (``StepInfo.blocked``); the caller replans or drops the goal.

Both functions are pure and shape-stable, so ``jax.jit(jax.vmap(step, in_axes=(0, 0, None)),
static_argnums=2)`` compiles once per preset. The caller (an agent strategy) decides when
there is nothing left to do; the environment only closes the budget gate.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from bfsop_jax.config import Preset, get_preset
from bfsop_jax.env.types import Action, EnvState, StepInfo
from bfsop_jax.navigation.distance import distance_field
from bfsop_jax.navigation.grid import (
    plan_cell_to_xy,
    planning_blocked,
    true_blocked,
    xy_to_plan_cell,
)
from bfsop_jax.navigation.path import advance, is_traversable
from bfsop_jax.sensing.detection import landmarks_of_interest, observe, verified_targets
from bfsop_jax.sensing.mapping import update_belief
from bfsop_jax.world.constants import N_CATEGORIES, N_TARGETS, is_receptacle
from bfsop_jax.world.types import House

__all__ = ["reset", "step", "sense", "make_action", "sample_start_pose"]


def sense(state: EnvState, pose: jax.Array, preset: Preset, active: jax.Array = True) -> EnvState:
    """Sense from ``pose``: ray-cast mapping, then target verification and LOI detection.

    ``active`` (bool []) masks the whole update, so callers can sense conditionally
    without ``lax.cond`` (which becomes a select under ``vmap`` anyway).
    """
    belief = update_belief(state.belief, state.house.occupied, pose, preset)
    det = observe(state.house, pose, preset)
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


def sample_start_pose(key: jax.Array, house: House, preset: Preset) -> jax.Array:
    """A uniformly random start pose [3] on a robot-traversable planning cell.

    Cells whose 3x3 neighbourhood is entirely traversable are preferred, so the start is
    never wedged in a pocket between furniture.
    """
    blocked = true_blocked(house.occupied, preset)
    free = ~blocked
    padded = jnp.pad(free, 1, constant_values=False)
    hp, wp = free.shape
    interior = free
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            interior = interior & padded[1 + di : 1 + di + hp, 1 + dj : 1 + dj + wp]
    candidates = jnp.where(interior.any(), interior, free)
    k_cell, k_heading = jax.random.split(key)
    flat = jax.random.categorical(k_cell, jnp.where(candidates.ravel(), 0.0, -jnp.inf))
    cell = jnp.stack([flat // wp, flat % wp]).astype(jnp.int32)
    xy = plan_cell_to_xy(cell, preset)
    heading = jax.random.uniform(k_heading, (), minval=-math.pi, maxval=math.pi)
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
        heading = pose[2] + quarter * (math.pi / 2)
        return sense(state, pose.at[2].set(heading), preset), None

    state, _ = jax.lax.scan(look, state, jnp.arange(4, dtype=jnp.float32))
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


def step(state: EnvState, action: Action, preset: Preset | str) -> tuple[EnvState, StepInfo]:
    """Execute one macro action (up to ``preset.micro_steps`` motion steps).

    Returns the new state and a :class:`StepInfo`. Path length accumulates the exact
    polyline length moved; the budget gate makes the final step end at L == B exactly.
    """
    preset = get_preset(preset)
    field = distance_field(planning_blocked(state.belief, preset), action.goal_xy, preset)
    found_before = state.found.sum()

    def motion_step(carry, _):
        state, arrived, blocked, unreachable = carry
        active = ~state.done & ~arrived & ~blocked & ~unreachable
        remaining = jnp.maximum(state.budget - state.path_length, 0.0)
        step_len = jnp.minimum(preset.move_step_m, remaining)
        new_xy, travelled, reached, heading = advance(field, state.pose[:2], step_len, preset)
        # The gate uses the planner's own rule on the cell being entered, so a path the
        # planner allowed only fails it when newly seen obstacles block that cell.
        entered = plan_cell_to_xy(xy_to_plan_cell(new_xy, preset), preset)
        traversable = is_traversable(state.belief, entered, preset)
        # Nothing to descend and not at the goal: the goal is cut off on this map.
        stuck = active & ~reached & (travelled <= 0.0)
        moving = active & traversable & (travelled > 0.0)
        # The budget gate: a step shortened to the remaining budget lands exactly on B.
        at_budget = moving & (step_len >= remaining) & (travelled >= step_len)
        path_length = jnp.where(
            at_budget, state.budget, state.path_length + jnp.where(moving, travelled, 0.0)
        )
        pose = jnp.where(moving, jnp.concatenate([new_xy, heading[None]]), state.pose)
        state = state.replace(pose=pose, path_length=path_length)
        state = sense(state, pose, preset, active=moving)
        state = state.replace(done=state.done | (state.path_length >= state.budget))
        carry = (
            state,
            arrived | (active & reached & traversable),
            blocked | (active & ~traversable),
            unreachable | stuck,
        )
        return carry, (state.pose, moving, jnp.where(moving, travelled, 0.0))

    init = (state, jnp.zeros((), bool), jnp.zeros((), bool), jnp.zeros((), bool))
    (state, arrived, blocked, unreachable), (poses, moved, travelled) = jax.lax.scan(
        motion_step, init, None, length=preset.micro_steps
    )

    # On arrival at a viewpoint: face the landmark and sense once more (turning is free).
    d = action.look_xy - state.pose[:2]
    facing = state.pose.at[2].set(jnp.arctan2(d[1], d[0]))
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
    )
    return state, info
