"""BF-SOP: frontier exploration plus SOP-planned landmark tours (SPEC 7.4-7.5).

The heuristic strategy switcher keeps the pending landmarks of interest (detected, not
yet visited). While exploring, it estimates an exploitation plan cheaply (greedy SOP
insertion over the landmark centres with straight-line costs times a detour factor;
identical for every planner) and switches to exploitation when

* the plan's reward per metre beats the recent exploration yield (landmark reward
  discovered per metre explored, an exponential moving average), or
* the remaining budget is close to the plan's cost, or
* no frontier is reachable, or
* the landmark cap ``preset.n_loi`` is full.

On switching, the SOP instance is built on the online map
(:func:`bfsop_jax.sop.builder.build_instance`) and the *planner* (the VNS teacher through
its host callback, or the Strategic Transformer) computes the tour, which is executed to
its end (truncated by the budget gate; a viewpoint that turns out unreachable is
dropped); visited landmarks are retired; then the agent explores again. No mode flip
mid-tour.

The episode loop is a ``lax.scan``; the expensive branch (instance + planner) runs under
``lax.cond``, so an unbatched rollout only pays for it when it switches. Every switch is
recorded (instance and plan): these are the on-trajectory decisions of the dataset.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from flax import struct

from bfsop_jax.agents.fbe import FBE, FBEMemory
from bfsop_jax.config import Preset
from bfsop_jax.env.env import step
from bfsop_jax.env.types import Action, EnvState, StepInfo
from bfsop_jax.sop.builder import build_instance
from bfsop_jax.sop.callback import vns_callback
from bfsop_jax.sop.types import Solution, SOPInstance, plan_length

__all__ = [
    "Decision",
    "Memory",
    "Planner",
    "bfsop_rollout",
    "greedy_estimate",
    "init_memory",
    "vns_planner",
]

Planner = Callable[[SOPInstance], Solution]

DETOUR = 1.3  # geodesic / straight-line ratio assumed by the cheap estimate
YIELD_DECAY = 0.9  # per macro step of exploration (about 20 m of memory)
BUDGET_MARGIN = 1.2  # exploit when the remaining budget is within this factor of the plan
MAX_ATTEMPTS = 3  # blocked attempts before a tour viewpoint is dropped


@struct.dataclass
class Memory:
    """The strategy switcher's state. T = preset.n_loi tour slots, M = objects."""

    touring: jax.Array  # bool []
    tour_goal: jax.Array  # float32 [T, 2]: viewpoints in visiting order
    tour_look: jax.Array  # float32 [T, 2]: the landmark each viewpoint faces
    tour_landmark: jax.Array  # int32 [T]: landmark slot of each viewpoint
    tour_length: jax.Array  # int32 []
    tour_position: jax.Array  # int32 []: next viewpoint
    attempts: jax.Array  # int32 []: blocked attempts on the current viewpoint
    retired: jax.Array  # bool [M]: landmarks visited or dropped
    considered: jax.Array  # bool [M]: pending set at the last (declined) evaluation
    explore_m: jax.Array  # float32 []: decayed metres explored
    explore_reward: jax.Array  # float32 []: decayed landmark reward discovered
    switches: jax.Array  # int32 []
    explore: FBEMemory  # the exploration strategy's memory


@struct.dataclass
class Decision:
    """One macro step's record; ``switched`` marks an exploitation decision."""

    switched: jax.Array  # bool []
    instance: SOPInstance  # the SOP posed at the switch (zeros otherwise)
    plan: Solution  # the planner's tour
    touring: jax.Array  # bool []: the agent was executing a tour this step


def vns_planner(seed: int = 0, **vns_kwargs) -> Planner:
    """The VNS teacher as a planner: one instance through the batched host callback."""

    def plan(instance: SOPInstance) -> Solution:
        batch = jax.tree_util.tree_map(lambda a: a[None], instance)
        sol = vns_callback(batch, jnp.full((1,), seed, jnp.int32), **vns_kwargs)
        return jax.tree_util.tree_map(lambda a: a[0], sol)

    return plan


_EXPLORER = FBE()


def init_memory(state: EnvState, preset: Preset) -> Memory:
    m, t = state.found.shape[-1], preset.n_loi
    return Memory(
        touring=jnp.zeros((), bool),
        tour_goal=jnp.zeros((t, 2), jnp.float32),
        tour_look=jnp.zeros((t, 2), jnp.float32),
        tour_landmark=jnp.full((t,), -1, jnp.int32),
        tour_length=jnp.zeros((), jnp.int32),
        tour_position=jnp.zeros((), jnp.int32),
        attempts=jnp.zeros((), jnp.int32),
        retired=jnp.zeros((m,), bool),
        considered=jnp.zeros((m,), bool),
        explore_m=jnp.zeros((), jnp.float32),
        explore_reward=jnp.zeros((), jnp.float32),
        switches=jnp.zeros((), jnp.int32),
        explore=_EXPLORER.init(state, preset),
    )


