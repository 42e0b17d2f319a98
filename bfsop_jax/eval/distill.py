"""The evaluation stage of the distillation pipeline (``python -m experiments.distill``).

Held-out instances posed in held-out houses (:func:`eval_instances`) are planned by the
VNS teacher, greedy insertion and the Transformer's planners (:func:`preset_planners`),
with the ablations and the ``--compare`` models on the same instances against the same
teacher plans (:func:`stage_eval`: ``solver_eval.json``, ``tables.md``,
``tour_comparison.png``, ``decoder_distance_mass.png``, ``compare.png``); then Table I on a
reduced navigation protocol (:func:`stage_navigation`). The stages take the parsed command
line (``args``, the options of :mod:`experiments.distill`); the presets and the other
stages are :mod:`bfsop_jax.training.distill`'s.
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from bfsop_jax import files
from bfsop_jax.config import EVAL_SEED_START, parse_seed_range
from bfsop_jax.data.generate import pose_tasks
from bfsop_jax.eval import solvers as solver_eval
from bfsop_jax.policy import StrategicPolicy
from bfsop_jax.training.distill import ABLATIONS, COMPARE_PLANNERS, DistillPreset
from bfsop_jax.viz import plot_distance_mass, plot_model_comparison, plot_tour_comparison

__all__ = [
    "eval_instances",
    "preset_planners",
    "stage_eval",
    "stage_navigation",
    "tour_figure",
]


def preset_planners(preset: DistillPreset, compare: bool = False) -> dict[str, dict[str, Any]]:
    """The planners (name -> ``StrategicPolicy.plan`` options) a preset's evaluation runs for
    its model, or with ``compare`` for each ``--compare`` model."""
    names = preset.compare_planners if compare else preset.planners
    if not names:
        return COMPARE_PLANNERS if compare else solver_eval.PLANNERS
    return {name: solver_eval.PLANNERS[name] for name in names}


def eval_instances(
    preset: DistillPreset,
    lo: int,
    hi: int,
    tasks: int,
    progress: bool = True,
    maps: bool = False,
) -> tuple[Any, np.ndarray] | tuple[Any, np.ndarray, dict[int, np.ndarray]]:
    """The held-out instances an evaluation of houses ``lo..hi-1`` plans: ``tasks`` virtual
    tasks posed per house (those without a rewarding set dropped), and the house seed of each
    instance ``[I]``; with ``maps`` also the map they were posed on per house (house seed ->
    int8 [H, W] cell states, :func:`~bfsop_jax.data.generate.pose_tasks`). Deterministic in
    its arguments."""
    cfg = dataclasses.replace(preset.data, tasks_per_house=tasks)
    return pose_tasks(np.arange(lo, hi), cfg, progress=progress, maps=maps)


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
    instances, owners, maps = eval_instances(
        preset, lo, hi, tasks, progress=not args.no_progress, maps=True
    )
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
    _figures(policy, instances, evaluation, out, owners, maps, preset.data.preset)
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
    return {"episodes": len(episodes), "methods": result["methods"],
            "verdict": nav.verdict(result)}  # fmt: skip


def tour_figure(
    instance: Any,
    plans: dict[str, list[int]],
    house_map: np.ndarray | None,
    preset: str,
    path: str | os.PathLike,
) -> dict[str, tuple[list[int], float, float]]:
    """Draw ``plans`` (name -> node ids in visiting order) of one unbatched ``instance``
    over the map it was posed on (``plot_tour_comparison``), each tour along its legs'
    shortest paths on that map (the paths its geodesic costs measure); returns name ->
    (nodes, reward, cost in metres) as titled.

    Args:
        house_map: int8 [H, W] cell states of the belief map the instance was built on
            (:func:`~bfsop_jax.data.generate.pose_tasks` with ``maps``), or None: straight
            legs on white.
        preset: name of the environment preset (grid and cell sizes) of the map.
    """
    from bfsop_jax.agents.record import OCCUPIED
    from bfsop_jax.config import get_preset
    from bfsop_jax.navigation import geodesic_route, true_blocked
    from bfsop_jax.sop import evaluate

    env = get_preset(preset)
    scored = {}
    for name, nodes in plans.items():
        reward, cost, _ = evaluate(instance, nodes)
        scored[name] = (nodes, float(reward), float(cost))
    if house_map is None:
        plot_tour_comparison(instance, scored, path)
        return scored
    # the optimistic planning map of the instance: the known-occupied cells inflated by the
    # robot radius (planning_blocked of the log-odds map is this same inflation)
    blocked = true_blocked(jnp.asarray(house_map == OCCUPIED), env)
    coords = np.asarray(instance.coords)
    routes = {
        name: geodesic_route(blocked, coords[[n for n in nodes if n >= 0]], env)
        for name, nodes in plans.items()
    }
    plot_tour_comparison(instance, scored, path, belief=house_map, cell_size=env.cell_size,
                         known=0.0, routes=routes)  # fmt: skip
    return scored


def _figures(
    policy, instances, evaluation, out: Path, owners: np.ndarray, maps: dict, env: str
) -> None:
    """The tour comparison and the distance-mass figures (the mass is added to the
    evaluation's summary). ``owners`` [I]: the house seed of each instance; ``maps``: house
    seed -> the int8 map its tasks were posed on; ``env``: the environment preset's name."""
    result = evaluation.summary
    vns_plans = [s.node_list() for s in evaluation.teacher[0]]
    model_plans = evaluation.plans["transformer+2opt"]
    # the instance where the teacher visits the most sets (a readable, non-trivial tour)
    i = int(np.argmax([len(p) for p in vns_plans]))
    inst = solver_eval.take(instances, i)
    plans = {
        "VNS teacher": vns_plans[i],
        "Transformer + 2-opt": [int(x) for x in model_plans[i] if x >= 0],
    }
    house_map = maps.get(int(owners[i]))
    tour_figure(inst, plans, house_map, env, out / "tour_comparison.png")
    mass = solver_eval.decoder_distance_mass(policy, instances)
    result["distance_mass"] = {"all_steps": mass[0].tolist(), "first_step": mass[1].tolist()}
    plot_distance_mass(mass, out / "decoder_distance_mass.png")


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
