"""Table I: every navigation strategy on the same held-out episodes, scored by PPL.

    python -m experiments.evaluate --preset demo --house-seeds 1000000:1000010 \\
        --categories all --methods fbe,bfs_global,tfl_reactive,bfsop_vns,bfsop_st \\
        [--checkpoint DIR] [--procthor-dir DIR] [--gif N] --out DIR

    python -m experiments.evaluate --scan --preset demo --out DIR   # baselines, validation

Writes ``DIR/results.json`` (per-method summaries and per-episode records),
``DIR/table1.md``, ``DIR/ppl.png``, ``DIR/ppl_per_category.png`` and
``DIR/trajectories.png``; an interrupted run resumes from its finished chunks. ``--gif N``
then re-runs the first N episodes of the protocol with every method, one at a time with
the frame recorder (the same episodes), and writes them as animations to
``DIR/gifs/{method}_{house}_{category}.gif`` (:mod:`bfsop_jax.eval.gifs`).

``--scan`` runs the baselines' parameter grid (BFS-Global's budget fraction,
TFL-Reactive's trigger radius and timer, the BF-SOP switcher's tour horizon and yield
weight) on *validation* houses (seeds from ``VALIDATION_SEED_START``, never the test
houses) and writes ``DIR/scan.md`` ranked by PPL; the strategies' defaults are the
settings it picks. ``--methods`` limits the scan to those methods' grids (``bfsop_vns``
and ``bfsop_st`` share the switcher's grid).
"""

from __future__ import annotations

import argparse
import itertools
import json
import platform
import sys
import time
from pathlib import Path
from typing import Any

from bfsop_jax.config import (
    EVAL_SEED_START,
    PRESET_NAMES,
    VALIDATION_SEED_START,
    get_preset,
    parse_seed_range,
)
from bfsop_jax.eval import navigation as nav
from bfsop_jax.files import write_text
from bfsop_jax.world.constants import TARGET_NAMES, target_id

SCAN_GRID: dict[str, list[dict[str, Any]]] = {
    "bfs_global": [{"fraction": f} for f in (0.1, 0.25, 0.5, 0.75)],
    "tfl_reactive": [
        {"radius_m": r, "timer_m": t}
        for r, t in itertools.product((2.0, 3.0, 4.0, 5.0, 6.0), (10.0, 20.0, 40.0))
    ],
    # the switcher shared by both BF-SOP variants, scanned with the Transformer planner
    "bfsop_st": [{"tour_horizon_m": h} for h in (4.0, 6.0, 10.0, 20.0, 1000.0)]
    + [{"tour_horizon_m": 6.0, "yield_weight": w} for w in (0.5, 1.0)],
}


def _settings_key(method: str) -> str:
    return "bfsop" if method.startswith("bfsop") else method


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m experiments.evaluate`` (options: docs/cli.md)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--preset", default="demo", choices=PRESET_NAMES)
    ap.add_argument("--house-seeds", default=None,
                    help=f"held-out house seeds START:END (default {EVAL_SEED_START}:"
                    f"{EVAL_SEED_START + 10}; with --procthor-dir: file indices)")  # fmt: skip
    ap.add_argument("--categories", default="all", help="'all' or comma-separated names")
    ap.add_argument("--methods", default=",".join(nav.METHODS),
                    help=f"comma-separated, from {', '.join(nav.METHODS + nav.ABLATIONS)} "
                    "(default: the five of Table I)")  # fmt: skip
    ap.add_argument(
        "--checkpoint", default=None, help="Transformer run dir (default: the shipped demo model)"
    )
    ap.add_argument("--procthor-dir", default=None, help="evaluate on ProcTHOR house JSON files")
    ap.add_argument(
        "--settings", default=None, help='JSON overrides, e.g. {"bfs_global": {"fraction": 0.4}}'
    )
    ap.add_argument("--batch", type=int, default=30, help="episodes per vmapped chunk")
    ap.add_argument("--devices", type=int, default=None,
                    help="split chunks over the first N local devices (default all)")  # fmt: skip
    ap.add_argument("--scan", action="store_true", help="scan baseline settings (validation)")
    ap.add_argument("--gif", type=int, default=0, metavar="N",
                    help="also animate every method's first N episodes (DIR/gifs/)")  # fmt: skip
    ap.add_argument("--out", default=None, help="output dir (default runs/evaluate-<preset>)")
    ap.add_argument("--no-progress", action="store_true")
    return ap


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    return build_parser().parse_args(argv)


