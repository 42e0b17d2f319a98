"""How good the dataset's teacher labels are: the labelling VNS against the reference one.

Usage::

    python -m benchmarks.bench_labels --preset paper --houses 2 --tasks 20

Virtual tasks are posed in held-out houses exactly as the distillation evaluation poses
them (``experiments.distill``'s eval stage), then each instance is solved twice, one at a
time on the host, with the same seed: by the VNS at the labelling configuration a dataset
uses (``--vns-iters`` / ``--vns-no-improve``, the reference options otherwise) and by the
reference configuration (2,000 iterations, 1,000 without improvement). Printed: the mean
reward of both, their ratio, the share of instances where the labels reach the reference
reward, the mean time per solve of each and ``labelling/reference time: X`` last. Record
results with the machine and the date in ``docs/benchmarks.md``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import time

import jax
import numpy as np

from benchmarks.cli import positive_int, run_main
from bfsop_jax.config import EVAL_SEED_START, PRESET_NAMES
from bfsop_jax.data.generate import DataConfig, pose_tasks
from bfsop_jax.eval.solvers import take
from bfsop_jax.sop import solve_vns
from bfsop_jax.sop.vns.config import VNSConfig


def _solve_all(instances, n: int, config: VNSConfig) -> tuple[np.ndarray, float]:
    rewards, t0 = [], time.perf_counter()
    for i in range(n):
        rewards.append(float(solve_vns(take(instances, i), seed=0, config=config).reward))
    return np.asarray(rewards), (time.perf_counter() - t0) / max(n, 1)


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m benchmarks.bench_labels`` (options: docs/cli.md)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="paper", choices=PRESET_NAMES)
    ap.add_argument("--houses", type=positive_int, default=2, help="held-out houses")
    ap.add_argument("--tasks", type=positive_int, default=20, help="virtual tasks per house")
    ap.add_argument("--vns-iters", type=positive_int, default=500)
    ap.add_argument("--vns-no-improve", type=positive_int, default=250)
    return ap


def main() -> None:
    args = build_parser().parse_args()
    cfg = DataConfig(preset=args.preset, houses=1, tasks_per_house=args.tasks)
    seeds = np.arange(EVAL_SEED_START, EVAL_SEED_START + args.houses)
    instances, _ = pose_tasks(seeds, cfg, progress=False)
    n = int(np.asarray(instances.set_id).shape[0])
    print(f"{dt.date.today()} {platform.machine()} {os.cpu_count()} CPU(s), jax "
          f"{jax.__version__}; preset {args.preset}, {n} instances of houses "
          f"{seeds[0]}..{seeds[-1]}")  # fmt: skip
    solve_vns(take(instances, 0), seed=0)  # warm-up
    label_cfg = VNSConfig.labelling(args.vns_iters, args.vns_no_improve)
    labels, t_label = _solve_all(instances, n, label_cfg)
    reference, t_ref = _solve_all(instances, n, VNSConfig())
    equal = float(np.mean(labels >= reference - 1e-6))
    print(f"labelling VNS {args.vns_iters}/{args.vns_no_improve}: mean reward "
          f"{labels.mean():.4f}, {1e3 * t_label:.0f} ms per solve")  # fmt: skip
    print(f"reference VNS 2000/1000: mean reward {reference.mean():.4f}, "
          f"{1e3 * t_ref:.0f} ms per solve")  # fmt: skip
    print(f"labels / reference reward: {labels.mean() / max(reference.mean(), 1e-12):.4f}; "
          f"labels reach the reference reward on {equal:.0%} of instances")  # fmt: skip
    print(f"labelling/reference time: {t_label / max(t_ref, 1e-12):.2f}")


if __name__ == "__main__":
    run_main(main)
