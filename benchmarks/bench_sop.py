"""SOP solver benchmark: VNS teacher quality and speed, exact solver, 2-opt latency.

Sections (each can be limited or skipped):

1. the Set-2 instances with proven optima: share of optima reached by the VNS, mean gap,
   time; optionally the exact solver on the same files (``--exact``);
2. the Set-2 literature instances (omega 0.4/0.6/0.8) with at most ``--max-sets`` sets:
   mean gap to the best known reward, VNS time next to the published VNS-SOP time;
3. random navigation-like instances (15 sets x 5 viewpoints, open path, about half the
   sets fit): VNS time and optimality against the exact solver, then the latency of the
   JAX 2-opt + budget gate for batches of 1 and 64 (compilation timed apart);
4. small random instances (6-10 sets): how often the VNS finds the exact optimum.

The benchmark data (``sop/`` of the developers' shared folder) is looked up in
``$BFSOP_SHARED/sop`` or ``../shared/sop`` next to the repository; pass ``--sop-dir``
otherwise. Run: ``python benchmarks/bench_sop.py --optima 150 --best-known 40``.
"""

from __future__ import annotations

import argparse
import csv
import os
import platform
import re
import statistics
import time
from pathlib import Path

import jax
import numpy as np
from tqdm import tqdm

from benchmarks.cli import count, positive_float, positive_int, run_main
from bfsop_jax.sop import (
    Solution,
    budget_gate,
    evaluate,
    plan_length,
    read_sop,
    solve_exact,
    solve_greedy,
    solve_vns,
    two_opt,
)
from bfsop_jax.sop.io import random_instance

REPO = Path(__file__).resolve().parents[1]


def _sop_dir(arg: str | None) -> Path | None:
    if arg:
        return Path(arg)
    root = Path(os.environ.get("BFSOP_SHARED", REPO.parent / "shared"))
    path = root / "sop"
    return path if path.exists() else None


def _timed(fn, *args, **kwargs):
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0, time.process_time() - c0


def _gap(reward: float, best: float) -> float:
    return 0.0 if best <= 0 else 100.0 * (best - reward) / best


def bench_optima(sop: Path, limit: int, exact: bool, exact_max_sets: int, vns_kwargs) -> None:
    rows = list(csv.DictReader((sop / "exact_optima_set2.csv").open()))[:limit]
    hits, gaps, wall, cpu = 0, [], [], []
    misses = []
    ex_ok, ex_n, ex_time = 0, 0, []
    for row in tqdm(rows, desc="proven optima", unit="inst"):
        inst = read_sop(sop / "instances" / row["file"])
        best = float(row["optimal_reward"])
        sol, w, c = _timed(solve_vns, inst, seed=0, **vns_kwargs)
        reward = float(sol.reward)
        hits += abs(reward - best) < 1e-6
        if abs(reward - best) >= 1e-6:
            misses.append(f"{row['file']} {reward:g}/{best:g}")
        gaps.append(_gap(reward, best))
        wall.append(w)
        cpu.append(c)
        if exact and inst.num_sets - 1 <= exact_max_sets:
            ex, w, _ = _timed(solve_exact, inst, reference=sol, min_cost=False)
            ex_n += 1
            ex_ok += float(ex.reward) == best
            ex_time.append(w)
    n = len(rows)
    print(f"\n[1] proven optima (Set 2, <= 22 sets): {n} instances")
    print(f"    VNS reaches the optimum on {hits}/{n} = {100 * hits / max(n, 1):.1f}%")
    print(f"    mean gap {statistics.fmean(gaps):.3f}%, max gap {max(gaps):.2f}%")
    print(
        f"    VNS time per instance: mean {statistics.fmean(wall):.2f} s wall "
        f"({statistics.fmean(cpu):.2f} s CPU), median {statistics.median(wall):.2f} s"
    )
    if misses:
        print("    missed: " + "; ".join(misses))
    if exact:
        print(
            f"    exact solver (<= {exact_max_sets} sets, VNS reference, reward only): "
            f"{ex_ok}/{ex_n} optima reproduced, mean {statistics.fmean(ex_time or [0]):.2f} s, "
            f"max {max(ex_time or [0]):.2f} s"
        )