def _mesh(devices: int | None):
    """A mesh over the first ``devices`` local devices (all by default); None for one."""
    from bfsop_jax.parallel import first_devices_mesh

    try:
        return first_devices_mesh(devices, local=True)
    except ValueError as err:
        _fail(str(err))


def _fail(message: str) -> None:
    raise SystemExit(f"error: {message}")


def _check(args: argparse.Namespace) -> dict[str, Any]:
    """Validate everything before anything runs; one-line errors."""
    checked: dict[str, Any] = {}
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    known = nav.METHODS + nav.ABLATIONS
    unknown = [m for m in methods if m not in known]
    if unknown or not methods:
        _fail(f"unknown method {unknown[0] if unknown else '(none)'!r}; "
              f"methods are {', '.join(known)}")  # fmt: skip
    twice = [m for i, m in enumerate(methods) if m in methods[:i]]
    if twice:
        _fail(f"--methods lists {twice[0]!r} twice")
    checked["methods"] = methods
    if args.scan:
        keys = {_settings_key(m) for m in methods}
        checked["scan"] = [m for m in SCAN_GRID if _settings_key(m) in keys]
        if not checked["scan"]:
            _fail(f"--scan: none of the methods has a grid; scanned methods are "
                  f"{', '.join(SCAN_GRID)} (bfsop_vns shares bfsop_st's)")  # fmt: skip
    if args.categories.strip() == "all":
        checked["categories"] = list(range(len(TARGET_NAMES)))
    else:
        try:
            checked["categories"] = [target_id(c.strip()) for c in args.categories.split(",")]
        except ValueError as err:
            _fail(str(err))
        cats = checked["categories"]
        twice = [k for i, k in enumerate(cats) if k in cats[:i]]
        if twice:
            _fail(f"--categories lists {TARGET_NAMES[twice[0]]} twice")
    if args.procthor_dir is not None:
        default = "0:10"  # file indices
    elif args.scan:
        default = f"{VALIDATION_SEED_START}:{VALIDATION_SEED_START + 4}"
    else:
        default = f"{EVAL_SEED_START}:{EVAL_SEED_START + 10}"
    try:
        checked["houses"] = parse_seed_range(args.house_seeds or default)
    except ValueError as err:
        _fail(str(err))
    if args.procthor_dir is None and not args.scan and checked["houses"].start < EVAL_SEED_START:
        _fail(f"house seeds below {EVAL_SEED_START} are training houses; evaluate on held-out "
              "seeds")  # fmt: skip
    if args.batch < 1:
        _fail("--batch must be at least 1")
    if args.gif < 0:
        _fail("--gif must be a number of episodes (0 or more)")
    if args.gif and args.scan:
        _fail("--gif animates the episodes of Table I, not of --scan")
    try:
        checked["settings"] = json.loads(args.settings) if args.settings else {}
        if not isinstance(checked["settings"], dict) or not all(
            isinstance(fields, dict) for fields in checked["settings"].values()
        ):
            raise ValueError('expected a JSON object of objects, e.g. {"bfsop": {...}}')
        for name, fields in checked["settings"].items():
            if name not in ("bfs_global", "tfl_reactive", "bfsop", "transformer", "explorer"):
                raise ValueError(
                    f"unknown key {name!r} (bfs_global, tfl_reactive, bfsop, transformer, explorer)"
                )
            base = name in ("bfsop", "transformer", "explorer")
            nav.make_strategy("fbe" if base else name, None, {name: fields})
    except (json.JSONDecodeError, TypeError, ValueError) as err:
        _fail(f"--settings: {err}")
    checked["policy"] = None
    if "bfsop_st" in methods or args.scan:
        from bfsop_jax.policy import StrategicPolicy

        try:
            checked["policy"] = StrategicPolicy.load(args.checkpoint)
        except ValueError as err:
            _fail(f"--checkpoint: {err}")
    try:
        checked["house_set"] = nav.HouseSet(get_preset(args.preset), args.procthor_dir)
    except ValueError as err:
        _fail(str(err))
    if args.procthor_dir is not None and checked["houses"].start >= len(checked["house_set"]):
        r = checked["houses"]
        _fail(f"--house-seeds {r.start}:{r.stop}: the folder has {len(checked['house_set'])} "
              "files")  # fmt: skip
    return checked


