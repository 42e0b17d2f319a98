"""Figures. Each ``plot_*`` function is independent: it draws one picture of one thing,
onto a given Matplotlib ``ax`` or a new figure, and optionally saves it as a PNG.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless: figures are written to files, never shown

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import ListedColormap  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch, Rectangle  # noqa: E402

from bfsop_jax.world import constants as C  # noqa: E402
from bfsop_jax.world.types import House  # noqa: E402

__all__ = [
    "plot_belief",
    "plot_category_ppl",
    "plot_house",
    "plot_ppl",
    "plot_sweep",
    "plot_trajectories_side_by_side",
    "plot_trajectory",
]

ROOM_COLOURS: tuple[str, ...] = ("#f6d8a8", "#cfe3c1", "#c9d8ef", "#d7ecef")  # by room type
TARGET_COLOURS: tuple[str, ...] = (
    "#d62728", "#b8860b", "#1f77b4", "#7f7f7f", "#9467bd",
    "#8c564b", "#17becf", "#ff7f0e", "#2ca02c",
)  # fmt: skip
TARGET_MARKERS: tuple[str, ...] = ("o", "s", "^", "D", "v", "P", "X", "*", "h")
# Short furniture labels drawn inside the rectangles that are large enough.
FURNITURE_LABELS: dict[str, str] = {
    "CounterTop": "Counter", "Fridge": "Fridge", "DiningTable": "Dining", "ShelvingUnit": "Shelf",
    "SideTable": "Side", "Sofa": "Sofa", "CoffeeTable": "Coffee", "TVStand": "TV",
    "Desk": "Desk", "Dresser": "Dresser", "Bed": "Bed", "Sink": "Sink", "Toilet": "WC",
    "ArmChair": "Arm", "Chair": "Chair", "Stool": "Stool", "GarbageCan": "Bin",
}  # fmt: skip


def _save(fig: plt.Figure, path: str | Path | None) -> None:
    if path is not None:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=fig.dpi, bbox_inches="tight")


def _finish_map(fig, ax, handles, extent, title, path) -> plt.Figure:
    """Legend outside on the right, metric axes on the map's extent, optional title/PNG."""
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7,
              frameon=False)  # fmt: skip
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    if title is not None:
        ax.set_title(title)
    _save(fig, path)
    return fig


def _dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """Square dilation of a boolean image by ``radius`` cells (NumPy only)."""
    h, w = mask.shape
    padded = np.pad(mask, radius)
    out = np.zeros_like(mask)
    for dy in range(2 * radius + 1):
        for dx in range(2 * radius + 1):
            out |= padded[dy : dy + h, dx : dx + w]
    return out


