"""Distil the VNS teacher into the Strategic Transformer and compare the two planners.

    python -m experiments.distill [--preset demo|paper] [--out runs/<name>]
    python -m experiments.distill --stage eval --checkpoint DIR --eval-seeds START:END --out DIR2

Stages (``--stage all`` runs them in order):

1. ``data``: teacher-labelled SOP instances from training houses (seeds below the
   evaluation range): every exploitation decision of a BF-SOP agent planning with the VNS,
   plus retrospective virtual tasks on each exploration run's final partial map, labelled
   by the VNS through the batched host callback. Cached under ``--data-dir`` (default
   ``data/distill-<preset>``) as versioned shards: a second run reuses them and an
   interrupted one resumes. Over several machines (``docs/scale-out.md``): each runs
   ``--stage data --shard I/N --data-dir DIR_I`` (the shards with index % N == I), then
   ``--merge-data DIR_0,DIR_1,... [--data-dir DST]`` gathers them into one dataset
   (``--merge-data`` alone stops after the merge; with ``--stage train`` it goes on).
2. ``train``: behaviour cloning with teacher forcing (orbax checkpoint every epoch,
   ``--resume`` continues), metrics in ``metrics.jsonl`` / ``metrics.csv`` and
   ``training_curve.png``. With ``--ablations`` three more models are trained on the same
   data with the same seed: without the geometric attention bias, ``budget_aware``, and
   without the budget mask.
3. ``eval``: held-out instances posed the same way in held-out houses; the VNS teacher
   (reference configuration), the greedy insertion start and the Transformer (without and
   with 2-opt, with symmetry augmentation, best of 8) plan each of them. Writes
   ``solver_eval.json``, ``tables.md`` (Tables II and III, ablations),
   ``tour_comparison.png`` and ``decoder_distance_mass.png``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from bfsop_jax.eval.distill import (
    _trained_ablations,
    eval_instances,
    preset_planners,
    stage_eval,
    stage_navigation,
)
from bfsop_jax.model import DECODERS
from bfsop_jax.training.config import MODEL_PRESETS
from bfsop_jax.training.distill import (
    ABLATIONS,
    COMPARE_PLANNERS,
    PRESETS,
    DistillPreset,
    stage_dagger,
    stage_data,
    stage_rl,
    stage_train,
)
from bfsop_jax.training.distill import _data_config as _data_config
from bfsop_jax.training.distill import _refuse_shared_houses as _refuse_shared_houses
from bfsop_jax.training.distill import _run_config as _run_config
from bfsop_jax.training.distill import _split as _split
from bfsop_jax.training.distill import _train_run_config as _train_run_config
from bfsop_jax.training.rl import BASELINES, RLConfig

# the presets and the stages live in bfsop_jax.training.distill and bfsop_jax.eval.distill;
# re-exported here for the other experiment scripts and the tests
__all__ = [
    "ABLATIONS",
    "COMPARE_PLANNERS",
    "PRESETS",
    "DistillPreset",
    "eval_instances",
    "main",
    "preset_planners",
    "stage_dagger",
    "stage_data",
    "stage_eval",
    "stage_navigation",
    "stage_rl",
    "stage_train",
]


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m experiments.distill`` (options: docs/cli.md)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="demo", choices=sorted(PRESETS))
    ap.add_argument("--out", default=None, help="run directory (default runs/distill-<preset>)")
    ap.add_argument(
        "--stage", default=None, choices=["all", "data", "train", "eval", "dagger", "rl"],
        help="default: all (data with --merge-data); dagger: DAgger rounds from --checkpoint; "
        "rl: reward fine-tuning of --checkpoint into <out>/rl",
    )  # fmt: skip
    ap.add_argument(
        "--data-dir", default=None, help="dataset cache (default data/distill-<preset>)"
    )
    ap.add_argument(
        "--shard", default=None, metavar="I/N",
        help="data: generate only the shards with index %% N == I (one of N machines)",
    )  # fmt: skip
    ap.add_argument(
        "--merge-data", default=None, metavar="DIR1,DIR2,...",
        help="merge the dataset directories of --shard runs into --data-dir",
    )  # fmt: skip
    ap.add_argument(
        "--extra-data", default=None, metavar="DIR1,DIR2,...",
        help="train / rl: more datasets (e.g. another preset's, same N and K) added to the "
        "training set, each with its own last houses added to the validation set",
    )  # fmt: skip
    ap.add_argument("--checkpoint", default=None, help="eval: trained run dir (default --out)")
    ap.add_argument("--eval-seeds", default=None, help="eval house seeds START:END (held out)")
    ap.add_argument("--houses", type=int, default=None, help="override: training houses")
    ap.add_argument("--tasks", type=int, default=None, help="override: virtual tasks per house")
    ap.add_argument("--epochs", type=int, default=None, help="override: training epochs")
    ap.add_argument(
        "--model", default=None, choices=sorted(MODEL_PRESETS),
        help="override: model size preset and its training recipe (default: the preset's; "
        "demo d=64 x 3 layers, paper d=128 x 6 layers)",
    )  # fmt: skip
    ap.add_argument(
        "--decoder", default=None, choices=list(DECODERS),
        help="override: how a chosen node enters the plan: insertion (where it adds the "
        "least cost, default) or append (the paper's pointer decoding)",
    )  # fmt: skip
    ap.add_argument(
        "--lr", type=float, default=None,
        help="override: Adam learning rate of behaviour cloning (the preset's: demo 1e-3, "
        "paper 1e-4; dagger: the rounds', default the base run's last)",
    )  # fmt: skip
    ap.add_argument(
        "--on-policy", type=float, default=None, metavar="W",
        help="train: weight of the loss on the student's own plans' states, labelled by the "
        "teacher's nodes they still allow (insertion decoder; default 0: teacher states only)",
    )  # fmt: skip
    ap.add_argument(
        "--init", default=None, metavar="DIR",
        help="train: start from this trained model's parameters (same model config), e.g. "
        "to fine-tune a shipped model with --on-policy",
    )  # fmt: skip
    ap.add_argument("--resume", action="store_true", help="continue an interrupted training run")
    ap.add_argument("--ablations", action="store_true", help="also train the ablations")
    ap.add_argument("--eval-tasks", type=int, default=None, help="override: tasks per eval house")
    ap.add_argument("--no-navigation", action="store_true", help="skip the navigation stage")
    ap.add_argument(
        "--compare", default=None, metavar="DIR1,DIR2,...",
        help="eval: other models (run directories or the shipped 'demo' / 'paper') planned "
        "on the same instances against the same teacher plans",
    )  # fmt: skip
    ap.add_argument("--rounds", type=int, default=3, help="dagger: DAgger rounds")
    ap.add_argument(
        "--dagger-epochs", type=int, default=10, help="dagger: training epochs per round"
    )
    ap.add_argument(
        "--dagger-houses", type=int, default=20,
        help="dagger: training houses the student drives in per round",
    )  # fmt: skip
    ap.add_argument(
        "--dagger-categories", type=int, default=3,
        help="dagger: episodes (target categories) per training house and round",
    )  # fmt: skip
    ap.add_argument("--rl-epochs", type=int, default=8, help="rl: fine-tuning epochs")
    ap.add_argument("--rl-lr", type=float, default=RLConfig.lr, help="rl: Adam learning rate")
    ap.add_argument(
        "--rl-samples", type=int, default=RLConfig.samples, help="rl: sampled plans per instance"
    )
    ap.add_argument(
        "--rl-bc-weight", type=float, default=RLConfig.bc_weight,
        help="rl: weight of the teacher's cross-entropy next to the reward term",
    )  # fmt: skip
    ap.add_argument(
        "--rl-baseline", default=RLConfig.baseline, choices=list(BASELINES),
        help="rl: a sampled plan's reward is measured against the mean of the instance's "
        "other samples (leave_one_out) or against its greedy plan (greedy, self-critical)",
    )  # fmt: skip
    ap.add_argument("--no-progress", action="store_true")
    return ap


def _parse(argv: list[str] | None) -> argparse.Namespace:
    args = build_parser().parse_args(argv)
    if args.stage is None:
        args.stage = "data" if args.merge_data else "all"
    if args.compare is not None:
        args.compare = [d for d in (x.strip() for x in args.compare.split(",")) if d]
        if not args.compare:
            raise ValueError("--compare expects a comma-separated list of models")
    if args.extra_data is not None:
        args.extra_data = [d for d in (x.strip() for x in args.extra_data.split(",")) if d]
        if not args.extra_data:
            raise ValueError("--extra-data expects a comma-separated list of directories")
    for name in ("houses", "tasks", "epochs", "eval_tasks", "rounds", "dagger_epochs",
                 "dagger_houses", "dagger_categories", "rl_epochs", "rl_samples"):  # fmt: skip
        value = getattr(args, name)
        if value is not None and value < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {value}")
    if args.lr is not None and not args.lr > 0:
        raise ValueError(f"--lr must be a positive learning rate, got {args.lr}")
    if not args.rl_lr > 0:
        raise ValueError(f"--rl-lr must be a positive learning rate, got {args.rl_lr}")
    if args.on_policy is not None and not args.on_policy >= 0:
        raise ValueError(f"--on-policy must be a weight >= 0, got {args.on_policy}")
    if args.shard is not None:
        args.shard = _parse_shard(args.shard)
        if args.stage == "eval":
            raise ValueError("--shard splits the data stage; it has no meaning for --stage eval")
    if args.merge_data is not None:
        args.merge_data = [d for d in (x.strip() for x in args.merge_data.split(",")) if d]
        if not args.merge_data:
            raise ValueError("--merge-data expects a comma-separated list of directories")
        if args.shard is not None:
            raise ValueError("--merge-data and --shard do not go together: generate, then merge")
        if args.stage == "eval":
            raise ValueError("--merge-data prepares the data; it has no meaning for --stage eval")
    return args


def _parse_shard(text: str) -> tuple[int, int]:
    """``"I/N"`` -> ``(I, N)`` with ``0 <= I < N``; a ValueError naming ``--shard`` else."""
    try:
        i, n = (int(x) for x in text.split("/"))
    except ValueError:
        i, n = -1, 0
    if not 0 <= i < n:
        raise ValueError(f"--shard expects I/N with 0 <= I < N (e.g. 0/2), got {text!r}")
    return i, n


def main(argv: list[str] | None = None) -> dict[str, Any]:
    args = _parse(argv)
    preset = PRESETS[args.preset]
    out = Path(args.out or f"runs/distill-{args.preset}")
    data_dir = Path(args.data_dir or f"data/distill-{args.preset}")
    t0 = time.perf_counter()
    summary: dict[str, Any] = {}
    ablations = None
    if args.stage in ("all", "data", "train"):
        store, cfg = stage_data(args, preset, data_dir)
        if args.stage != "data":
            ablations = stage_train(args, preset, store, cfg, out)
            summary["training"] = ablations
    if args.stage == "dagger":
        store, cfg = stage_data(args, preset, data_dir)
        summary["dagger"] = stage_dagger(args, preset, store, cfg, out)
    if args.stage == "rl":
        store, cfg = stage_data(args, preset, data_dir)
        summary["rl"] = stage_rl(args, preset, store, cfg, out)
    if args.stage == "eval" and args.ablations:
        ablations = _trained_ablations(out if args.checkpoint is None else Path(args.checkpoint))
    if args.stage in ("all", "eval"):
        result = stage_eval(args, preset, out, ablations if args.ablations else None)
        summary["solver_eval"] = result
    print(f"done in {time.perf_counter() - t0:.0f} s; outputs in {out}")
    line = summary.get("solver_eval", {}).get("navigation", {}).get("verdict")
    if line:  # the last line: what a newcomer reads first
        print(line)
    return summary


if __name__ == "__main__":
    try:
        main()
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(2) from None
