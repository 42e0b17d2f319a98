"""Tables, figures and summaries of the navigation benchmark's results.

Per-method means with bootstrap intervals (:func:`summarise`), paired differences
(:func:`paired`), Table I in markdown (:func:`write_table1`), the figures
(:func:`write_figures`, each method in its own colour: :func:`method_colours`), and a
method's saved paths read back from a run directory (:func:`load_paths`). Everything here
reads what :func:`bfsop_jax.eval.navigation.evaluate_navigation` wrote; it is importable
from :mod:`bfsop_jax.eval.navigation` too.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bfsop_jax import files, metrics
from bfsop_jax.eval.methods import ABLATIONS, BASELINES, CANDIDATE_METHODS, LABELS, METHODS
from bfsop_jax.world.constants import TARGET_NAMES

if TYPE_CHECKING:
    from bfsop_jax.eval.navigation import HouseSet

__all__ = [
    "load_paths",
    "method_colours",
    "paired",
    "summarise",
    "verdict",
    "write_figures",
    "write_table1",
]


def _method_files(folder: Path, method: str, suffix: str) -> list[Path]:
    """A method's files in ``episodes/`` (its numbered chunks in order, then its planner
    latency), ``suffix`` one of ``".json"``, ``".npz"`` or ``"*"``; never another method's
    whose name extends this one's (``tfl_reactive_gain`` for ``tfl_reactive``)."""
    tail = lambda f: f.stem[len(method) + 1 :]
    mine = [
        f for f in folder.glob(f"{method}_*{'' if suffix == '*' else suffix}")
        if tail(f) == "planner" or tail(f).isdigit()
    ]
    chunk = lambda f: int(tail(f)) if tail(f).isdigit() else math.inf  # planner last
    return sorted(mine, key=chunk)


def summarise(records: Iterable[dict[str, Any]], methods: Sequence[str]) -> dict[str, Any]:
    """Per-method means with 95 % bootstrap intervals (episodes are the resampled unit)."""
    records = list(records)
    out = {}
    for m in methods:
        rows = [r for r in records if r["method"] == m]
        if not rows:
            continue
        col = lambda k, rows=rows: np.asarray([r[k] for r in rows], float)
        ppl = col("ppl")
        out[m] = {
            "label": LABELS[m],
            "episodes": len(rows),
            "ppl_mean": float(ppl.mean()),
            "ppl_ci95": list(metrics.bootstrap_ci(ppl)),
            "ppl_end_mean": float(col("ppl_end").mean()),
            "progress_mean": float(col("progress").mean()),
            "progress_ci95": list(metrics.bootstrap_ci(col("progress"))),
            "found_all_fraction": float(np.mean(col("found") == col("total"))),
            "path_length_mean": float(col("path_length").mean()),
            "path_length_end_mean": float(col("path_length_end").mean()),
            "switches_mean": float(col("switches").mean()),
            "planner_calls_mean": float(col("planner_calls").mean()),
            "revisit_mean": float(col("revisit").mean()),
            "planner_ms": rows[0].get("planner_ms"),
        }
    return out


def paired(
    records: Sequence[dict[str, Any]], a: str, b: str, by_house: bool = False
) -> tuple[float, float, float]:
    """Paired bootstrap (mean, lo, hi) of PPL(a) - PPL(b) over their shared episodes; with
    ``by_house`` whole houses are resampled (the interval for other houses; needs episodes
    in at least two houses)."""
    key = lambda r: (r["house_seed"], r["category"])
    pa = {key(r): r["ppl"] for r in records if r["method"] == a}
    pb = {key(r): r["ppl"] for r in records if r["method"] == b}
    shared = sorted(set(pa) & set(pb))
    if not shared:
        raise ValueError(f"methods {a} and {b} share no episode")
    groups = [k[0] for k in shared] if by_house else None
    return metrics.paired_bootstrap_ci(
        [pa[k] for k in shared], [pb[k] for k in shared], groups=groups
    )