def plot_house(
    house: House,
    path: str | Path | None = None,
    ax: plt.Axes | None = None,
    title: str | None = None,
) -> plt.Figure:
    """Top view of one (unbatched) house: rooms coloured by type, walls black, furniture
    rectangles with short labels, targets as markers coloured by category. Axes in metres.

    Draws on ``ax`` when given (and returns its figure), else on a new figure sized to the
    house; saves a PNG to ``path`` when given.
    """
    occupied = np.asarray(house.occupied)
    if occupied.ndim != 2:
        raise ValueError(f"plot_house takes one house, got occupied of shape {occupied.shape}")
    room_of_cell = np.asarray(house.room_of_cell)
    room_type = np.asarray(house.room_type)
    category = np.asarray(house.object_category)
    xy = np.asarray(house.object_xy)
    half = np.asarray(house.object_half_extent)
    cs = float(house.cell_size)
    h, w = occupied.shape
    extent = (0.0, w * cs, 0.0, h * cs)

    if ax is None:
        scale = 7.0 / max(w * cs, h * cs) ** 0.5
        fig, ax = plt.subplots(figsize=(w * cs * scale / 2.2 + 2.5, h * cs * scale / 2.2), dpi=110)
    else:
        fig = ax.figure

    # Floor by room type (index 0 = outside / wall), walls black on top.
    kind = np.where(room_of_cell >= 0, room_type[np.maximum(room_of_cell, 0)] + 1, 0)
    floor_cmap = ListedColormap(["white", *ROOM_COLOURS])
    ax.imshow(kind, origin="lower", extent=extent, cmap=floor_cmap, vmin=0, vmax=len(ROOM_COLOURS),
              interpolation="nearest")  # fmt: skip
    # Walls are occupied non-room cells next to a room; farther out is the outside.
    near_room = _dilate(room_of_cell >= 0, radius=2)
    wall = occupied & (room_of_cell < 0) & near_room
    outside = (room_of_cell < 0) & ~near_room
    blocked = occupied & (room_of_cell >= 0)  # furniture and filled pockets
    overlay = np.zeros((h, w, 4))
    overlay[outside] = (0.85, 0.85, 0.85, 1.0)
    overlay[wall] = (0.0, 0.0, 0.0, 1.0)
    overlay[blocked] = (0.35, 0.3, 0.25, 0.35)
    ax.imshow(overlay, origin="lower", extent=extent, interpolation="nearest")

    # Furniture (and floor plants) as rectangles.
    font = max(4.0, min(7.0, 160.0 / max(w * cs, h * cs)))
    for m in np.flatnonzero(category >= C.N_TARGETS):
        (x, y), (hx, hy) = xy[m], half[m]
        ax.add_patch(Rectangle((x - hx, y - hy), 2 * hx, 2 * hy, facecolor="#8b6f47",
                               edgecolor="#3b2f1e", linewidth=0.6, alpha=0.85))  # fmt: skip
        label = FURNITURE_LABELS.get(C.CATEGORY_NAMES[category[m]], "")
        if label and 2 * max(hx, hy) >= 0.11 * len(label) * font / 6 and min(hx, hy) >= 0.15:
            ax.text(x, y, label, ha="center", va="center", fontsize=font, color="white",
                    rotation=90 if hy > hx * 1.3 else 0, clip_on=True)  # fmt: skip

    # Targets as markers by category (floor plants get their marker too).
    target_handles = []
    for t, name in enumerate(C.TARGET_NAMES):
        sel = category == t
        if sel.any():
            ax.scatter(xy[sel, 0], xy[sel, 1], s=22, marker=TARGET_MARKERS[t], c=TARGET_COLOURS[t],
                       edgecolors="black", linewidths=0.4, zorder=5)  # fmt: skip
        target_handles.append(
            Line2D(
                [],
                [],
                linestyle="",
                marker=TARGET_MARKERS[t],
                markerfacecolor=TARGET_COLOURS[t],
                markeredgecolor="black",
                label=f"{name} ({int(sel.sum())})",
            )  # fmt: skip
        )
    room_handles = [
        Patch(
            facecolor=ROOM_COLOURS[k],
            edgecolor="grey",
            label=f"{n} ({int((room_type == k).sum())})",
        )
        for k, n in enumerate(C.ROOM_TYPE_NAMES)
    ]
    room_handles.append(Patch(facecolor="#8b6f47", edgecolor="#3b2f1e", label="furniture"))
    return _finish_map(fig, ax, room_handles + target_handles, extent, title, path)


def _belief_image(belief: np.ndarray, known: float) -> np.ndarray:
    """RGB image of a log-odds map: unknown grey, known free white, known occupied black."""
    img = np.full(belief.shape + (3,), 0.72)
    img[belief < -known] = 1.0
    img[belief > known] = 0.0
    return img


