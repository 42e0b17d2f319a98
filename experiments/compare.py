"""Compare strategies across recorded Table I runs, on the episodes they share.

    python -m experiments.compare runs/val-a:tfl_reactive runs/val-b:bfsop_st \\
        [--label "TFL-Reactive" --label "BF-SOP"] [--png DIR/compare.png]

Each argument is ``RUN_DIR:METHOD`` (a ``results.json`` written by
``experiments.evaluate`` and a method in it); ``+`` joins runs of the same strategy on
disjoint houses (``runs/a:bfsop_st+runs/b:bfsop_st``). The first is the reference.
Printed: mean PPL and progress over the shared episodes, the paired difference to the
reference with a 95% bootstrap interval over houses (whole houses resampled), the ratio,
and the mean PPL by the episode's instance count (1-2, 3-5, 6-10, 11+); for runs that
record them, where the unverified targets are (on a receptacle the agent detected, on one
it never detected, on the floor) and the share of metres toured. ``--png`` also draws the
by-count means as grouped bars (each method in its Table I colour, its later runs in
lighter shades), and beside it (``<name>_targets.png``) where the targets are as stacked
bars, for runs that record it (atomic writes).
"""

from __future__ import annotations

import argparse
import json
import sys
import textwrap
from pathlib import Path

import numpy as np

from bfsop_jax.metrics import paired_bootstrap_ci

BINS = ((1, 2), (3, 5), (6, 10), (11, 10**9))


def _bin_name(lo: int, hi: int) -> str:
    return f"{lo}+" if hi >= 10**9 else f"{lo}-{hi}"


def load(spec: str) -> tuple[dict[tuple[int, str], dict], dict[str, dict]]:
    """``RUN:METHOD[+RUN:METHOD...]`` -> ({(house seed, category): episode record}, {run
    directory: how it was scored}). The joined runs must hold disjoint episodes."""
    out: dict[tuple[int, str], dict] = {}
    scored: dict[str, dict] = {}
    for part in spec.split("+"):
        run, sep, method = part.rpartition(":")
        if not sep or not run or not method:
            raise ValueError(f"{part!r}: expected RUN_DIR:METHOD")
        path = Path(run) / "results.json"
        if not path.is_file():
            raise ValueError(f"{path}: no results.json (run experiments.evaluate first)")
        result = json.loads(path.read_text())
        # runs written before the scoring was recorded were scored the first way
        scored[run] = {k: result.get(k, 1 if k == "scoring" else None)
                       for k in ("preset", "budget_m", "scoring")}  # fmt: skip
        episodes = [e for e in result["episodes"] if e["method"] == method]
        if not episodes:
            raise ValueError(f"{path}: no episodes of method {method!r}")
        for e in episodes:
            key = (int(e["house_seed"]), str(e["category"]))
            if key in out:
                raise ValueError(f"{part}: episode {key} is also in an earlier run of {spec!r} "
                                 "(`+` joins runs on disjoint houses)")  # fmt: skip
            out[key] = e
    return out, scored


def _same_scoring(scored: dict[str, dict]) -> None:
    """Refuse runs of other presets, budgets or PPL scorings."""
    for field, hint in (("preset", ""), ("budget_m", ""), ("scoring", (
            "; run the older one's experiments.evaluate command again (same --out) to "
            "re-score it"))):  # fmt: skip
        values = {run: s[field] for run, s in scored.items()}
        if len(set(map(str, values.values()))) > 1:
            seen = ", ".join(f"{v} in {run}" for run, v in values.items())
            raise ValueError(f"the runs differ in {field} ({seen}){hint}")


def shared(specs: list[str]) -> tuple[list[dict], list[tuple[int, str]]]:
    """The runs of ``specs`` (loaded once) and the episodes they all hold, sorted."""
    loaded = [load(s) for s in specs]
    _same_scoring({run: s for _, scored in loaded for run, s in scored.items()})
    runs = [episodes for episodes, _ in loaded]
    keys = sorted(set.intersection(*(set(r) for r in runs)))
    if not keys:
        raise ValueError("the runs share no episode (house, category)")
    return runs, keys


def compare(specs: list[str], labels: list[str]) -> tuple[str, np.ndarray, list[str]]:
    """The comparison table (Markdown), the by-count means [methods, bins] and the bins'
    names (with their episode counts)."""
    return table(*shared(specs), labels)


