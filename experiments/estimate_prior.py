"""Estimate the co-occurrence prior P(target | landmark) from training houses.

    python -m experiments.estimate_prior [--preset demo] [--houses 256] [--out data/...]

Training houses use seeds below ``EVAL_SEED_START``; evaluation houses never contribute.
"""

from __future__ import annotations

import argparse
import datetime as dt

import jax
import numpy as np
from tqdm import tqdm

from bfsop_jax.config import EVAL_SEED_START, PRESET_NAMES, get_preset
from bfsop_jax.world.constants import CATEGORY_NAMES, N_TARGETS, TARGET_NAMES
from bfsop_jax.world.generator import generate_house
from bfsop_jax.world.prior import DEFAULT_PRIOR_PATH, estimate_prior, save_prior


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m experiments.estimate_prior`` (options: docs/cli.md)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="demo", choices=PRESET_NAMES)
    ap.add_argument("--houses", type=int, default=256, help="number of training houses")
    ap.add_argument("--seed-start", type=int, default=0, help="first training house seed")
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--out", default=str(DEFAULT_PRIOR_PATH))
    return ap


def main(argv: list[str] | None = None) -> None:
    args = build_parser().parse_args(argv)
    preset = get_preset(args.preset)
    if args.houses < 1 or args.batch < 1 or args.seed_start < 0:
        raise SystemExit(
            f"error: need --houses >= 1, --batch >= 1 and --seed-start >= 0, got "
            f"{args.houses}, {args.batch} and {args.seed_start}"
        )
    if args.seed_start + args.houses > EVAL_SEED_START:
        raise SystemExit(f"training seeds must stay below {EVAL_SEED_START} (evaluation seeds)")

    generate = jax.jit(jax.vmap(generate_house, in_axes=(0, None)), static_argnums=1)
    seeds = np.arange(args.seed_start, args.seed_start + args.houses)
    hits = np.zeros((len(CATEGORY_NAMES), N_TARGETS))
    counts = np.zeros(len(CATEGORY_NAMES))
    for lo in tqdm(range(0, len(seeds), args.batch), desc="training houses", unit="batch"):
        batch = seeds[lo : lo + args.batch]
        keys = jax.vmap(jax.random.key)(batch)
        houses = jax.device_get(generate(keys, preset))
        prior, n = estimate_prior(houses)
        hits += prior * n[:, None]
        counts += n
    prior = np.where(counts[:, None] > 0, hits / np.maximum(counts[:, None], 1), 0.0)
    meta = {
        "preset": preset.name,
        "houses": int(args.houses),
        "seeds": f"{args.seed_start}:{args.seed_start + args.houses}",
        "landmark_counts": {CATEGORY_NAMES[k]: int(c) for k, c in enumerate(counts) if c},
        "date": dt.date.today().isoformat(),
    }
    save_prior(args.out, prior, meta)
    print(f"wrote {args.out}")
    top = np.argsort(-prior, axis=0)[:3]
    for c, name in enumerate(TARGET_NAMES):
        cues = ", ".join(f"{CATEGORY_NAMES[k]} {prior[k, c]:.2f}" for k in top[:, c])
        print(f"  {name:<11} {cues}")


if __name__ == "__main__":
    main()
