"""Run one episode of a navigation strategy in a generated house and draw it.

    python -m experiments.simulate [--method bfsop_st] [--preset demo] [--seed 1000000]
                                   [--category HousePlant] [--budget M] [--checkpoint DIR]
                                   [--gif] [--out runs/simulate]

Generates a house, runs the strategy (``fbe``, ``bfs_global``, ``tfl_reactive``,
``bfsop_vns`` or ``bfsop_st``: BF-SOP with the shipped demo Transformer, or the one in
``--checkpoint``) until the episode ends, then writes ``house.png``, ``belief.png``,
``trajectory.png`` and ``summary.json`` into ``--out``; with ``--gif`` also
``episode.gif``, the episode as an animation (:func:`bfsop_jax.viz.animate_episode`).
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
from bfsop_jax.config import EVAL_SEED_START, PRESET_NAMES, get_preset
from bfsop_jax.env import reset
from bfsop_jax.eval import gifs
from bfsop_jax.eval import navigation as nav
from bfsop_jax.navigation.frontiers import frontier_clusters
from bfsop_jax.viz.animation import MAX_FRAMES, frame_indices
from bfsop_jax.world import TARGET_NAMES, generate_house, target_id


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m experiments.simulate`` (options: docs/cli.md)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--method", default="bfsop_st", choices=nav.METHODS + nav.ABLATIONS)
    ap.add_argument("--preset", default="demo", choices=PRESET_NAMES)
    ap.add_argument("--seed", type=int, default=EVAL_SEED_START, help="house seed")
    ap.add_argument("--category", default=None, help="target category (default: most frequent)")
    ap.add_argument("--budget", type=float, default=None, help="travel budget in metres")
    ap.add_argument(
        "--checkpoint", default=None, help="bfsop_st's Transformer run dir (default: shipped demo)"
    )
    ap.add_argument("--gif", action="store_true", help="also write episode.gif")
    ap.add_argument("--out", default="runs/simulate")
    return ap


def main(argv: list[str] | None = None) -> dict:
    args = build_parser().parse_args(argv)
    preset = get_preset(args.preset)
    if args.budget is not None and not 0 < args.budget < float("inf"):
        raise SystemExit(f"error: --budget must be a positive number of metres, got {args.budget}")
    policy = None
    if args.method == "bfsop_st":
        from bfsop_jax.policy import StrategicPolicy

        try:
            policy = StrategicPolicy.load(args.checkpoint)
        except ValueError as err:
            raise SystemExit(f"error: --checkpoint: {err}") from None
    strategy = nav.make_strategy(args.method, policy)
    label = nav.LABELS[args.method]
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
    recorder = gifs.make_recorder(strategy, preset)
    with tqdm(total=math.ceil(budget), desc=label, unit="m") as bar:
        recording = recorder.record(state, progress=lambda m: bar.update(int(m) - bar.n))
    state, frames = recording.final, recording.frames

    found = np.asarray(state.found)
    lois = np.asarray(state.landmarks_seen)
    summary = {
        "method": args.method,
        "preset": preset.name,
        "house_seed": args.seed,
        "category": TARGET_NAMES[category],
        "instances": int(counts[category]),
        "found": int(found.sum()),
        "progress": float(found.sum() / max(counts[category], 1)),
        "path_length_m": float(state.path_length),
        "budget_m": budget,
        "landmarks_of_interest_seen": int(lois.sum()),
        "macro_steps": int(np.asarray(recording.trajectory.active).sum()),
        "tours": int(np.asarray(recording.trajectory.switched).sum()),
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
        frames.path_xy,
        out / "trajectory.png",
        house=house,
        touring=frames.path_touring,
        found_xy=np.asarray(house.object_xy)[found],
        title=f"{label} for {name}: found {summary['found']}/{summary['instances']}",
    )
    if args.gif:
        title = f"{label}: {name} in house {args.seed} ({preset.name})"
        gif = viz.animate_episode(frames, out / "episode.gif", title)
        summary["gif_frames"] = len(frame_indices(frames.n_frames, MAX_FRAMES))
        summary["gif_bytes"] = gif.stat().st_size
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps(summary, indent=1))
    print(f"figures written to {out}/")
    return summary


if __name__ == "__main__":
    main()
