"""Batched rollout throughput of every navigation strategy on the evaluation protocol.

Usage::

    python -m benchmarks.bench_rollout --preset demo --batch 90 \\
        --methods fbe,bfs_global,tfl_reactive,bfsop_vns,bfsop_st

The batch is the first ``--batch`` episodes of the Table I protocol (9 categories over
held-out houses from seed 1,000,000); ``--houses H`` caps the distinct houses (the
protocol's episodes of H houses, repeated to fill the batch, e.g. ``--batch 4096
--houses 64`` on an accelerator). Per method, all episodes run together (one
``jax.vmap``) until every one has stopped. Prints episodes/s and motion steps/s
(compilation timed apart), macro steps, planner calls, and where the time goes:

* ``decide_ms`` and ``env_ms``: one macro step's strategy decision and environment step,
  timed alone on the whole batch (median of repeats) at the episodes' start states;
* ``vns_s``: host seconds the VNS teacher spent solving (masked callback, both cores);
* ``plan_ms``: one planner call at batch 1 (median), on instances posed from the final maps.

FBE's rollout is the floor every strategy pays (sensing, motion, frontier search); the
ratio ``vs_fbe`` is each method's rollout time over FBE's, measured side by side in one
run. Record results with the machine and date in ``docs/benchmarks.md``.
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
from bfsop_jax.config import EVAL_SEED_START, PRESET_NAMES, get_preset
from bfsop_jax.env import observe, step
from bfsop_jax.eval import navigation as nav
from bfsop_jax.sop import callback as vns_host
from bfsop_jax.world.prior import default_prior


def run(
    preset_name: str,
    batch: int,
    methods: list[str],
    checkpoint: str | None,
    max_houses: int | None = None,
) -> list[dict]:
    preset = get_preset(preset_name)
    houses = nav.HouseSet(preset)
    n_houses = max(1, -(-batch // 9))
    if max_houses is not None:
        n_houses = min(n_houses, max_houses)
    episodes = nav.protocol_episodes(
        houses, range(EVAL_SEED_START, EVAL_SEED_START + n_houses), list(range(9))
    )
    episodes = (episodes * (1 + batch // max(len(episodes), 1)))[:batch]
    policy = None
    if "bfsop_st" in methods:
        from bfsop_jax.policy import StrategicPolicy

        policy = StrategicPolicy.load(checkpoint)
    prior = jnp.asarray(default_prior())
    keys = jnp.stack([e.key for e in episodes])
    hs = nav._stack([houses[e.house] for e in episodes])
    cats = jnp.asarray([e.category for e in episodes], jnp.int32)
    budgets = jnp.full((batch,), preset.budget_m, jnp.float32)
    rows = []
    for method in methods:
        strategy = nav.make_strategy(method, policy)
        runner = nav._Runner(strategy, preset, prior)
        states = runner.reset(keys, hs, cats, budgets)
        memory = runner.init(states)
        vns_host.reset_callback_stats()
        t = time.perf_counter()
        final, traj = runner.run(states, None)
        compile_s = runner.compile_s
        wall = time.perf_counter() - t - compile_s
        vns = vns_host.callback_stats()
        act = jax.jit(jax.vmap(lambda m, s, st=strategy: st.act(m, observe(s), preset)))
        env = jax.jit(jax.vmap(lambda s, a: step(s, a, preset)))
        action = act(memory, states)[0]
        decide = time_calls(act, memory, states).median
        env_s = time_calls(env, states, action).median
        plan_ms = nav._planner_latency_ms(strategy, final, preset)
        moves = int(np.asarray(traj.moved).sum())
        rows.append({
            "preset": preset_name, "method": method, "batch": batch,
            "episodes_per_s": batch / wall, "motion_steps_per_s": moves / wall,
            "rollout_s": wall, "compile_s": compile_s,
            "macro_steps": int(np.asarray(traj.active).any(axis=0).sum()),
            "planner_calls": int(np.asarray(traj.planned).sum()),
            "decide_ms": 1e3 * decide, "env_ms": 1e3 * env_s,
            "vns_s": vns["seconds"], "plan_ms": plan_ms,
        })  # fmt: skip
    base = next((r["rollout_s"] for r in rows if r["method"] == "fbe"), None)
    for r in rows:
        r["vs_fbe"] = r["rollout_s"] / base if base else float("nan")
    return rows


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m benchmarks.bench_rollout`` (options: docs/cli.md)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="demo", choices=PRESET_NAMES)
    ap.add_argument("--batch", type=positive_int, default=90)
    ap.add_argument("--houses", type=positive_int, default=None, help="cap on distinct houses")
    ap.add_argument("--methods", default=",".join(nav.METHODS))
    ap.add_argument("--checkpoint", default=None)
    ap.add_argument("--json", help="also write the figures to this JSON file")
    return ap


def main() -> None:
    args = build_parser().parse_args()
    where = machine()
    print(f"# bench_rollout  preset={args.preset}  batch={args.batch}  {where}  "
          f"{dt.date.today().isoformat()}")  # fmt: skip
    rows = run(args.preset, args.batch, args.methods.split(","), args.checkpoint, args.houses)
    cols = ("method", "episodes_per_s", "motion_steps_per_s", "rollout_s", "vs_fbe",
            "compile_s", "macro_steps", "planner_calls", "decide_ms", "env_ms", "vns_s",
            "plan_ms")  # fmt: skip
    print(" | ".join(cols))
    for r in rows:
        fmt = lambda v: f"{v:.3g}" if isinstance(v, float) else ("-" if v is None else str(v))
        print(" | ".join(fmt(r[c]) for c in cols), flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"machine": where, "rows": rows}, f, indent=1)


if __name__ == "__main__":
    run_main(main)
