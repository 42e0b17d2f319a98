"""Run one exploration episode in a generated house and draw it.

    python -m experiments.simulate [--preset demo] [--seed 1000000] [--category HousePlant]
                                   [--out runs/simulate]

Generates a house, runs the frontier-exploration agent (FBE) until the budget gate
closes, then writes ``house.png``, ``belief.png``, ``trajectory.png`` and
``summary.json`` into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import jax
import numpy as np
from tqdm import tqdm

from bfsop_jax import viz
from bfsop_jax.agents import FBE, continue_rollout, max_macro_steps
from bfsop_jax.config import EVAL_SEED_START, PRESET_NAMES, get_preset
from bfsop_jax.env import observe, reset
from bfsop_jax.navigation.frontiers import frontier_clusters
from bfsop_jax.world import TARGET_NAMES, generate_house, target_id


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="demo", choices=PRESET_NAMES)
    ap.add_argument("--seed", type=int, default=EVAL_SEED_START, help="house seed")
    ap.add_argument("--category", default=None, help="target category (default: most frequent)")
    ap.add_argument("--budget", type=float, default=None, help="travel budget in metres")
    ap.add_argument("--out", default="runs/simulate")
    args = ap.parse_args(argv)
    preset = get_preset(args.preset)
    if args.budget is not None and not 0 < args.budget < float("inf"):
        raise SystemExit(f"error: --budget must be a positive number of metres, got {args.budget}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    t0 = time.perf_counter()
    house = jax.jit(generate_house, static_argnums=1)(jax.random.key(args.seed), preset)
    cats = np.asarray(house.object_category)
    is_target = (cats >= 0) & (cats < len(TARGET_NAMES))
    counts = np.bincount(cats[is_target], minlength=len(TARGET_NAMES))
    if args.category is None:
        category = int(np.argmax(counts))
    else:
        category = target_id(args.category)
        if counts[category] == 0:
            present = ", ".join(n for n, c in zip(TARGET_NAMES, counts, strict=True) if c)
            missing = TARGET_NAMES[category]
            raise SystemExit(f"no {missing} in house {args.seed}; present: {present}")

    state = jax.jit(reset, static_argnums=3)(
        jax.random.key(args.seed), house, category, preset, None, args.budget
    )
    budget = float(state.budget)
    start = np.asarray(state.pose)[None]
    chunk = 10
    fbe = FBE()
    memory = fbe.init(observe(state), preset)
    run_chunk = jax.jit(lambda s, m: continue_rollout(s, m, fbe, preset, chunk))
    n_chunks = math.ceil(max_macro_steps(budget, preset) / chunk)
    trajectories = []
    with tqdm(total=math.ceil(budget), desc="exploring", unit="m") as bar:
        for _ in range(n_chunks):
            state, memory, traj = run_chunk(state, memory)
            trajectories.append(jax.device_get(traj))
            bar.update(int(float(state.path_length)) - bar.n)
            if bool(state.done) or not bool(traj.active[-1]):
                break

    poses = np.concatenate([start] + [t.poses[t.moved] for t in trajectories])
    found = np.asarray(state.found)
    lois = np.asarray(state.landmarks_seen)
    summary = {
        "preset": preset.name,
        "house_seed": args.seed,
        "category": TARGET_NAMES[category],
        "instances": int(counts[category]),
        "found": int(found.sum()),
        "progress": float(found.sum() / max(counts[category], 1)),
        "path_length_m": float(state.path_length),
        "budget_m": budget,
        "landmarks_of_interest_seen": int(lois.sum()),
        "macro_steps": int(sum(t.active.sum() for t in trajectories)),
        "wall_time_s": time.perf_counter() - t0,
    }
    name = TARGET_NAMES[category]
    viz.plot_house(house, out / "house.png", title=f"{preset.name} house, seed {args.seed}")
    viz.plot_belief(
        state.belief,
        preset,
        out / "belief.png",
        frontiers=frontier_clusters(state.belief, preset),
        landmarks=(np.asarray(house.object_xy)[lois], cats[lois]),
        pose=state.pose,
        title=f"belief after {summary['path_length_m']:.0f} m (landmarks of interest for {name})",
    )
    viz.plot_trajectory(
        poses,
        out / "trajectory.png",
        house=house,
        found_xy=np.asarray(house.object_xy)[found],
        title=f"FBE for {name}: found {summary['found']}/{summary['instances']}",
    )
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps(summary, indent=1))
    print(f"figures written to {out}/")
    return summary


if __name__ == "__main__":
    main()
