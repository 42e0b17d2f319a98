"""World benchmark: houses/s, ray-cast map updates/s, env steps/s, distance-matrix latency.

Usage::

    python -m benchmarks.bench_world --preset demo --batch 64
    python -m benchmarks.bench_world --preset smoke --batch 16 --json out.json

Every figure is measured after compilation (compile time printed apart), with
``block_until_ready`` and the best of ``--repeats`` timed calls. Record results with the
machine and date in ``docs/benchmarks.md``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks import bench_distance, bench_mapping
from benchmarks.cli import positive_int, run_main
from bfsop_jax.config import PRESET_NAMES, get_preset
from bfsop_jax.env import make_action, reset, step
from bfsop_jax.world.constants import N_CATEGORIES, N_TARGETS
from bfsop_jax.world.generator import generate_house


def _timed(fn, *args, repeats: int) -> tuple[float, float]:
    """(first call seconds incl. compile, best of ``repeats`` seconds)."""
    t = time.perf_counter()
    jax.block_until_ready(fn(*args))
    first = time.perf_counter() - t
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t)
    return first, best


def bench_houses(preset_name: str, batch: int, repeats: int) -> dict:
    preset = get_preset(preset_name)
    gen = jax.jit(jax.vmap(generate_house, in_axes=(0, None)), static_argnums=1)
    keys = jax.vmap(jax.random.key)(jnp.arange(batch))
    first, best = _timed(gen, keys, preset, repeats=repeats)
    return {"houses_per_s": batch / best, "house_compile_s": first - best}


def bench_env(preset_name: str, batch: int, repeats: int) -> dict:
    """Batched ``env.step`` (one macro action = ``micro_steps`` sense-and-move steps)."""
    preset = get_preset(preset_name)
    keys = jax.vmap(jax.random.key)(jnp.arange(batch))
    houses = jax.jit(jax.vmap(generate_house, in_axes=(0, None)), static_argnums=1)(keys, preset)
    prior = jnp.ones((N_CATEGORIES, N_TARGETS), jnp.float32)
    states = jax.jit(jax.vmap(reset, in_axes=(0, 0, None, None, None)), static_argnums=3)(
        keys, houses, 0, preset, prior
    )
    # Far goals keep every motion step of the macro action busy.
    goals = jnp.asarray([preset.width_m, preset.height_m]) - states.pose[:, :2]
    batched = jax.jit(jax.vmap(step, in_axes=(0, 0, None)), static_argnums=2)
    first, best = _timed(batched, states, make_action(goals), preset, repeats=repeats)
    single = jax.jit(step, static_argnums=2)
    s0 = jax.tree_util.tree_map(lambda a: a[0], states)
    _, best1 = _timed(single, s0, make_action(goals[0]), preset, repeats=repeats)
    return {
        "env_steps_per_s": batch / best,
        "env_motion_steps_per_s": batch * preset.micro_steps / best,
        "env_step_ms_single": 1e3 * best1,
        "env_compile_s": first - best,
    }


def run(preset_name: str = "demo", batch: int = 64, repeats: int = 5) -> dict:
    out = {
        "preset": preset_name,
        "batch": batch,
        "date": dt.date.today().isoformat(),
        "machine": f"{platform.machine()} {os.cpu_count()} cores, {jax.default_backend()}",
        "device": str(jax.devices()[0]),
    }
    out |= bench_houses(preset_name, batch, repeats)
    mapping = bench_mapping.run(preset_name, batch, repeats)
    out["map_updates_per_s"] = mapping.get("updates_per_s")
    out["map_updates_per_s_in_scan"] = mapping.get("updates_per_s_in_scan")
    out["map_updates_per_s_donated"] = mapping.get("updates_per_s_donated")
    out["map_stage_ms"] = mapping.get("stage_ms")
    out |= bench_env(preset_name, batch, repeats)
    dist = bench_distance.run(preset_name, 76, repeats)
    out["distance_matrix_76_ms"] = dist.get("matrix_ms_median", dist.get("matrix_ms"))
    out["distance"] = dist
    return out


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m benchmarks.bench_world`` (options: docs/cli.md)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="demo", choices=PRESET_NAMES)
    ap.add_argument("--batch", type=positive_int, default=64)
    ap.add_argument("--repeats", type=positive_int, default=5)
    ap.add_argument("--json", help="also write the figures to this JSON file")
    return ap


def main() -> None:
    args = build_parser().parse_args()
    res = run(args.preset, args.batch, args.repeats)
    print(f"# bench_world  preset={res['preset']} batch={res['batch']}  {res['machine']}")
    for key in (
        "houses_per_s",
        "house_compile_s",
        "map_updates_per_s",
        "map_updates_per_s_donated",
        "map_updates_per_s_in_scan",
        "env_steps_per_s",
        "env_motion_steps_per_s",
        "env_step_ms_single",
        "env_compile_s",
        "distance_matrix_76_ms",
    ):
        val = res.get(key)
        print(f"{key:28s} {val:12.2f}" if isinstance(val, (int, float)) else f"{key:28s} {val}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(res, f, indent=1, default=str)


if __name__ == "__main__":
    run_main(main)
