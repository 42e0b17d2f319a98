"""Where teacher-labelled data generation spends its time, and batched against per-house.

Usage::

    python -m benchmarks.bench_data --preset demo --houses 4 --tasks 48

One shard of ``--houses`` training houses is generated twice, side by side in one run:

* **batched** (what ``generate_dataset`` does): the shard's exploration runs in one
  vmapped program, the virtual tasks of all houses labelled by one VNS callback over all
  rows, and the houses' BF-SOP (VNS) episodes side by side (the teacher solves the rows
  that switch at a step together, on all cores);
* **per house** (the former loop): tasks labelled and the on-trajectory episode run one
  house at a time, so each planning decision is a one-row VNS call on one core.

Each stage is timed on its own (exploration, virtual tasks incl. labelling,
on-trajectory episodes) after a warm-up shard that compiles everything (houses from
another seed range). The teacher's host time is read from the callback's counters, so the
on-trajectory stage splits into rollout and VNS. Printed: seconds per stage, houses/s and
labelled instances/s of both schedules, and ``batched/per-house speedup: X`` last.
Record results with the machine and the date in ``docs/benchmarks.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.cli import positive_int, run_main
from bfsop_jax.config import PRESET_NAMES, get_preset
from bfsop_jax.data import generate as gen
from bfsop_jax.sop.callback import callback_stats, reset_callback_stats
from bfsop_jax.world.prior import default_prior


def _per_house(seeds, preset, config, prior, timings: dict[str, float]) -> int:
    """The former schedule: one house at a time after the batched exploration."""
    label = jax.jit(gen.label_virtual_tasks, static_argnums=(3, 4))
    decide = jax.jit(gen.on_trajectory_decisions, static_argnums=(4, 5))
    t0 = time.perf_counter()
    keys, houses, states = gen._explored(seeds, preset, config, prior, gen._generate_houses,
                                         gen._explore_jit)  # fmt: skip
    jax.block_until_ready(states)
    timings["explore"] = timings.get("explore", 0.0) + time.perf_counter() - t0
    rows = 0
    for j, seed in enumerate(seeds):
        state = jax.tree_util.tree_map(lambda a, j=j: a[j], states)
        t0 = time.perf_counter()
        vns_seeds = jnp.arange(config.tasks_per_house, dtype=jnp.int32) + int(seed) * 1000
        inst, _, labels = label(jax.random.fold_in(keys[j], 2), state, vns_seeds, preset, config)
        jax.block_until_ready(labels)
        rows += int((np.asarray(inst.set_reward) > 0).any(-1).sum())
        t1 = time.perf_counter()
        timings["virtual"] = timings.get("virtual", 0.0) + t1 - t0
        cat = gen._present_category(houses, j, jax.random.fold_in(keys[j], 3))
        _, _, switched = decide(keys[j], state.house, cat, prior, preset, config)
        jax.block_until_ready(switched)
        rows += int(np.asarray(switched).sum())
        timings["on_trajectory"] = timings.get("on_trajectory", 0.0) + time.perf_counter() - t1
    return rows


def _report(name: str, timings: dict[str, float], vns_s: float, houses: int, rows: int) -> float:
    total = sum(timings.values())
    parts = ", ".join(f"{k} {v:.1f} s" for k, v in timings.items())
    print(f"{name}: {total:.1f} s ({parts}); on-trajectory VNS host time {vns_s:.1f} s")
    print(f"  {houses / total:.3f} houses/s, {rows / total:.2f} labelled instances/s ({rows} rows)")
    return total


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m benchmarks.bench_data`` (options: docs/cli.md)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="demo", choices=PRESET_NAMES)
    ap.add_argument("--houses", type=positive_int, default=4)
    ap.add_argument("--tasks", type=positive_int, default=48)
    ap.add_argument("--vns-iters", type=positive_int, default=500)
    ap.add_argument("--vns-no-improve", type=positive_int, default=250)
    return ap


def main() -> None:
    args = build_parser().parse_args()
    preset = get_preset(args.preset)
    config = dataclasses.replace(
        gen.DataConfig(preset=args.preset), houses=100, houses_per_shard=args.houses,
        tasks_per_house=args.tasks, vns_iters=args.vns_iters,
        vns_no_improve=args.vns_no_improve,
    )  # fmt: skip
    prior = jnp.asarray(default_prior())
    print(f"{dt.date.today()} {platform.machine()} {os.cpu_count()} CPU(s), "
          f"jax {jax.__version__} on {jax.devices()[0].platform}; preset {args.preset}, "
          f"{args.houses} houses x {args.tasks} tasks, VNS {args.vns_iters}/"
          f"{args.vns_no_improve}")  # fmt: skip
    warm = np.arange(50, 50 + args.houses)
    gen.shard_records(warm, preset, config, prior)  # compile the batched programs
    _per_house(warm[:1], preset, config, prior, {})  # and the per-house ones
    seeds = np.arange(args.houses)

    timings: dict[str, float] = {}
    reset_callback_stats()
    rows = len(gen.shard_records(seeds, preset, config, prior, timings)["source"])
    batched = _report("batched", timings, callback_stats()["seconds"], args.houses, rows)

    timings = {}
    reset_callback_stats()
    rows = _per_house(seeds, preset, config, prior, timings)
    single = _report("per house", timings, callback_stats()["seconds"], args.houses, rows)
    print(f"batched/per-house speedup: {single / batched:.2f}")


if __name__ == "__main__":
    run_main(main)
