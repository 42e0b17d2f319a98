"""SOP pictures: planned tours side by side on one instance, and where the decoder's
probability goes by distance (the numbers come from
:func:`bfsop_jax.eval.solvers.decoder_distance_mass`).
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import matplotlib.pyplot as plt
import numpy as np

from bfsop_jax.viz.style import TOURING_COLOUR, finish, style_axes

if TYPE_CHECKING:
    from bfsop_jax.sop import SOPInstance

__all__ = ["plot_distance_mass", "plot_tour_comparison"]

QUINTILE_TICKS = ("Q1\n(nearest)", "Q2", "Q3", "Q4", "Q5\n(farthest)")


def plot_distance_mass(mass: np.ndarray, path: str | os.PathLike) -> None:
    """Bar chart of the decoder's probability mass per distance quintile, over all steps and
    over the first step alone, against the uniform choice (0.2 per quintile).

    Args: mass: [2, 5] rows (all steps, first step), columns nearest to farthest quintile,
    as returned by :func:`bfsop_jax.eval.solvers.decoder_distance_mass`.
    """
    fig, ax = plt.subplots(figsize=(6, 3.6))
    x = np.arange(5)
    ax.bar(x - 0.2, mass[0], 0.4, label="all steps")
    ax.bar(x + 0.2, mass[1], 0.4, label="first step (t = 0)")
    ax.axhline(0.2, color="grey", ls=":", lw=1, label="uniform")
    ax.set_xticks(x, QUINTILE_TICKS)
    style_axes(ax, ylabel="decoder probability mass",
               title="Where the decoder looks: distance quintiles",
               legend={"fontsize": 8})  # fmt: skip
    finish(fig, path, tight_bbox=False, dpi=110, close=True)


def plot_tour_comparison(
    instance: SOPInstance,
    plans: dict[str, tuple[list[int], float, float]],
    path: str | os.PathLike,
) -> None:
    """One panel per planner on the same (unbatched) instance: nodes coloured by set (sized
    by the set's reward, faint when it is worth nothing), the start (white circle), the
    tour (straight lines between the chosen viewpoints; the costs are geodesic) ending in a
    cross, reward and cost in the title.

    Args: instance: one instance ([N, 2] coords, [N] set ids, [K] set rewards); plans:
    name -> (node ids in visiting order, reward, cost).
    """
    xy = np.asarray(instance.coords)
    set_id = np.asarray(instance.set_id)
    reward = np.asarray(instance.set_reward)
    start = int(instance.start)
    real = set_id >= 0
    fig, axes = plt.subplots(1, len(plans), figsize=(5.2 * len(plans), 4.6), squeeze=False)
    cmap = plt.get_cmap("tab20")
    for ax, (name, (nodes, r, c)) in zip(axes[0], plans.items(), strict=True):
        for s in np.unique(set_id[real]):
            pts = xy[(set_id == s) & real]
            if s == set_id[start]:
                continue
            alpha = 0.9 if reward[s] > 0 else 0.25
            ax.scatter(pts[:, 0], pts[:, 1], s=18 + 60 * reward[s] / max(reward.max(), 1e-9),
                       color=cmap(int(s) % 20), alpha=alpha)  # fmt: skip
        tour = xy[[n for n in nodes if n >= 0]]
        ax.plot(tour[:, 0], tour[:, 1], "-", color=TOURING_COLOUR, lw=1.6)
        ax.scatter(tour[1:, 0], tour[1:, 1], s=60, facecolors="none", edgecolors=TOURING_COLOUR)
        ax.plot(*xy[start], "o", ms=10, mfc="white", mec="k", mew=2)
        if len(tour) > 1:
            ax.plot(*tour[-1], "x", ms=10, color="k", mew=2)
        ax.set_aspect("equal")
        title = f"{name}\nreward {r:.2f}, cost {c:.1f} m"
        style_axes(ax, xlabel="x (m)", ylabel="y (m)", title=title, grid="both", grid_alpha=0.2)
    finish(fig, path, tight_bbox=False, dpi=110, close=True)