def table(
    runs: list[dict], keys: list[tuple[int, str]], labels: list[str]
) -> tuple[str, np.ndarray, list[str]]:
    """:func:`compare` on runs already loaded by :func:`shared`."""
    houses = np.array([k[0] for k in keys])
    total = np.array([runs[0][k]["total"] for k in keys])
    ppl = np.array([[r[k]["ppl"] for k in keys] for r in runs])  # [methods, episodes]
    progress = np.array([[r[k]["progress"] for k in keys] for r in runs])
    in_bin = [(total >= lo) & (total <= hi) for lo, hi in BINS]
    by_bin = np.array([[p[b].mean() if b.any() else np.nan for b in in_bin] for p in ppl])
    names = [f"{_bin_name(*bin_)} ({int(b.sum())})" for bin_, b in zip(BINS, in_bin, strict=True)]
    head = " | ".join(names)
    lines = [
        f"{len(keys)} shared episodes, {len(set(houses.tolist()))} houses; PPL by instance "
        "count in the last columns (episodes).",
        "",
        f"| method | PPL | progress | - {labels[0]} [95% CI over houses] | ratio | {head} |",
        "|---|---|---|---|---|" + "---|" * len(BINS),
    ]
    several = len(set(houses.tolist())) > 1  # an interval over houses needs two or more
    for i, label in enumerate(labels):
        if i == 0:
            diff = "reference"
        elif not several:
            diff = "- (one house)"
        else:
            d, lo, hi = paired_bootstrap_ci(ppl[i], ppl[0], groups=houses)
            diff = f"{d:+.3f} [{lo:+.3f}, {hi:+.3f}]"
        ratio = ppl[i].mean() / max(ppl[0].mean(), 1e-12)
        cells = " | ".join(f"{v:.3f}" for v in by_bin[i])
        lines.append(
            f"| {label} | {ppl[i].mean():.3f} | {progress[i].mean():.3f} | {diff} | "
            f"{ratio:.2f}x | {cells} |"
        )
    lines += _accounting(runs, keys, labels)
    return "\n".join(lines), by_bin, names


def compare_targets(specs: list[str], labels: list[str]) -> dict[str, np.ndarray]:
    """:func:`account_means` over the episodes the runs share."""
    return account_means(*shared(specs), labels)


ACCOUNT = ("found", "missed_seen", "missed_unseen", "missed_floor")


def account_means(runs: list[dict], keys: list, labels: list[str]) -> dict[str, np.ndarray]:
    """{label: [found, missed_seen, missed_unseen, missed_floor]} per-episode means, for
    the runs that record them."""
    out = {}
    for label, run in zip(labels, runs, strict=True):
        eps = [run[k] for k in keys]
        if all(f in e for e in eps for f in ACCOUNT):
            out[label] = np.array([np.mean([e[f] for e in eps]) for f in ACCOUNT])
    return out