def bench_best_known(sop: Path, limit: int, max_sets: int, vns_kwargs) -> None:
    rows = list(csv.DictReader((sop / "best_known_set2.csv").open()))
    # the leading number of an instance name is its count of sets (start set excluded)
    rows = [r for r in rows if int(re.match(r"\d+", r["instance"]).group()) <= max_sets]
    rows = rows[:: max(1, len(rows) // max(limit, 1))][:limit]  # spread over sizes and budgets
    gaps, pub_gaps, wall, cpu, pub = [], [], [], [], []
    for row in tqdm(rows, desc="best known", unit="inst"):
        inst = read_sop(sop / "instances" / row["file"])
        sol, w, c = _timed(solve_vns, inst, seed=0, **vns_kwargs)
        best = float(row["best_known"])
        gaps.append(_gap(float(sol.reward), best))
        pub_gaps.append(_gap(float(row["vns_sop_avg"]), best))
        wall.append(w)
        cpu.append(c)
        pub.append(float(row["vns_sop_time_s"]))
    n = len(rows)
    print(f"\n[2] literature instances (Set 2, omega 0.4-0.8, <= {max_sets} sets): {n} instances")
    print(
        f"    mean gap to best known: VNS {statistics.fmean(gaps):.3f}% "
        f"(published VNS-SOP average run: {statistics.fmean(pub_gaps):.3f}%)"
    )
    print(
        f"    time per instance: mean {statistics.fmean(wall):.2f} s wall "
        f"({statistics.fmean(cpu):.2f} s CPU) vs published {statistics.fmean(pub):.2f} s (C++)"
    )


def bench_random(count: int, vns_kwargs, repeats: int) -> None:
    insts = [random_instance(1000 + s) for s in range(count)]
    wall, cpu, hits, visited = [], [], 0, []
    plans = []
    for inst in tqdm(insts, desc="navigation-like", unit="inst"):
        sol, w, c = _timed(solve_vns, inst, seed=0, **vns_kwargs)
        best = solve_exact(inst, reference=sol)
        hits += abs(float(sol.reward) - float(best.reward)) <= 1e-6
        wall.append(w)
        cpu.append(c)
        visited.append(len(sol.node_list()) - 1)
        plans.append(sol)
    print(f"\n[3] random navigation-like instances (15 sets x 5 viewpoints, open): {count}")
    print(f"    sets visited: mean {statistics.fmean(visited):.1f} of 15")
    print(
        f"    VNS time: median {statistics.median(wall):.2f} s wall "
        f"({statistics.median(cpu):.2f} s CPU), max {max(wall):.2f} s"
    )
    print(f"    VNS reaches the exact optimum on {hits}/{count}")
    _bench_two_opt(insts, repeats)


def bench_small(count: int, vns_kwargs) -> None:
    """VNS against the exact optimum on small random instances (6-10 sets, open/closed)."""
    rng = np.random.default_rng(7)
    hits, gaps, closed_hits, closed_n = 0, [], 0, 0
    for s in tqdm(range(count), desc="small random", unit="inst"):
        closed = s % 2 == 1
        inst = random_instance(
            5000 + s,
            num_sets=int(rng.integers(6, 11)),
            viewpoints=int(rng.integers(2, 5)),
            closed=closed,
            budget_scale=float(rng.uniform(0.2, 0.6)),
        )
        sol = solve_vns(inst, seed=s, **vns_kwargs)
        best = float(solve_exact(inst, reference=sol).reward)
        hit = abs(float(sol.reward) - best) <= 1e-6
        hits += hit
        closed_hits += hit and closed
        closed_n += closed
        gaps.append(_gap(float(sol.reward), best))
    print(f"\n[4] small random instances (6-10 sets x 2-4 viewpoints, half closed): {count}")
    print(
        f"    VNS equals the exact optimum on {hits}/{count} = {100 * hits / count:.1f}% "
        f"(closed tours {closed_hits}/{closed_n}); mean gap {statistics.fmean(gaps):.3f}%, "
        f"max {max(gaps):.2f}%"
    )


def _scrambled(inst, rng) -> tuple[np.ndarray, float]:
    """Greedy plan with its visiting order shuffled: something for 2-opt to repair."""
    nodes = solve_greedy(inst).node_list()
    inner = nodes[1:]
    rng.shuffle(inner)
    padded = np.full(plan_length(inst.num_sets), -1, np.int32)
    padded[: len(nodes)] = [nodes[0]] + inner
    return padded


def _bench_two_opt(insts, repeats: int) -> None:
    rng = np.random.default_rng(0)
    print("    JAX 2-opt + budget gate (max_iters=100) on shuffled greedy plans:")

    @jax.jit
    def refine(inst, plan):
        return budget_gate(inst, two_opt(inst, plan))

    for batch in (1, 64):
        chosen = [insts[i % len(insts)] for i in range(batch)]
        stacked = jax.tree_util.tree_map(lambda *x: np.stack(x), *chosen)
        nodes = np.stack([_scrambled(i, rng) for i in chosen])
        zeros = np.zeros(batch, np.float32)
        plan = Solution(nodes=nodes, reward=zeros, cost=zeros)
        stacked, plan = jax.device_put((stacked, plan))
        t0 = time.perf_counter()
        out = jax.block_until_ready(refine(stacked, plan))
        compile_s = time.perf_counter() - t0
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            out = jax.block_until_ready(refine(stacked, plan))
            times.append(time.perf_counter() - t0)
        before = np.array([evaluate(i, n)[1] for i, n in zip(chosen, nodes, strict=True)])
        after = np.array([evaluate(i, n)[1] for i, n in zip(chosen, out.nodes, strict=True)])
        print(
            f"      batch {batch:3d}: first call (compile) {compile_s:.2f} s, then median "
            f"{1e3 * statistics.median(times):.2f} ms per batch "
            f"({1e3 * statistics.median(times) / batch:.3f} ms per plan); "
            f"mean cost {before.mean():.1f} -> {after.mean():.1f}"
        )


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m benchmarks.bench_sop`` (options: docs/cli.md)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sop-dir", help="folder with instances/ and the two CSV files")
    parser.add_argument("--optima", type=count, default=150, help="proven optima (0: skip)")
    parser.add_argument("--exact", action="store_true", help="also run the exact solver there")
    parser.add_argument("--exact-max-sets", type=positive_int, default=16)
    parser.add_argument("--best-known", type=count, default=40, help="literature instances")
    parser.add_argument("--max-sets", type=positive_int, default=50)
    parser.add_argument("--random", type=count, default=20, help="navigation-like instances")
    parser.add_argument("--small", type=count, default=100, help="small instances vs exact")
    parser.add_argument("--repeats", type=positive_int, default=20, help="timing repeats for 2-opt")
    parser.add_argument(
        "--time-limit", type=positive_float, default=None, help="VNS seconds per instance"
    )
    return parser


def main() -> None:
    args = build_parser().parse_args()
    vns_kwargs = {"time_limit": args.time_limit}
    print(
        f"bfsop_jax SOP benchmark, {time.strftime('%Y-%m-%d %H:%M')}, "
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPU cores, "
        f"jax {jax.__version__} on {jax.default_backend()}"
    )
    sop = _sop_dir(args.sop_dir)
    if sop is None and (args.optima or args.best_known):
        print("benchmark data not found: skipping sections 1 and 2 (see --sop-dir)")
    if sop is not None and args.optima:
        bench_optima(sop, args.optima, args.exact, args.exact_max_sets, vns_kwargs)
    if sop is not None and args.best_known:
        bench_best_known(sop, args.best_known, args.max_sets, vns_kwargs)
    if args.random:
        bench_random(args.random, vns_kwargs, args.repeats)
    if args.small:
        bench_small(args.small, vns_kwargs)


if __name__ == "__main__":
    run_main(main)
