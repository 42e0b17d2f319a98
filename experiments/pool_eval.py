"""Pool solver evaluations of one model on disjoint ranges of held-out houses.

    python -m experiments.pool_eval RUN_A RUN_B [...] --out DIR

Each ``RUN`` is the output directory of ``python -m experiments.distill --stage eval``
(its ``solver_eval.json``), made with the same checkpoint and teacher configuration on
house ranges that do not overlap. Extending an evaluation to more houses this way narrows
the paired intervals without planning the old houses again. Writes ``DIR/solver_eval.json``
(the pooled summary, per-instance rewards included), ``DIR/tables.md`` (reward ratio,
paired difference to greedy insertion with its 95 % bootstrap interval, latency) and
``DIR/paired.png`` (each planner's paired difference in every run and in the pool).
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
from bfsop_jax.viz import plot_paired_differences

EVAL_FILE = "solver_eval.json"


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", help="evaluation directories (solver_eval.json)")
    parser.add_argument("--out", required=True, help="output directory")
    args = parser.parse_args(argv)
    results = []
    for run in args.runs:
        path = Path(run) / EVAL_FILE
        if not path.is_file():
            parser.error(f"no {EVAL_FILE} in {run}")
        results.append(json.loads(path.read_text()))
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
    text = header + solver_eval.compare_table({pooled["checkpoint"]: pooled["planners"]})
    write_text(out / "tables.md", text)
    names = [n for n in pooled["planners"] if n not in ("vns", "greedy_insertion")]
    groups = {
        f"houses {r['house_seeds'][0]}..{r['house_seeds'][1] - 1} ({r['instances']})": [
            solver_eval.paired_vs(r, n) for n in names
        ]
        for r in results
    }
    groups[f"pooled ({pooled['instances']})"] = [solver_eval.paired_vs(pooled, n) for n in names]
    title = f"{pooled['instances']} held-out instances, {len(results)} evaluations"
    plot_paired_differences(
        names, {k: np.asarray(v) for k, v in groups.items()}, out / "paired.png", title
    )
    print(text)
    return pooled


if __name__ == "__main__":
    main(sys.argv[1:])
