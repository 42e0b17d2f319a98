"""Episode GIFs: record an episode (:class:`bfsop_jax.agents.record.EpisodeRecorder`) and
draw it (:func:`bfsop_jax.viz.animate_episode`); the glue behind ``experiments.simulate
--gif`` and ``experiments.evaluate --gif N``.

The evaluation's GIFs re-run episodes of its protocol one at a time with the recorder:
the same reset key (:attr:`~bfsop_jax.eval.navigation.Episode.key`), house, category,
budget and prior, so (the rollout being batch invariant) the same episodes as the
batched evaluation's, whose path is left untouched.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from bfsop_jax.agents.record import EpisodeRecorder, Recording
from bfsop_jax.config import Preset
from bfsop_jax.env import EnvState, reset
from bfsop_jax.eval import navigation as nav
from bfsop_jax.world.constants import TARGET_NAMES

__all__ = [
    "MAP_CELLS",
    "episode_gif_name",
    "gif_downsample",
    "make_recorder",
    "record_gif",
    "write_episode_gifs",
]

MAP_CELLS = 360  # a GIF's map is at most about this many cells wide (more cannot show)


def gif_downsample(preset: Preset) -> int:
    """Belief cells per recorded cell: 1 up to :data:`MAP_CELLS` cells across (smoke,
    demo), 2 for the paper preset's 520; a GIF's map is about 450 pixels wide."""
    return max(1, math.ceil(max(preset.grid_shape) / MAP_CELLS))


def make_recorder(strategy: Any, preset: Preset) -> EpisodeRecorder:
    """A recorder that takes a frame every macro step, belief reduced by
    :func:`gif_downsample` (about 75 KB a frame on demo)."""
    return EpisodeRecorder(strategy, preset, every=1, downsample=gif_downsample(preset))


def record_gif(
    recorder: EpisodeRecorder,
    state: EnvState,
    path: str | os.PathLike,
    title: str,
    progress: Any = None,
    **animate: Any,
) -> tuple[Path, Recording]:
    """Record the episode from ``state`` and write it as a GIF at ``path``; ``progress``
    (called with metres travelled) and ``animate`` (keyword arguments of
    :func:`~bfsop_jax.viz.animate_episode`) are optional. Returns the path and the
    recording."""
    from bfsop_jax import viz

    recording = recorder.record(state, progress=progress)
    return viz.animate_episode(recording.frames, path, title, **animate), recording


def episode_gif_name(method: str, house: str, category: int) -> str:
    """``{method}_{house}_{category}.gif``."""
    return f"{method}_{house}_{TARGET_NAMES[category]}.gif"


def write_episode_gifs(
    methods: Sequence[str],
    episodes: Sequence[nav.Episode],
    houses: nav.HouseSet,
    out_dir: str | os.PathLike,
    policy: Any = None,
    settings: dict[str, dict[str, Any]] | None = None,
    prior: np.ndarray | None = None,
    progress: bool = True,
) -> list[dict[str, Any]]:
    """A GIF of each of ``episodes`` for every method, in ``out_dir``
    (:func:`episode_gif_name`); ``policy``, ``settings`` and ``prior`` as for
    :func:`~bfsop_jax.eval.navigation.evaluate_navigation` (budget: the preset's).

    Returns one row per GIF: method, house, category, ``found`` / ``total``,
    ``path_length`` (m), ``frames`` recorded, ``bytes`` and ``gif`` (its file name).
    """
    preset = houses.preset
    out = Path(out_dir)
    if prior is None:
        from bfsop_jax.world.prior import default_prior

        prior = default_prior()
    prior = jnp.asarray(prior, jnp.float32)
    start = jax.jit(lambda k, h, c, b: reset(k, h, c, preset, prior, b))
    rows = []
    bar = tqdm(total=len(methods) * len(episodes), desc="GIFs", unit="gif", disable=not progress)
    for method in methods:
        recorder = make_recorder(nav.make_strategy(method, policy, settings), preset)
        for ep in episodes:
            name = houses.name(ep.house)
            state = start(ep.key, houses[ep.house], jnp.int32(ep.category),
                          jnp.float32(preset.budget_m))  # fmt: skip
            title = f"{nav.LABELS[method]}: {TARGET_NAMES[ep.category]} in house {name}"
            path, rec = record_gif(
                recorder, state, out / episode_gif_name(method, name, ep.category), title
            )
            f = rec.frames
            rows.append({
                "method": method, "house": name, "category": TARGET_NAMES[ep.category],
                "found": int(f.found_count[-1]), "total": f.total,
                "path_length": float(f.path_length[-1]), "frames": f.n_frames,
                "bytes": path.stat().st_size, "gif": path.name,
            })  # fmt: skip
            bar.update(1)
    bar.close()
    return rows
