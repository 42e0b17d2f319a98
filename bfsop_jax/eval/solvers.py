"""Solver evaluation: the distilled planner against the VNS teacher (Tables II/III;
docs/design.md §9).

Every planner plans the same held-out instances in one run, so the ratios are measured
side by side:

* the VNS teacher (:func:`bfsop_jax.sop.solve_vns`, reference configuration unless told
  otherwise), one instance at a time on the host;
* the greedy-insertion start of the VNS (context: what a one-pass heuristic reaches);
* the Strategic Transformer through :class:`~bfsop_jax.policy.StrategicPolicy`: greedy
  decoding without and with the bounded 2-opt (Table III), and each quality extra
  (coordinate symmetries, best of k samples) reported apart.

Latency is wall-clock per instance after compilation: *single* is the median over calls
with one instance each (``block_until_ready`` included); *batched* is the time of a batch
of ``batch_size`` instances divided by its size. The speedup is the VNS single latency over
the planner's single latency (medians).

:func:`decoder_distance_mass` measures where the decoder's probability goes: the nodes
allowed at a step are ranked by their cost from the current node and cut into five
distance quintiles; the node probability mass (END excluded, renormalised) that falls in
each quintile is averaged over all steps, and over the first step alone.
"""

from __future__ import annotations

import dataclasses
import json
import os
import statistics
import time
from typing import Any

import jax
import numpy as np
from tqdm import tqdm

from bfsop_jax import files
from bfsop_jax.metrics import paired_bootstrap_ci
from bfsop_jax.sop import Solution, SOPInstance, solve_greedy, solve_vns
from bfsop_jax.viz import plot_distance_mass, plot_tour_comparison  # re-exported: drawn in viz

__all__ = [
    "PLANNERS",
    "SolverEvaluation",
    "decoder_distance_mass",
    "evaluate_solvers",
    "compare_table",
    "evaluate_teacher",
    "paired_vs",
    "plot_distance_mass",
    "plot_tour_comparison",
    "pool_summaries",
    "take",
    "write_tables",
]

# name -> StrategicPolicy.plan options; the first two are Table III's pair
PLANNERS: dict[str, dict[str, Any]] = {
    "transformer": {"two_opt": False},
    "transformer+2opt": {"two_opt": True},
    "transformer+2opt+augment": {"two_opt": True, "augment": True},
    "transformer+2opt+best_of_8": {"two_opt": True, "best_of": 8},
    "transformer+2opt+fill": {"two_opt": True, "fill": True},
    "transformer+2opt+augment+fill": {"two_opt": True, "augment": True, "fill": True},
    "transformer+2opt+best_of_2+fill": {"two_opt": True, "best_of": 2, "fill": True},
    "transformer+2opt+best_of_4+fill": {"two_opt": True, "best_of": 4, "fill": True},
    "transformer+2opt+multi_start": {"two_opt": True, "multi_start": True},
    "transformer+2opt+best_of_8+fill": {"two_opt": True, "best_of": 8, "fill": True},
    "transformer+2opt+multi_start+fill": {"two_opt": True, "multi_start": True, "fill": True},
    # multi-start over the 8 top-scored first sets plus 4 samples (chosen on validation
    # houses as the best option under 10 ms on a 2-core CPU)
    "transformer+2opt+multi_start_8+best_of_4+fill": {
        "two_opt": True,
        "multi_start": 8,
        "best_of": 4,
        "fill": True,
    },
    "transformer+2opt+all": {"two_opt": True, "augment": True, "best_of": 8, "fill": True},
}


def take(instances: SOPInstance, index: Any) -> SOPInstance:
    """Instance(s) ``index`` of a NumPy batch (an int gives a single instance)."""
    return jax.tree_util.tree_map(lambda a: np.asarray(a)[index], instances)


def _count(instances: SOPInstance) -> int:
    return int(np.asarray(instances.set_id).shape[0])


def _summary(rewards: list[float], costs: list[float], single_ms: list[float]) -> dict[str, Any]:
    return {
        "mean_reward": float(np.mean(rewards)),
        "mean_cost": float(np.mean(costs)),
        "latency_ms_single": float(statistics.median(single_ms)),
        "latency_ms_single_mean": float(np.mean(single_ms)),
        "rewards": [round(float(r), 6) for r in rewards],  # per instance (paired intervals)
    }


