"""Episode animations: a GIF of the agent's belief map filling in as it explores and tours.

:func:`animate_episode` draws the frames that :class:`bfsop_jax.agents.record.EpisodeRecorder`
records (plain NumPy arrays; this module imports no agent code) with Matplotlib's
``PillowWriter``. Each frame shows

* the belief map as :func:`~bfsop_jax.viz.plot_belief` draws it (unknown grey, free
  white, occupied black);
* the path so far, exploration red and touring blue (as in
  :func:`~bfsop_jax.viz.plot_trajectory`), the start a circle, the agent a green dot
  with its heading;
* the viewpoints of the tour being executed that are still ahead, a dashed blue polyline
  from the agent with hollow markers (strategies that tour);
* the verified targets, gold stars;
* a budget bar (metres used of the budget), the found counter ("found 3 / 7"), the
  macro step and the mode, and a title.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.animation import PillowWriter
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Rectangle

from bfsop_jax.files import atomic_write
from bfsop_jax.viz.style import AGENT_COLOUR, EXPLORATION_COLOUR, TOURING_COLOUR
from bfsop_jax.viz.world import UNKNOWN_GREY, belief_image, draw_belief

if TYPE_CHECKING:  # annotations only: the viz package imports no agent code
    from bfsop_jax.agents.record import EpisodeFrames

__all__ = ["MAX_FRAMES", "animate_episode", "frame_indices"]

MAX_FRAMES = 120  # frames of a GIF at most: a 150 m demo episode stays around 1 MB
STAR_COLOUR = "gold"
BAR_COLOUR = "#606060"  # budget used
# the tour ahead: a dashed line through hollow viewpoint markers
TOUR_STYLE = {"ls": "--", "lw": 1.3, "color": TOURING_COLOUR, "marker": "o", "ms": 6,
              "mfc": "white", "mec": TOURING_COLOUR, "mew": 1.3}  # fmt: skip
STAR_STYLE = {"ls": "", "marker": "*", "ms": 11, "mfc": STAR_COLOUR, "mec": "black"}


def frame_indices(n_frames: int, max_frames: int) -> np.ndarray:
    """int [min(n_frames, max_frames)]: the recorded frames a GIF shows, evenly spread,
    the first and the last always among them."""
    if n_frames < 1 or max_frames < 2:
        raise ValueError(f"need at least one frame and max_frames >= 2, got {n_frames}, "
                         f"{max_frames}")  # fmt: skip
    if n_frames <= max_frames:
        return np.arange(n_frames)
    # consecutive picks are more than one frame apart, so rounding keeps them distinct
    return np.round(np.linspace(0, n_frames - 1, max_frames)).astype(np.int64)


class _GifWriter(PillowWriter):
    """``PillowWriter`` that writes atomically (a temporary file, then a rename) and holds
    the last frame for ``hold_ms`` milliseconds."""

    def __init__(self, fps: float, hold_ms: int):
        super().__init__(fps=fps)
        self.hold_ms = int(hold_ms)

    def finish(self) -> None:
        frames = self._frames
        step = int(round(1000 / self.fps))
        durations = [step] * len(frames)
        durations[-1] = max(step, self.hold_ms)

        def write(f):
            frames[0].save(f, format="GIF", save_all=True, append_images=frames[1:],
                           duration=durations, loop=0)  # fmt: skip

        atomic_write(self.outfile, write, mode="wb")


def _mode_polyline(
    xy: np.ndarray, touring: np.ndarray, mode: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The moves made in ``mode`` as one NaN-broken polyline: x, y [E] and, per entry, the
    index of its path point (NaN breaks: the run's last), nondecreasing, so the entries
    with index < n draw the path's first n points. Move i goes from point i to i + 1 in
    the mode of point i + 1; each run of moves in ``mode`` is one unbroken line."""
    moves = np.flatnonzero(touring[1:] == mode)
    if not len(moves):
        return np.zeros(0), np.zeros(0), np.zeros(0, np.int64)
    starts = moves[np.r_[True, np.diff(moves) > 1]]
    ends = moves[np.r_[np.diff(moves) > 1, True]]
    index, gap = [], []
    for a, b in zip(starts, ends, strict=True):  # moves a..b: points a..b + 1, then a break
        index.append(np.r_[np.arange(a, b + 2), b + 1])
        gap.append(np.r_[np.zeros(b + 2 - a, bool), True])
    index, gap = np.concatenate(index), np.concatenate(gap)
    x = np.where(gap, np.nan, xy[index, 0])
    y = np.where(gap, np.nan, xy[index, 1])
    return x, y, index


