"""The training curve: imitation loss and teacher agreement per epoch and replica."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

import matplotlib.pyplot as plt

from bfsop_jax.viz.style import finish, style_axes

__all__ = ["plot_dagger", "plot_training_curve"]


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


def plot_dagger(history: Sequence[Mapping[str, Any]], path: str | os.PathLike) -> None:
    """DAgger rounds: reward ratio to the VNS per planner (left) and PPL (right, with its
    95 % interval) against the round (0 = the behaviour-cloning model).

    Args: history: one row per round (``round``, ``reward_ratio[<planner>]`` entries and
    optional ``ppl``, ``ppl_ci95``), as :func:`bfsop_jax.training.dagger.run_dagger`
    returns them.
    """
    if not history:
        return
    rounds = [r["round"] for r in history]
    has_ppl = all("ppl" in r for r in history)
    fig, axes = plt.subplots(1, 2 if has_ppl else 1, figsize=(10 if has_ppl else 5.5, 4), dpi=100)
    ax_r = axes[0] if has_ppl else axes
    for key in [k for k in history[0] if k.startswith("reward_ratio[")]:
        ax_r.plot(rounds, [r[key] for r in history], "o-", label=key[13:-1])
    style_axes(ax_r, xlabel="DAgger round", ylabel="reward / VNS", title="held-out instances",
               grid="both", legend={"fontsize": 7})  # fmt: skip
    ax_r.set_xticks(rounds)
    if has_ppl:
        ax_p = axes[1]
        ppl = [r["ppl"] for r in history]
        lo = [r["ppl"] - r["ppl_ci95"][0] for r in history]
        hi = [r["ppl_ci95"][1] - r["ppl"] for r in history]
        ax_p.errorbar(rounds, ppl, yerr=[lo, hi], fmt="o-", capsize=4)
        style_axes(ax_p, xlabel="DAgger round", ylabel="PPL", grid="both",
                   title="BF-SOP (Transformer), held-out episodes")  # fmt: skip
        ax_p.set_xticks(rounds)
    finish(fig, path, tight_bbox=False, close=True)


def plot_rl(rows: Sequence[Mapping[str, Any]], path: str | os.PathLike) -> None:
    """Reward fine-tuning: the validation greedy reward ratio and the training sampled one
    (reward / teacher reward) against the epoch (0 = the behaviour-cloned model); the
    selected epoch is circled.

    Args: rows: one row per epoch as :func:`bfsop_jax.training.rl.finetune_rl` returns them.
    """
    if not rows:
        return
    fig, ax = plt.subplots(figsize=(5.5, 4), dpi=100)
    epochs = [r["epoch"] for r in rows]
    ax.plot(epochs, [r["val_greedy_ratio"] for r in rows], "o-", label="validation, greedy")
    tuned = [r for r in rows if "train_sample_ratio" in r]
    if tuned:
        ax.plot([r["epoch"] for r in tuned], [r["train_sample_ratio"] for r in tuned], "s--",
                label="training, sampled")  # fmt: skip
    chosen = [r for r in rows if r.get("selected")]
    if chosen:
        ax.plot([chosen[0]["epoch"]], [chosen[0]["val_greedy_ratio"]], "o", ms=14, mfc="none",
                mec="k", label="selected")  # fmt: skip
    style_axes(
        ax, xlabel="fine-tuning epoch", ylabel="reward / teacher reward",
        title="reward fine-tuning (no 2-opt)", grid="both", legend={"fontsize": 8},
    )  # fmt: skip
    ax.set_xticks(epochs)
    finish(fig, path, tight_bbox=False, close=True)