def paired_vs(
    result: dict[str, Any],
    name: str,
    other: str = "greedy_insertion",
    seed: int = 0,
    by_house: bool = False,
) -> tuple[float, float, float]:
    """Paired reward difference of planner ``name`` over ``other`` on the same instances,
    in units of the VNS's mean reward (so it reads as a difference of reward ratios):
    ``(mean, lo, hi)`` with a 95 % percentile bootstrap interval over instances, or with
    ``by_house`` over houses (whole houses resampled, using ``result["instance_houses"]``:
    the interval for other houses, not only for other tasks in the same houses).

    Raises:
        ValueError: ``by_house`` on a result without per-instance houses.
    """
    p = result["planners"]
    scale = max(p["vns"]["mean_reward"], 1e-12)
    a = np.asarray(p[name]["rewards"]) / scale
    b = np.asarray(p[other]["rewards"]) / scale
    groups = None
    if by_house:
        if "instance_houses" not in result:
            raise ValueError("no instance_houses in this evaluation: cannot resample houses")
        groups = result["instance_houses"]
    return paired_bootstrap_ci(a, b, seed=seed, groups=groups)


def _canonical(value: Any) -> str:
    """A recorded value as text that ignores key order (read from JSON or not)."""
    return json.dumps(value, sort_keys=True, default=str)


def _house_ranges(seeds: Any) -> list[tuple[int, int]]:
    """An evaluation's ``house_seeds``, ``[lo, hi]`` or a pooled list of them, as ranges."""
    try:
        if len(seeds) == 2 and all(isinstance(x, int) for x in seeds):
            return [(int(seeds[0]), int(seeds[1]))]
        return [(int(lo), int(hi)) for lo, hi in seeds]
    except (TypeError, ValueError):
        raise ValueError(f"house_seeds must be [lo, hi] or a list of them, got {seeds!r}") from None


def pool_summaries(results: list[dict[str, Any]]) -> dict[str, Any]:
    """One summary over evaluations of the same model on disjoint ranges of held-out houses.

    An evaluation's confidence interval narrows with its instance count; this pools runs
    made at different times (``solver_eval.json`` dictionaries of :func:`evaluate_solvers`
    with their ``house_seeds`` and ``checkpoint``) as if they were one run over all their
    houses: per-instance rewards are concatenated, reward ratios are over the pooled VNS
    mean reward, mean costs are instance-weighted. Only planners present in every run are
    kept. Latencies were measured per run (possibly on a busier machine): the pooled
    ``latency_ms_single`` is the instance-weighted mean of the runs' medians (ms) and the
    speedup is recomputed from it. Per-instance houses (``instance_houses``) are pooled when
    every run has them.

    A pooled summary pools again with further runs (its ``house_seeds`` is a list of
    ranges).

    Raises:
        ValueError: no runs, a run without house seeds or per-instance rewards, runs of
            different checkpoints, presets, VNS configurations or tasks per house, a planner
            name run with different options, or overlapping house ranges.
    """
    if not results:
        raise ValueError("pool_summaries needs at least one evaluation")
    first = results[0]
    if not all("house_seeds" in r for r in results):
        raise ValueError("an evaluation without house_seeds cannot be pooled (whose houses?)")
    for key in ("checkpoint", "vns_config", "preset", "tasks_per_house"):
        values = {_canonical(r[key]) for r in results if key in r}  # runs before the key: any
        if len(values) > 1:
            raise ValueError(f"evaluations of different {key}s cannot be pooled: {values}")
    ranges = sorted(rng for r in results for rng in _house_ranges(r["house_seeds"]))
    for (_, hi), (lo, _) in zip(ranges[:-1], ranges[1:], strict=True):
        if lo < hi:
            raise ValueError(f"evaluations with overlapping house ranges: {ranges}")
    names = [n for n in first["planners"] if all(n in r["planners"] for r in results)]
    for name in names:
        options = {_canonical(r["planners"][name]["options"]) for r in results
                   if "options" in r["planners"][name]}  # fmt: skip
        if len(options) > 1:
            raise ValueError(f"planner {name!r} ran with different options: {options}")
    counts = np.asarray([r["instances"] for r in results], float)
    weights = counts / counts.sum()
    planners: dict[str, dict[str, Any]] = {}
    for name in names:
        rows = [r["planners"][name] for r in results]
        if any(len(row.get("rewards", ())) != n for row, n in zip(rows, counts, strict=True)):
            raise ValueError(f"planner {name!r} lacks per-instance rewards in an evaluation")
        rewards = [x for row in rows for x in row["rewards"]]
        planners[name] = {
            **({"options": rows[0]["options"]} if "options" in rows[0] else {}),
            "mean_reward": float(np.mean(rewards)),
            "mean_cost": float(np.dot(weights, [row["mean_cost"] for row in rows])),
            "latency_ms_single": float(np.dot(weights, [row["latency_ms_single"] for row in rows])),
            "rewards": rewards,
        }
    vns = planners["vns"]
    for row in planners.values():
        row["reward_ratio"] = row["mean_reward"] / max(vns["mean_reward"], 1e-12)
        row["speedup"] = vns["latency_ms_single"] / max(row["latency_ms_single"], 1e-12)
    pooled = {
        "instances": int(counts.sum()),
        "preset": next((r["preset"] for r in results if "preset" in r), None),
        "checkpoint": first["checkpoint"],
        "vns_config": first["vns_config"],
        "house_seeds": [list(r) for r in ranges],
        "planners": planners,
    }
    tasks = [r["tasks_per_house"] for r in results if "tasks_per_house" in r]
    if tasks:
        pooled["tasks_per_house"] = tasks[0]
    if all("instance_houses" in r for r in results):
        pooled["instance_houses"] = [h for r in results for h in r["instance_houses"]]
    return pooled