def animate_episode(
    frames: EpisodeFrames,
    path: str | os.PathLike,
    title: str | None = None,
    *,
    max_frames: int = MAX_FRAMES,
    fps: float = 8.0,
    dpi: float = 75.0,
    map_width_in: float = 6.0,
    hold_s: float = 2.0,
) -> Path:
    """Write the episode ``frames`` as a GIF at ``path`` (atomically); returns the path.

    Args:
        frames: the recorded episode (:class:`bfsop_jax.agents.record.EpisodeFrames`:
            F frames of NumPy arrays, positions in metres).
        title: e.g. method, house and category.
        max_frames: at most this many frames (evenly spread over the episode,
            :func:`frame_indices`; the path between two shown frames is drawn whole).
        fps: frames per second; the last frame is held ``hold_s`` seconds.
        dpi, map_width_in: pixels per inch, and the map's width in inches (its height
            follows the house's aspect): a demo episode at the defaults is 622 x 435
            pixels, 0.4-0.6 MB for 90-120 frames.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    show = frame_indices(frames.n_frames, max_frames)
    belief = np.asarray(frames.belief)
    cs = float(frames.belief_cell_m)
    h, w = belief.shape[1:]
    width_m, height_m = w * cs, h * cs
    map_h = map_width_in * height_m / width_m
    left, right, top, bottom = 0.55, 1.75, 0.45, 0.85  # inches around the map
    fig_w, fig_h = left + map_width_in + right, top + map_h + bottom
    fig = plt.figure(figsize=(fig_w, fig_h), dpi=dpi)
    ax = fig.add_axes((left / fig_w, bottom / fig_h, map_width_in / fig_w, map_h / fig_h))
    bar = fig.add_axes((left / fig_w, 0.22 / fig_h, map_width_in / fig_w, 0.16 / fig_h))
    try:
        image = draw_belief(ax, belief[show[0]], cs, 0.0)
        ax.set_xlim(0.0, width_m)
        ax.set_ylim(0.0, height_m)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7, length=2, pad=1)
        if title:
            fig.suptitle(title, fontsize=10, y=1 - 0.08 / fig_h, va="top")

        xy = np.asarray(frames.path_xy, np.float32)
        touring = np.asarray(frames.path_touring, bool)
        reached = np.searchsorted(np.asarray(frames.path_frame), show, side="right")  # points
        lines = []
        for mode, colour in ((False, EXPLORATION_COLOUR), (True, TOURING_COLOUR)):
            (line,) = ax.plot([], [], color=colour, lw=1.6, zorder=8)
            lines.append((line, *_mode_polyline(xy, touring, mode)))
        ax.plot(*xy[0], "o", ms=7, mfc="none", mec="black", mew=1.5, zorder=9)
        (tour_line,) = ax.plot([], [], zorder=9, **TOUR_STYLE)
        (heading,) = ax.plot([], [], color=AGENT_COLOUR, lw=2.0, zorder=10)
        (agent,) = ax.plot([], [], "o", ms=7, color=AGENT_COLOUR, mec="black", mew=0.8,
                           zorder=11)  # fmt: skip
        stars = ax.scatter(np.zeros(0), np.zeros(0), s=150, marker="*", c=STAR_COLOUR,
                           edgecolors="black", linewidths=0.7, zorder=12)  # fmt: skip
        handles = [Line2D([], [], color=EXPLORATION_COLOUR, lw=1.6, label="exploration")]
        if touring.any() or np.asarray(frames.tour_valid).any():  # a strategy that tours
            handles += [
                Line2D([], [], color=TOURING_COLOUR, lw=1.6, label="touring"),
                Line2D([], [], label="tour ahead", **TOUR_STYLE),
            ]
        handles += [
            Line2D([], [], label="verified target", **STAR_STYLE),
            Line2D([], [], ls="", marker="o", color=AGENT_COLOUR, mec="black", label="agent"),
            Line2D([], [], ls="", marker="o", mfc="none", mec="black", label="start"),
            Patch(facecolor="white", edgecolor="grey", label="known free"),
            Patch(facecolor="black", label="known occupied"),
            Patch(facecolor=(UNKNOWN_GREY,) * 3, edgecolor="grey", label="unknown"),
        ]
        ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8,
                  frameon=False, borderaxespad=0.0)  # fmt: skip
        found_text = ax.text(1.03, 0.18, "", transform=ax.transAxes, fontsize=11,
                             fontweight="bold", va="bottom")  # fmt: skip
        status = ax.text(1.03, 0.02, "", transform=ax.transAxes, fontsize=8, va="bottom",
                         linespacing=1.3)  # fmt: skip

        budget = max(float(frames.budget), 1e-9)
        bar.set_xlim(0.0, 1.0)
        bar.set_ylim(0.0, 1.0)
        bar.set_xticks([])
        bar.set_yticks([])
        bar.add_patch(Rectangle((0, 0), 1, 1, facecolor="#e8e8e8", edgecolor="none"))
        fill = bar.add_patch(Rectangle((0, 0), 0, 1, facecolor=BAR_COLOUR, edgecolor="none"))
        bar_text = bar.text(0.0, 1.35, "", transform=bar.transAxes, fontsize=9, va="bottom")

        tour_xy = np.asarray(frames.tour_xy, np.float32)
        tour_valid = np.asarray(frames.tour_valid, bool)
        found_xy = np.asarray(frames.found_xy, np.float32).reshape(-1, 2)
        found_frame = np.asarray(frames.found_frame)
        pose = np.asarray(frames.pose, np.float32)
        length = np.asarray(frames.path_length, np.float32)
        found = np.asarray(frames.found_count)
        mode = np.asarray(frames.touring, bool)
        steps = np.asarray(frames.macro_steps)
        arrow = 0.045 * max(width_m, height_m)  # heading tick length (m)

        writer = _GifWriter(fps=fps, hold_ms=int(1000 * hold_s))
        writer.setup(fig, path, dpi=dpi)
        for i, f in enumerate(show):
            image.set_data(belief_image(belief[f], 0.0))
            for line, xs, ys, index in lines:
                upto = np.searchsorted(index, reached[i], side="left")
                line.set_data(xs[:upto], ys[:upto])
            x, y, th = (float(v) for v in pose[f])
            agent.set_data([x], [y])
            heading.set_data([x, x + arrow * math.cos(th)], [y, y + arrow * math.sin(th)])
            ahead = tour_xy[f][tour_valid[f]]
            if len(ahead):
                route = np.concatenate([[[x, y]], ahead])
                tour_line.set_data(route[:, 0], route[:, 1])
                tour_line.set_markevery(range(1, len(route)))
            else:
                tour_line.set_data([], [])
            stars.set_offsets(found_xy[found_frame <= f])
            fill.set_width(min(float(length[f]) / budget, 1.0))
            bar_text.set_text(f"budget: {length[f]:.1f} / {budget:g} m used")
            found_text.set_text(f"found {int(found[f])} / {int(frames.total)}")
            status.set_text(f"macro step {int(steps[f])}\n"
                            f"{'touring' if mode[f] else 'exploring'}")  # fmt: skip
            writer.grab_frame()
        writer.finish()
    finally:
        plt.close(fig)
    return path
