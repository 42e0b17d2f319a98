"""The one style of every figure: the headless backend, colours and markers, axes styling
and :func:`finish` (layout, atomic PNG write, optional close), which every figure ends with.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

# Figures are written to files, never shown: the Agg backend works without a display.
# An explicit choice (MPLBACKEND) is respected.
if "MPLBACKEND" not in os.environ:
    matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402

from bfsop_jax.files import atomic_write  # noqa: E402

__all__ = [
    "AGENT_COLOUR",
    "BLUE",
    "EXPLORATION_COLOUR",
    "FRONTIER_COLOUR",
    "METHOD_COLOURS",
    "RED",
    "ROOM_COLOURS",
    "TARGET_COLOURS",
    "TARGET_MARKERS",
    "TOURING_COLOUR",
    "finish",
    "method_colour",
    "save",
    "style_axes",
]

ROOM_COLOURS: tuple[str, ...] = ("#f6d8a8", "#cfe3c1", "#c9d8ef", "#d7ecef")  # by room type
TARGET_COLOURS: tuple[str, ...] = (
    "#d62728", "#b8860b", "#1f77b4", "#7f7f7f", "#9467bd",
    "#8c564b", "#17becf", "#ff7f0e", "#2ca02c",
)  # fmt: skip
TARGET_MARKERS: tuple[str, ...] = ("o", "s", "^", "D", "v", "P", "X", "*", "h")
METHOD_COLOURS: tuple[str, ...] = (
    "#7f7f7f", "#bcbd22", "#ff7f0e", "#2ca02c", "#1f77b4", "#9467bd", "#8c564b", "#e377c2",
)  # fmt: skip
BLUE, RED = "#1f77b4", "#d62728"  # Matplotlib's first and fourth default colours
EXPLORATION_COLOUR = RED  # trajectory segments while exploring
TOURING_COLOUR = BLUE  # trajectory segments while executing a tour; planned tours
FRONTIER_COLOUR = "#ff7f0e"
AGENT_COLOUR = "#2ca02c"


def method_colour(i: int) -> str:
    """Colour of the ``i``-th method in a comparison (cycles through :data:`METHOD_COLOURS`)."""
    return METHOD_COLOURS[i % len(METHOD_COLOURS)]


def style_axes(
    ax: plt.Axes,
    *,
    xlabel: str | None = None,
    ylabel: str | None = None,
    title: str | None = None,
    title_size: float | None = None,
    grid: str | None = None,
    grid_alpha: float = 0.3,
    legend: dict[str, Any] | None = None,
) -> plt.Axes:
    """Labels, title, a light grid (``grid``: ``"x"``, ``"y"`` or ``"both"``) and a legend
    (``legend``: keyword arguments of ``ax.legend``); what is ``None`` is left untouched."""
    if xlabel is not None:
        ax.set_xlabel(xlabel)
    if ylabel is not None:
        ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title, **({} if title_size is None else {"fontsize": title_size}))
    if grid is not None:
        ax.grid(axis=grid, alpha=grid_alpha)
    if legend is not None:
        ax.legend(**legend)
    return ax


def save(
    fig: plt.Figure, path: str | os.PathLike, tight_bbox: bool = True, dpi: float | None = None
) -> Path:
    """Write ``fig`` as a PNG at ``dpi`` (default: the figure's), atomically (a temporary
    file next to it, then a rename), creating the folder; ``tight_bbox`` crops to the drawn
    content."""
    path = Path(path)
    bbox = "tight" if tight_bbox else None
    kind = path.suffix.lstrip(".") or "png"
    dpi = fig.dpi if dpi is None else dpi
    atomic_write(
        path, lambda f: fig.savefig(f, format=kind, dpi=dpi, bbox_inches=bbox), mode="wb"
    )
    return path


def finish(
    fig: plt.Figure,
    path: str | os.PathLike | None,
    *,
    layout: bool | Sequence[float] = True,
    tight_bbox: bool = True,
    dpi: float | None = None,
    close: bool = False,
) -> plt.Figure:
    """End a figure: ``tight_layout`` (``layout``: True, False, or the rect to fit in), save
    it to ``path`` when given (:func:`save`, at ``dpi``), and close it when ``close`` (for figures
    drawn again and again, such as a training curve per epoch). Returns ``fig``."""
    if layout is True:
        fig.tight_layout()
    elif layout is not False:
        fig.tight_layout(rect=tuple(layout))
    if path is not None:
        save(fig, path, tight_bbox=tight_bbox, dpi=dpi)
    if close:
        plt.close(fig)
    return fig
