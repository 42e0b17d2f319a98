"""Imitation metrics (JAX) and the per-epoch training log (JSONL, CSV, a PNG curve).

``metrics.jsonl`` and ``metrics.csv`` hold one row per (epoch, replica) with the columns
:data:`COLUMNS`; ``training_curve.png`` plots train / validation loss and accuracy of
every replica. A resumed run first drops rows of epochs after its checkpoint, so the log
always matches the parameters on disk.
"""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

from bfsop_jax import files
from bfsop_jax.model.decode import TeacherForcing
from bfsop_jax.parallel import is_primary
from bfsop_jax.viz import plot_training_curve  # re-exported: drawn in viz

__all__ = ["COLUMNS", "MetricsLog", "imitation_stats", "plot_training_curve"]

COLUMNS = (
    "epoch",
    "replica",
    "seed",
    "base_lr",
    "lr",
    "train_loss",
    "train_acc",
    "val_loss",
    "val_acc",
    "seconds",
)


def imitation_stats(tf: TeacherForcing, weight: jax.Array | None = None) -> jax.Array:
    """[3] float32 sums over valid steps: negative log-likelihood, correct arg-max, steps.

    With ``tf.targets`` (several right entries per step) the likelihood is that of any
    right entry, and an arg-max is correct when it is one of them.

    ``weight``: optional [B] per-instance weight (0 drops a padded instance).
    """
    valid = tf.valid.astype(jnp.float32)
    if weight is not None:
        valid = valid * weight[:, None]
    if tf.targets is None:
        log_p = jnp.take_along_axis(tf.log_probs, tf.target[..., None], axis=-1)[..., 0]
        correct = jnp.argmax(tf.log_probs, axis=-1) == tf.target
    else:  # several right answers (insertion decoder): the probability of any of them
        hit = tf.targets & valid[..., None].astype(bool)
        log_p = jax.nn.logsumexp(jnp.where(hit, tf.log_probs, -jnp.inf), axis=-1)
        log_p = jnp.where(jnp.any(hit, axis=-1), log_p, 0.0)
        pick = jnp.argmax(tf.log_probs, axis=-1)
        correct = jnp.take_along_axis(tf.targets, pick[..., None], axis=-1)[..., 0]
    return jnp.stack(
        [
            -jnp.sum(jnp.where(valid > 0, log_p, 0.0) * valid),
            jnp.sum(correct * valid),
            jnp.sum(valid),
        ]
    )


class MetricsLog:
    """Append-only epoch log of a run directory."""

    def __init__(self, run_dir: str | os.PathLike, keep_until_epoch: int = 0):
        self.run_dir = Path(run_dir)
        self.jsonl = self.run_dir / "metrics.jsonl"
        self.csv = self.run_dir / "metrics.csv"
        self.png = self.run_dir / "training_curve.png"
        self.rows: list[dict[str, Any]] = []
        if self.jsonl.exists():
            for line in self.jsonl.read_text().splitlines():
                try:
                    row = json.loads(line)
                except json.JSONDecodeError:
                    continue  # a line cut by an interruption
                if row.get("epoch", 0) <= keep_until_epoch:
                    self.rows.append(row)
        self._rewrite()

    def append(self, rows: list[dict[str, Any]]) -> None:
        """Add the rows of one epoch and refresh the CSV and the curve."""
        self.rows.extend(rows)
        if not is_primary():
            return
        with self.jsonl.open("a") as f:
            for row in rows:
                f.write(json.dumps(row) + "\n")
        self._write_csv()
        plot_training_curve(self.rows, self.png)

    def _rewrite(self) -> None:
        if not is_primary():  # one writer in a multi-host run
            return
        files.write_text(self.jsonl, "".join(json.dumps(r) + "\n" for r in self.rows))
        self._write_csv()

    def _write_csv(self) -> None:
        def write(f):
            writer = csv.DictWriter(f, fieldnames=COLUMNS, extrasaction="ignore")
            writer.writeheader()
            writer.writerows(self.rows)

        files.atomic_write(self.csv, write)
