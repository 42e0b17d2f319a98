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
import dataclasses
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

from bfsop_jax import files
from bfsop_jax.config import EVAL_SEED_START, parse_seed_range
from bfsop_jax.data.generate import DataConfig, generate_dataset, pose_tasks
from bfsop_jax.data.shards import ShardStore, merge_datasets
from bfsop_jax.eval import solvers as solver_eval
from bfsop_jax.model import DECODERS
from bfsop_jax.policy import StrategicPolicy
from bfsop_jax.training import RunConfig, train
from bfsop_jax.training.bc import evaluate_imitation
from bfsop_jax.training.config import MODEL_PRESETS
from bfsop_jax.training.rl import BASELINES, RLConfig
from bfsop_jax.viz import plot_distance_mass, plot_model_comparison, plot_tour_comparison


@dataclasses.dataclass(frozen=True)
class DistillPreset:
    """Sizes of one distillation run."""

    data: DataConfig
    val_houses: int  # the last training houses are held out for validation (model choice)
    model: str  # model / recipe preset of bfsop_jax.training
    lrs: tuple[float, ...]
    eval_houses: int  # held-out houses for the solver evaluation
    eval_tasks: int = 24  # tasks posed per held-out house
    epochs: int | None = None  # None: the recipe's value
    seeds: tuple[int, ...] = (0,)
    # decoder masks nodes that no longer fit the budget (END only when none does), scores
    # each candidate by its step features too (move cost, budget left, reward per
    # distance), puts a chosen node where it adds the least cost and improves the route
    # after every insertion (docs/model.md)
    model_options: tuple[tuple[str, Any], ...] = (
        ("budget_mask", True),
        ("step_features", True),
        ("decoder", "insertion"),
        ("refine", True),
    )
    augment: bool = True  # train on random coordinate symmetries of each instance
    # navigation evaluation at the end (a reduced Table I protocol: these many held-out
    # houses x these categories, 0 houses = skip); the full one is experiments.evaluate
    nav_houses: int = 2
    nav_categories: tuple[str, ...] = ()  # () = all nine
    nav_methods: tuple[str, ...] = ("fbe", "bfs_global", "tfl_reactive", "bfsop_vns", "bfsop_st")
    # Table II's planners (names of bfsop_jax.eval.solvers.PLANNERS; () = all of them) and
    # those ``--compare`` runs for each other model (() = COMPARE_PLANNERS)
    planners: tuple[str, ...] = ()
    compare_planners: tuple[str, ...] = ()


PRESETS: dict[str, DistillPreset] = {
    # minutes on a 2-core laptop CPU: small data, the demo model, 30 epochs at lr 1e-3
    # (the paper's 1e-4 needs its 100 epochs on far more data)
    "demo": DistillPreset(
        data=DataConfig(
            preset="demo",
            houses=24,
            houses_per_shard=4,
            tasks_per_house=48,
            vns_iters=500,
            vns_no_improve=250,
        ),  # fmt: skip
        val_houses=4,
        model="demo",
        lrs=(1e-3,),
        eval_houses=4,
    ),
    # the paper setting (~1e5 step-level transitions; meant for a GPU and a long run). The
    # teacher labels at 500 / 250 iterations, as on demo (`python -m benchmarks.bench_labels
    # --preset paper` compares these labels with the reference configuration's rewards)
    "paper": DistillPreset(
        data=DataConfig(
            preset="paper",
            houses=1024,
            houses_per_shard=4,
            tasks_per_house=48,
            vns_iters=500,
            vns_no_improve=250,
        ),  # fmt: skip
        val_houses=64,
        model="paper",
        lrs=(1e-4,),
        eval_houses=10,
    ),
    # a tiny end-to-end run for tests
    "smoke": DistillPreset(
        data=DataConfig(
            preset="smoke",
            houses=2,
            houses_per_shard=1,
            tasks_per_house=6,
            vns_iters=100,
            vns_no_improve=50,
            on_trajectory=False,
        ),  # fmt: skip
        val_houses=1,
        model="tiny",
        lrs=(1e-3,),
        eval_houses=1,
        eval_tasks=6,
        epochs=2,
        nav_houses=1,
        nav_categories=("HousePlant",),
        nav_methods=("fbe",),
        # the paper's append decoder: the insertion decoder's programs (with the route
        # improvement) take minutes to compile in every planner of the evaluation; tests of
        # the insertion decoder and its CLI train it explicitly
        model_options=(("budget_mask", True), ("step_features", True), ("decoder", "append")),
        # one planner of each kind (every planner program compiles twice: single, batched)
        planners=(
            "transformer",
            "transformer+2opt",
            "transformer+2opt+augment",
            "transformer+2opt+best_of_2+fill",
            "transformer+2opt+multi_start_8+best_of_4+fill",
        ),
        compare_planners=("transformer+2opt",),  # the other model is a shipped one
    ),
}