def verdict(result: dict[str, Any]) -> str:
    """One line a newcomer can read: BF-SOP (Transformer)'s PPL as a multiple of the best
    baseline's and of its VNS teacher's, on the same episodes, with 95 % paired bootstrap
    intervals of the ratio (over houses when the episodes span several, else over
    episodes), and whether each interval lies above 1, below it, or holds it (a tie).
    Empty when ``result`` has no BF-SOP (Transformer) row or nothing to compare it with."""
    methods, episodes = result["methods"], result["episodes"]
    if "bfsop_st" not in methods:
        return ""
    baselines = [m for m in BASELINES if m in methods]
    others = []
    if baselines:
        best = max(baselines, key=lambda m: methods[m]["ppl_mean"])
        others.append((best, f"the best baseline ({LABELS[best]})"))
    if "bfsop_vns" in methods:
        others.append(("bfsop_vns", "its VNS teacher"))
    several = len({r["house_seed"] for r in episodes}) > 1
    key = lambda r: (r["house_seed"], r["category"])
    mine = {key(r): r["ppl"] for r in episodes if r["method"] == "bfsop_st"}
    parts = []
    for other, what in others:
        theirs = {key(r): r["ppl"] for r in episodes if r["method"] == other}
        shared = sorted(set(mine) & set(theirs))
        b = [theirs[k] for k in shared]
        if not shared or sum(b) <= 0:
            continue
        groups = [k[0] for k in shared] if several else None
        ratio, lo, hi = metrics.paired_ratio_ci([mine[k] for k in shared], b, groups=groups)
        call = "ahead" if lo > 1 else "behind" if hi < 1 else "a tie"
        parts.append(f"{ratio:.2f}x {what} [{lo:.2f}x, {hi:.2f}x]: {call}")
    if not parts:
        return ""
    over = "houses" if several else "episodes"
    n = len(mine)
    return (f"Verdict: BF-SOP (Transformer) PPL {methods['bfsop_st']['ppl_mean']:.3f} is "
            + " and ".join(parts) + f" ({n} episodes; 95% CI over {over}).")


def _ci(lo_hi: Sequence[float]) -> str:
    return f"[{lo_hi[0]:.3f}, {lo_hi[1]:.3f}]"


