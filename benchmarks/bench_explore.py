"""Exploration benchmark: does frontier exploration use its budget, and how fast does it run?

Usage::

    python -m benchmarks.bench_explore --presets smoke,demo,paper --houses 32
    python -m benchmarks.bench_explore --presets demo --batch 1024   # on an accelerator

Per preset: ``--houses`` evaluation houses (seeds from 1,000,000, target HousePlant)
explored by a batch of ``--batch`` episodes (default: one per house; a larger batch
cycles over the houses, episode e starting from reset key ``house seed + 10**7 * r`` of
its r-th repeat, r = e // houses) with FBE until the budget gate closes or no reachable
frontier is left. Prints budget use (path length / budget: median, minimum),
the share of *stalled* episodes (budget use < 0.95 while a reachable frontier remains),
goals dropped per episode, batched motion steps per second (compilation timed apart),
and where a macro step's time goes (the strategy's decision vs the environment step,
each timed alone on the same batch). The header names the backend and the geodesic
solver (``BFSOP_GEODESICS=sweeps|relax`` forces one; ``JAX_PLATFORMS=cpu`` runs the CPU
on a GPU machine). Record results with the machine and date in ``docs/benchmarks.md``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import time

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.cli import positive_int, run_main
from benchmarks.timing import machine, time_calls
from bfsop_jax.agents import FBE, continue_rollout, max_macro_steps
from bfsop_jax.config import EVAL_SEED_START, get_preset
from bfsop_jax.env import observe, reset, step
from bfsop_jax.navigation.distance import distance_field
from bfsop_jax.navigation.frontiers import frontier_clusters, nearest_frontier
from bfsop_jax.navigation.grid import motion_blocked
from bfsop_jax.world import generate_house, target_id


def _frontier_left(state, preset):
    blocked = motion_blocked(state.belief, state.pose[:2], preset)
    field = distance_field(blocked, state.pose[:2], preset)
    return nearest_frontier(frontier_clusters(state.belief, preset), field, preset)[0] >= 0


REPEAT_KEY_STRIDE = 10**7  # reset keys of repeated houses: seed + stride * repeat


def run(preset_name: str, houses: int, batch_size: int | None = None) -> dict:
    preset = get_preset(preset_name)
    batch_size = houses if batch_size is None else batch_size
    if houses < 1 or batch_size < 1:
        raise ValueError(f"--houses and --batch must be positive, got {houses} and {batch_size}")
    seeds = jnp.arange(EVAL_SEED_START, EVAL_SEED_START + houses)
    house_keys = jax.vmap(jax.random.key)(seeds)
    generated = jax.jit(jax.vmap(generate_house, in_axes=(0, None)), static_argnums=1)(
        house_keys, preset
    )
    episode = np.arange(batch_size)
    which = jnp.asarray(episode % houses)
    batch = jax.tree_util.tree_map(lambda x: x[which], generated)
    keys = jax.vmap(jax.random.key)(seeds[which] + REPEAT_KEY_STRIDE * (episode // houses))
    reset_b = jax.jit(jax.vmap(reset, in_axes=(0, 0, None, None)), static_argnums=3)
    states = reset_b(keys, batch, target_id("HousePlant"), preset)
    fbe = FBE()
    n_steps = max_macro_steps(preset.budget_m, preset)
    roll = jax.jit(jax.vmap(lambda s, m: continue_rollout(s, m, fbe, preset, n_steps)))
    memory = jax.vmap(lambda s: fbe.init(observe(s), preset))(states)

    t = time.perf_counter()
    compiled = roll.lower(states, memory).compile()
    compile_s = time.perf_counter() - t
    t = time.perf_counter()
    final, final_memory, traj = jax.block_until_ready(compiled(states, memory))
    wall = time.perf_counter() - t

    use = np.asarray(final.path_length / final.budget)
    left = np.asarray(jax.jit(jax.vmap(lambda s: _frontier_left(s, preset)))(final))
    stalled = (use < 0.95) & left
    moves = int(np.asarray(traj.moved).sum())

    # Where a macro step's time goes: the decision and the environment step, alone.
    act = jax.jit(jax.vmap(lambda m, s: fbe.act(m, observe(s), preset)))
    env_step = jax.jit(jax.vmap(lambda s, a: step(s, a, preset)))
    action, _, _ = act(memory, states)
    act_s = time_calls(act, memory, states, repeats=3).best
    step_s = time_calls(env_step, states, action, repeats=3).best
    return {
        "preset": preset_name,
        "houses": houses,
        "batch": batch_size,
        "budget_m": preset.budget_m,
        "budget_use_median": float(np.median(use)),
        "budget_use_min": float(use.min()),
        "stalled": int(stalled.sum()),
        "stalled_share": float(stalled.mean()),
        "ended_without_frontier": int((use < 0.95).sum() - stalled.sum()),
        "dropped_goals_per_episode": float(np.asarray(final_memory.n_dropped).mean()),
        "macro_steps": n_steps,
        "motion_steps": moves,
        "rollout_s": wall,
        "compile_s": compile_s,
        "motion_steps_per_s": moves / wall,
        "decision_ms_per_batch": 1e3 * act_s,
        "env_step_ms_per_batch": 1e3 * step_s,
    }


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m benchmarks.bench_explore`` (options: docs/cli.md)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", default="smoke,demo,paper")
    ap.add_argument("--houses", type=positive_int, default=32, help="distinct houses")
    ap.add_argument(
        "--batch", type=positive_int, default=None, help="episodes run together (default: --houses)"
    )
    ap.add_argument("--json", help="also write the figures to this JSON file")
    return ap


def main() -> None:
    args = build_parser().parse_args()
    where = machine()
    batch = args.houses if args.batch is None else args.batch
    print(f"# bench_explore  houses={args.houses}  batch={batch}  {where}  {dt.date.today()}")
    cols = (
        "preset",
        "batch",
        "budget_use_median",
        "budget_use_min",
        "stalled",
        "ended_without_frontier",
        "dropped_goals_per_episode",
        "motion_steps_per_s",
        "decision_ms_per_batch",
        "env_step_ms_per_batch",
        "compile_s",
    )
    print(" | ".join(cols))
    results = []
    for name in args.presets.split(","):
        res = run(name.strip(), args.houses, batch)
        results.append(res)
        cells = [f"{res[c]:.3f}" if isinstance(res[c], float) else str(res[c]) for c in cols]
        print(" | ".join(cells), flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"machine": where, "results": results}, f, indent=1)


if __name__ == "__main__":
    run_main(main)
