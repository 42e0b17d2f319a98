"""Pictures of the world: the top view of a house and the agent's belief map.

Each ``plot_*`` function draws one picture onto a given Matplotlib ``ax`` or a new figure,
and optionally saves it as a PNG.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib.image
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.colors import ListedColormap
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Rectangle

from bfsop_jax.viz.style import (
    AGENT_COLOUR,
    FRONTIER_COLOUR,
    ROOM_COLOURS,
    TARGET_COLOURS,
    TARGET_MARKERS,
    finish,
    style_axes,
)
from bfsop_jax.world import constants as C
from bfsop_jax.world.types import House

if TYPE_CHECKING:  # annotations only: the viz package imports no navigation code
    from numpy.typing import ArrayLike

    from bfsop_jax.config import Preset
    from bfsop_jax.navigation.frontiers import Frontiers

__all__ = ["belief_image", "draw_belief", "plot_belief", "plot_house"]

# Short furniture labels drawn inside the rectangles that are large enough.
FURNITURE_LABELS: dict[str, str] = {
    "CounterTop": "Counter", "Fridge": "Fridge", "DiningTable": "Dining", "ShelvingUnit": "Shelf",
    "SideTable": "Side", "Sofa": "Sofa", "CoffeeTable": "Coffee", "TVStand": "TV",
    "Desk": "Desk", "Dresser": "Dresser", "Bed": "Bed", "Sink": "Sink", "Toilet": "WC",
    "ArmChair": "Arm", "Chair": "Chair", "Stool": "Stool", "GarbageCan": "Bin",
}  # fmt: skip
FURNITURE_FACE, FURNITURE_EDGE = "#8b6f47", "#3b2f1e"
UNKNOWN_GREY = 0.72  # grey level of unknown cells in a belief map


def _finish_map(fig, ax, handles, extent, title, path) -> plt.Figure:
    """Legend outside on the right, metric axes on the map's extent, optional title/PNG."""
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_aspect("equal")
    legend = {"handles": handles, "loc": "upper left", "bbox_to_anchor": (1.01, 1.0),
              "fontsize": 7, "frameon": False}  # fmt: skip
    style_axes(ax, xlabel="x (m)", ylabel="y (m)", title=title, legend=legend)
    return finish(fig, path, layout=False)


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
        ax.add_patch(Rectangle((x - hx, y - hy), 2 * hx, 2 * hy, facecolor=FURNITURE_FACE,
                               edgecolor=FURNITURE_EDGE, linewidth=0.6, alpha=0.85))  # fmt: skip
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
    furniture = Patch(facecolor=FURNITURE_FACE, edgecolor=FURNITURE_EDGE, label="furniture")
    room_handles.append(furniture)
    return _finish_map(fig, ax, room_handles + target_handles, extent, title, path)


def belief_image(belief: np.ndarray, known: float) -> np.ndarray:
    """RGB image [H, W, 3] of a belief map [H, W]: unknown grey, known free white, known
    occupied black.

    ``belief`` is log-odds with ``known`` the preset's ``logodds_known``, or cell states
    (-1 free, 0 unknown, 1 occupied, as :func:`bfsop_jax.agents.record.belief_states`
    records them) with ``known`` 0.
    """
    belief = np.asarray(belief)
    img = np.full(belief.shape + (3,), UNKNOWN_GREY)
    img[belief < -known] = 1.0
    img[belief > known] = 0.0
    return img


def draw_belief(
    ax: plt.Axes, belief: np.ndarray, cell_size: float, known: float
) -> matplotlib.image.AxesImage:
    """Draw a belief map [H, W] (:func:`belief_image`) on ``ax`` with its cells of
    ``cell_size`` metres, origin at the lower left; returns the image (an animation
    updates it with ``set_data(belief_image(...))``)."""
    h, w = np.shape(belief)
    extent = (0.0, w * cell_size, 0.0, h * cell_size)
    return ax.imshow(belief_image(belief, known), origin="lower", extent=extent,
                     interpolation="nearest")  # fmt: skip


def plot_belief(
    belief: ArrayLike,
    preset: Preset,
    path: str | Path | None = None,
    ax: plt.Axes | None = None,
    frontiers: Frontiers | ArrayLike | None = None,
    landmarks: tuple[np.ndarray, np.ndarray] | None = None,
    pose: ArrayLike | None = None,
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
    draw_belief(ax, belief, cs, preset.logodds_known)
    handles = []
    if frontiers is not None:
        if hasattr(frontiers, "xy"):
            valid = np.asarray(frontiers.valid)
            fxy, size = np.asarray(frontiers.xy)[valid], np.asarray(frontiers.size)[valid]
            ax.scatter(fxy[:, 0], fxy[:, 1], s=8 + 2 * size, c=FRONTIER_COLOUR, edgecolors="black",
                       linewidths=0.4, zorder=4)  # fmt: skip
        else:
            mask = np.asarray(frontiers)
            pc = preset.plan_cell_size
            ii, jj = np.nonzero(mask)
            ax.scatter((jj + 0.5) * pc, (ii + 0.5) * pc, s=3, c=FRONTIER_COLOUR, marker="s",
                       zorder=4)  # fmt: skip
        handles.append(Line2D([], [], linestyle="", marker="o", markerfacecolor=FRONTIER_COLOUR,
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
        arrow = {"arrowstyle": "->", "color": AGENT_COLOUR, "lw": 1.5}
        tip = (x + 0.8 * np.cos(th), y + 0.8 * np.sin(th))
        ax.annotate("", xy=tip, xytext=(x, y), arrowprops=arrow, zorder=7)
        ax.plot([x], [y], "o", color=AGENT_COLOUR, ms=5, zorder=7)
        handles.append(Line2D([], [], linestyle="", marker="o", color=AGENT_COLOUR, label="agent"))
    handles += [
        Patch(facecolor="white", edgecolor="grey", label="known free"),
        Patch(facecolor="black", label="known occupied"),
        Patch(facecolor=(UNKNOWN_GREY,) * 3, label="unknown"),
    ]
    return _finish_map(fig, ax, handles, extent, title, path)