# the planners ``--compare`` runs for each other model (greedy + 2-opt and the options
# that stay under 10 ms on a 2-core CPU)
COMPARE_PLANNERS = {
    name: solver_eval.PLANNERS[name]
    for name in (
        "transformer+2opt",
        "transformer+2opt+fill",
        "transformer+2opt+best_of_4+fill",
        "transformer+2opt+best_of_8+fill",
        "transformer+2opt+multi_start+fill",
        "transformer+2opt+multi_start_8+best_of_4+fill",
    )
}

ABLATIONS = {
    "no_step_features": {"step_features": False},  # the pointer alone
    "no_geometric_bias": {"geometric_bias": False},
    "budget_aware": {"budget_aware": True},
    "no_budget_mask": {"budget_mask": False},  # the paper's decoder masks
}


def _parse(argv: list[str] | None) -> argparse.Namespace:
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
    args = ap.parse_args(argv)
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


def _data_config(args, preset: DistillPreset) -> DataConfig:
    cfg = preset.data
    if args.houses is not None:
        cfg = dataclasses.replace(cfg, houses=args.houses)
    if args.tasks is not None:
        cfg = dataclasses.replace(cfg, tasks_per_house=args.tasks)
    return cfg


def _n_val_shards(cfg: DataConfig, val_houses: int) -> int:
    """Validation shards: those of the last ``val_houses`` houses, but never more than a
    sixteenth of the dataset (at least one shard) when ``--houses`` shrinks it."""
    if cfg.n_shards < 2:
        return 0
    houses = min(val_houses, max(cfg.houses_per_shard, cfg.houses // 16))
    return max(1, -(-houses // cfg.houses_per_shard))


def _split(store, cfg: DataConfig, val_houses: int):
    """Training and validation dicts: the shards of the last validation houses
    (:func:`_n_val_shards`) validate."""
    n_val = _n_val_shards(cfg, val_houses)
    shards = list(range(cfg.n_shards))
    train_ds = store.load(shards[: len(shards) - n_val])
    val_ds = store.load(shards[len(shards) - n_val :]) if n_val else None
    return train_ds, val_ds


def _run_config(
    preset: DistillPreset,
    data_cfg: DataConfig,
    epochs: int | None,
    model_name: str | None = None,
    **model_kw,
):
    base = RunConfig.named(model_name or preset.model, preset=data_cfg.preset)
    model = dataclasses.replace(base.model, **{**dict(preset.model_options), **model_kw})
    recipe = dataclasses.replace(base.train, augment=preset.augment)
    if epochs is not None or preset.epochs is not None:
        recipe = dataclasses.replace(recipe, epochs=epochs or preset.epochs)
    return RunConfig(model=model, train=recipe, preset=data_cfg.preset)


def _indices(xs: list[int], most: int = 8) -> str:
    return ", ".join(map(str, xs[:most])) + (f", ... ({len(xs)} in all)" if len(xs) > most else "")


def stage_data(args, preset: DistillPreset, data_dir: Path):
    """Generate (``--shard I/N``: this process's part of) or merge the dataset.

    Returns ``(store, cfg)``. Raises a ValueError when the stage goes on to training but
    shards are missing (a ``--shard`` part, an incomplete merge): the message names them
    and says how to finish.
    """
    cfg = _data_config(args, preset)
    shard = getattr(args, "shard", None) or (0, 1)
    sources = getattr(args, "merge_data", None)
    t0 = time.perf_counter()
    if sources:
        store = merge_datasets(data_dir, sources, config=dataclasses.asdict(cfg))
        print(f"merged {', '.join(map(str, sources))} into {data_dir}")
    else:
        store = generate_dataset(data_dir, cfg, shard=shard, progress=not args.no_progress)
    done = set(store.complete_shards())
    rows = sum(store.meta["shards"][str(i)]["rows"] for i in done)
    missing = [i for i in range(cfg.n_shards) if i not in done]
    print(
        f"dataset {data_dir}: {rows} instances, {cfg.n_shards - len(missing)}/{cfg.n_shards} "
        f"shards ({time.perf_counter() - t0:.0f} s)"
    )
    if missing:
        n = shard[1]
        parts = sorted({i % n for i in missing}) if n > 1 else []
        if parts:
            shown = ", ".join(f"--shard {j}/{n}" for j in parts[:4]) + (", ..." * (len(parts) > 4))
            how = f"generate them with --stage data {shown} (each into its own --data-dir)"
        else:
            how = "generate them with --stage data --shard I/N (each into its own --data-dir)"
        msg = (
            f"dataset {data_dir} lacks shards {_indices(missing)} of {cfg.n_shards}: {how}, "
            "merge them with --merge-data DIR_0,DIR_1,... --data-dir DST, then run "
            "--stage train --data-dir DST"
        )
        if args.stage != "data":
            raise ValueError(msg)
        print(f"note: {msg}")
    return store, cfg


def _concat(parts: list[dict[str, np.ndarray]], names: list[str]) -> dict[str, np.ndarray]:
    """One dataset from several with the same fields and shapes (ValueError naming the
    directory that differs)."""
    first = parts[0]
    for part, name in zip(parts[1:], names[1:], strict=True):
        for key in first:
            if key not in part or part[key].shape[1:] != first[key].shape[1:]:
                shape = part[key].shape[1:] if key in part else "missing"
                raise ValueError(
                    f"--extra-data {name}: field {key!r} has shape {shape}, the training "
                    f"data's has {first[key].shape[1:]} (train on datasets of one N and K)"
                )
    return {k: np.concatenate([p[k] for p in parts]) for k in first}


def _refuse_shared_houses(directory, trains, vals, extra_train, extra_val) -> None:
    """ValueError when a house validates on one side and trains on the other (model
    selection would see its own training houses)."""
    seeds = lambda parts: {int(h) for p in parts if p is not None for h in p["house_seed"]}
    shared = (seeds(vals) & seeds([extra_train])) | (seeds(trains) & seeds([extra_val]))
    if shared:
        raise ValueError(
            f"--extra-data {directory}: houses {sorted(shared)[:5]} train on one side and "
            "validate on the other; use datasets of disjoint houses"
        )


def _with_extra_data(args, train_ds, val_ds, meta: dict[str, Any]):
    """Add the ``--extra-data`` directories: their training houses to the training set,
    their validation houses (by their own preset) to the validation set."""
    trains, vals, names = [train_ds], [val_ds], [str(meta["data_dir"])]
    meta["extra_data"] = []
    for directory in args.extra_data or []:
        store = ShardStore.open(directory)
        cfg = DataConfig(**store.config)
        missing = [i for i in range(cfg.n_shards) if i not in set(store.complete_shards())]
        if missing:
            raise ValueError(f"--extra-data {directory}: shards {_indices(missing)} missing")
        val_houses = PRESETS[cfg.preset].val_houses if cfg.preset in PRESETS else 0
        extra_train, extra_val = _split(store, cfg, val_houses)
        if cfg.preset == meta["data_config"]["preset"]:  # the same seed, the same house
            _refuse_shared_houses(directory, trains, vals, extra_train, extra_val)
        trains.append(extra_train)
        vals.append(extra_val)
        names.append(directory)
        meta["extra_data"].append({"data_dir": directory, "data_config": store.config})
    if len(trains) == 1:
        return train_ds, val_ds
    train_ds = _concat(trains, names)
    kept = [(v, n) for v, n in zip(vals, names, strict=True) if v is not None]
    val_ds = _concat([v for v, _ in kept], [n for _, n in kept]) if kept else None
    return train_ds, val_ds


def _train_run_config(args, preset: DistillPreset, cfg: DataConfig, model_kw: dict) -> RunConfig:
    """The run config of one training run: the preset's, the model overrides, the CLI's
    epochs, model size and ``--on-policy`` weight."""
    config = _run_config(preset, cfg, args.epochs, args.model, **model_kw)
    if args.on_policy is None:
        return config
    return dataclasses.replace(
        config, train=dataclasses.replace(config.train, on_policy=args.on_policy)
    )


def _check_kept_model(
    run_dir: Path, config: RunConfig, meta: dict[str, Any], train_ds: Any,
    seeds: tuple[int, ...], lrs: tuple[float, ...],
) -> None:  # fmt: skip
    """ValueError unless the model kept in ``run_dir`` was trained as this call would train
    it: the same model and recipe, seeds and learning rates, data and initialisation."""
    from bfsop_jax import checkpoint as ckpt
    from bfsop_jax.training.bc import dataset_info

    old = ckpt.read_config(run_dir)
    had = old.get("dataset", {})
    differ = ckpt.differing({
        "model or training recipe": (old.get("run"), config.to_dict()),
        "seeds or learning rates": (
            sorted((r.get("seed"), r.get("lr")) for r in old.get("replicas", [])),
            sorted((s, float(lr)) for s in seeds for lr in lrs),
        ),
        "data": (
            [had.get("meta", {}).get("data_config"), had.get("train", {}).get("instances")],
            [meta["data_config"], dataset_info(train_ds)["instances"]],
        ),
        "--extra-data": (
            [e.get("data_config") for e in had.get("meta", {}).get("extra_data", [])],
            [e["data_config"] for e in meta.get("extra_data", [])],
        ),
        "--init": (had.get("meta", {}).get("init"), meta.get("init")),
    })  # fmt: skip
    if differ:
        raise ValueError(
            f"{run_dir} holds a model trained otherwise (its {', '.join(differ)} differ); "
            "pass another --out (or delete its model/ to train it again)"
        )


def stage_train(args, preset: DistillPreset, store, cfg: DataConfig, out: Path) -> dict[str, Any]:
    train_ds, val_ds = _split(store, cfg, preset.val_houses)
    meta = {"data_dir": str(store.root), "data_config": dataclasses.asdict(cfg)}
    train_ds, val_ds = _with_extra_data(args, train_ds, val_ds, meta)
    decoder = {"decoder": args.decoder, "refine": args.decoder == "insertion"}
    runs = {"main": (out, decoder if args.decoder else {})}
    if args.ablations:
        for name, kw in ABLATIONS.items():
            runs[name] = (out / "ablations" / name, {**runs["main"][1], **kw})
    init = StrategicPolicy.load(args.init) if args.init else None
    if init is not None:
        meta["init"] = str(args.init)
    summary = {}
    for name, (run_dir, kw) in runs.items():
        config = _train_run_config(args, preset, cfg, kw)
        if init is not None and init.config != config.model:
            raise ValueError(
                f"--init {args.init}: its model config differs from this run's "
                f"({init.config} vs {config.model}); pass the same --model / --decoder"
            )
        resume = args.resume and (run_dir / "checkpoints").exists()
        lrs = (args.lr,) if args.lr is not None else preset.lrs
        if (run_dir / "model").is_dir() and not args.resume:
            _check_kept_model(run_dir, config, meta, train_ds, preset.seeds, lrs)
            print(f"{name}: trained model found in {run_dir}, kept (pass --resume to continue)")
        else:
            t0 = time.perf_counter()
            print(f"training {name} ({config.train.epochs} epochs) -> {run_dir}")
            train(config, train_ds, val_ds, run_dir, seeds=preset.seeds, lrs=lrs,
                  resume=resume, progress=not args.no_progress, dataset_meta=meta,
                  init_params=None if init is None else init.params)  # fmt: skip
            print(f"  {time.perf_counter() - t0:.0f} s")
        policy = StrategicPolicy.load(run_dir)
        stats = evaluate_imitation(policy.model, val_ds if val_ds is not None else train_ds)
        summary[name] = {
            "run_dir": str(run_dir),
            "val_loss": stats["loss"],
            "val_acc": stats["acc"],
        }
    return summary


def preset_planners(preset: DistillPreset, compare: bool = False) -> dict[str, dict[str, Any]]:
    """The planners (name -> ``StrategicPolicy.plan`` options) a preset's evaluation runs for
    its model, or with ``compare`` for each ``--compare`` model."""
    names = preset.compare_planners if compare else preset.planners
    if not names:
        return COMPARE_PLANNERS if compare else solver_eval.PLANNERS
    return {name: solver_eval.PLANNERS[name] for name in names}


def eval_instances(
    preset: DistillPreset, lo: int, hi: int, tasks: int, progress: bool = True
) -> tuple[Any, np.ndarray]:
    """The held-out instances an evaluation of houses ``lo..hi-1`` plans: ``tasks`` virtual
    tasks posed per house (those without a rewarding set dropped), and the house seed of each
    instance ``[I]``. Deterministic in its arguments."""
    cfg = dataclasses.replace(preset.data, tasks_per_house=tasks)
    return pose_tasks(np.arange(lo, hi), cfg, progress=progress)


def stage_eval(args, preset: DistillPreset, out: Path, ablations: dict[str, Any] | None) -> dict:
    checkpoint = Path(args.checkpoint) if args.checkpoint else out
    if args.eval_seeds:
        rng = parse_seed_range(args.eval_seeds)
        lo, hi = rng.start, rng.stop
        if lo < EVAL_SEED_START:
            print(f"warning: eval seeds below {EVAL_SEED_START} may be training houses")
    else:
        lo, hi = EVAL_SEED_START, EVAL_SEED_START + preset.eval_houses
    tasks = args.eval_tasks or preset.eval_tasks
    policy = StrategicPolicy.load(checkpoint)
    # every --compare model loads before the long part (a bad path costs nothing)
    others = {other: StrategicPolicy.load(other) for other in args.compare or []}
    instances, owners = eval_instances(preset, lo, hi, tasks, progress=not args.no_progress)
    n = int(owners.shape[0])
    print(f"evaluation: {n} instances from houses {lo}..{hi - 1}")
    evaluation = solver_eval.evaluate_solvers(
        policy, instances, planners=preset_planners(preset), progress=not args.no_progress
    )
    result = evaluation.summary
    result["house_seeds"] = [int(lo), int(hi)]
    result["tasks_per_house"] = int(tasks)
    result["instance_houses"] = [int(h) for h in owners]  # paired intervals over houses
    result["preset"] = args.preset
    result["checkpoint"] = str(checkpoint)
    result["machine"] = f"{platform.machine()}, {os.cpu_count()} CPU cores, {jax.default_backend()}"
    result["date"] = time.strftime("%Y-%m-%d")
    ablation_rows = None
    if ablations:
        teacher = evaluation.teacher
        ablation_rows = {}
        for name, info in ablations.items():
            pol = (
                policy
                if Path(info["run_dir"]) == checkpoint
                else StrategicPolicy.load(info["run_dir"])
            )
            sub = solver_eval.evaluate_solvers(
                pol, instances, planners={"transformer+2opt": {"two_opt": True}},
                progress=False, teacher=teacher,
            )  # fmt: skip
            row = sub.summary["planners"]["transformer+2opt"]
            ablation_rows[name] = {**info, **{k: row[k] for k in ("mean_reward", "mean_cost",
                                                                 "reward_ratio")}}  # fmt: skip
        result["ablations"] = ablation_rows
    compare_planners = preset_planners(preset, compare=True)
    if args.compare:
        result["compare"] = {str(checkpoint): result["planners"]}
        for other, other_policy in others.items():
            sub = solver_eval.evaluate_solvers(
                other_policy, instances, planners=compare_planners,
                progress=not args.no_progress, teacher=evaluation.teacher,
            )  # fmt: skip
            result["compare"][other] = sub.summary["planners"]
    out.mkdir(parents=True, exist_ok=True)
    _figures(policy, instances, evaluation, out)
    solver_eval.write_json(result, out / "solver_eval.json")
    header = (
        f"# Distillation results ({args.preset})\n\nHeld-out houses {lo}..{hi - 1}, "
        f"{n} instances, {result['machine']}, {result['date']}. Checkpoint: `{checkpoint}`."
    )
    text = solver_eval.write_tables(result, out / "tables.md", ablation_rows, header)
    if args.compare:
        text += solver_eval.compare_table(
            result["compare"], compare_planners, result["instance_houses"]
        )
        files.write_text(out / "tables.md", text)
        title = f"{args.preset}: {n} held-out instances of houses {lo}..{hi - 1}"
        plot_model_comparison(result["compare"], out / "compare.png", compare_planners, title)
    print(text)
    if preset.nav_houses > 0 and not args.no_navigation:
        result["navigation"] = stage_navigation(args, preset, out, policy, checkpoint)
        solver_eval.write_json(result, out / "solver_eval.json")  # with its navigation
    return result


def stage_navigation(args, preset: DistillPreset, out: Path, policy, checkpoint: Path) -> dict:
    """Table I on a reduced protocol with the trained planner; appended to ``tables.md``."""
    from bfsop_jax.config import get_preset
    from bfsop_jax.eval import navigation as nav
    from bfsop_jax.world.constants import TARGET_NAMES, target_id

    houses = nav.HouseSet(get_preset(preset.data.preset))
    ids = range(EVAL_SEED_START, EVAL_SEED_START + preset.nav_houses)
    cats = [target_id(c) for c in preset.nav_categories] or list(range(len(TARGET_NAMES)))
    episodes = nav.protocol_episodes(houses, ids, cats)
    nav_dir = out / "navigation"
    result = nav.evaluate_navigation(
        list(preset.nav_methods), episodes, houses, nav_dir, policy=policy,
        batch=len(episodes), progress=not args.no_progress,
        protocol={"checkpoint": str(checkpoint), "reduced": True},
    )  # fmt: skip
    nav.write_figures(result, nav_dir, houses)
    header = (
        f"\n## Table I: navigation, reduced protocol\n\n{len(episodes)} episodes: held-out "
        f"houses {ids.start}..{ids.stop - 1} x {len(cats)} categories (absent categories move "
        "to the next house), every method on the same episodes. The full protocol (9 x 10 "
        "houses) is `python -m experiments.evaluate`.\n"
    )
    text = nav.write_table1(result, nav_dir / "table1.md", header)
    tables = out / "tables.md"
    files.write_text(tables, (tables.read_text() if tables.is_file() else "") + text)
    print(text)
    return {"episodes": len(episodes), "methods": result["methods"]}


def stage_dagger(args, preset: DistillPreset, store, cfg: DataConfig, out: Path) -> list[dict]:
    """DAgger rounds from the trained run ``--checkpoint`` (default ``--out``).

    The student drives in the training houses of the training shards (validation houses
    stay out); every round is judged on held-out instances (reward ratio to the VNS of
    greedy + 2-opt and of multi-start + fill) and, unless ``--no-navigation``, by the PPL
    of BF-SOP (Transformer) on the reduced navigation protocol's held-out episodes. The
    rounds' models are never chosen on those figures: the last round is the result.
    """
    from bfsop_jax.config import get_preset
    from bfsop_jax.eval import navigation as nav
    from bfsop_jax.training.dagger import DaggerConfig, run_dagger
    from bfsop_jax.world.constants import TARGET_NAMES, target_id

    base = Path(args.checkpoint) if args.checkpoint else out
    if not (base / "model").is_dir():
        raise ValueError(f"--stage dagger needs a trained run in {base} (train it first)")
    dagger = DaggerConfig(
        rounds=args.rounds, epochs=args.dagger_epochs, houses_per_round=args.dagger_houses,
        categories_per_house=args.dagger_categories, lr=args.lr,
    )  # fmt: skip
    train_ds, val_ds = _split(store, cfg, preset.val_houses)
    n_val = _n_val_shards(cfg, preset.val_houses)
    train_houses = min(cfg.houses, (cfg.n_shards - n_val) * cfg.houses_per_shard)
    seeds = np.arange(cfg.seed_start, cfg.seed_start + train_houses)
    dagger_dir = out / "dagger"

    lo = EVAL_SEED_START
    if args.eval_seeds:
        rng = parse_seed_range(args.eval_seeds)
        lo, hi = rng.start, rng.stop
        if lo < EVAL_SEED_START:
            raise ValueError(f"--eval-seeds {lo}:{hi}: rounds are judged on held-out houses "
                             f"(>= {EVAL_SEED_START}), not on training houses")  # fmt: skip
    else:
        hi = lo + preset.eval_houses
    eval_cfg = dataclasses.replace(cfg, tasks_per_house=args.eval_tasks or preset.eval_tasks)
    instances, _ = pose_tasks(np.arange(lo, hi), eval_cfg, progress=not args.no_progress)
    teacher = solver_eval.evaluate_teacher(instances, progress=not args.no_progress)
    planners = {name: solver_eval.PLANNERS[name]
                for name in ("transformer+2opt", "transformer+2opt+multi_start+fill")}  # fmt: skip
    houses = nav.HouseSet(get_preset(cfg.preset))
    ids = range(EVAL_SEED_START, EVAL_SEED_START + preset.nav_houses)
    cats = [target_id(c) for c in preset.nav_categories] or list(range(len(TARGET_NAMES)))
    episodes = nav.protocol_episodes(houses, ids, cats)

    def evaluate(policy, r: int) -> dict[str, Any]:
        ev = solver_eval.evaluate_solvers(policy, instances, planners=planners, repeats=1,
                                          progress=False, teacher=teacher).summary  # fmt: skip
        row: dict[str, Any] = {
            f"reward_ratio[{name}]": ev["planners"][name]["reward_ratio"] for name in planners
        }
        row["reward_ratio[greedy_insertion]"] = (
            ev["planners"]["greedy_insertion"]["mean_reward"] / ev["planners"]["vns"]["mean_reward"]
        )
        if not args.no_navigation and preset.nav_houses > 0:
            res = nav.evaluate_navigation(
                ["bfsop_st"], episodes, houses, dagger_dir / f"navigation-{r:02d}", policy=policy,
                batch=len(episodes), progress=False,
            )  # fmt: skip
            m = res["methods"]["bfsop_st"]
            row.update(ppl=m["ppl_mean"], ppl_ci95=m["ppl_ci95"], episodes=m["episodes"])
        print(f"round {r}: " + ", ".join(f"{k} {v}" for k, v in row.items() if k != "ppl_ci95"))
        return row

    history = run_dagger(base, train_ds, val_ds, seeds, cfg, dagger_dir, dagger, evaluate,
                         progress=not args.no_progress)  # fmt: skip
    _dagger_report(history, dagger_dir)
    return history


def stage_rl(args, preset: DistillPreset, store, cfg: DataConfig, out: Path) -> list[dict]:
    """Reward fine-tuning of the trained run ``--checkpoint`` (default ``--out``) on the
    training records, into ``<out>/rl``; the validation houses' greedy reward picks the
    epoch (``rl.md``, ``rl.png``). Evaluate it with ``--stage eval --checkpoint <out>/rl``."""
    from bfsop_jax.files import write_text
    from bfsop_jax.training.rl import finetune_rl
    from bfsop_jax.viz import plot_rl

    base = Path(args.checkpoint) if args.checkpoint else out
    if not (base / "model").is_dir():
        raise ValueError(f"--stage rl needs a trained run in {base} (train it first)")
    rl = RLConfig(epochs=args.rl_epochs, lr=args.rl_lr, samples=args.rl_samples,
                  bc_weight=args.rl_bc_weight, baseline=args.rl_baseline)  # fmt: skip
    train_ds, val_ds = _split(store, cfg, preset.val_houses)
    train_ds, val_ds = _with_extra_data(args, train_ds, val_ds, {"data_dir": str(store.root)})
    if val_ds is None:
        raise ValueError("--stage rl needs validation houses (a dataset of several shards)")
    rl_dir = out / "rl"
    print(f"reward fine-tuning {base} ({rl.epochs} epochs) -> {rl_dir}")
    rows = finetune_rl(base, train_ds, val_ds, rl_dir, rl, progress=not args.no_progress)
    head = ("| epoch | validation greedy / teacher | training sampled / teacher | "
            "teacher cross-entropy | seconds | selected |")
    lines = [head, "|---|---|---|---|---|---|"]
    for r in rows:
        sample = f"{r['train_sample_ratio']:.3f}" if "train_sample_ratio" in r else "-"
        loss = f"{r['train_bc_loss']:.3f}" if "train_bc_loss" in r else "-"
        lines.append(f"| {r['epoch']} | {r['val_greedy_ratio']:.3f} | {sample} | {loss} | "
                     f"{r.get('seconds', '-')} | {'yes' if r['selected'] else ''} |")  # fmt: skip
    write_text(rl_dir / "rl.md", "\n".join(lines) + "\n")
    plot_rl(rows, rl_dir / "rl.png")
    print("\n".join(lines))
    return rows


def _dagger_report(history: list[dict[str, Any]], out: Path) -> None:
    """``dagger.md`` (one row per round) and ``dagger.png`` (reward ratio and PPL)."""
    from bfsop_jax.files import write_text
    from bfsop_jax.viz import plot_dagger

    keys = [k for k in history[0] if k.startswith("reward_ratio[")]
    has_ppl = "ppl" in history[0]
    head = ["round", "DAgger rows", "training rows", *[k[13:-1] for k in keys]]
    head += ["PPL [95% CI]"] if has_ppl else []
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in history:
        cells = [str(row["round"]), str(row["rows"]), str(row["aggregate"])]
        cells += [f"{row[k]:.3f}" for k in keys]
        if has_ppl:
            lo, hi = row["ppl_ci95"]
            cells.append(f"{row['ppl']:.3f} [{lo:.3f}, {hi:.3f}]")
        lines.append("| " + " | ".join(cells) + " |")
    write_text(out / "dagger.md", "\n".join(lines) + "\n")
    plot_dagger(history, out / "dagger.png")
    print("\n".join(lines))


def _figures(policy, instances, evaluation, out: Path) -> None:
    """The tour comparison and the distance-mass figures (the mass is added to the
    evaluation's summary)."""
    from bfsop_jax.sop import evaluate

    result = evaluation.summary
    vns_plans = [s.node_list() for s in evaluation.teacher[0]]
    model_plans = evaluation.plans["transformer+2opt"]
    # the instance where the teacher visits the most sets (a readable, non-trivial tour)
    i = int(np.argmax([len(p) for p in vns_plans]))
    inst = solver_eval.take(instances, i)
    plans = {}
    for name, nodes in (
        ("VNS teacher", vns_plans[i]),
        ("Transformer + 2-opt", [int(x) for x in model_plans[i] if x >= 0]),
    ):
        reward, cost, _ = evaluate(inst, nodes)
        plans[name] = (nodes, float(reward), float(cost))  # fmt: skip
    plot_tour_comparison(inst, plans, out / "tour_comparison.png")
    mass = solver_eval.decoder_distance_mass(policy, instances)
    result["distance_mass"] = {"all_steps": mass[0].tolist(), "first_step": mass[1].tolist()}
    plot_distance_mass(mass, out / "decoder_distance_mass.png")


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
    return summary


def _trained_ablations(run_dir: Path) -> dict[str, Any]:
    rows = {}
    for name, path in [("main", run_dir)] + [(n, run_dir / "ablations" / n) for n in ABLATIONS]:
        if not (path / "model").is_dir():
            continue
        rows[name] = {"run_dir": str(path), "val_loss": float("nan"), "val_acc": float("nan")}
        metrics = path / "metrics.jsonl"
        if metrics.exists():
            last = [json.loads(x) for x in metrics.read_text().splitlines() if x.strip()]
            if last:
                rows[name].update(
                    val_loss=last[-1].get("val_loss"), val_acc=last[-1].get("val_acc")
                )
    return rows


if __name__ == "__main__":
    try:
        main()
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(2) from None
