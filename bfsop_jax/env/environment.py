"""The user-facing environment, in gymnax 1.0's conventions, built on ``reset`` / ``step``.

    env, params = make("demo")                       # or "smoke", "paper"
    obs, state = env.reset(key, params)
    obs, state, reward, terminated, truncated, info = env.step(key, state, action, params)

``params`` (:class:`EnvParams`) is a pytree of what may vary per episode or per sweep
without recompiling: the budget, the co-occurrence prior, the category weights, the
macro-step limit and the house source (procedural house seeds in a range, or a stacked
set of imported houses). Everything that sets a shape is static: the preset and the
action interface, fixed by :func:`make`.

Episode. ``reset`` draws a house from the source, a target category the house contains
(weighted by ``category_weights``) and a start pose (:func:`bfsop_jax.env.reset`: a free
cell, then a 360 degree look). One ``step`` is one macro action
(:func:`bfsop_jax.env.step`: up to ``preset.micro_steps`` motion steps towards a goal).

* **reward**: targets verified since the last reward divided by the category's number of
  instances in the house (the first step also pays for targets the initial look verified),
  so an episode's return is its progress P_T = found / total. The reward reads the true
  house; the observation never does.
* **terminated**: the budget gate closed (L = B), or every instance of the category is
  verified (nothing left to earn); with candidates also when the agent chose *stop*, or
  when nothing is left to choose (no reachable frontier and no pending landmark with a
  reachable viewpoint).
* **truncated**: ``params.max_steps`` macro steps were taken without termination.

A finished episode stays finished: further steps change nothing and pay nothing (wrap
the environment in :class:`bfsop_jax.env.wrappers.AutoReset` to start the next one).

Two action interfaces (:func:`make`'s ``actions``):

* ``"native"``: an :class:`~bfsop_jax.env.types.Action` (a goal point and a look point);
  the observation is the :class:`~bfsop_jax.env.types.Observation` the project's own
  strategies see (belief map, pose, budget, detected objects).
* ``"candidates"``: an int32 [] index among K candidates posed from the observation
  (:mod:`bfsop_jax.env.candidates`); the observation is a
  :class:`~bfsop_jax.env.candidates.CandidateObservation` with an ``action_mask``.

Everything is pure and shape-stable: jit, vmap and scan it freely; the same key gives the
same episode alone or in a batch.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from bfsop_jax.agents.rollout import max_macro_steps
from bfsop_jax.config import EVAL_SEED_START, Preset, get_preset
from bfsop_jax.env.candidates import (
    FEATURES,
    STOP,
    CandidateConfig,
    CandidateMemory,
    CandidateObservation,
    candidate_action,
    candidate_observation,
    init_candidates,
    update_candidates,
)
from bfsop_jax.env.env import observe, reset, step
from bfsop_jax.env.spaces import Box, Dict, Discrete
from bfsop_jax.env.types import Action, EnvState, Observation
from bfsop_jax.sensing.mapping import ANGLE_UNITS
from bfsop_jax.world.constants import N_CATEGORIES, N_TARGETS
from bfsop_jax.world.generator import generate_house
from bfsop_jax.world.types import House

__all__ = ["ACTIONS", "EnvParams", "NavigationEnv", "TaskState", "make"]

ACTIONS: tuple[str, ...] = ("native", "candidates")


@struct.dataclass
class EnvParams:
    """What may vary per episode or sweep without recompiling (all pytree leaves).

    The house source: with ``houses`` (a :class:`House` with a leading axis S, e.g. stacked
    imported ProcTHOR houses) each reset draws one of them uniformly; without, it generates
    the procedural house of a seed drawn uniformly from ``[seed_low, seed_high)``.
    """

    budget: jax.Array  # float32 []: travel budget B, metres
    prior: jax.Array  # float32 [N_CATEGORIES, N_TARGETS]: co-occurrence prior P(c | landmark)
    category_weights: jax.Array  # float32 [N_TARGETS]: relative odds of each target category
    max_steps: jax.Array  # int32 []: macro steps before truncation
    seed_low: jax.Array  # int32 []: first procedural house seed
    seed_high: jax.Array  # int32 []: one past the last procedural house seed
    houses: House | None = None  # stacked houses [S, ...]; None: procedural seeds


@struct.dataclass
class TaskState:
    """The environment's state: the simulator's, the episode's task and the interface's."""

    env: EnvState  # the simulator (true house, belief, pose, budget, found)
    house_id: jax.Array  # int32 []: the house seed, or its index in params.houses
    n_targets: jax.Array  # int32 []: instances of the category in the house
    rewarded: jax.Array  # int32 []: verified targets already paid as reward
    start_xy: jax.Array  # float32 [2]: the start position, metres
    last_find_length: jax.Array  # float32 []: L when the last target was verified (0: none)
    stopped: jax.Array  # bool []: the episode terminated (stop, nothing left, gate, all found)
    candidates: CandidateMemory | None = None  # the candidate interface's memory


@dataclasses.dataclass(frozen=True)
class NavigationEnv:
    """BF-SOP's navigation task as a gymnax-style environment (module docstring).

    Build it with :func:`make`. Frozen and hashable, so it may be a static argument.
    """

    preset: Preset
    actions: str = "native"
    candidate_config: CandidateConfig = CandidateConfig()

    def __post_init__(self):
        if self.actions not in ACTIONS:
            raise ValueError(f"actions must be one of {', '.join(ACTIONS)}, got {self.actions!r}")
        self.candidate_config.sizes(self.preset)  # a bad F or L fails here

    # -- gymnax's surface -------------------------------------------------------------
    @property
    def name(self) -> str:
        return f"BFSOP-{self.preset.name}-{self.actions}"

    @property
    def num_actions(self) -> int:
        """K candidates (``"candidates"``); the native action is continuous: 0."""
        return self.candidate_config.n_candidates(self.preset) if self.candidates else 0

    @property
    def candidates(self) -> bool:
        return self.actions == "candidates"

    def default_params(self, prior: Any = None) -> EnvParams:
        """The preset's budget, the shipped prior (estimated from training houses), every
        category equally likely, training house seeds ``[0, EVAL_SEED_START)``."""
        if prior is None:
            from bfsop_jax.world.prior import default_prior

            prior = default_prior()
        prior = jnp.asarray(prior, jnp.float32)
        if prior.shape != (N_CATEGORIES, N_TARGETS):
            raise ValueError(
                f"prior must have shape [{N_CATEGORIES}, {N_TARGETS}], got {tuple(prior.shape)}"
            )
        return EnvParams(
            budget=jnp.asarray(self.preset.budget_m, jnp.float32),
            prior=prior,
            category_weights=jnp.ones(N_TARGETS, jnp.float32),
            max_steps=jnp.asarray(max_macro_steps(self.preset.budget_m, self.preset), jnp.int32),
            seed_low=jnp.asarray(0, jnp.int32),
            seed_high=jnp.asarray(EVAL_SEED_START, jnp.int32),
        )

    def reset(self, key: jax.Array, params: EnvParams) -> tuple[Any, TaskState]:
        """Draw a house, a category it contains and a start; returns ``(obs, state)``."""
        k_house, k_cat, k_start = jax.random.split(key, 3)
        house, house_id = self.draw_house(k_house, params)
        counts = target_counts(house)
        weights = jnp.maximum(params.category_weights, 0.0) * (counts > 0)
        # no listed category in this house: any category it contains
        weights = jnp.where(jnp.any(weights > 0), weights, (counts > 0).astype(jnp.float32))
        category = jax.random.categorical(k_cat, jnp.log(weights)).astype(jnp.int32)
        return self.reset_to(k_start, params, house, category, house_id)

    def reset_to(
        self,
        key: jax.Array,
        params: EnvParams,
        house: House,
        category: jax.Array | int,
        house_id: jax.Array | int = -1,
    ) -> tuple[Any, TaskState]:
        """Start the episode in ``house`` for ``category`` (int32 []) with the start pose
        drawn from ``key``: the same episode as ``bfsop_jax.env.reset(key, house, category,
        preset, params.prior, params.budget)``, so fixed protocols (the navigation
        benchmark's) can be replayed. ``house_id`` is only recorded (for scoring)."""
        category = jnp.asarray(category, jnp.int32)
        sim = reset(key, house, category, self.preset, params.prior, params.budget)
        n_targets = target_counts(house)[category]
        state = TaskState(
            env=sim,
            house_id=jnp.asarray(house_id, jnp.int32),
            n_targets=n_targets,
            rewarded=jnp.zeros((), jnp.int32),
            start_xy=sim.pose[:2],
            last_find_length=jnp.zeros((), jnp.float32),
            stopped=sim.done | (sim.found.sum() >= n_targets),
        )
        if self.candidates:
            state = state.replace(
                candidates=init_candidates(observe(sim), self.preset, self.candidate_config)
            )
        return self.observation(state), state

    def step(
        self, key: jax.Array, state: TaskState, action: Any, params: EnvParams
    ) -> tuple[Any, TaskState, jax.Array, jax.Array, jax.Array, dict[str, Any]]:
        """One macro action: ``(obs, state, reward, terminated, truncated, info)``.

        ``key`` is accepted for gymnax compatibility; the simulator is deterministic.
        ``info`` reports the step (``travelled`` metres, ``motion_steps`` that moved,
        ``arrived``, ``blocked``, the motion steps' ``poses`` [K, 3]) and the episode so
        far (``found``, ``n_targets``, ``progress``, ``path_length``,
        ``last_find_length``, ``start_xy``, ``house``, ``category``, ``found_mask`` [M]),
        all of the stepped state (before any reset).
        """
        del key
        sim = state.env
        if self.candidates:
            index = jnp.asarray(action, jnp.int32)
            native = candidate_action(state.candidates.candidates, index)
            stop = state.candidates.candidates.kind[index] == STOP
        else:
            native, stop = action, jnp.zeros((), bool)
        running = ~state.stopped & ~stop
        new_sim, info = step(sim, native, self.preset)
        keep = lambda a, b: jnp.where(running, a, b)
        new_sim = jax.tree_util.tree_map(keep, new_sim, sim)
        found = new_sim.found.sum().astype(jnp.int32)
        # L when the last target was verified: the first motion step that reached the
        # count, or the end of the step (found by the final look)
        reached = info.found_counts >= found
        at = jnp.where(jnp.any(reached), info.path_lengths[jnp.argmax(reached)],
                       new_sim.path_length)  # fmt: skip
        new_find = running & (found > sim.found.sum())
        state = state.replace(
            env=new_sim,
            last_find_length=jnp.where(new_find, at, state.last_find_length),
        )
        if self.candidates:
            memory = update_candidates(
                state.candidates, index, info, observe(new_sim), self.preset,
                self.candidate_config,
            )  # fmt: skip
            memory = jax.tree_util.tree_map(keep, memory, state.candidates)
            nothing_left = ~jnp.any(memory.candidates.valid[1:])
            state = state.replace(candidates=memory)
        else:
            nothing_left = jnp.zeros((), bool)
        reward = (found - state.rewarded).astype(jnp.float32) * _per_target(state)
        terminated = state.stopped | stop | new_sim.done | (found >= state.n_targets)
        terminated = terminated | nothing_left
        truncated = ~terminated & (new_sim.steps >= params.max_steps)
        state = state.replace(rewarded=found, stopped=terminated)
        info_out = {
            "travelled": jnp.where(running, info.travelled, 0.0),
            "motion_steps": jnp.where(running, info.moved.sum(dtype=jnp.int32), 0),
            "arrived": running & info.arrived,
            "blocked": running & info.blocked,
            "poses": jnp.where(running, info.poses, sim.pose),
            **self.episode_info(state),
        }
        return self.observation(state), state, reward, terminated, truncated, info_out

    # -- views ------------------------------------------------------------------------
    def observation(self, state: TaskState) -> Any:
        """The agent's observation of ``state`` (nothing of the true house leaks)."""
        obs = observe(state.env)
        if self.candidates:
            return candidate_observation(state.candidates.candidates, obs)
        return obs

    def episode_info(self, state: TaskState) -> dict[str, jax.Array]:
        """The episode so far, as reported in ``info`` (reads the true house: for scoring
        and logging, not for the agent)."""
        found = state.env.found.sum().astype(jnp.int32)
        house = state.env.house
        return {
            "found": found,
            "n_targets": state.n_targets,
            "progress": found.astype(jnp.float32) * _per_target(state),
            "path_length": state.env.path_length,
            "last_find_length": state.last_find_length,
            "macro_steps": state.env.steps,
            "start_xy": state.start_xy,
            "house": state.house_id,
            "category": state.env.category,
            "found_mask": state.env.found & (house.object_category == state.env.category),
        }

    def draw_house(self, key: jax.Array, params: EnvParams) -> tuple[House, jax.Array]:
        """A house from the source (``params.houses`` or the seed range) and its id."""
        if params.houses is not None:
            n = jax.tree_util.tree_leaves(params.houses)[0].shape[0]
            index = jax.random.randint(key, (), 0, n, dtype=jnp.int32)
            return jax.tree_util.tree_map(lambda a: a[index], params.houses), index
        seed = jax.random.randint(key, (), params.seed_low, params.seed_high, dtype=jnp.int32)
        return generate_house(jax.random.key(seed), self.preset), seed

    def action_space(self, params: EnvParams | None = None) -> Any:
        """``Discrete(K)`` for candidates; for native actions a :class:`Dict` of an
        :class:`Action` (goal and look points inside the footprint, a look flag)."""
        if self.candidates:
            return Discrete(self.num_actions)
        extent = self._extent()
        return Dict(
            {
                "goal_xy": Box(0.0, extent, (2,)),
                "look_xy": Box(0.0, extent, (2,)),
                "look": Box(0, 1, (), jnp.bool_),
            },
            cls=Action,
        )

    def observation_space(self, params: EnvParams | None = None) -> Dict:
        """A :class:`Dict` of the observation's fields (shapes, dtypes, bounds)."""
        p = self.preset
        extent = self._extent()
        top_heading = math.pi * (1 - 2 / ANGLE_UNITS)  # headings are whole angle units
        pose = Box(np.array([0.0, 0.0, -math.pi], np.float32),
                   np.array([*extent, top_heading], np.float32), (3,))  # fmt: skip
        metres = Box(0.0, np.inf, ())
        if self.candidates:
            k = self.num_actions
            return Dict(
                {
                    "features": Box(-np.inf, np.inf, (k, len(FEATURES))),
                    "action_mask": Box(0, 1, (k,), jnp.bool_),
                    "kind": Box(0, 2, (k,), jnp.int32),
                    "goal_xy": Box(0.0, extent, (k, 2)),
                    "distance": Box(0.0, np.inf, (k,)),
                    "pose": pose,
                    "remaining": metres,
                    "budget": metres,
                    "found": Box(0, p.max_objects, (), jnp.int32),
                },
                cls=CandidateObservation,
            )
        m = p.max_objects
        return Dict(
            {
                "belief": Box(-p.logodds_clamp, p.logodds_clamp, p.grid_shape),
                "pose": pose,
                "path_length": metres,
                "budget": metres,
                "category": Discrete(N_TARGETS),
                "prior": Box(0.0, 1.0, (N_CATEGORIES, N_TARGETS)),
                "object_seen": Box(0, 1, (m,), jnp.bool_),
                "object_category": Box(-1, N_CATEGORIES - 1, (m,), jnp.int32),
                "object_xy": Box(0.0, extent, (m, 2)),
                "object_half_extent": Box(0.0, extent, (m, 2)),
                "landmark": Box(0, 1, (m,), jnp.bool_),
                "found": Box(0, 1, (m,), jnp.bool_),
                "done": Box(0, 1, (), jnp.bool_),
            },
            cls=Observation,
        )

    def _extent(self) -> np.ndarray:
        """float32 [2]: the planning grid's width and height in metres (x, y)."""
        hp, wp = self.preset.plan_shape
        return np.array([wp, hp], np.float32) * np.float32(self.preset.plan_cell_size)


def _per_target(state: TaskState) -> jax.Array:
    """float32 []: 1 / instances (a reciprocal, then products: the same in every program)."""
    return 1.0 / jnp.maximum(state.n_targets, 1).astype(jnp.float32)


def target_counts(house: House) -> jax.Array:
    """int32 [N_TARGETS]: instances of each target category in ``house``."""
    cats = house.object_category
    return jnp.sum(cats[:, None] == jnp.arange(N_TARGETS), axis=0, dtype=jnp.int32)


def make(
    preset: str | Preset = "demo",
    actions: str = "native",
    candidate_config: CandidateConfig | None = None,
    prior: Any = None,
) -> tuple[NavigationEnv, EnvParams]:
    """``env, params = make("demo")`` (also ``"smoke"``, ``"paper"``).

    Args:
        preset: preset name or :class:`~bfsop_jax.config.Preset` (sets every shape).
        actions: ``"native"`` (goal and look points) or ``"candidates"`` (a discrete
            choice among K goals posed from the observation, with an action mask).
        candidate_config: F, L and FBE's bookkeeping numbers for ``"candidates"``.
        prior: the co-occurrence prior of the default params (default: the shipped one,
            estimated from training houses).
    """
    env = NavigationEnv(get_preset(preset), actions, candidate_config or CandidateConfig())
    return env, env.default_params(prior)
