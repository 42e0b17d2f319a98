"""Evaluation charts: PPL per method, PPL per target category and method, the
hyper-parameter sweep (reward / VNS per swept value) and several planners' reward against
their latency (models side by side), paired differences with their intervals (evaluations
and their pool).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.ticker import FormatStrFormatter

from bfsop_jax.viz.style import BLUE, RED, finish, method_colour, style_axes

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

__all__ = [
    "plot_category_ppl",
    "plot_model_comparison",
    "plot_paired_differences",
    "plot_ppl",
    "plot_sweep",
]


def plot_ppl(
    labels: Sequence[str],
    means: ArrayLike,
    intervals: ArrayLike,
    path: str | Path | None = None,
    title: str | None = None,
    colours: Sequence[str] | None = None,
) -> plt.Figure:
    """Bar chart of the mean PPL per method with its 95 % interval (error bars), the value
    written in each bar.

    Args: labels [n] method names, means [n], intervals [n, 2] (lo, hi); colours [n] (the
    method colours in order by default), so a method keeps its colour when others are
    missing.
    """
    means = np.asarray(means, float)
    lo_hi = np.asarray(intervals, float).reshape(-1, 2)
    fig, ax = plt.subplots(figsize=(1.3 * len(means) + 2.0, 3.6), dpi=110)
    x = np.arange(len(means))
    err = np.stack([means - lo_hi[:, 0], lo_hi[:, 1] - means])
    colours = colours or [method_colour(i) for i in range(len(means))]
    ax.bar(x, means, color=colours, yerr=err, capsize=4, edgecolor="black", lw=0.6)
    for xi, m in zip(x, means, strict=True):
        ax.text(xi, m / 2, f"{m:.3f}", ha="center", va="center", fontsize=8, color="white")
    ax.set_ylim(0, max(1e-3, float(np.nanmax(lo_hi[:, 1]))) * 1.15)
    return _finish_bars(fig, ax, x, labels, "PPL (mean, 95% bootstrap CI)", title, path)


def plot_paired_differences(
    planners: Sequence[str],
    groups: Mapping[str, ArrayLike],
    path: str | Path | None = None,
    title: str | None = None,
    xlabel: str = "reward / VNS minus greedy insertion's (paired, 95% CI)",
) -> plt.Figure:
    """Forest plot: each planner's paired difference to a reference with its interval, one
    marker per group (e.g. each evaluation run and their pool) in rows; a line at 0.

    Args: planners [p] row names; groups: label -> [p, 3] (difference, lo, hi) rows in
    the order of ``planners`` (NaN rows are not drawn). The last group is drawn in black,
    filled (the pooled estimate); the others hollow, in the method colours.
    """
    names = list(planners)
    g = len(groups)
    fig, ax = plt.subplots(figsize=(7.4, 0.2 * len(names) * (1 + 0.3 * g) + 1.6), dpi=110)
    offsets = (np.arange(g) - (g - 1) / 2) * (0.7 / max(g, 1))
    y = np.arange(len(names))[::-1].astype(float)
    for i, (label, rows) in enumerate(groups.items()):
        rows = np.asarray(rows, float).reshape(len(names), 3)
        last = i == g - 1
        colour = "black" if last else method_colour(i)
        ok = np.isfinite(rows).all(axis=1)
        err = np.stack([rows[ok, 0] - rows[ok, 1], rows[ok, 2] - rows[ok, 0]])
        ax.errorbar(rows[ok, 0], y[ok] + offsets[i], xerr=err, fmt="o", color=colour,
                    mfc=colour if last else "white", ms=5, capsize=3, lw=1.2 if last else 0.9,
                    label=label)  # fmt: skip
    ax.axvline(0.0, color=RED, lw=0.9, ls=":")
    ax.set_yticks(y, names, fontsize=8)
    style_axes(ax, xlabel=xlabel, title=title, title_size=10, grid="x")
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=min(g, 3),
              frameon=False)  # fmt: skip
    return finish(fig, path)


def _finish_bars(fig, ax, x, ticks, ylabel, title, path) -> plt.Figure:
    """Slanted tick labels, a y grid, the title; layout and PNG."""
    ax.set_xticks(x, ticks, rotation=20, ha="right", fontsize=8)
    style_axes(ax, ylabel=ylabel, title=title, title_size=10, grid="y")
    return finish(fig, path)


def plot_category_ppl(
    categories: Sequence[str],
    labels: Sequence[str],
    table: ArrayLike,
    path: str | Path | None = None,
    title: str | None = None,
    colours: Sequence[str] | None = None,
) -> plt.Figure:
    """Grouped bar chart of the mean PPL per target category (groups) and method (bars,
    legend on the right; a NaN entry, a method without episodes of a category, draws no bar).

    Args: categories [c] names, labels [n] method names, table [n, c] mean PPL; colours
    [n] as in :func:`plot_ppl`.
    """
    table = np.asarray(table, float)
    n, c = table.shape
    fig, ax = plt.subplots(figsize=(max(6.0, 0.9 * c + 2.0) + 1.8, 3.6), dpi=110)
    width = 0.8 / n
    x = np.arange(c)
    colours = colours or [method_colour(i) for i in range(n)]
    for i in range(n):
        offset = (i - (n - 1) / 2) * width
        ax.bar(x + offset, table[i], width, label=labels[i], color=colours[i], ec="black",
               lw=0.4)  # fmt: skip
    style_axes(ax, legend={"fontsize": 7, "loc": "upper left", "bbox_to_anchor": (1.01, 1.0)})
    return _finish_bars(fig, ax, x, categories, "PPL (mean over houses)", title, path)


def plot_sweep(
    results: Sequence[Mapping[str, Any]],
    grid: Mapping[str, Sequence[Any]],
    path: str | Path | None = None,
    reference: float | None = None,
) -> plt.Figure:
    """Reward / VNS of every sweep combination against each swept key (one panel per key
    with more than one value): one jittered dot per combination, the mean per value.

    Args: results: [R] rows with ``settings`` (key -> value) and ``reward_ratio``; grid:
    key -> list of values (the panel's x positions, in grid order); reference: a horizontal
    line (e.g. greedy insertion's ratio on the same instances).
    """
    keys = [k for k in grid if len(grid[k]) > 1] or list(grid)
    fig, axes = plt.subplots(
        1, len(keys), figsize=(3.0 * len(keys) + 0.6, 3.2), dpi=110, sharey=True, squeeze=False
    )
    ratios = np.asarray([r["reward_ratio"] for r in results], float)
    rng = np.random.default_rng(0)  # horizontal jitter only, so equal points stay visible
    for ax, key in zip(axes[0], keys, strict=True):
        values = list(grid[key])
        pos = np.asarray([values.index(r["settings"][key]) for r in results], float)
        ax.scatter(pos + rng.uniform(-0.12, 0.12, len(pos)), ratios, s=18, alpha=0.7,
                   color=BLUE, edgecolor="black", lw=0.4, zorder=3)  # fmt: skip
        means = [ratios[pos == i].mean() for i in range(len(values))]
        ax.plot(range(len(values)), means, color=RED, marker="_", ms=18, lw=1.2,
                label="mean", zorder=4)  # fmt: skip
        if reference is not None:
            ax.axhline(reference, color="grey", ls="--", lw=1, label="greedy insertion")
        ax.set_xticks(range(len(values)), [str(v) for v in values], fontsize=8)
        style_axes(ax, xlabel=key, grid="y")
    style_axes(axes[0][0], ylabel="reward / VNS (greedy + 2-opt)",
               legend={"fontsize": 7, "loc": "best"})  # fmt: skip
    fig.suptitle(f"Sweep: {len(results)} combinations", fontsize=10)
    return finish(fig, path)


# planner names shortened for the point labels of :func:`plot_model_comparison`
_SHORT = (("transformer+2opt", "greedy"), ("+best_of_", "+best"), ("multi_start", "multi"))


def plot_model_comparison(
    models: Mapping[str, Mapping[str, Mapping[str, Any]]],
    path: str | Path | None = None,
    planners: Iterable[str] | None = None,
    title: str | None = None,
    goals: Sequence[float] = (0.95, 0.985),
    latency_budget_ms: float = 10.0,
) -> plt.Figure:
    """Reward / VNS against single-instance latency (ms, log scale) of every planner of
    every model on the same instances: one colour per model, each planner a labelled
    point; greedy insertion as a black star; dotted lines at the reward
    ``goals`` and at ``latency_budget_ms``.

    Args: models: model label -> planner name -> a summary row with ``mean_reward`` and
    ``latency_ms_single`` (the ``planners`` of an evaluation summary); each model's ``vns``
    row is the reward's reference; planners: the planner names drawn, as in
    :func:`bfsop_jax.eval.solvers.compare_table` (default: every one but ``vns`` and
    ``greedy_insertion``).
    """
    fig, ax = plt.subplots(figsize=(7.6, 4.4), dpi=110)
    insertion = None
    skip = ("vns", "greedy_insertion")
    shown = None if planners is None else set(planners)
    labels = []  # (x, y, text, colour), placed once every point is drawn
    for i, (label, planners) in enumerate(models.items()):
        scale = max(planners["vns"]["mean_reward"], 1e-12)
        rows = sorted(
            (r["latency_ms_single"], r["mean_reward"] / scale, name)
            for name, r in planners.items()
            if name not in skip and (shown is None or name in shown)
        )
        x, y = [r[0] for r in rows], [r[1] for r in rows]
        colour = method_colour(i + 1)
        ax.plot(x, y, color=colour, marker="o", ms=6, ls="none", mec="black", mew=0.4, label=label)
        for xi, yi, name in rows:
            for old, new in _SHORT:
                name = name.replace(old, new)
            labels.append((xi, yi, name, colour))
        if insertion is None and "greedy_insertion" in planners:
            g = planners["greedy_insertion"]
            insertion = (g["latency_ms_single"], g["mean_reward"] / scale)
    if insertion is not None:
        ax.plot(*insertion, marker="*", ms=11, color="black", ls="none", label="greedy insertion")
    for goal in goals:
        ax.axhline(goal, color="grey", ls=":", lw=1)
    ax.axvline(latency_budget_ms, color="grey", ls=":", lw=1)
    ax.set_xscale("log")
    _place_labels(ax, labels)
    ax.xaxis.set_major_formatter(FormatStrFormatter("%g"))
    ax.xaxis.set_minor_formatter(FormatStrFormatter("%g"))
    ax.tick_params(axis="x", which="minor", labelsize=7)
    style_axes(ax, xlabel="latency per instance, single (ms, log scale)",
               ylabel="reward / VNS", title=title, title_size=10, grid="both",
               legend={"fontsize": 7, "loc": "lower right"})  # fmt: skip
    return finish(fig, path)


def _place_labels(ax: plt.Axes, labels: list[tuple[float, float, str, str]]) -> None:
    """Annotate points (x, y, text, colour) at 6 pt, each label moved up or down in steps
    of 7 pt until its box clears the labels already placed (nearly coinciding points)."""
    ax.autoscale_view()
    to_display = ax.transData.transform
    points_to_pixels = ax.figure.dpi / 72.0
    placed: list[tuple[float, float, float, float]] = []  # pixel boxes x0, x1, y0, y1
    for x, y, text, colour in sorted(labels, key=lambda r: (-r[1], r[0])):
        px, py = to_display((x, y))
        width = 3.2 * len(text) * points_to_pixels
        for step in (0, 1, -1, 2, -2, 3, -3, 4, -4):
            dy = -3 - 7 * step  # points
            y0 = py + (dy - 2) * points_to_pixels
            box = (px + 4 * points_to_pixels, px + 4 * points_to_pixels + width, y0,
                   y0 + 6 * points_to_pixels)  # fmt: skip
            if not any(b[0] < box[1] and box[0] < b[1] and b[2] < box[3] and box[2] < b[3]
                       for b in placed):  # fmt: skip
                break
        placed.append(box)
        ax.annotate(text, (x, y), xytext=(4, dy), textcoords="offset points", fontsize=6,
                    color=colour)  # fmt: skip