def _run_host_solver(fn, instances: SOPInstance, desc: str, progress: bool):
    sols, times = [], []
    for i in tqdm(range(_count(instances)), desc=desc, unit="inst", disable=not progress):
        inst = take(instances, i)
        t0 = time.perf_counter()
        sol = fn(inst)
        times.append(1e3 * (time.perf_counter() - t0))
        sols.append(sol)
    return sols, times


def _policy_single(policy, instances: SOPInstance, options: dict[str, Any], desc, progress):
    n = _count(instances)
    jax.block_until_ready(policy.plan(take(instances, 0), **options))  # compile
    rewards, costs, times = [], [], []
    nodes = []
    for i in tqdm(range(n), desc=desc, unit="inst", disable=not progress):
        inst = take(instances, i)
        t0 = time.perf_counter()
        sol = jax.block_until_ready(policy.plan(inst, **options))
        times.append(1e3 * (time.perf_counter() - t0))
        rewards.append(float(sol.reward))
        costs.append(float(sol.cost))
        nodes.append(np.asarray(sol.nodes))
    return rewards, costs, times, nodes


def _policy_batched(policy, instances: SOPInstance, options: dict[str, Any], batch: int, repeats):
    """ms per instance for full batches of ``batch`` (the first batch compiles first)."""
    n = _count(instances)
    batch = min(batch, n)
    chunks = [take(instances, slice(lo, lo + batch)) for lo in range(0, n - batch + 1, batch)]
    jax.block_until_ready(policy.plan(chunks[0], **options))
    best = []
    for chunk in chunks:
        runs = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            jax.block_until_ready(policy.plan(chunk, **options))
            runs.append(time.perf_counter() - t0)
        best.append(min(runs))
    per_batch = statistics.median(best)
    return 1e3 * per_batch / batch, batch / per_batch, batch


def evaluate_teacher(
    instances: SOPInstance, vns_kwargs: dict[str, Any] | None = None, progress: bool = True
) -> tuple[list[Solution], list[float]]:
    """The VNS teacher's plans of every instance and the ms each took (one at a time):
    the ``teacher`` argument of :func:`evaluate_solvers`, for several models to share."""
    vns_kwargs = dict(vns_kwargs or {})
    return _run_host_solver(
        lambda x: solve_vns(x, seed=0, **vns_kwargs), instances, "VNS teacher", progress
    )


