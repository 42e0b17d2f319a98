"""Vmapped against sequential training of same-shape sweep configurations.

Usage::

    python -m benchmarks.bench_sweep --preset demo --configs 8 --instances 512 --epochs 3

Eight (``--configs``) configurations that share every array shape (here: the learning
rates 1e-4 .. 3e-3 x two seeds, the kind of grid ``experiments.sweep`` runs) train

* **vmapped**: as the replicas of one jitted program (what ``experiments.sweep`` does), and
* **sequentially**: one after another, each as a one-replica program,

on the same data, side by side in one run. Compilation is excluded from both (each program
runs one warm-up epoch first); the timed part is ``--epochs`` epochs. The data are random
instances of the preset's SOP size (N nodes, K sets) labelled by greedy insertion: the
cost of a training step does not depend on the labels. The final losses of the two
schedules are printed too (they must agree: the same configurations train either way).

The last line is ``vmapped/sequential speedup: X``. Record results with the machine and
the date in ``docs/benchmarks.md``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.cli import positive_int, run_main
from bfsop_jax.config import get_preset
from bfsop_jax.sop.io import random_instance
from bfsop_jax.sop.vns import solve_greedy
from bfsop_jax.training import Replica, dataset_from_instances
from bfsop_jax.training.bc import _epoch_key, init_states, make_train_epoch
from bfsop_jax.training.config import RunConfig


def _data(preset_name: str, n: int) -> dict[str, np.ndarray]:
    preset = get_preset(preset_name)
    insts = [random_instance(s, num_sets=preset.n_loi, viewpoints=preset.n_viewpoints)
             for s in range(n)]  # fmt: skip
    return dataset_from_instances(insts, [solve_greedy(i) for i in insts])


def _configs(recipe, count: int) -> list[Replica]:
    lrs = np.geomspace(1e-4, 3e-3, max(1, count // 2))
    grid = [(seed, float(lr)) for lr in lrs for seed in (0, 1)][:count]
    return [Replica.of(recipe, seed, lr) for seed, lr in grid]


def _run(graphdef, config, members, data, epochs: int) -> tuple[float, np.ndarray]:
    """Seconds for ``epochs`` epochs of one program over ``members`` (after a warm-up)."""
    _, states = init_states(config.model, config.train, replicas=members)
    n = int(data["set_id"].shape[0])
    epoch = make_train_epoch(graphdef, config.train, n)

    def keys(e):
        return jnp.stack([_epoch_key(r.seed, e) for r in members])

    states, stats = epoch(states, data, keys(0))  # compile + warm-up epoch
    jax.block_until_ready(stats)
    t0 = time.perf_counter()
    for e in range(1, epochs + 1):
        states, stats = epoch(states, data, keys(e))
    jax.block_until_ready(stats)
    seconds = time.perf_counter() - t0
    stats = np.asarray(stats)
    return seconds, stats[:, 0] / np.maximum(stats[:, 2], 1)


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m benchmarks.bench_sweep`` (options: docs/cli.md)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="demo", choices=["demo", "paper"])
    ap.add_argument("--model", default=None, help="model preset (default: the preset's)")
    ap.add_argument("--configs", type=positive_int, default=8)
    ap.add_argument("--instances", type=positive_int, default=512)
    ap.add_argument("--epochs", type=positive_int, default=3)
    return ap


def main(argv: list[str] | None = None) -> dict:
    args = build_parser().parse_args(argv)
    if args.configs < 2 or args.instances < 1 or args.epochs < 1:
        raise SystemExit("error: need --configs >= 2, --instances >= 1, --epochs >= 1")
    config = RunConfig.named(args.model or args.preset, preset=args.preset)
    keep = ("coords", "cost", "set_id", "set_reward", "budget", "teacher_nodes")
    data = {k: jnp.asarray(v) for k, v in _data(args.preset, args.instances).items() if k in keep}
    members = _configs(config.train, args.configs)
    graphdef, _ = init_states(config.model, config.train, replicas=members[:1])

    vmapped_s, vmapped_loss = _run(graphdef, config, members, data, args.epochs)
    sequential_s, sequential_loss = 0.0, []
    for rep in members:
        seconds, loss = _run(graphdef, config, [rep], data, args.epochs)
        sequential_s += seconds
        sequential_loss.append(loss[0])
    steps = args.epochs * (args.instances // min(config.train.batch_size, args.instances))
    backend = f"{jax.default_backend()} ({jax.devices()[0].device_kind})"
    print(f"machine: {platform.machine()}, {os.cpu_count()} CPU cores, {backend}, "
          f"{dt.date.today()}")  # fmt: skip
    print(f"preset {args.preset}: model {config.model.d_model}x{config.model.n_layers} "
          f"(heads {config.model.n_heads}, ff {config.model.d_ff}), batch "
          f"{config.train.batch_size}, {args.instances} instances of N = "
          f"{data['set_id'].shape[1]}, {args.epochs} timed epochs ({steps} steps) "
          "per config")  # fmt: skip
    print(f"{args.configs} configurations vmapped:   {vmapped_s:8.2f} s "
          f"({args.configs * steps / vmapped_s:.1f} config-steps/s)")  # fmt: skip
    print(f"{args.configs} configurations in turn:   {sequential_s:8.2f} s "
          f"({args.configs * steps / sequential_s:.1f} config-steps/s)")  # fmt: skip
    diff = float(np.max(np.abs(np.asarray(sequential_loss) - vmapped_loss)))
    print(f"final epoch loss, max |vmapped - sequential| over configs: {diff:.2e}")
    speedup = sequential_s / vmapped_s
    print(f"vmapped/sequential speedup: {speedup:.2f}")
    return {"vmapped_s": vmapped_s, "sequential_s": sequential_s, "speedup": speedup,
            "loss_diff": diff}  # fmt: skip


if __name__ == "__main__":
    run_main(main)
