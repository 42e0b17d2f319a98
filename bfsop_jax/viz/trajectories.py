"""Executed trajectories: one over the house or the belief map, or several methods side by
side in the same house. Exploration is red, touring (SOP tour execution) blue, the start a
circle, the end a cross and verified targets gold stars.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.lines import Line2D

from bfsop_jax.viz.style import EXPLORATION_COLOUR, TOURING_COLOUR, finish, style_axes
from bfsop_jax.viz.world import plot_belief, plot_house
from bfsop_jax.world.types import House

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from bfsop_jax.config import Preset

__all__ = ["plot_trajectories_side_by_side", "plot_trajectory"]


def plot_trajectory(
    poses: ArrayLike,
    path: str | Path | None = None,
    ax: plt.Axes | None = None,
    house: House | None = None,
    belief: ArrayLike | None = None,
    preset: Preset | None = None,
    touring: ArrayLike | None = None,
    found_xy: ArrayLike | None = None,
    title: str | None = None,
) -> plt.Figure:
    """An executed trajectory over the house (or the final belief map).

    Exploration segments are red, touring (SOP tour execution) segments blue; the start is
    a circle and the end a cross.

    Args:
        poses: [T, 2+] visited positions in order (metres).
        house: draw the true house underneath (``plot_house``), or
        belief, preset: draw the final [H, W] log-odds belief map underneath (``plot_belief``).
        touring: optional [T] bool, true where the agent was executing a tour.
        found_xy: optional [F, 2] verified target positions (gold stars).
    """
    poses = np.asarray(poses)[:, :2]
    if ax is None:
        fig, ax = plt.subplots(figsize=(9, 7), dpi=110)
    else:
        fig = ax.figure
    if house is not None:
        plot_house(house, ax=ax)
    elif belief is not None and preset is not None:
        plot_belief(belief, preset, ax=ax)
    touring = np.zeros(len(poses), bool) if touring is None else np.asarray(touring, bool)
    for mode, colour in ((False, EXPLORATION_COLOUR), (True, TOURING_COLOUR)):
        seg = np.where(touring[1:] == mode, 1.0, np.nan)[:, None]
        xs = np.stack([poses[:-1, 0], poses[1:, 0], np.full(len(poses) - 1, np.nan)], axis=1)
        ys = np.stack([poses[:-1, 1], poses[1:, 1], np.full(len(poses) - 1, np.nan)], axis=1)
        ax.plot((xs * seg).ravel(), (ys * seg).ravel(), color=colour, lw=1.4, zorder=8)
    ax.plot(*poses[0], "o", ms=8, mfc="none", mec="black", mew=1.8, zorder=9)
    ax.plot(*poses[-1], "x", ms=9, color="black", mew=2.0, zorder=9)
    if found_xy is not None and len(found_xy):
        f = np.asarray(found_xy)
        ax.scatter(f[:, 0], f[:, 1], s=90, marker="*", c="gold", edgecolors="black", zorder=10)
    style_axes(ax, title=title)
    return finish(fig, path, layout=False)


def plot_trajectories_side_by_side(
    house: House,
    runs: Sequence[tuple[str, ArrayLike, ArrayLike, ArrayLike]],
    path: str | Path | None = None,
    title: str | None = None,
) -> plt.Figure:
    """Several methods' trajectories in the same house, one panel each.

    Args:
        house: the true house drawn underneath.
        runs: list of ``(label, xy [S, 2], touring [S] bool, found_xy [F, 2])``;
            exploration is red, touring blue, the start a circle and the end a cross.
    """
    h, w = house.grid_shape
    cs = house.cell_size
    aspect = (w * cs) / (h * cs)
    fig, axes = plt.subplots(1, len(runs), figsize=(5.2 * aspect * len(runs) + 2.5, 5.6), dpi=110)
    axes = np.atleast_1d(axes)
    for ax, (label, xy, touring, found_xy) in zip(axes, runs, strict=True):
        plot_trajectory(xy, ax=ax, house=house, touring=touring, found_xy=found_xy, title=label)
        legend = ax.get_legend()
        if legend is not None and ax is not axes[-1]:
            legend.remove()
    handles = [
        Line2D([], [], color=EXPLORATION_COLOUR, lw=1.6, label="exploration"),
        Line2D([], [], color=TOURING_COLOUR, lw=1.6, label="touring"),
        Line2D([], [], marker="o", ls="", mfc="none", mec="black", label="start"),
        Line2D([], [], marker="x", ls="", color="black", label="end"),
        Line2D([], [], marker="*", ls="", mfc="gold", mec="black", ms=10, label="found"),
    ]
    fig.legend(handles=handles, loc="lower center", ncol=5, fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    return finish(fig, path, layout=(0, 0.06, 1, 0.97))
