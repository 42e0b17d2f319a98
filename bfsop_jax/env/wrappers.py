"""Wrappers around :class:`~bfsop_jax.env.environment.NavigationEnv`, gymnax style.

* :class:`AutoReset`: a finished episode (terminated or truncated) is replaced by a fresh
  one in the same step, and the step's own last observation goes to
  ``info["final_observation"]``. It stays vectorised: the new episodes are chosen with
  ``jnp.where`` selects, never ``lax.map``. Drawing a house costs about as much as many
  macro steps, so under ``vmap`` the reset itself runs only on the rows that finished
  (:func:`bfsop_jax.agents.sparse.sparse_cond`: those rows are gathered into small
  vectorised sub-batches; no reset runs when no row finished). ``sparse=False`` runs it
  on every row every step instead (gymnax's way), for comparison.
* :class:`LogWrapper`: episode statistics. ``info["returned_episode"]`` (bool []) marks
  the step that finished an episode; ``info["episode_*"]`` then hold that episode's
  return, macro steps, path length, found, total, progress, the path length when the
  last target was verified, its start, house, category and found instances, enough to
  score it by PPL on the host (:func:`episode_ppl`, the navigation benchmark's scoring).

Wrap in that order, ``LogWrapper(AutoReset(env))``, so the log sees every episode end.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from bfsop_jax.agents.sparse import sparse_cond

__all__ = ["AutoReset", "LogState", "LogWrapper", "Wrapper", "episode_ppl"]


class Wrapper:
    """Forwards everything it does not override to the wrapped environment."""

    def __init__(self, env: Any):
        self.env = env

    def __getattr__(self, name: str) -> Any:
        return getattr(self.env, name)


def _select(pred: jax.Array, a: Any, b: Any) -> Any:
    return jax.tree_util.tree_map(lambda x, y: jnp.where(pred, x, y), a, b)


class AutoReset(Wrapper):
    """Starts the next episode in the step that ends one (module docstring)."""

    def __init__(self, env: Any, sparse: bool = True):
        super().__init__(env)
        self.sparse = sparse

    def step(
        self, key: jax.Array, state: Any, action: Any, params: Any
    ) -> tuple[Any, Any, jax.Array, jax.Array, jax.Array, dict[str, Any]]:
        key_step, key_reset = jax.random.split(key)
        obs, state, reward, terminated, truncated, info = self.env.step(
            key_step, state, action, params
        )
        done = terminated | truncated
        info = {**info, "final_observation": obs}
        if self.sparse:
            # the rows that did not finish come back as they were: no select needed (a
            # select over the whole state, houses included, costs a copy of it every step)
            obs, state = sparse_cond(
                done,
                lambda _, k, p, o, s: self.env.reset(k, p),
                lambda k, p, o, s: (o, s),
                key_reset, params, obs, state,
            )  # fmt: skip
        else:
            obs_new, state_new = self.env.reset(key_reset, params)
            obs, state = _select(done, obs_new, obs), _select(done, state_new, state)
        return obs, state, reward, terminated, truncated, info


@struct.dataclass
class LogState:
    """The wrapped state plus the running episode's sums and the last finished one's."""

    env_state: Any
    episode_return: jax.Array  # float32 []: reward summed over the running episode
    returned: dict  # the last finished episode's statistics (the info's episode_* fields)


_EPISODE_FIELDS = (
    "found", "n_targets", "progress", "path_length", "last_find_length", "macro_steps",
    "start_xy", "house", "category", "found_mask",
)  # fmt: skip


class LogWrapper(Wrapper):
    """Episode statistics in ``info`` (module docstring). Wrap an :class:`AutoReset`."""

    def reset(self, key: jax.Array, params: Any) -> tuple[Any, LogState]:
        return self._wrap(*self.env.reset(key, params))

    def reset_to(self, *args: Any, **kwargs: Any) -> tuple[Any, LogState]:
        """The wrapped environment's ``reset_to`` (a given house and category)."""
        return self._wrap(*self.env.reset_to(*args, **kwargs))

    def _wrap(self, obs: Any, state: Any) -> tuple[Any, LogState]:
        blank = {f"episode_{k}": jnp.zeros_like(v) for k, v in self._probe(state).items()}
        blank["episode_return"] = jnp.zeros((), jnp.float32)
        return obs, LogState(state, jnp.zeros((), jnp.float32), blank)

    def _probe(self, state: Any) -> dict[str, jax.Array]:
        inner = state
        while not hasattr(inner, "start_xy"):  # the TaskState under other wrappers
            inner = inner.env_state
        env = self.env
        while not hasattr(env, "episode_info"):
            env = env.env
        return env.episode_info(inner)

    def step(
        self, key: jax.Array, state: LogState, action: Any, params: Any
    ) -> tuple[Any, LogState, jax.Array, jax.Array, jax.Array, dict[str, Any]]:
        obs, env_state, reward, terminated, truncated, info = self.env.step(
            key, state.env_state, action, params
        )
        done = terminated | truncated
        ret = state.episode_return + reward
        finished = {f"episode_{k}": info[k] for k in _EPISODE_FIELDS}
        finished["episode_return"] = ret
        returned = _select(done, finished, state.returned)
        state = LogState(env_state, jnp.where(done, 0.0, ret), returned)
        return obs, state, reward, terminated, truncated, {
            **info, **returned, "returned_episode": done,
        }  # fmt: skip


def episode_ppl(
    info: dict[str, Any], preset: Any, houses: Any = None
) -> dict[str, float]:
    """Score one finished episode logged by :class:`LogWrapper` on the host, as the
    navigation benchmark does: PPL = P * min(1, L_opt / L) with L the path length at the
    last verification and L_opt the shortest path from the start through the found
    instances (true map).

    Args:
        info: one episode's ``episode_*`` fields (NumPy or JAX scalars; pick one row of a
            batch first).
        preset: the environment's preset.
        houses: a :class:`~bfsop_jax.eval.navigation.HouseSet` to read the house from
            (ProcTHOR files, or a cache); default: the procedural house of the seed.

    Returns ``{"ppl", "l_opt", "progress", "path_length"}`` (metres where lengths).
    """
    from bfsop_jax import metrics
    from bfsop_jax.eval.navigation import Episode, HouseSet, optimal_found_length

    houses = HouseSet(preset) if houses is None else houses
    ep = Episode(int(info["episode_house"]), int(info["episode_category"]))
    found_mask = np.asarray(info["episode_found_mask"], bool)
    start = np.asarray(info["episode_start_xy"], np.float32)
    l_opt = optimal_found_length(ep, houses, start, np.flatnonzero(found_mask))
    found, total = int(info["episode_found"]), int(info["episode_n_targets"])
    length = float(info["episode_last_find_length"])
    return {
        "ppl": float(metrics.ppl(found, total, length, l_opt)),
        "l_opt": l_opt,
        "progress": found / max(total, 1),
        "path_length": length,
    }
