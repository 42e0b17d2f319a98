"""Pool solver evaluations of one model on disjoint ranges of held-out houses.

    python -m experiments.pool_eval RUN_A RUN_B [...] --out DIR

Each ``RUN`` is the output directory of ``python -m experiments.distill --stage eval``
(its ``solver_eval.json``), made with the same checkpoint and teacher configuration on
house ranges that do not overlap. Extending an evaluation to more houses this way narrows
the paired intervals without planning the old houses again. Writes ``DIR/solver_eval.json``
(the pooled summary, per-instance rewards included), ``DIR/tables.md`` (reward ratio,
paired difference to greedy insertion with its 95 % bootstrap interval, latency) and
``DIR/paired.png`` (each planner's paired difference in every run and in the pool).

When every run records the house of each instance (runs made since it is recorded, or
with ``--recover-houses``), the pooled table and figure add the paired interval over
houses: whole houses resampled, the interval for other houses rather than for other tasks
in the same houses. ``--recover-houses`` re-poses an older run's tasks (exploration runs
only, no planning), checks that greedy insertion's reward on them equals the recorded one
instance for instance, and adds the houses to that run's ``solver_eval.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from bfsop_jax.eval import solvers as solver_eval
from bfsop_jax.files import write_text
from bfsop_jax.sop import solve_greedy
from bfsop_jax.viz import plot_paired_differences
from experiments import distill

EVAL_FILE = "solver_eval.json"


def recover_houses(
    result: dict[str, Any], progress: bool = True, preset: str | None = None
) -> list[int]:
    """The house seed of each instance ``[I]`` of an evaluation that did not record them.

    Re-poses its tasks (same preset, houses and tasks per house; deterministic) and checks
    that they are the evaluated instances: same count, and greedy insertion (deterministic)
    reaches the recorded reward on every one. ``preset`` names the preset of a run made
    before evaluations recorded it.

    Raises:
        ValueError: no preset recorded or given, or the re-posed instances differ.
    """
    name = result.get("preset", preset)
    if name is None:
        raise ValueError("an evaluation without its preset: pass --preset to re-pose its tasks")
    if name not in distill.PRESETS:
        raise ValueError(f"unknown preset {name!r}; presets are {', '.join(distill.PRESETS)}")
    config = distill.PRESETS[name]
    seeds = result.get("house_seeds")
    if not (isinstance(seeds, list) and len(seeds) == 2 and all(isinstance(x, int) for x in seeds)):
        raise ValueError(f"house_seeds must be one range [lo, hi] to re-pose tasks, got {seeds!r}")
    lo, hi = seeds
    rewards = result.get("planners", {}).get("greedy_insertion", {}).get("rewards")
    if rewards is None or "instances" not in result:
        raise ValueError("no per-instance greedy insertion rewards to check re-posed tasks on")
    tasks = result.get("tasks_per_house", config.eval_tasks)
    instances, owners = distill.eval_instances(config, lo, hi, tasks, progress=progress)
    if owners.shape[0] != result["instances"]:
        raise ValueError(
            f"re-posed {owners.shape[0]} instances of houses {lo}..{hi - 1}, the evaluation "
            f"has {result['instances']}: not the same tasks"
        )
    recorded = np.asarray(rewards)
    replanned = np.asarray(
        [float(solve_greedy(solver_eval.take(instances, i)).reward) for i in range(owners.shape[0])]
    )
    bad = np.flatnonzero(np.abs(replanned - recorded) > 1e-5)
    if bad.size:
        raise ValueError(
            f"greedy insertion differs on {bad.size} re-posed instances (first: {bad[0]}): "
            "not the same tasks"
        )
    return [int(h) for h in owners]


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m experiments.pool_eval`` (options: docs/cli.md)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", help="evaluation directories (solver_eval.json)")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument(
        "--recover-houses",
        action="store_true",
        help="re-pose the tasks of runs that lack per-instance houses (checked against their "
        "greedy insertion rewards) and add the houses to their solver_eval.json",
    )
    parser.add_argument(
        "--preset",
        choices=sorted(distill.PRESETS),
        help="with --recover-houses: the preset of runs that do not record theirs",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    return parser


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = build_parser()
    args = parser.parse_args(argv)
    results = []
    for run in args.runs:
        path = Path(run) / EVAL_FILE
        if not path.is_file():
            parser.error(f"no {EVAL_FILE} in {run}")
        results.append(json.loads(path.read_text()))
    for run, result in zip(args.runs, results, strict=True):
        if args.recover_houses and "instance_houses" not in result:
            try:
                result["instance_houses"] = recover_houses(
                    result, not args.no_progress, args.preset
                )
                result.setdefault("preset", args.preset)
            except ValueError as err:
                parser.error(f"{run}: {err}")
            solver_eval.write_json(result, Path(run) / EVAL_FILE)
            print(f"{run}: per-instance houses recovered and recorded")
    try:
        pooled = solver_eval.pool_summaries(results)
    except ValueError as err:
        parser.error(str(err))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    pooled["runs"] = [str(r) for r in args.runs]
    solver_eval.write_json(pooled, out / EVAL_FILE)
    ranges = ", ".join(f"{lo}..{hi - 1}" for lo, hi in pooled["house_seeds"])
    header = (
        f"# Pooled solver evaluation\n\n{pooled['instances']} held-out instances of houses "
        f"{ranges} ({len(results)} runs). Checkpoint: `{pooled['checkpoint']}`. Latency: "
        "instance-weighted mean of the runs' medians.\n"
    )
    houses = pooled.get("instance_houses")
    if houses is not None and len(set(houses)) < 2:
        houses = None
        header += "One house: intervals over instances only.\n"
    elif houses is None:
        header += "No per-instance houses in every run: intervals over instances only.\n"
    else:
        header += (
            f"{len(set(houses))} houses; 'CI over houses' resamples whole houses (the "
            "interval for other houses).\n"
        )
    text = header + solver_eval.compare_table(
        {pooled["checkpoint"]: pooled["planners"]}, instance_houses=houses
    )
    write_text(out / "tables.md", text)
    names = [n for n in pooled["planners"] if n not in ("vns", "greedy_insertion")]
    groups = {
        f"houses {r['house_seeds'][0]}..{r['house_seeds'][1] - 1} ({r['instances']})": [
            solver_eval.paired_vs(r, n) for n in names
        ]
        for r in results
    }
    groups[f"pooled ({pooled['instances']})"] = [solver_eval.paired_vs(pooled, n) for n in names]
    if houses is not None:
        groups[f"pooled, houses resampled ({len(set(houses))})"] = [
            solver_eval.paired_vs(pooled, n, by_house=True) for n in names
        ]
    title = f"{pooled['instances']} held-out instances, {len(results)} evaluations"
    plot_paired_differences(
        names, {k: np.asarray(v) for k, v in groups.items()}, out / "paired.png", title
    )
    print(text)
    return pooled


if __name__ == "__main__":
    main(sys.argv[1:])