def run_table1(args: argparse.Namespace, c: dict[str, Any], out: Path) -> dict[str, Any]:
    houses = c["house_set"]
    ids = [h for h in c["houses"] if h < len(houses)]
    episodes = nav.protocol_episodes(houses, ids, c["categories"])
    if not episodes:
        _fail("no episode: no house holds any of the categories")
    protocol = {
        "house_seeds": [ids[0], ids[-1] + 1],
        "categories": [TARGET_NAMES[k] for k in c["categories"]],
        "procthor_dir": args.procthor_dir,
        "checkpoint": args.checkpoint or "shipped demo model",
        "machine": f"{platform.machine()}, {platform.system()}",
    }
    t0 = time.perf_counter()
    result = nav.evaluate_navigation(
        c["methods"], episodes, houses, out, policy=c["policy"], settings=c["settings"],
        batch=args.batch, progress=not args.no_progress, protocol=protocol,
        mesh=_mesh(args.devices),
    )  # fmt: skip
    result["wall_s"] = time.perf_counter() - t0
    nav.write_figures(result, out, houses)
    header = (
        f"# Table I: navigation ({args.preset}, houses {ids[0]}:{ids[-1] + 1}, "
        f"{len(c['categories'])} categories)\n"
    )
    text = nav.write_table1(result, out / "table1.md", header)
    print(text)
    if args.gif:
        from bfsop_jax.eval import gifs

        result["gifs"] = gifs.write_episode_gifs(
            c["methods"], episodes[: args.gif], houses, out / "gifs", policy=c["policy"],
            settings=c["settings"], progress=not args.no_progress,
        )  # fmt: skip
        print(f"{len(result['gifs'])} episode GIFs written to {out / 'gifs'}/")
    return result


def run_scan(args: argparse.Namespace, c: dict[str, Any], out: Path) -> list[dict[str, Any]]:
    """Every grid setting of each baseline on the validation houses, ranked by PPL."""
    houses = c["house_set"]
    ids = [h for h in c["houses"] if h < len(houses)]
    episodes = nav.protocol_episodes(houses, ids, c["categories"])
    if not episodes:
        _fail("no episode: no house holds any of the categories")
    rows = []
    for method in c["scan"]:
        key = _settings_key(method)
        for setting in SCAN_GRID[method]:
            tag = "_".join(f"{k}{v:g}" for k, v in setting.items())
            # the grid's values over the user's --settings (the rest of them still hold)
            settings = {**c["settings"], key: {**c["settings"].get(key, {}), **setting}}
            result = nav.evaluate_navigation(
                [method], episodes, houses, out / f"{method}_{tag}",
                settings=settings, policy=c["policy"],
                batch=args.batch, progress=not args.no_progress, mesh=_mesh(args.devices),
            )  # fmt: skip
            s = result["methods"][method]
            rows.append({
                "method": method, "setting": setting, "ppl_mean": s["ppl_mean"],
                "ppl_ci95": s["ppl_ci95"], "progress_mean": s["progress_mean"],
            })  # fmt: skip
    rows.sort(key=lambda r: (r["method"], -r["ppl_mean"]))
    lines = [f"# Baseline scan on validation houses {c['houses'].start}:{c['houses'].stop} "
             f"({args.preset}, {len(episodes)} episodes)", "",
             "| method | setting | PPL [95% CI] | progress |", "|---|---|---|---|"]  # fmt: skip
    for r in rows:
        lo, hi = r["ppl_ci95"]
        lines.append(
            f"| {nav.LABELS[r['method']]} | {json.dumps(r['setting'])} | "
            f"{r['ppl_mean']:.3f} [{lo:.3f}, {hi:.3f}] | {r['progress_mean']:.3f} |"
        )
    best = {m: max((r for r in rows if r["method"] == m), key=lambda r: r["ppl_mean"])["setting"]
            for m in c["scan"]}  # fmt: skip
    lines += ["", f"Best settings: `{json.dumps(best)}`"]
    write_text(out / "scan.md", "\n".join(lines) + "\n")
    write_text(out / "scan.json", json.dumps({"rows": rows, "best": best}, indent=1) + "\n")
    print("\n".join(lines))
    return rows


def main(argv: list[str] | None = None) -> dict[str, Any] | list[dict[str, Any]]:
    args = parse_args(argv)
    c = _check(args)
    out = Path(args.out or f"runs/evaluate-{args.preset}{'-scan' if args.scan else ''}")
    out.mkdir(parents=True, exist_ok=True)
    try:
        if args.scan:
            return run_scan(args, c, out)
        return run_table1(args, c, out)
    except ValueError as err:  # e.g. resuming into a directory of another evaluation
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(2) from None


if __name__ == "__main__":
    main()