def plot_belief(
    belief,
    preset,
    path: str | Path | None = None,
    ax: plt.Axes | None = None,
    frontiers=None,
    landmarks: tuple[np.ndarray, np.ndarray] | None = None,
    pose=None,
    title: str | None = None,
) -> plt.Figure:
    """The agent's belief map: unknown grey, free white, occupied black.

    Args:
        belief: [H, W] log-odds on the 0.1 m grid.
        preset: the preset (cell size, known threshold).
        frontiers: optional ``Frontiers`` (cluster points, drawn orange, sized by cluster)
            or a [Hp, Wp] bool frontier-cell mask on the planning grid.
        landmarks: optional ``(xy [L, 2], category [L])`` landmarks of interest (squares
            labelled by category).
        pose: optional [3] agent pose (arrow).
    """
    belief = np.asarray(belief)
    cs = preset.cell_size
    h, w = belief.shape
    extent = (0.0, w * cs, 0.0, h * cs)
    if ax is None:
        fig, ax = plt.subplots(figsize=(2.0 + w * cs / 3.2, h * cs / 3.2), dpi=110)
    else:
        fig = ax.figure
    ax.imshow(_belief_image(belief, preset.logodds_known), origin="lower", extent=extent,
              interpolation="nearest")  # fmt: skip
    handles = []
    if frontiers is not None:
        if hasattr(frontiers, "xy"):
            valid = np.asarray(frontiers.valid)
            fxy, size = np.asarray(frontiers.xy)[valid], np.asarray(frontiers.size)[valid]
            ax.scatter(fxy[:, 0], fxy[:, 1], s=8 + 2 * size, c="#ff7f0e", edgecolors="black",
                       linewidths=0.4, zorder=4)  # fmt: skip
        else:
            mask = np.asarray(frontiers)
            pc = preset.plan_cell_size
            ii, jj = np.nonzero(mask)
            ax.scatter((jj + 0.5) * pc, (ii + 0.5) * pc, s=3, c="#ff7f0e", marker="s", zorder=4)
        handles.append(Line2D([], [], linestyle="", marker="o", markerfacecolor="#ff7f0e",
                              markeredgecolor="black", label="frontier"))  # fmt: skip
    if landmarks is not None:
        lxy, lcat = (np.asarray(a) for a in landmarks)
        ax.scatter(lxy[:, 0], lxy[:, 1], s=30, marker="s", c="#1f77b4", edgecolors="black",
                   linewidths=0.5, zorder=5)  # fmt: skip
        for (x, y), c in zip(lxy, lcat, strict=True):
            name = C.CATEGORY_NAMES[int(c)]
            ax.text(x, y + 0.35, FURNITURE_LABELS.get(name, name), fontsize=5, ha="center",
                    color="#1f3f74", zorder=6)  # fmt: skip
        handles.append(Line2D([], [], linestyle="", marker="s", markerfacecolor="#1f77b4",
                              markeredgecolor="black", label="landmark of interest"))  # fmt: skip
    if pose is not None:
        x, y, th = (float(v) for v in np.asarray(pose))
        arrow = {"arrowstyle": "->", "color": "#2ca02c", "lw": 1.5}
        tip = (x + 0.8 * np.cos(th), y + 0.8 * np.sin(th))
        ax.annotate("", xy=tip, xytext=(x, y), arrowprops=arrow, zorder=7)
        ax.plot([x], [y], "o", color="#2ca02c", ms=5, zorder=7)
        handles.append(Line2D([], [], linestyle="", marker="o", color="#2ca02c", label="agent"))
    handles += [
        Patch(facecolor="white", edgecolor="grey", label="known free"),
        Patch(facecolor="black", label="known occupied"),
        Patch(facecolor=(0.72, 0.72, 0.72), label="unknown"),
    ]
    return _finish_map(fig, ax, handles, extent, title, path)


