"""The training curve: imitation loss and teacher agreement per epoch and replica."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

import matplotlib.pyplot as plt

from bfsop_jax.viz.style import finish, style_axes

__all__ = ["plot_training_curve"]


def plot_training_curve(rows: Sequence[Mapping[str, Any]], path: str | os.PathLike) -> None:
    """Two panels, loss (cross-entropy per step) and next-node accuracy per epoch: one colour
    per replica, train solid, validation dashed (drawn when every epoch has it); replicas are
    labelled by replica index (replicas may differ in more than seed and learning rate, see
    the run's config.json), seed and learning rate when there are several. Nothing is
    written for no rows.

    Args: rows: the log rows (``epoch``, ``replica``, ``seed``, ``base_lr``, ``train_loss``,
    ``train_acc`` and optional ``val_loss``, ``val_acc``), in any order.
    """
    if not rows:
        return
    fig, (ax_loss, ax_acc) = plt.subplots(1, 2, figsize=(10, 4), dpi=100)
    replicas = sorted({r["replica"] for r in rows})
    for rep in replicas:
        mine = sorted((r for r in rows if r["replica"] == rep), key=lambda r: r["epoch"])
        epochs = [r["epoch"] for r in mine]
        label = (
            f"#{rep}: seed {mine[0]['seed']}, lr {mine[0]['base_lr']:.0e}"
            if len(replicas) > 1
            else ""
        )
        for ax, key in ((ax_loss, "loss"), (ax_acc, "acc")):
            (line,) = ax.plot(epochs, [r[f"train_{key}"] for r in mine], label=f"train {label}")
            val = [r.get(f"val_{key}") for r in mine]
            if all(v is not None for v in val):
                ax.plot(epochs, val, "--", color=line.get_color(), label=f"val {label}")
    style_axes(ax_loss, xlabel="epoch", ylabel="cross-entropy per step", title="imitation loss")
    style_axes(ax_acc, xlabel="epoch", ylabel="next-node accuracy", title="teacher agreement")
    for ax in (ax_loss, ax_acc):
        style_axes(ax, grid="both", legend={"fontsize": 7})
    finish(fig, path, tight_bbox=False, close=True)