def evaluate_solvers(
    policy,
    instances: SOPInstance,
    vns_kwargs: dict[str, Any] | None = None,
    planners: dict[str, dict[str, Any]] | None = None,
    batch_size: int = 64,
    repeats: int = 3,
    progress: bool = True,
    teacher: tuple[list[Solution], list[float]] | None = None,
) -> SolverEvaluation:
    """Plan every instance with the teacher, the greedy baseline and each planner.

    Args:
        policy: a :class:`~bfsop_jax.policy.StrategicPolicy`.
        instances: a NumPy batch of held-out instances.
        vns_kwargs: options of :func:`solve_vns` (default: its reference configuration).
        planners: name -> ``policy.plan`` options (default :data:`PLANNERS`).
        batch_size: batch of the batched-latency measurement.
        repeats: timed repetitions of each batch (the fastest counts).
        teacher: precomputed ``(solutions, latencies_ms)`` of the VNS on these instances
            (lets several models share one teacher run).

    Returns:
        The ``solver_eval.json`` dictionary: per planner mean reward and cost, latencies,
        reward ratio to the VNS, speedup over it; the instance count; 2-opt effect.
    """
    n = _count(instances)
    if n == 0:
        raise ValueError("evaluate_solvers needs at least one instance")
    vns_kwargs = dict(vns_kwargs or {})
    planners = PLANNERS if planners is None else planners
    if teacher is None:
        teacher = evaluate_teacher(instances, vns_kwargs, progress)
    vns_sols, vns_ms = teacher
    if len(vns_sols) != n or len(vns_ms) != n:
        raise ValueError(
            f"the teacher has {len(vns_sols)} plans and {len(vns_ms)} latencies for {n} "
            "instances (it must come from evaluate_teacher on these instances)"
        )
    vns_r = [float(s.reward) for s in vns_sols]
    vns_c = [float(s.cost) for s in vns_sols]
    result: dict[str, Any] = {
        "instances": n,
        "vns_config": {"seed": 0, **vns_kwargs},
        "planners": {"vns": _summary(vns_r, vns_c, vns_ms)},
    }
    greedy_sols, greedy_ms = _run_host_solver(solve_greedy, instances, "greedy", progress)
    result["planners"]["greedy_insertion"] = _summary(
        [float(s.reward) for s in greedy_sols], [float(s.cost) for s in greedy_sols], greedy_ms
    )
    vns_mean = max(float(np.mean(vns_r)), 1e-12)
    plans: dict[str, list[np.ndarray]] = {}
    for name, options in planners.items():
        rewards, costs, single, nodes = _policy_single(policy, instances, options, name, progress)
        per_inst, per_s, used = _policy_batched(policy, instances, options, batch_size, repeats)
        row = _summary(rewards, costs, single)
        row.update(
            options=options,
            latency_ms_batched=per_inst,
            plans_per_s_batched=per_s,
            batch_size=used,
            reward_ratio=float(np.mean(rewards)) / vns_mean,
            speedup=result["planners"]["vns"]["latency_ms_single"] / row["latency_ms_single"],
            matches_teacher_reward=float(
                np.mean(np.abs(np.asarray(rewards) - np.asarray(vns_r)) <= 1e-4)
            ),
        )
        result["planners"][name] = row
        plans[name] = nodes
    if "transformer" in result["planners"] and "transformer+2opt" in result["planners"]:
        off, on = result["planners"]["transformer"], result["planners"]["transformer+2opt"]
        result["two_opt"] = {
            "cost_change_pct": 100.0
            * (on["mean_cost"] - off["mean_cost"])
            / max(off["mean_cost"], 1e-12),
            "reward_change_pct": 100.0
            * (on["mean_reward"] - off["mean_reward"])
            / max(off["mean_reward"], 1e-12),
            "latency_overhead_ms_single": on["latency_ms_single"] - off["latency_ms_single"],
            "latency_overhead_ms_batched": on["latency_ms_batched"] - off["latency_ms_batched"],
        }
    return SolverEvaluation(summary=result, teacher=teacher, plans=plans)


@dataclasses.dataclass
class SolverEvaluation:
    """What :func:`evaluate_solvers` returns."""

    summary: dict[str, Any]  # the ``solver_eval.json`` content (JSON-able)
    teacher: tuple[list[Solution], list[float]]  # VNS plans and ms: reusable for other models
    plans: dict[str, list[np.ndarray]]  # planner -> [T] node ids per instance (figures)


