"""Episode frames for animations: any strategy's rollout, with what the agent believed and
planned recorded as it went.

The rollout's :class:`~bfsop_jax.agents.rollout.Trajectory` holds what the metrics need
(poses, path length, found counts, the mode), not the belief map nor the tour being
executed: a per-step belief map would cost every batched evaluation [T, H, W] floats per
episode. This module records them for one episode at a time, for pictures only
(:func:`bfsop_jax.viz.animate_episode`), and leaves the rollout as it is:

* a *frame* is taken every ``every`` macro steps (and once at the start): the belief map
  quantised to int8 cell states (-1 known free, 0 unknown, 1 known occupied, optionally
  reduced over ``downsample`` x ``downsample`` blocks), the pose, path length, verified
  targets, and, for strategies that tour (a :class:`~bfsop_jax.agents.tour.SwitchMemory`),
  the viewpoints of the current tour still ahead;
* between frames it runs :func:`~bfsop_jax.agents.rollout.continue_rollout` itself (the
  very scan body of :func:`~bfsop_jax.agents.rollout.rollout`), so a recorded episode is
  the same episode as a rolled-out or batched one, bit for bit;
* ``chunk`` frames run as one jitted ``lax.scan`` (compiled once per
  :class:`EpisodeRecorder`), and the host stops after the chunk in which the episode
  ended.

Unlike a strategy, the recorder reads the true house, for one number only: the count of
target instances (the "found 3 / 7" of a frame). It never feeds anything to the strategy.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from bfsop_jax.agents.rollout import Strategy, Trajectory, continue_rollout, max_macro_steps
from bfsop_jax.agents.tour import SwitchMemory
from bfsop_jax.config import Preset
from bfsop_jax.env.env import observe
from bfsop_jax.env.types import EnvState

__all__ = [
    "EpisodeFrames",
    "EpisodeRecorder",
    "Recording",
    "belief_states",
    "record_episode",
]

FREE, UNKNOWN, OCCUPIED = -1, 0, 1  # int8 cell states of a recorded belief map


@struct.dataclass
class _Snapshot:
    """What one frame keeps of the state and memory (device side, stacked over frames)."""

    belief: jax.Array  # int8 [H', W']: FREE / UNKNOWN / OCCUPIED
    pose: jax.Array  # float32 [3]
    path_length: jax.Array  # float32 []
    found: jax.Array  # bool [M]
    tour_xy: jax.Array  # float32 [T + 1, 2]: completion viewpoint, then the tour's
    tour_valid: jax.Array  # bool [T + 1]: still ahead


@dataclasses.dataclass(frozen=True)
class EpisodeFrames:
    """One episode as frames for :func:`bfsop_jax.viz.animate_episode` (NumPy only).

    F = frames (the start, then one every ``every`` macro steps until the episode
    ended), P = path points, T = tour slots (``preset.n_loi`` + 1), N = verified targets.
    Positions are in metres.
    """

    belief: np.ndarray  # int8 [F, H', W']: -1 known free, 0 unknown, 1 known occupied
    belief_cell_m: float  # metres per belief cell (cell_size * downsample)
    pose: np.ndarray  # float32 [F, 3]: x, y (m), heading (rad) at each frame
    path_length: np.ndarray  # float32 [F]: L at each frame (m)
    found_count: np.ndarray  # int32 [F]: targets verified by each frame
    touring: np.ndarray  # bool [F]: the last macro step before the frame was touring
    macro_steps: np.ndarray  # int32 [F]: macro steps the strategy had taken by each frame
    tour_xy: np.ndarray  # float32 [F, T, 2]: the tour's viewpoints in visiting order
    tour_valid: np.ndarray  # bool [F, T]: the viewpoint is still ahead at that frame
    path_xy: np.ndarray  # float32 [P, 2]: the start, then every position moved to
    path_touring: np.ndarray  # bool [P]: the move to that point was made touring
    path_frame: np.ndarray  # int32 [P]: first frame at which the point is reached
    found_xy: np.ndarray  # float32 [N, 2]: verified targets' centres, in order found
    found_frame: np.ndarray  # int32 [N]: first frame at which each is verified
    total: int  # target instances of the category in the house
    budget: float  # B (m)

    @property
    def n_frames(self) -> int:
        return int(self.belief.shape[0])


@dataclasses.dataclass(frozen=True)
class Recording:
    """What :meth:`EpisodeRecorder.record` returns (host arrays)."""

    final: EnvState  # the state after the episode
    trajectory: Trajectory  # [S, ...] every macro step run, as rollout returns it
    frames: EpisodeFrames


def belief_states(belief: jax.Array, preset: Preset, downsample: int = 1) -> jax.Array:
    """int8 [ceil(H / d), ceil(W / d)] cell states of a [H, W] log-odds map.

    -1 known free (log-odds below ``-preset.logodds_known``), 1 known occupied (above
    ``+logodds_known``), 0 unknown; the thresholds of
    :func:`bfsop_jax.viz.world.belief_image`. With ``downsample`` d > 1 a d x d block is
    occupied when any of its cells is, else free when any is, else unknown (walls stay
    visible).
    """
    known = preset.logodds_known
    state = jnp.where(belief > known, OCCUPIED, jnp.where(belief < -known, FREE, UNKNOWN))
    state = state.astype(jnp.int8)
    d = int(downsample)
    if d <= 1:
        return state
    h, w = state.shape
    hp, wp = -(-h // d) * d, -(-w // d) * d
    state = jnp.pad(state, ((0, hp - h), (0, wp - w)))
    blocks = state.reshape(hp // d, d, wp // d, d)
    occupied = jnp.any(blocks == OCCUPIED, axis=(1, 3))
    free = jnp.any(blocks == FREE, axis=(1, 3))
    return jnp.where(occupied, OCCUPIED, jnp.where(free, FREE, UNKNOWN)).astype(jnp.int8)


def _tour_ahead(memory: Any, preset: Preset) -> tuple[jax.Array, jax.Array]:
    """The current tour's viewpoints still ahead: ([T + 1, 2] xy, [T + 1] valid); the
    first slot is a completion viewpoint (taken before the tour goes on). None for a
    strategy that does not tour."""
    t = preset.n_loi + 1
    if not isinstance(memory, SwitchMemory):
        return jnp.zeros((t, 2), jnp.float32), jnp.zeros((t,), bool)
    tour = memory.tour
    idx = jnp.arange(tour.goal.shape[0])
    ahead = tour.touring & (idx >= tour.position) & (idx < tour.length)
    xy = jnp.concatenate([tour.extra_goal[None], tour.goal], axis=0)
    valid = jnp.concatenate([(tour.touring & tour.extra)[None], ahead], axis=0)
    return xy.astype(jnp.float32), valid


def _snapshot(state: EnvState, memory: Any, preset: Preset, downsample: int) -> _Snapshot:
    xy, valid = _tour_ahead(memory, preset)
    return _Snapshot(
        belief=belief_states(state.belief, preset, downsample),
        pose=state.pose,
        path_length=state.path_length,
        found=state.found,
        tour_xy=xy,
        tour_valid=valid,
    )


class EpisodeRecorder:
    """Records episodes of one strategy on one preset (the chunk program compiles once).

    Args:
        strategy: any strategy (FBE, BFSGlobal, TFLReactive, BFSOP with any planner).
        preset: the episodes' preset.
        every: macro steps between frames.
        chunk: frames per jitted call.
        downsample: belief cells per frame cell along each axis (1: the 0.1 m grid).
    """

    def __init__(
        self, strategy: Strategy, preset: Preset, every: int = 1, chunk: int = 16,
        downsample: int = 1,
    ):  # fmt: skip
        if every < 1 or chunk < 1 or downsample < 1:
            raise ValueError("every, chunk and downsample must be at least 1")
        self.strategy, self.preset = strategy, preset
        self.every, self.chunk, self.downsample = int(every), int(chunk), int(downsample)

        def run(state, memory):
            def body(carry, _):
                state, memory = carry
                state, memory, traj = continue_rollout(state, memory, strategy, preset, every)
                return (state, memory), (traj, _snapshot(state, memory, preset, downsample))

            (state, memory), (traj, snaps) = jax.lax.scan(body, (state, memory), None, length=chunk)
            flat = lambda a: a.reshape((chunk * every,) + a.shape[2:])
            return state, memory, jax.tree_util.tree_map(flat, traj), snaps

        self._run = jax.jit(run)
        self._start = jax.jit(
            lambda s: (strategy.init(observe(s), preset), _snapshot(s, None, preset, downsample))
        )

    def record(
        self, state: EnvState, n_steps: int | None = None,
        progress: Callable[[float], Any] | None = None,
    ) -> Recording:  # fmt: skip
        """Run the episode from ``state`` (one episode, unbatched) until it ends, for at
        most ``n_steps`` macro steps rounded up to whole chunks (default
        :func:`max_macro_steps` of its budget, which lets it end); ``progress`` is called
        with the path length (m) after every chunk."""
        if np.ndim(state.path_length) != 0:
            raise ValueError(f"record takes one episode, got a batch {np.shape(state.path_length)}")
        budget = float(state.budget)
        n_steps = max_macro_steps(budget, self.preset) if n_steps is None else int(n_steps)
        per_call = self.chunk * self.every
        memory, first = jax.device_get(self._start(state))
        snaps, trajs = [first], []
        for _ in range(max(1, math.ceil(n_steps / per_call))):
            state, memory, traj, snap = self._run(state, memory)
            traj, snap = jax.device_get((traj, snap))
            trajs.append(traj)
            snaps.append(snap)
            if progress is not None:
                progress(float(state.path_length))
            if not bool(traj.active[-1]):
                break
        final = jax.device_get(state)
        cat = lambda *a: np.concatenate(a, axis=0)
        traj = jax.tree_util.tree_map(cat, *trajs)
        snap = jax.tree_util.tree_map(lambda s0, *r: cat(np.asarray(s0)[None], *r), *snaps)
        house = final.house
        total = int(np.sum(np.asarray(house.object_category) == int(final.category)))
        frames = _frames(snap, traj, first, final, self.every, self.downsample, self.preset, total)
        return Recording(final=final, trajectory=traj, frames=frames)


def _frames(
    snap: _Snapshot, traj: Trajectory, first: _Snapshot, final: EnvState, every: int,
    downsample: int, preset: Preset, total: int,
) -> EpisodeFrames:  # fmt: skip
    """Host-side frames: cut after the last frame with an active macro step, the path
    flattened to points with the frame each is reached at."""
    active = np.asarray(traj.active)  # [S]
    groups = active.reshape(-1, every)  # [F - 1, every]
    ran = np.flatnonzero(groups.any(axis=1))
    n = 1 + (int(ran[-1]) + 1 if len(ran) else 0)  # frames kept
    step_frame = np.arange(len(active)) // every + 1  # frame after each macro step
    touring = np.asarray(traj.touring) & active
    # the mode of each frame: that of the last active macro step before it
    last = np.where(groups, np.arange(every)[None], -1).max(axis=1)  # [F - 1]
    frame_touring = np.zeros(n, bool)
    g = np.arange(n - 1)
    frame_touring[1:] = np.where(last[g] >= 0, touring.reshape(-1, every)[g, last[g]], False)
    macro = np.concatenate([[0], np.cumsum(groups.sum(axis=1))])[:n].astype(np.int32)

    moved = np.asarray(traj.moved)  # [S, K]
    xy = np.asarray(traj.poses)[..., :2][moved]
    path_xy = np.concatenate([np.asarray(first.pose)[None, :2], xy]).astype(np.float32)
    k = moved.shape[1]
    per_point = lambda a: np.broadcast_to(a[:, None], (len(a), k))[moved]
    path_touring = np.concatenate([[False], per_point(touring)])
    path_frame = np.concatenate([[0], per_point(step_frame)]).astype(np.int32)

    found = np.asarray(snap.found)[:n]  # [F, M]
    slots = np.flatnonzero(found[-1])
    when = np.argmax(found[:, slots], axis=0).astype(np.int32)
    order = np.argsort(when, kind="stable")
    obj_xy = np.asarray(observe(final).object_xy)  # found targets are detected objects
    return EpisodeFrames(
        belief=np.asarray(snap.belief)[:n],
        belief_cell_m=preset.cell_size * downsample,
        pose=np.asarray(snap.pose, np.float32)[:n],
        path_length=np.asarray(snap.path_length, np.float32)[:n],
        found_count=found.sum(axis=1).astype(np.int32),
        touring=frame_touring,
        macro_steps=macro,
        tour_xy=np.asarray(snap.tour_xy, np.float32)[:n],
        tour_valid=np.asarray(snap.tour_valid)[:n],
        path_xy=path_xy,
        path_touring=path_touring,
        path_frame=path_frame,
        found_xy=obj_xy[slots[order]].astype(np.float32),
        found_frame=when[order],
        total=total,
        budget=float(final.budget),
    )


def record_episode(
    state: EnvState, strategy: Strategy, preset: Preset, *, every: int = 1, chunk: int = 16,
    downsample: int = 1, n_steps: int | None = None,
) -> Recording:  # fmt: skip
    """Record one episode from ``state`` (see :class:`EpisodeRecorder`; to record several
    episodes of one strategy, make one recorder and call its ``record`` for each)."""
    recorder = EpisodeRecorder(strategy, preset, every=every, chunk=chunk, downsample=downsample)
    return recorder.record(state, n_steps=n_steps)
