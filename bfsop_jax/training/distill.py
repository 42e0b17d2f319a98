"""The distillation pipeline behind ``python -m experiments.distill``: presets and stages.

:class:`DistillPreset` and :data:`PRESETS` size a run (data, model, evaluation);
:data:`ABLATIONS` are the model variants ``--ablations`` trains, :data:`COMPARE_PLANNERS`
the planners ``--compare`` runs. The stages here take the parsed command line (``args``,
the options of :mod:`experiments.distill`): :func:`stage_data` generates or merges the
teacher-labelled dataset, :func:`stage_train` trains the model (and the ablations; a model
kept in its run directory must have been trained as this call would), :func:`stage_dagger`
runs DAgger rounds and :func:`stage_rl` the reward fine-tuning. The evaluation stage is
:mod:`bfsop_jax.eval.distill`'s.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

import numpy as np

from bfsop_jax.config import EVAL_SEED_START, parse_seed_range
from bfsop_jax.data.generate import DataConfig, generate_dataset, pose_tasks
from bfsop_jax.data.shards import ShardStore, merge_datasets
from bfsop_jax.eval import solvers as solver_eval
from bfsop_jax.policy import StrategicPolicy
from bfsop_jax.training.bc import evaluate_imitation, train
from bfsop_jax.training.config import RunConfig
from bfsop_jax.training.rl import RLConfig

__all__ = [
    "ABLATIONS",
    "COMPARE_PLANNERS",
    "PRESETS",
    "DistillPreset",
    "stage_dagger",
    "stage_data",
    "stage_rl",
    "stage_train",
]


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