def write_json(result: dict[str, Any], path: str | os.PathLike) -> None:
    """Write an evaluation summary (``SolverEvaluation.summary``) atomically."""
    files.write_json(path, result)


def _fmt(x: float, digits: int = 2) -> str:
    return f"{x:.{digits}f}"


def write_tables(
    result: dict[str, Any],
    path: str | os.PathLike,
    ablations: dict[str, dict[str, Any]] | None = None,
    header: str = "",
) -> str:
    """Markdown Tables II and III (and the ablation table when given); written atomically."""
    p = result["planners"]
    vns = p["vns"]
    lines = [header.rstrip(), ""] if header else []
    lines += [
        f"## Table II: solver comparison ({result['instances']} held-out instances)",
        "",
        "| planner | avg reward | avg cost | reward / VNS | latency single (ms) "
        "| latency batched (ms/inst) | plans/s batched | speedup vs VNS |",
        "|---|---|---|---|---|---|---|---|",
        f"| VNS teacher | {_fmt(vns['mean_reward'])} | {_fmt(vns['mean_cost'])} | 1.000 "
        f"| {_fmt(vns['latency_ms_single'], 1)} | - | - | 1x |",
    ]
    g = p["greedy_insertion"]
    lines.append(
        f"| greedy insertion | {_fmt(g['mean_reward'])} | {_fmt(g['mean_cost'])} "
        f"| {g['mean_reward'] / max(vns['mean_reward'], 1e-12):.3f} "
        f"| {_fmt(g['latency_ms_single'], 1)} | - | - "
        f"| {vns['latency_ms_single'] / g['latency_ms_single']:.0f}x |"
    )
    for name, row in p.items():
        if name in ("vns", "greedy_insertion"):
            continue
        lines.append(
            f"| {name} | {_fmt(row['mean_reward'])} | {_fmt(row['mean_cost'])} "
            f"| {row['reward_ratio']:.3f} | {_fmt(row['latency_ms_single'])} "
            f"| {_fmt(row['latency_ms_batched'], 3)} | {row['plans_per_s_batched']:.0f} "
            f"| {row['speedup']:.0f}x |"
        )
    if "two_opt" in result:
        off, on, t = p["transformer"], p["transformer+2opt"], result["two_opt"]
        lines += [
            "",
            "## Table III: the bounded 2-opt (greedy decoding, then budget gate)",
            "",
            "| planner | avg reward | avg cost | latency single (ms) | latency batched (ms/inst) |",
            "|---|---|---|---|---|",
            f"| Transformer | {_fmt(off['mean_reward'])} | {_fmt(off['mean_cost'])} "
            f"| {_fmt(off['latency_ms_single'])} | {_fmt(off['latency_ms_batched'], 3)} |",
            f"| Transformer + 2-opt | {_fmt(on['mean_reward'])} | {_fmt(on['mean_cost'])} "
            f"| {_fmt(on['latency_ms_single'])} | {_fmt(on['latency_ms_batched'], 3)} |",
            "",
            f"2-opt: cost {t['cost_change_pct']:+.1f}%, reward {t['reward_change_pct']:+.1f}%, "
            f"latency {t['latency_overhead_ms_single']:+.2f} ms single, "
            f"{t['latency_overhead_ms_batched']:+.3f} ms/inst batched.",
        ]
    if ablations:
        lines += [
            "",
            "## Ablations (same data, same seed; greedy decoding + 2-opt)",
            "",
            "| model | val loss | val acc | avg reward | reward / VNS | avg cost |",
            "|---|---|---|---|---|---|",
        ]
        for name, row in ablations.items():
            lines.append(
                f"| {name} | {_fmt(row['val_loss'], 3)} | {_fmt(row['val_acc'], 3)} "
                f"| {_fmt(row['mean_reward'])} | {row['reward_ratio']:.3f} "
                f"| {_fmt(row['mean_cost'])} |"
            )
    text = "\n".join(lines) + "\n"
    files.write_text(path, text)
    return text