def plot_trajectory(
    poses,
    path: str | Path | None = None,
    ax: plt.Axes | None = None,
    house: House | None = None,
    belief=None,
    preset=None,
    touring=None,
    found_xy=None,
    title: str | None = None,
) -> plt.Figure:
    """An executed trajectory over the house (or the final belief map).

    Exploration segments are red, touring (SOP tour execution) segments blue; the start is
    a circle and the end a cross (SPEC 11).

    Args:
        poses: [T, 2+] visited positions in order (metres).
        house: draw the true house underneath (``plot_house``), or
        belief, preset: draw the final belief map underneath (``plot_belief``).
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
    for mode, colour in ((False, "#d62728"), (True, "#1f77b4")):
        seg = np.where(touring[1:] == mode, 1.0, np.nan)[:, None]
        xs = np.stack([poses[:-1, 0], poses[1:, 0], np.full(len(poses) - 1, np.nan)], axis=1)
        ys = np.stack([poses[:-1, 1], poses[1:, 1], np.full(len(poses) - 1, np.nan)], axis=1)
        ax.plot((xs * seg).ravel(), (ys * seg).ravel(), color=colour, lw=1.4, zorder=8)
    ax.plot(*poses[0], "o", ms=8, mfc="none", mec="black", mew=1.8, zorder=9)
    ax.plot(*poses[-1], "x", ms=9, color="black", mew=2.0, zorder=9)
    if found_xy is not None and len(found_xy):
        f = np.asarray(found_xy)
        ax.scatter(f[:, 0], f[:, 1], s=90, marker="*", c="gold", edgecolors="black", zorder=10)
    if title is not None:
        ax.set_title(title)
    _save(fig, path)
    return fig


METHOD_COLOURS: tuple[str, ...] = ("#7f7f7f", "#bcbd22", "#ff7f0e", "#2ca02c", "#1f77b4")


def plot_ppl(
    labels, means, intervals, path: str | Path | None = None, title: str | None = None
) -> plt.Figure:
    """Mean PPL per method with its 95 % interval (error bars).

    Args: labels [n] method names, means [n], intervals [n, 2] (lo, hi).
    """
    means = np.asarray(means, float)
    lo_hi = np.asarray(intervals, float).reshape(-1, 2)
    fig, ax = plt.subplots(figsize=(1.3 * len(means) + 2.0, 3.6), dpi=110)
    x = np.arange(len(means))
    err = np.stack([means - lo_hi[:, 0], lo_hi[:, 1] - means])
    colours = [METHOD_COLOURS[i % len(METHOD_COLOURS)] for i in range(len(means))]
    ax.bar(x, means, color=colours, yerr=err, capsize=4, edgecolor="black", lw=0.6)
    for xi, m in zip(x, means, strict=True):
        ax.text(xi, m / 2, f"{m:.3f}", ha="center", va="center", fontsize=8, color="white")
    ax.set_ylim(0, max(1e-3, float(np.nanmax(lo_hi[:, 1]))) * 1.15)
    return _finish_bars(fig, ax, x, labels, "PPL (mean, 95% bootstrap CI)", title, path)


def _finish_bars(fig, ax, x, ticks, ylabel, title, path) -> plt.Figure:
    ax.set_xticks(x, ticks, rotation=20, ha="right", fontsize=8)
    ax.set_ylabel(ylabel)
    ax.grid(axis="y", alpha=0.3)
    if title:
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    _save(fig, path)
    return fig


def plot_category_ppl(
    categories, labels, table, path: str | Path | None = None, title: str | None = None
) -> plt.Figure:
    """Mean PPL per target category (groups) and method (bars).

    Args: categories [c] names, labels [n] method names, table [n, c] mean PPL.
    """
    table = np.asarray(table, float)
    n, c = table.shape
    fig, ax = plt.subplots(figsize=(max(6.0, 0.9 * c + 2.0) + 1.8, 3.6), dpi=110)
    width = 0.8 / n
    x = np.arange(c)
    for i in range(n):
        colour = METHOD_COLOURS[i % len(METHOD_COLOURS)]
        offset = (i - (n - 1) / 2) * width
        ax.bar(x + offset, table[i], width, label=labels[i], color=colour, ec="black", lw=0.4)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return _finish_bars(fig, ax, x, categories, "PPL (mean over houses)", title, path)


def plot_trajectories_side_by_side(
    house: House,
    runs,
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
        Line2D([], [], color="#d62728", lw=1.6, label="exploration"),
        Line2D([], [], color="#1f77b4", lw=1.6, label="touring"),
        Line2D([], [], marker="o", ls="", mfc="none", mec="black", label="start"),
        Line2D([], [], marker="x", ls="", color="black", label="end"),
        Line2D([], [], marker="*", ls="", mfc="gold", mec="black", ms=10, label="found"),
    ]
    fig.legend(handles=handles, loc="lower center", ncol=5, fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0.06, 1, 0.97))
    _save(fig, path)
    return fig


def plot_sweep(
    results, grid, path: str | Path | None = None, reference: float | None = None
) -> plt.Figure:
    """Reward / VNS of every sweep combination against each swept key (one panel per key).

    Args: results: rows with ``settings`` (key -> value) and ``reward_ratio``; grid: key ->
    list of values (the panel's x positions, in grid order); reference: a horizontal line
    (e.g. greedy insertion's ratio on the same instances).
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
                   color="#1f77b4", edgecolor="black", lw=0.4, zorder=3)  # fmt: skip
        means = [ratios[pos == i].mean() for i in range(len(values))]
        ax.plot(range(len(values)), means, color="#d62728", marker="_", ms=18, lw=1.2,
                label="mean", zorder=4)  # fmt: skip
        if reference is not None:
            ax.axhline(reference, color="grey", ls="--", lw=1, label="greedy insertion")
        ax.set_xticks(range(len(values)), [str(v) for v in values], fontsize=8)
        ax.set_xlabel(key)
        ax.grid(axis="y", alpha=0.3)
    axes[0][0].set_ylabel("reward / VNS (greedy + 2-opt)")
    axes[0][0].legend(fontsize=7, loc="best")
    fig.suptitle(f"Sweep: {len(results)} combinations", fontsize=10)
    fig.tight_layout()
    _save(fig, path)
    return fig
