"""Hyper-parameter sweeps of the Strategic Transformer in as few compiled programs as possible.

    python -m experiments.sweep --preset demo --grid lr=3e-4,1e-3,3e-3 --grid seed=0,1,2 \\
        --grid layers=3,6 --epochs 30 --out runs/sweep-demo      # or --grid-file grid.toml

Every combination of the grid trains on the cached distillation dataset of the preset
(built first if missing, exactly as ``python -m experiments.distill`` builds it, in the
same ``--data-dir``) and is evaluated on the same held-out instances (tasks posed in
held-out houses, planned by the VNS teacher once): reward / VNS of greedy decoding +
2-opt + budget gate, and its latency.

Combinations that differ only in replica keys (seed, lr, grad_clip, lr_decay,
decay_every, warmup, label_smoothing, augment) train as replicas of one vmapped, jitted
program; each set of values of the shape-changing keys (layers, width, heads, ff,
geometric_bias, budget_aware, budget_mask, step_features, batch_size, epochs) is a group, compiled
once. With several devices the replicas (or the minibatches) are spread over all of them.

Outputs in ``--out``: ``runs/<combination>/`` (``config.json`` + ``model/``, loadable by
``StrategicPolicy.load``, and ``sweep_result.json``), ``groups/<group>/`` (the group's
training run: checkpoints, metrics), ``sweep.csv``, ``sweep.md`` (ranked by reward ratio)
and ``sweep.png`` (reward ratio against each swept key). An interrupted sweep resumes:
finished combinations are skipped, an interrupted group continues from its checkpoint.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import io
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
from bfsop_jax.data.generate import pose_tasks
from bfsop_jax.eval import solvers as solver_eval
from bfsop_jax.parallel import barrier, first_devices_mesh, initialize, is_primary, mesh_size
from bfsop_jax.policy import StrategicPolicy
from bfsop_jax.sop.types import Solution, plan_length
from bfsop_jax.training import train
from bfsop_jax.training.sweep import (
    GROUP_KEYS,
    Grid,
    Group,
    merge_grids,
    parse_grid_args,
    read_grid_file,
)
from experiments import distill

RESULT_FILE = "sweep_result.json"
PLANNER = "transformer+2opt"  # greedy decoding + 2-opt + budget gate, no sampling, no fill


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m experiments.sweep`` (options: docs/cli.md)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="demo", choices=sorted(distill.PRESETS))
    ap.add_argument("--grid", action="append", default=[], metavar="KEY=V1,V2,...")
    ap.add_argument("--grid-file", default=None, help="TOML file with a [grid] table of lists")
    ap.add_argument("--epochs", type=int, default=None, help="epochs of every combination")
    ap.add_argument("--out", default=None, help="sweep directory (default runs/sweep-<preset>)")
    ap.add_argument("--data-dir", default=None, help="dataset cache (default: distill's)")
    ap.add_argument("--houses", type=int, default=None, help="override: training houses")
    ap.add_argument("--tasks", type=int, default=None, help="override: virtual tasks per house")
    ap.add_argument("--eval-seeds", default=None, help="held-out house seeds START:END")
    ap.add_argument("--eval-tasks", type=int, default=None, help="tasks per held-out house")
    ap.add_argument("--devices", type=int, default=None, help="first N devices (default all)")
    ap.add_argument("--no-progress", action="store_true")
    return ap


def _parse(argv: list[str] | None) -> argparse.Namespace:
    return build_parser().parse_args(argv)


def _grid(args, base) -> Grid:
    parts = []
    if args.grid_file:
        parts.append(read_grid_file(args.grid_file, base))
    if args.grid:
        parts.append(parse_grid_args(args.grid, base))
    if not parts:
        raise ValueError("no grid: give --grid KEY=V1,V2 (repeatable) or --grid-file FILE")
    return merge_grids(*parts, base=base)


def _atomic_json(obj: Any, path: Path) -> None:
    if is_primary():  # one writer in a multi-host run
        files.write_json(path, obj)


# -- held-out instances and their teacher plans (cached) --------------------------------------
def _eval_set(args, preset: distill.DistillPreset, out: Path, progress: bool):
    """Held-out instances and the VNS plans of them, cached in ``out/eval_set.npz``."""
    if args.eval_seeds:
        seeds = parse_seed_range(args.eval_seeds)
        if seeds.start < EVAL_SEED_START:
            raise ValueError(f"--eval-seeds must be held-out houses (>= {EVAL_SEED_START})")
    else:
        seeds = range(EVAL_SEED_START, EVAL_SEED_START + preset.eval_houses)
    tasks = args.eval_tasks or preset.eval_tasks
    key = {"seeds": [seeds.start, seeds.stop], "tasks": tasks, "data": preset.data.preset}
    path = out / "eval_set.npz"
    if path.exists():
        with np.load(path) as z:
            if json.loads(str(z["key"])) == key:
                arrays = {k: z[k] for k in z.files}
                return _unpack_eval(arrays), key
        raise ValueError(f"{path} holds another evaluation set; use a new --out")
    cfg = dataclasses.replace(preset.data, tasks_per_house=tasks)
    instances, _ = pose_tasks(np.arange(seeds.start, seeds.stop), cfg, progress=progress)
    teacher = solver_eval.evaluate_teacher(instances, progress=progress)
    k = int(np.shape(instances.set_reward)[-1])
    arrays = {f"inst_{k}": np.asarray(v) for k, v in dataclasses.asdict(instances).items()}
    arrays.update(
        vns_nodes=np.stack([s.padded(plan_length(k)).nodes for s in teacher[0]]),
        vns_reward=np.asarray([float(s.reward) for s in teacher[0]], np.float32),
        vns_cost=np.asarray([float(s.cost) for s in teacher[0]], np.float32),
        vns_ms=np.asarray(teacher[1], np.float64),
        key=np.asarray(json.dumps(key)),
    )
    files.atomic_write(path, lambda f: np.savez(f, **arrays), mode="wb")
    return (instances, teacher), key


def _unpack_eval(arrays: dict[str, np.ndarray]):
    from bfsop_jax.sop.types import SOPInstance

    inst = SOPInstance(**{k[5:]: v for k, v in arrays.items() if k.startswith("inst_")})
    sols = [
        Solution(nodes=n, reward=np.float32(r), cost=np.float32(c))
        for n, r, c in zip(arrays["vns_nodes"], arrays["vns_reward"], arrays["vns_cost"],
                           strict=True)
    ]  # fmt: skip
    return inst, (sols, [float(x) for x in arrays["vns_ms"]])


# -- training and evaluating one group --------------------------------------------------------
def _last_rows(group_dir: Path) -> dict[int, dict[str, Any]]:
    """The last epoch's metric row of every replica of a group's run."""
    path = group_dir / "metrics.jsonl"
    rows: dict[int, dict[str, Any]] = {}
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                row = json.loads(line)
            except json.JSONDecodeError:
                continue
            rows[row["replica"]] = row  # later epochs overwrite earlier ones
    return rows


def _num_params(policy: StrategicPolicy) -> int:
    return int(sum(np.size(x) for x in jax.tree_util.tree_leaves(policy._params)))


def run_group(
    group: Group, base, data, meta: dict[str, Any], out: Path, evaluation, mesh, progress: bool
) -> list[dict[str, Any]]:
    """Train one group (one program, unless already trained) and evaluate its members."""
    run_dirs = [out / "runs" / c.name for c in group.members]
    results = [_read_result(d) for d in run_dirs]
    if all(r is not None for r in results):
        return results
    config = group.members[0].run_config(base)
    replicas = [c.replica(config, default_lr=base_lr(meta)) for c in group.members]
    group_dir = out / "groups" / group.name
    if not all((d / "model").is_dir() for d in run_dirs):
        resume = (group_dir / "checkpoints").is_dir()
        print(f"group {group.name}: {len(replicas)} replicas, {config.train.epochs} epochs")
        t0 = time.perf_counter()
        train(
            config, data[0], data[1], group_dir, replicas=replicas, replica_dirs=run_dirs,
            resume=resume, progress=progress, dataset_meta=meta, mesh=mesh,
        )  # fmt: skip
        print(f"  trained in {time.perf_counter() - t0:.0f} s")
    if not is_primary():  # process 0 evaluates and writes the results
        barrier(f"sweep:evaluated:{group.name}")
        return []
    rows = _last_rows(group_dir)
    instances, teacher = evaluation
    for i, (combo, run_dir) in enumerate(zip(group.members, run_dirs, strict=True)):
        if results[i] is not None:
            continue
        policy = StrategicPolicy.load(run_dir)
        res = solver_eval.evaluate_solvers(
            policy, instances, planners={PLANNER: {"two_opt": True}}, progress=False,
            teacher=teacher,
        ).summary  # fmt: skip
        row = res["planners"][PLANNER]
        last = rows.get(i, {})
        results[i] = {
            "name": combo.name,
            "settings": combo.settings,
            "group": group.name,
            "run_dir": str(run_dir),
            "reward_ratio": row["reward_ratio"],
            "greedy_insertion_ratio": res["planners"]["greedy_insertion"]["mean_reward"]
            / max(res["planners"]["vns"]["mean_reward"], 1e-12),
            "latency_ms_single": row["latency_ms_single"],
            "latency_ms_batched": row["latency_ms_batched"],
            "speedup": row["speedup"],
            "val_loss": last.get("val_loss"),
            "val_acc": last.get("val_acc"),
            "train_loss": last.get("train_loss"),
            "epochs": config.train.epochs,
            "params": _num_params(policy),
            "instances": res["instances"],
        }
        _atomic_json(results[i], run_dir / RESULT_FILE)
    barrier(f"sweep:evaluated:{group.name}")
    return results


def base_lr(meta: dict[str, Any]) -> float:
    return float(meta["default_lr"])


def _read_result(run_dir: Path) -> dict[str, Any] | None:
    path = run_dir / RESULT_FILE
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError:
        return None


# -- outputs -----------------------------------------------------------------------------------
COLUMNS = (
    "rank", "name", "reward_ratio", "val_loss", "val_acc", "latency_ms_single",
    "latency_ms_batched", "params", "group",
)  # fmt: skip


def _ranked(results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    order = sorted(results, key=lambda r: (-r["reward_ratio"], r["val_loss"] or np.inf))
    return [{**r, "rank": i + 1} for i, r in enumerate(order)]


def write_outputs(results: list[dict[str, Any]], grid: Grid, out: Path, header: str) -> str:
    """``sweep.csv``, ``sweep.md`` and ``sweep.png``; returns the markdown text."""
    ranked = _ranked(results)
    keys = list(grid)
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow([*COLUMNS, *keys])
    for r in ranked:
        writer.writerow([r[c] for c in COLUMNS] + [r["settings"][k] for k in keys])
    files.write_text(out / "sweep.csv", buf.getvalue())

    def f(x, digits=3):
        return "-" if x is None else f"{x:.{digits}f}"

    lines = [header.rstrip(), ""]
    lines += [
        "| rank | " + " | ".join(keys) + " | reward / VNS | val loss | val acc "
        "| latency single (ms) | latency batched (ms/inst) | parameters |",
        "|---" * (len(keys) + 7) + "|",
    ]
    for r in ranked:
        cells = [str(r["rank"]), *(str(r["settings"][k]) for k in keys)]
        cells += [
            f(r["reward_ratio"]),
            f(r["val_loss"]),
            f(r["val_acc"]),
            f(r["latency_ms_single"], 2),
            f(r["latency_ms_batched"], 3),
            f"{r['params']:,}",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    greedy = ranked[0]["greedy_insertion_ratio"] if ranked else None
    lines += ["", f"Greedy insertion on the same instances: {f(greedy)} of the VNS."]
    text = "\n".join(lines) + "\n"
    files.write_text(out / "sweep.md", text)
    from bfsop_jax.viz import plot_sweep

    plot_sweep(ranked, grid, out / "sweep.png", reference=greedy)
    return text


# -- the program ---------------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> dict[str, Any]:
    initialize()  # joins a multi-host run when BFSOP_COORDINATOR is set (docs/scale-out.md)
    args = _parse(argv)
    preset = distill.PRESETS[args.preset]
    if args.epochs is not None and args.epochs < 1:
        raise ValueError(f"--epochs must be >= 1, got {args.epochs}")
    base = distill._run_config(preset, preset.data, args.epochs)
    grid = _grid(args, base)  # every grid error comes before any work
    if "epochs" in grid and args.epochs is not None:
        raise ValueError("grid key 'epochs' and --epochs both set the run length; give one")
    mesh = first_devices_mesh(args.devices)
    out = Path(args.out or f"runs/sweep-{args.preset}")
    data_dir = Path(args.data_dir or f"data/distill-{args.preset}")
    out.mkdir(parents=True, exist_ok=True)
    progress = not args.no_progress
    # what every combination shares: a finished combination is reused only under the same
    # (the grid itself may grow: its new combinations train, the old ones are kept)
    fixed = {"preset": args.preset, "epochs": args.epochs, "houses": args.houses,
             "tasks": args.tasks, "data_dir": str(data_dir)}  # fmt: skip
    plan_path = out / "sweep.json"
    if plan_path.exists():
        before = json.loads(plan_path.read_text())
        differ = [k for k in fixed if k in before and before[k] != fixed[k]]
        if differ:
            was = ", ".join(f"--{k.replace('_', '-')} {before[k]}, now {fixed[k]}" for k in differ)
            raise ValueError(f"{out} holds a sweep with other fixed settings ({was}); use a new "
                             "--out")  # fmt: skip
    _atomic_json({**fixed, "grid": grid}, plan_path)

    t0 = time.perf_counter()
    data_args = argparse.Namespace(houses=args.houses, tasks=args.tasks, stage="train",
                                   no_progress=args.no_progress)  # fmt: skip
    if is_primary():
        store, cfg = distill.stage_data(data_args, preset, data_dir)
    barrier("sweep:data")
    if not is_primary():
        store, cfg = distill.stage_data(data_args, preset, data_dir)
    train_ds, val_ds = distill._split(store, cfg, preset.val_houses)
    meta = {"data_dir": str(store.root), "data_config": dataclasses.asdict(cfg),
            "default_lr": preset.lrs[0]}  # fmt: skip
    if is_primary():  # process 0 builds the caches, the others then read them
        evaluation, eval_key = _eval_set(args, preset, out, progress)
    barrier("sweep:eval-set")
    if not is_primary():
        evaluation, eval_key = _eval_set(args, preset, out, progress)
    from bfsop_jax.training.sweep import groups as grid_groups

    all_groups = grid_groups(grid)
    n_combos = sum(len(g.members) for g in all_groups)
    devices = 1 if mesh is None else mesh_size(mesh)
    print(f"sweep: {n_combos} combinations in {len(all_groups)} compiled groups on "
          f"{devices} device(s)")  # fmt: skip
    results = []
    for group in all_groups:
        results += run_group(group, base, (train_ds, val_ds), meta, out, evaluation, mesh,
                             progress)  # fmt: skip
    n_eval = int(np.shape(evaluation[0].set_id)[0])
    header = (
        f"# Sweep ({args.preset})\n\n{n_combos} combinations in {len(all_groups)} compiled "
        f"groups; training data {store.root} ({len(train_ds['set_id'])} instances), "
        f"{n_eval} held-out instances from houses {eval_key['seeds'][0]}.."
        f"{eval_key['seeds'][1] - 1}; planner: greedy decoding + 2-opt + budget gate. "
        f"{platform.machine()}, {os.cpu_count()} CPU cores, {jax.default_backend()}, "
        f"{time.strftime('%Y-%m-%d')}. Fixed across the grid: "
        + ", ".join(f"{k}={v}" for k, v in _fixed(base).items() if k not in grid)
        + "."
    )
    if not is_primary():
        return {"results": [], "groups": [g.name for g in all_groups]}
    text = write_outputs(results, grid, out, header)
    print(text)
    print(f"done in {time.perf_counter() - t0:.0f} s; outputs in {out}")
    return {"results": results, "groups": [g.name for g in all_groups]}


def _fixed(base) -> dict[str, Any]:
    values = {k: getattr(base.model if part == "model" else base.train, field)
              for k, (_, part, field) in GROUP_KEYS.items()}  # fmt: skip
    return values


if __name__ == "__main__":
    try:
        main()
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(2) from None
