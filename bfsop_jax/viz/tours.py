"""SOP pictures: planned tours side by side on one instance, over the belief map the
instance was built on (the map drawing of :mod:`bfsop_jax.viz.world`; the tours' polylines
come from the caller, e.g. :func:`bfsop_jax.navigation.geodesic_route`), and where the
decoder's probability goes by distance (the numbers come from
:func:`bfsop_jax.eval.solvers.decoder_distance_mass`).
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import matplotlib.pyplot as plt
import numpy as np
from matplotlib import patheffects
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from bfsop_jax.viz.style import TOURING_COLOUR, finish, style_axes
from bfsop_jax.viz.world import UNKNOWN_GREY, draw_belief

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from bfsop_jax.sop import SOPInstance

__all__ = ["plot_distance_mass", "plot_tour_comparison"]

TOUR_COLOURS: tuple[str, ...] = (TOURING_COLOUR, "#d6006e", "#ff7f0e", "#2ca02c")
"""Colour of each planner's tour in :func:`plot_tour_comparison`, in the order of its plans."""
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


def _map_window(
    belief: np.ndarray | None, cell_size: float, points: np.ndarray, margin: float = 0.6
) -> tuple[float, float, float, float]:
    """(x0, x1, y0, y1) metres: the known part of ``belief`` [H, W] (cells that are not
    unknown, as :func:`~bfsop_jax.viz.world.belief_image` shows them) and ``points``
    [P, 2], with ``margin`` metres around, inside the map."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    if belief is None:
        return lo[0] - margin, hi[0] + margin, lo[1] - margin, hi[1] + margin
    h, w = belief.shape
    rows, cols = np.nonzero(np.asarray(belief) != 0)
    if rows.size:
        lo = np.minimum(lo, [cols.min() * cell_size, rows.min() * cell_size])
        hi = np.maximum(hi, [(cols.max() + 1) * cell_size, (rows.max() + 1) * cell_size])
    return (max(lo[0] - margin, 0.0), min(hi[0] + margin, w * cell_size),
            max(lo[1] - margin, 0.0), min(hi[1] + margin, h * cell_size))  # fmt: skip


def plot_tour_comparison(
    instance: SOPInstance,
    plans: dict[str, tuple[list[int], float, float]],
    path: str | os.PathLike,
    belief: ArrayLike | None = None,
    cell_size: float | None = None,
    known: float = 0.0,
    routes: dict[str, ArrayLike] | None = None,
) -> None:
    """One panel per planner on the same (unbatched) instance, over the belief map it was
    planned on: viewpoints coloured by set (one set per landmark, sized by the set's reward,
    faint when it is worth nothing), the start (white circle), the tour in the planner's
    colour with its visiting order numbered, ending in a cross; reward and cost in the
    title. Without ``belief`` the panels are on white.

    Args:
        instance: one instance ([N, 2] coords in metres, [N] set ids, [K] set rewards).
        plans: name -> (node ids in visiting order, reward, cost in metres).
        path: the PNG to write.
        belief: optional [H, W] map drawn underneath (:func:`~bfsop_jax.viz.world.draw_belief`):
            log-odds, or int8 cell states (-1 known free, 0 unknown, 1 known occupied, as
            :func:`bfsop_jax.data.generate.pose_tasks` keeps them) with ``known`` 0. The
            panels show its known part.
        cell_size: metres per cell of ``belief`` (needed with it).
        known: the log-odds threshold of a known cell (``preset.logodds_known``), 0 for
            cell states.
        routes: optional name -> [P, 2] polyline (metres) each tour follows, e.g. the
            legs' shortest paths on the map (:func:`bfsop_jax.navigation.geodesic_route`);
            a planner without one is drawn with straight segments between its viewpoints.
    """
    xy = np.asarray(instance.coords, np.float32)
    set_id = np.asarray(instance.set_id)
    reward = np.asarray(instance.set_reward)
    start = int(instance.start)
    real = set_id >= 0
    routes = routes or {}
    if belief is not None:
        if cell_size is None:
            raise ValueError("plot_tour_comparison: a belief map needs its cell_size (metres)")
        belief = np.asarray(belief)
        if belief.ndim != 2:
            raise ValueError(f"belief must be one [H, W] map, got shape {belief.shape}")
    shown = [xy[real]] + [np.asarray(r, np.float32).reshape(-1, 2) for r in routes.values()]
    states = None if belief is None else np.sign(np.where(np.abs(belief) > known, belief, 0))
    x0, x1, y0, y1 = _map_window(states, cell_size or 1.0, np.concatenate(shown))
    # panels 6 inches wide (the map's aspect sets their height), titles above, legend below
    panel_h = float(np.clip(6.0 * (y1 - y0) / max(x1 - x0, 1e-6), 2.5, 7.0))
    fig, axes = plt.subplots(
        1, len(plans), figsize=(6.6 * len(plans), panel_h + 1.9), squeeze=False, dpi=110
    )
    cmap = plt.get_cmap("tab20")
    outline = [patheffects.withStroke(linewidth=3.2, foreground="white")]  # lines on black
    halo = [patheffects.withStroke(linewidth=2, foreground="white")]  # the visit numbers
    for p, (ax, (name, (nodes, r, c))) in enumerate(zip(axes[0], plans.items(), strict=True)):
        colour = TOUR_COLOURS[p % len(TOUR_COLOURS)]
        if belief is not None:
            draw_belief(ax, belief, cell_size, known)
        for s in np.unique(set_id[real]):
            if s == set_id[start]:
                continue
            pts = xy[(set_id == s) & real]
            alpha = 0.9 if reward[s] > 0 else 0.3
            ax.scatter(pts[:, 0], pts[:, 1], s=14 + 50 * reward[s] / max(reward.max(), 1e-9),
                       color=cmap(int(s) % 20), alpha=alpha, edgecolors="black",
                       linewidths=0.3, zorder=4)  # fmt: skip
        visit = [n for n in nodes if n >= 0]
        tour = xy[visit]
        line = np.asarray(routes[name], np.float32).reshape(-1, 2) if name in routes else tour
        ax.plot(line[:, 0], line[:, 1], "-", color=colour, lw=1.8, zorder=6,
                path_effects=outline)  # fmt: skip
        ax.scatter(tour[1:, 0], tour[1:, 1], s=55, facecolors="none", edgecolors=colour,
                   linewidths=1.6, zorder=7)  # fmt: skip
        for k, (x, y) in enumerate(tour[1:], start=1):
            ax.annotate(str(k), (x, y), xytext=(4, 4), textcoords="offset points", fontsize=7,
                        fontweight="bold", color=colour, zorder=8, path_effects=halo)  # fmt: skip
        ax.plot(*xy[start], "o", ms=10, mfc="white", mec="k", mew=2, zorder=9)
        if len(tour) > 1:
            ax.plot(*tour[-1], "x", ms=10, color="k", mew=2.2, zorder=9)
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_aspect("equal")
        title = f"{name}\nreward {r:.2f}, cost {c:.1f} m"
        grid = None if belief is not None else "both"
        style_axes(ax, xlabel="x (m)", ylabel="y (m)", title=title, grid=grid, grid_alpha=0.2)
    handles = [
        Line2D([], [], color=TOUR_COLOURS[p % len(TOUR_COLOURS)], lw=1.8, label=f"{name} "
               + ("tour (shortest path of each leg)" if name in routes else "tour (straight legs)"))
        for p, name in enumerate(plans)
    ]  # fmt: skip
    handles += [
        Line2D([], [], ls="", marker="o", mfc=cmap(2), mec="black", mew=0.3,
               label="viewpoints of a landmark (colour: landmark, size: reward)"),
        Line2D([], [], ls="", marker="o", ms=9, mfc="white", mec="k", mew=2, label="start"),
        Line2D([], [], ls="", marker="x", ms=9, color="k", mew=2, label="end"),
        Line2D([], [], ls="", marker="$1$", ms=7, color="k", label="visiting order"),
    ]  # fmt: skip
    if belief is not None:
        handles += [
            Patch(facecolor="white", edgecolor="grey", label="known free"),
            Patch(facecolor="black", label="known occupied"),
            Patch(facecolor=(UNKNOWN_GREY,) * 3, edgecolor="grey", label="unknown"),
        ]
    fig.legend(handles=handles, loc="lower center", ncol=3, fontsize=8, frameon=False)
    finish(fig, path, layout=(0, 0.75 / (panel_h + 1.9), 1, 1), tight_bbox=False, dpi=110,
           close=True)  # fmt: skip
