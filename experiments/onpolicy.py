"""How well the Strategic Transformer plans the SOP instances BF-SOP poses online.

    python -m experiments.onpolicy --preset demo --houses 300:310 [--model demo]

The held-out instances of ``experiments.distill --stage eval`` are virtual tasks posed
like the training data (long budgets, one set per landmark). Online, BF-SOP poses other
ones: its short tour horizon, landmark parts as sets, coverage. This tool drives BF-SOP
episodes with the Transformer planning (up to ``--categories`` target categories per
house), has the VNS teacher label every instance the Transformer planned
(:func:`bfsop_jax.data.generate.student_records`, the DAgger rows), and prints the
Transformer's reward against the teacher's on exactly those instances: overall, the share
planned equally well, and by the number of rewarding sets. House seeds must be training
seeds (below the evaluation range), since these are the student's own training states.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

TOL = 1e-4  # rewards within this are "equal"
BY_SETS = ((1, 1), (2, 3), (4, 6), (7, 10**9))


def measure(preset_name: str, seeds: range, model: str, categories: int = 3) -> dict:
    """Driven episodes, teacher labels and the Transformer's plans; returns the figures."""
    import jax.numpy as jnp

    from bfsop_jax.agents import TransformerPlanner
    from bfsop_jax.config import EVAL_SEED_START, get_preset
    from bfsop_jax.data.generate import DataConfig, student_records
    from bfsop_jax.policy import StrategicPolicy
    from bfsop_jax.training.bc import instances_from_dataset
    from bfsop_jax.world.prior import default_prior

    if seeds.stop > EVAL_SEED_START:
        raise ValueError(f"--houses must be training seeds below {EVAL_SEED_START}")
    preset = get_preset(preset_name)
    policy = StrategicPolicy.load(model)
    config = DataConfig(preset=preset_name, vns_iters=500, vns_no_improve=250)
    clock = time.perf_counter()
    prior = jnp.asarray(default_prior())
    rec = student_records(np.asarray(seeds), TransformerPlanner(policy), preset, config,
                          prior, categories_per_house=categories)  # fmt: skip
    seconds = time.perf_counter() - clock
    plans = policy.plan(instances_from_dataset(rec))
    mine, teacher = np.asarray(plans.reward, np.float64), rec["teacher_reward"].astype(np.float64)
    sets = (rec["set_reward"] > 0).sum(-1)
    rows = []
    for lo, hi in BY_SETS:
        sel = (sets >= lo) & (sets <= hi)
        if sel.any():
            name = f"{lo}+" if hi >= 10**9 else (f"{lo}" if lo == hi else f"{lo}-{hi}")
            rows.append((name, int(sel.sum()), mine[sel].sum() / teacher[sel].sum()))
    return {
        "instances": len(mine),
        "ratio": mine.sum() / max(teacher.sum(), 1e-12),
        "equal": float(np.mean(np.abs(mine - teacher) <= TOL)),
        "worse": float(np.mean(mine < teacher - TOL)),
        "by_sets": rows,
        "seconds": seconds,
    }


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m experiments.onpolicy`` (options: docs/cli.md)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="demo", choices=["smoke", "demo", "paper"])
    ap.add_argument("--houses", default="300:310", help="training house seeds START:END")
    ap.add_argument("--model", default=None,
                    help="trained run dir or shipped name (default: the preset's)")  # fmt: skip
    ap.add_argument("--categories", type=int, default=3, help="episodes per house")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from bfsop_jax.config import parse_seed_range

    try:
        seeds = parse_seed_range(args.houses)
        if args.categories < 1:
            raise ValueError("--categories must be >= 1")
        model = args.model or ("paper" if args.preset == "paper" else "demo")
        out = measure(args.preset, seeds, model, args.categories)
    except ValueError as err:
        print(f"onpolicy: {err}", file=sys.stderr)
        return 2
    print(f"{out['instances']} instances planned online in {len(seeds)} houses "
          f"({out['seconds']:.0f} s of episodes and labels)")  # fmt: skip
    print(f"Transformer / VNS reward: {out['ratio']:.3f}; equal on {out['equal']:.1%}, "
          f"below on {out['worse']:.1%}")  # fmt: skip
    print("| rewarding sets | instances | Transformer / VNS |\n|---|---|---|")
    for name, n, ratio in out["by_sets"]:
        print(f"| {name} | {n} | {ratio:.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