def greedy_estimate(
    xy: jax.Array, reward: jax.Array, valid: jax.Array, start: jax.Array, budget: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """Greedy SOP insertion on points (open path, straight lines x ``DETOUR``).

    Args: xy [L, 2] landmark centres, reward [L], valid [L] bool, start [2], budget [].
    Returns ``(reward, cost)`` of the plan. Each round inserts the point with the best
    reward per added metre at its cheapest position, while the plan fits the budget.
    """
    n = xy.shape[0]
    pts = jnp.concatenate([start[None], xy], axis=0)
    dist = DETOUR * jnp.linalg.norm(pts[:, None] - pts[None], axis=-1)  # [L+1, L+1]

    def body(_, carry):
        order, length, used, total_r, total_c = carry
        # order: [L+1] node ids (0 = start), first `length` entries are the route.
        pos = jnp.arange(n + 1)
        prev = order  # insertion after position p (0 .. length-1)
        nxt = jnp.roll(order, -1)
        has_next = pos < length - 1
        cand = jnp.arange(1, n + 1)
        added = (
            dist[prev[:, None], cand[None, :]]
            + jnp.where(has_next[:, None], dist[cand[None, :], nxt[:, None]], 0.0)
            - jnp.where(has_next[:, None], dist[prev, nxt][:, None], 0.0)
        )  # [L+1 positions, L candidates]
        added = jnp.where((pos < length)[:, None], added, jnp.inf)
        best_pos = jnp.argmin(added, axis=0)
        best_add = jnp.min(added, axis=0)
        ok = valid & ~used & (total_c + best_add <= budget) & (reward > 0)
        ratio = jnp.where(ok, reward / jnp.maximum(best_add, 1e-3), -jnp.inf)
        k = jnp.argmax(ratio)
        go = jnp.isfinite(ratio[k])
        p = best_pos[k]
        shifted = jnp.where(pos > p + 1, jnp.roll(order, 1), order)
        new_order = jnp.where(pos == p + 1, k + 1, shifted)
        return (
            jnp.where(go, new_order, order),
            length + go.astype(jnp.int32),
            used.at[k].set(used[k] | go),
            total_r + jnp.where(go, reward[k], 0.0),
            total_c + jnp.where(go, best_add[k], 0.0),
        )

    init = (
        jnp.zeros(n + 1, jnp.int32),
        jnp.ones((), jnp.int32),
        jnp.zeros(n, bool),
        jnp.zeros((), jnp.float32),
        jnp.zeros((), jnp.float32),
    )
    _, _, _, total_r, total_c = jax.lax.fori_loop(0, n, body, init)
    return total_r, total_c


def _empty_decision(state: EnvState, preset: Preset) -> tuple[SOPInstance, Solution]:
    n, k = preset.n_sop_nodes, preset.n_loi + 1
    inst = SOPInstance(
        cost=jnp.zeros((n, n), jnp.float32),
        set_id=jnp.full((n,), -1, jnp.int32),
        set_reward=jnp.zeros((k,), jnp.float32),
        start=jnp.zeros((), jnp.int32),
        end=jnp.full((), -1, jnp.int32),
        budget=jnp.zeros((), jnp.float32),
        coords=jnp.zeros((n, 2), jnp.float32),
    )
    plan = Solution(
        nodes=jnp.full((plan_length(k),), -1, jnp.int32),
        reward=jnp.zeros((), jnp.float32),
        cost=jnp.zeros((), jnp.float32),
    )
    return inst, plan


def _landmark_rewards(state: EnvState) -> jax.Array:
    cat = state.house.object_category
    return jnp.where(cat >= 0, state.prior[jnp.maximum(cat, 0), state.category], 0.0)


def _decide(state: EnvState, memory: Memory, planner: Planner, preset: Preset):
    """Pick this macro step's action; maybe switch to exploitation (planner call)."""
    house = state.house
    pending = state.landmarks_seen & ~memory.retired
    remaining = state.budget - state.path_length
    explore_action, has_frontier, explore_memory = _EXPLORER.act(memory.explore, state, preset)

    # Cheap estimate over the top-n_loi pending landmarks.
    rew = jnp.where(pending, _landmark_rewards(state), 0.0)
    top_r, top_i = jax.lax.top_k(rew, min(preset.n_loi, rew.shape[0]))
    est_r, est_c = greedy_estimate(
        house.object_xy[top_i], top_r, top_r > 0, state.pose[:2], remaining
    )
    yield_rate = memory.explore_reward / jnp.maximum(memory.explore_m, 10.0)
    worth = (est_r / jnp.maximum(est_c, 1e-3) > yield_rate) | (remaining <= BUDGET_MARGIN * est_c)
    worth = worth | ~has_frontier | (pending.sum() >= preset.n_loi)
    changed = jnp.any(pending != memory.considered)
    switch = ~memory.touring & ~state.done & (est_r > 0) & worth & changed

    def plan_tour(_):
        inst, choice = build_instance(
            state.belief, state.pose[:2], remaining, pending, house.object_category,
            house.object_xy, house.object_half_extent, state.prior, state.category, preset,
        )  # fmt: skip
        plan = planner(inst)
        return inst, plan, choice.index

    def no_tour(_):
        inst, plan = _empty_decision(state, preset)
        return inst, plan, jnp.full((preset.n_loi,), -1, jnp.int32)

    inst, plan, loi_index = jax.lax.cond(switch, plan_tour, no_tour, None)

    # Tour slots from the plan (the start node first, then viewpoints).
    nodes = plan.nodes[1 : preset.n_loi + 1]
    is_vp = nodes > 0
    sets = inst.set_id[jnp.maximum(nodes, 0)]
    landmark = jnp.where(is_vp, loi_index[jnp.maximum(sets - 1, 0)], -1)
    goal = inst.coords[jnp.maximum(nodes, 0)]
    look = house.object_xy[jnp.maximum(landmark, 0)]
    tour_length = is_vp.sum().astype(jnp.int32)
    started = switch & (tour_length > 0)
    memory = memory.replace(
        touring=memory.touring | started,
        tour_goal=jnp.where(started, goal, memory.tour_goal),
        tour_look=jnp.where(started, look, memory.tour_look),
        tour_landmark=jnp.where(started, landmark, memory.tour_landmark),
        tour_length=jnp.where(started, tour_length, memory.tour_length),
        tour_position=jnp.where(started, 0, memory.tour_position),
        attempts=jnp.where(started, 0, memory.attempts),
        # A declined or empty evaluation is not repeated until the pending set changes.
        considered=jnp.where(memory.touring | started, memory.considered, pending),
        switches=memory.switches + started.astype(jnp.int32),
        explore=jax.tree_util.tree_map(
            lambda a, b: jnp.where(memory.touring, a, b), memory.explore, explore_memory
        ),
    )
    pos = jnp.minimum(memory.tour_position, preset.n_loi - 1)
    tour_action = Action(
        goal_xy=memory.tour_goal[pos], look_xy=memory.tour_look[pos], look=jnp.ones((), bool)
    )
    action = jax.tree_util.tree_map(
        lambda a, b: jnp.where(memory.touring, a, b), tour_action, explore_action
    )
    has_goal = memory.touring | has_frontier
    decision = Decision(switched=switch, instance=inst, plan=plan, touring=memory.touring)
    return action, has_goal, memory, decision


def _update(before: EnvState, after: EnvState, info: StepInfo, memory: Memory) -> Memory:
    """Advance the tour after a step; track the exploration yield."""
    pos = jnp.minimum(memory.tour_position, memory.tour_landmark.shape[0] - 1)
    attempts = memory.attempts + info.blocked.astype(jnp.int32)
    done_vp = memory.touring & (info.arrived | info.unreachable | (attempts >= MAX_ATTEMPTS))
    lm = memory.tour_landmark[pos]
    retired = memory.retired.at[jnp.maximum(lm, 0)].set(
        memory.retired[jnp.maximum(lm, 0)] | (done_vp & (lm >= 0))
    )
    position = memory.tour_position + done_vp.astype(jnp.int32)
    touring = memory.touring & (position < memory.tour_length)

    explore = _EXPLORER.update(memory.explore, before, after, info)
    rewards = _landmark_rewards(after)
    new_lois = after.landmarks_seen & ~before.landmarks_seen
    exploring = ~memory.touring
    decay = jnp.where(exploring, YIELD_DECAY, 1.0)
    return memory.replace(
        touring=touring,
        explore=jax.tree_util.tree_map(
            lambda a, b: jnp.where(memory.touring, a, b), memory.explore, explore
        ),
        tour_position=position,
        attempts=jnp.where(done_vp, 0, attempts),
        retired=retired,
        explore_m=decay * memory.explore_m + jnp.where(exploring, info.travelled, 0.0),
        explore_reward=decay * memory.explore_reward
        + jnp.where(exploring, jnp.sum(jnp.where(new_lois, rewards, 0.0)), 0.0),
    )


def bfsop_rollout(
    state: EnvState, planner: Planner, preset: Preset, n_steps: int
) -> tuple[EnvState, Memory, Decision, jax.Array]:
    """Run BF-SOP for ``n_steps`` macro steps (static); stops once it has nothing to do.

    Returns ``(final state, final memory, decisions [n_steps], poses [n_steps, K, 3])``
    where ``decisions.touring`` tells exploration from touring for each step's poses.
    Meant to run unbatched (``jax.jit``) so ``lax.cond`` skips the planner when no
    decision is taken; it is still vmappable (then every step pays for the planner).
    """

    def body(carry, _):
        state, memory = carry
        action, has_goal, memory, decision = _decide(state, memory, planner, preset)
        active = has_goal & ~state.done
        new_state, info = step(state, action, preset)
        new_memory = _update(state, new_state, info, memory)
        state = jax.tree_util.tree_map(lambda a, b: jnp.where(active, a, b), new_state, state)
        memory = jax.tree_util.tree_map(lambda a, b: jnp.where(active, a, b), new_memory, memory)
        poses = jnp.where(info.moved[:, None] & active, info.poses, jnp.nan)
        return (state, memory), (decision, poses)

    (state, memory), (decisions, poses) = jax.lax.scan(
        body, (state, init_memory(state, preset)), None, length=n_steps
    )
    return state, memory, decisions, poses