def decoder_distance_mass(policy, instances: SOPInstance, batch: int = 64) -> np.ndarray:
    """[2, 5] decoder node-probability mass per distance quintile: all steps, first step.

    Quintile 0 holds the nearest fifth of the nodes allowed at that step, by cost from the
    decoder's current node: the start at the first step, then the node chosen at the step
    before (for the append decoder the plan's previous node; for the insertion decoder the
    node last inserted, wherever in the route it went). Steps with fewer than five allowed
    nodes are skipped.
    """
    n = _count(instances)
    sums, counts = np.zeros((2, 5)), np.zeros(2)
    for lo in range(0, n, batch):
        chunk = take(instances, slice(lo, lo + batch))
        trace = jax.device_get(policy.trace(chunk))
        probs, allowed = np.asarray(trace.probs), np.asarray(trace.allowed)
        choices = np.asarray(trace.choices)  # [B, S]: the node chosen at each step, -1: END
        start = np.asarray(chunk.start)
        cost = np.asarray(chunk.cost)
        b, steps, n1 = probs.shape
        n_inst = cost.shape[1]
        for i in range(b):
            for t in range(steps):
                last = start[i] if t == 0 else choices[i, t - 1]
                if last < 0:
                    break
                ok = np.flatnonzero(allowed[i, t, : min(n1 - 1, n_inst)])
                mass = probs[i, t, ok]
                if ok.size < 5 or mass.sum() <= 0:
                    continue
                order = np.argsort(cost[i, last, ok], kind="stable")
                quint = np.empty(ok.size, np.int64)
                quint[order] = (5 * np.arange(ok.size)) // ok.size
                share = np.bincount(quint, weights=mass / mass.sum(), minlength=5)
                sums[0] += share
                counts[0] += 1
                if t == 0:
                    sums[1] += share
                    counts[1] += 1
    return sums / np.maximum(counts, 1)[:, None]


def compare_table(
    models: dict[str, dict[str, Any]],
    planners: dict[str, dict[str, Any]] | None = None,
    instance_houses: list[int] | None = None,
) -> str:
    """Markdown table of several models on the same instances and teacher plans.

    Args:
        models: model label -> the ``planners`` dictionary of its evaluation summary (each
            holds ``vns`` and ``greedy_insertion`` of the same instances).
        planners: the planner rows to show (default: every planner the models share).
        instance_houses: ``[I]`` house seed of each instance; adds a column with the paired
            interval over houses (whole houses resampled) when they hold two houses or more.

    Each row gives the reward ratio to the VNS, the paired difference to greedy insertion
    on the same instances (in reward-ratio units, 95 % bootstrap interval over instances,
    and over houses when given), the median single-instance latency and the speedup over
    the VNS.
    """
    first = next(iter(models.values()))
    names = list(planners or [n for n in first if n not in ("vns", "greedy_insertion")])
    if instance_houses is not None and len(set(instance_houses)) < 2:
        instance_houses = None  # one house: nothing to resample
    g = first["greedy_insertion"]
    vns = first["vns"]
    lines = [
        "",
        "## Models side by side (same instances, same teacher plans)",
        "",
        f"Greedy insertion: reward / VNS {g['mean_reward'] / max(vns['mean_reward'], 1e-12):.3f}"
        f" at {g['latency_ms_single']:.1f} ms.",
        "",
        "| model | planner | reward / VNS | minus greedy insertion [95% CI] "
        + ("| CI over houses " if instance_houses is not None else "")
        + "| latency single (ms) | speedup vs VNS |",
        "|---|---|---|---|---|---|" + ("---|" if instance_houses is not None else ""),
    ]
    for label, p in models.items():
        for name in names:
            if name not in p:
                continue
            d, lo, hi = paired_vs({"planners": p}, name)
            row = p[name]
            by_house = ""
            if instance_houses is not None:
                houses = {"planners": p, "instance_houses": instance_houses}
                _, hlo, hhi = paired_vs(houses, name, by_house=True)
                by_house = f"| [{hlo:+.3f}, {hhi:+.3f}] "
            lines.append(
                f"| {label} | {name} | {row['reward_ratio']:.3f} | {d:+.3f} [{lo:+.3f}, {hi:+.3f}] "
                f"{by_house}| {row['latency_ms_single']:.2f} | {row['speedup']:.0f}x |"
            )
    return "\n".join(lines) + "\n"