def write_table1(result: dict[str, Any], path: str | os.PathLike, header: str = "") -> str:
    """Table I (markdown): mean PPL per method with 95 % bootstrap intervals, and paired
    differences of BF-SOP (Transformer) with the best baseline and with BF-SOP (VNS)."""
    methods = result["methods"]
    lines = [header] if header else []
    lines += [
        "| method | PPL [95% CI] | PPL (episode end) | progress | L (m) | L end (m) | "
        "tours | planner calls | planner ms | revisit | found all |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in methods.values():
        ms = "" if s["planner_ms"] is None else f"{s['planner_ms']:.1f}"
        lines.append(
            f"| {s['label']} | {s['ppl_mean']:.3f} {_ci(s['ppl_ci95'])} | {s['ppl_end_mean']:.3f} "
            f"| {s['progress_mean']:.3f} | {s['path_length_mean']:.1f} "
            f"| {s['path_length_end_mean']:.1f} | {s['switches_mean']:.1f} "
            f"| {s['planner_calls_mean']:.1f} | {ms} | {s['revisit_mean']:.3f} "
            f"| {s['found_all_fraction']:.2f} |"
        )
    episodes = result["episodes"]
    n = max(s["episodes"] for s in methods.values())
    lines += ["", f"{n} episodes per method, the same for every method; preset "
              f"`{result['preset']}`, budget {result['budget_m']:g} m."]  # fmt: skip
    baselines = [m for m in BASELINES if m in methods]
    comparisons = []
    if "bfsop_st" in methods and baselines:
        best = max(baselines, key=lambda m: methods[m]["ppl_mean"])
        comparisons.append(("bfsop_st", best, "best baseline"))
    if "bfsop_st" in methods and "bfsop_vns" in methods:
        comparisons.append(("bfsop_st", "bfsop_vns", "teacher"))
    if "bfsop_vns" in methods and baselines:
        best = max(baselines, key=lambda m: methods[m]["ppl_mean"])
        comparisons.append(("bfsop_vns", best, "best baseline"))
    if "bfsop_st" in methods and "tfl_reactive_gain" in methods:
        comparisons.append(("bfsop_st", "tfl_reactive_gain", "the same explorer"))
    for cand in CANDIDATE_METHODS:
        comparisons += [(cand, b, "scripted candidates") for b in ("fbe", "tfl_reactive")
                        if cand in methods and b in methods]  # fmt: skip
    if comparisons:
        several = len({r["house_seed"] for r in episodes}) > 1
        lines += [
            "", "Paired differences (bootstrap over shared episodes, 95% CI; over houses: "
            "whole houses resampled, the interval for other houses):", "",
            "| comparison | PPL difference [95% CI] | over houses [95% CI] | PPL ratio |",
            "|---|---|---|---|",
        ]  # fmt: skip
        for a, b, what in comparisons:
            d, lo, hi = paired(episodes, a, b)
            house = "-"
            if several:
                _, hlo, hhi = paired(episodes, a, b, by_house=True)
                house = f"[{hlo:+.3f}, {hhi:+.3f}]"
            ratio = methods[a]["ppl_mean"] / max(methods[b]["ppl_mean"], 1e-12)
            lines.append(
                f"| {LABELS[a]} - {LABELS[b]} ({what}) | {d:+.3f} [{lo:+.3f}, {hi:+.3f}] "
                f"| {house} | {ratio:.2f}x |"
            )
    line = verdict(result)
    if line:
        lines += ["", line]
    text = "\n".join(lines) + "\n"
    files.write_text(path, text)
    return text


def load_paths(out_dir: str | os.PathLike, method: str) -> list[dict[str, np.ndarray]]:
    """A method's saved paths in episode order: ``[{"xy": [S, 2], "touring": [S], "found":
    [F, 2]}]`` (positions in metres; ``found``: the verified instances)."""
    out = Path(out_dir) / "episodes"
    paths = []
    for f in _method_files(out, method, ".npz"):
        with np.load(f) as z:
            n = len([k for k in z.files if k.endswith("_xy")])
            paths += [
                {"xy": z[f"{i}_xy"], "touring": z[f"{i}_touring"], "found": z[f"{i}_found"]}
                for i in range(n)
            ]
    return paths


def method_colours(names: Sequence[str]) -> list[str]:
    """Each method's own colour (its place in :data:`METHODS` then :data:`ABLATIONS`), the
    same in every figure whichever methods ran."""
    from bfsop_jax.viz.style import method_colour

    order = METHODS + ABLATIONS
    return [method_colour(order.index(m)) for m in names]


def write_figures(
    result: dict[str, Any], out_dir: str | os.PathLike, houses: HouseSet
) -> list[Path]:
    """``ppl.png``, ``ppl_per_category.png`` and ``trajectories.png`` (TFL-Reactive and
    BF-SOP (Transformer), or the first and last methods run, in the first episode's house)."""
    from bfsop_jax import viz

    out = Path(out_dir)
    methods = result["methods"]
    names = list(methods)
    written = []
    labels = [methods[m]["label"] for m in names]
    colours = method_colours(names)
    viz.plot_ppl(
        labels, [methods[m]["ppl_mean"] for m in names], [methods[m]["ppl_ci95"] for m in names],
        out / "ppl.png",
        title=f"PPL per method ({result['preset']}, {methods[names[0]]['episodes']} episodes)",
        colours=colours,
    )  # fmt: skip
    written.append(out / "ppl.png")
    episodes = result["episodes"]
    cats = [c for c in TARGET_NAMES if any(r["category"] == c for r in episodes)]
    table = np.zeros((len(names), len(cats)))
    for i, m in enumerate(names):
        for j, c in enumerate(cats):
            vals = [r["ppl"] for r in episodes if r["method"] == m and r["category"] == c]
            table[i, j] = np.mean(vals) if vals else np.nan
    viz.plot_category_ppl(cats, labels, table, out / "ppl_per_category.png",
                          title="PPL per target category", colours=colours)  # fmt: skip
    written.append(out / "ppl_per_category.png")
    pair = [m for m in ("tfl_reactive", "bfsop_st") if m in names]
    if len(pair) < 2:
        pair = [names[0], names[-1]] if len(names) > 1 else names[:1]
    first = [r for r in episodes if r["method"] == pair[0]][0]
    house_id = first["house_seed"]
    house = houses[house_id]
    runs = []
    for m in pair:
        rows = [r for r in episodes if r["method"] == m]
        i = next(k for k, r in enumerate(rows) if (r["house_seed"], r["category"])
                 == (house_id, first["category"]))  # fmt: skip
        p = load_paths(out, m)[i]
        r = rows[i]
        runs.append((f"{LABELS[m]}: found {r['found']}/{r['total']}, PPL {r['ppl']:.2f}",
                     p["xy"], p["touring"], p["found"]))  # fmt: skip
    viz.plot_trajectories_side_by_side(
        house, runs, out / "trajectories.png",
        title=f"{first['category']} in house {first['house']} (first episode of the protocol)",
    )  # fmt: skip
    written.append(out / "trajectories.png")
    return written