def plot_targets(means: dict[str, np.ndarray], path: str) -> None:
    """Stacked bars: where each method's targets are at the end of an episode."""
    import matplotlib.pyplot as plt

    from bfsop_jax.viz.style import save

    parts = ("verified", "on a detected receptacle", "on a receptacle never detected",
             "on the floor")  # fmt: skip
    colours = ("#2e7d32", "#f9a825", "#c62828", "#9e9e9e")
    labels = list(means)
    ticks = [textwrap.fill(label, 22) for label in labels]  # long labels on several lines
    fig, ax = plt.subplots(figsize=(3.2 + 1.6 * len(labels), 3.4))
    bottom = np.zeros(len(labels))
    for j, (name, colour) in enumerate(zip(parts, colours, strict=True)):
        v = np.array([means[m][j] for m in labels])
        ax.bar(ticks, v, 0.6, bottom=bottom, label=name, color=colour)
        bottom += v
    ax.set_ylabel("targets per episode (mean)")
    ax.tick_params(axis="x", labelsize=8)
    ax.legend(fontsize=8, frameon=False, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    save(fig, path)
    plt.close(fig)


def _accounting(runs: list[dict], keys: list, labels: list[str]) -> list[str]:
    """Where the targets are at the end, per episode (runs recorded since the fields
    exist; older runs are left out): verified, unverified on a receptacle the agent
    detected, on one it never detected, on the floor, and of those in a room never
    entered; the share of metres toured and of the finds made while touring."""
    rows = []
    means = account_means(runs, keys, labels)
    for label, run in zip(labels, runs, strict=True):
        eps = [run[k] for k in keys]
        if label not in means or not all(
            f in e for e in eps for f in ("touring_share", "found_touring")
        ):
            continue
        cells = " | ".join(f"{v:.2f}" for v in means[label])
        share = np.mean([e["touring_share"] for e in eps])
        toured = sum(e["found_touring"] for e in eps) / max(sum(e["found"] for e in eps), 1)
        # runs recorded before the field existed show a blank
        unentered = (f"{np.mean([e['missed_unentered'] for e in eps]):.2f}"
                     if all("missed_unentered" in e for e in eps) else "")  # fmt: skip
        rows.append(f"| {label} | {cells} | {unentered} | {share:.2f} | {toured:.2f} |")
    if not rows:
        return []
    return [
        "",
        "Targets per episode at the end: verified; unverified on a receptacle the agent "
        "detected, on one it never detected, on the floor, and (of those unverified) in a "
        "room the agent never entered; the share of metres spent touring, and of the finds "
        "made while touring.",
        "",
        "| method | found | on a detected receptacle | on an undetected one | on the floor "
        "| in a room never entered | touring share | finds while touring |",
        "|---|---|---|---|---|---|---|---|",
        *rows,
    ]


def run_colours(specs: list[str]) -> list[str]:
    """One colour per run: each method's own (as in ``ppl.png``); a method's second and
    later runs (two settings of one strategy, say) in ever lighter shades of it; runs of
    unknown methods by position."""
    from matplotlib.colors import to_hex, to_rgb

    from bfsop_jax.eval.navigation import ABLATIONS, METHODS, method_colours
    from bfsop_jax.viz.style import method_colour

    methods = [spec.split("+")[0].rpartition(":")[2] for spec in specs]
    if not set(methods) <= set(METHODS + ABLATIONS):
        return [method_colour(i) for i in range(len(specs))]
    out = []
    for i, (method, base) in enumerate(zip(methods, method_colours(methods), strict=True)):
        k = methods[:i].count(method)  # earlier runs of this method
        mix = 1.0 - 0.55 ** k  # 0, 0.45, 0.70, ... of the way to white
        out.append(to_hex([c + (1.0 - c) * mix for c in to_rgb(base)]))
    return out


def plot(
    by_bin: np.ndarray, labels: list[str], counts: list[str], path: str,
    colours: list[str] | None = None,
) -> None:  # fmt: skip
    """Grouped bars of mean PPL per instance-count bin, one bar per method (``colours``:
    one per method, default by position)."""
    import matplotlib.pyplot as plt

    from bfsop_jax.viz.style import method_colour, save

    m, b = by_bin.shape
    colours = colours or [method_colour(i) for i in range(m)]
    width = 0.8 / m
    fig, ax = plt.subplots(figsize=(3.6 + 1.5 * b, 3.4))
    for i in range(m):
        x = np.arange(b) + (i - (m - 1) / 2) * width
        ax.bar(x, by_bin[i], width, label=labels[i], color=colours[i])
    ax.set_xticks(np.arange(b), counts)
    ax.set_xlabel("instances of the target category in the house (episodes)")
    ax.set_ylabel("mean PPL")
    ax.legend(fontsize=8, frameon=False, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    save(fig, path)
    plt.close(fig)


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m experiments.compare`` (options: docs/cli.md)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", help="RUN_DIR:METHOD[+RUN_DIR:METHOD...]; first = reference")
    ap.add_argument("--label", action="append", default=None, help="one per run, in order")
    ap.add_argument("--png", default=None, help="also draw the by-count means here")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    labels = args.label or args.runs
    try:
        if len(labels) != len(args.runs):
            raise ValueError(f"{len(labels)} --label for {len(args.runs)} runs")
        runs, keys = shared(args.runs)
        text, by_bin, names = table(runs, keys, labels)
    except (ValueError, KeyError, json.JSONDecodeError) as err:
        print(f"compare: {err}", file=sys.stderr)
        return 2
    print(text)
    if args.png:
        plot(by_bin, labels, names, args.png, run_colours(args.runs))
        print(f"wrote {args.png}")
        means = account_means(runs, keys, labels)
        if means:
            where = str(Path(args.png).with_name(Path(args.png).stem + "_targets.png"))
            plot_targets(means, where)
            print(f"wrote {where}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
