"""How long the optimal visit length takes, and how close its heuristic gets, by size.

Usage::

    python -m benchmarks.bench_metrics --sizes 4,8,12,16,18,20,30,60 --matrices 5
    python -m benchmarks.bench_metrics --sizes 13,16,18,20 --preset paper --houses 32

The navigation evaluation computes the optimal visit length (the shortest open path from
the start through every target found, ``bfsop_jax.metrics.optimal_visit_length``) once per
episode: Held-Karp up to ``EXACT_MAX`` targets, an iterated local search above. For each
number of targets F, ``--matrices`` random Euclidean matrices (points uniform in a
20 m square, seeded) are solved both ways on the host. Printed per F: the median and
slowest milliseconds of each, how far above the optimum the heuristic lands (mean and
worst, percent) and on how many matrices it misses the optimum. Sizes above
``EXACT_FORCE_MAX`` are timed with the heuristic only. Record results with the machine and
the date in ``docs/benchmarks.md``.

``--preset P --houses H`` also counts, over H generated houses (evaluation seeds), how many
instances of each target category a house holds (the F of an episode that finds them all,
so the share above ``EXACT_MAX`` is how often the heuristic is used), and measures the
heuristic on the evaluation's own matrices: for each F of ``--sizes`` up to
``EXACT_FORCE_MAX`` and each house-category pair with at least F instances, a seeded random
F of them (as if those were the ones found), with the geodesic distances on the true map
between the episode's start and their verification points.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks.cli import positive_int, run_main
from benchmarks.timing import machine
from bfsop_jax.config import PRESET_NAMES
from bfsop_jax.metrics import EXACT_FORCE_MAX, EXACT_MAX, optimal_visit_length


def _euclidean(rng: np.random.Generator, f: int) -> np.ndarray:
    """[F+1, F+1] metres between F+1 points uniform in a 20 m square."""
    pts = rng.uniform(0.0, 20.0, size=(f + 1, 2))
    return np.linalg.norm(pts[:, None, :] - pts[None, :, :], axis=-1)


def _timed(d: np.ndarray, exact: bool) -> tuple[float, float]:
    """(length in metres, milliseconds) of one solve."""
    t0 = time.perf_counter()
    length = optimal_visit_length(d, exact=exact)
    return length, 1e3 * (time.perf_counter() - t0)


_MISS_PCT = 1e-6  # a miss: the heuristic this many percent or more above the optimum


def _gap_pct(mats: list[np.ndarray]) -> np.ndarray:
    """Percent above Held-Karp's optimum that the heuristic lands, per (finite) matrix."""
    heur = np.array([optimal_visit_length(d, exact=False) for d in mats])
    exact = np.array([optimal_visit_length(d, exact=True) for d in mats])
    return 100.0 * (heur / exact - 1.0)


def _gap_cells(gap: np.ndarray) -> str:
    """``mean / max`` percent and ``misses / matrices``."""
    shown = np.where(gap > -1e-9, np.maximum(gap, 0.0), gap)  # no "-0.000" from rounding
    return f"{shown.mean():.3f} / {shown.max():.3f} | {(gap >= _MISS_PCT).sum()} / {len(gap)}"


def _sizes(text: str) -> list[int]:
    """``--sizes``: comma-separated numbers of targets, each >= 1 (argparse type)."""
    try:
        sizes = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        sizes = []
    if not sizes or min(sizes) < 1:
        raise argparse.ArgumentTypeError(f"expected target counts >= 1, got {text!r}")
    return sizes


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m benchmarks.bench_metrics`` (options: docs/cli.md)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=_sizes, help="comma-separated numbers of targets F",
                        default=f"4,8,12,16,{EXACT_MAX},{EXACT_FORCE_MAX},30")  # fmt: skip
    parser.add_argument("--matrices", type=positive_int, default=5, help="random matrices per size")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--preset", default=None, choices=PRESET_NAMES,
                        help="also count targets per house")  # fmt: skip
    parser.add_argument("--houses", type=positive_int, default=32, help="houses counted (--preset)")
    return parser


def main(argv: list[str] | None = None) -> list[dict[str, float]]:
    args = build_parser().parse_args(argv)
    print(machine())
    print(f"automatic mode: exact up to EXACT_MAX = {EXACT_MAX} targets, "
          f"exact=True up to {EXACT_FORCE_MAX}")  # fmt: skip
    print("|  F | Held-Karp ms (median / max) | heuristic ms (median / max) "
          "| heuristic above optimum % (mean / max) | misses |")  # fmt: skip
    print("|---:|---:|---:|---:|---:|")
    rows = []
    rng = np.random.default_rng(args.seed)
    for f in args.sizes:
        mats = [_euclidean(rng, f) for _ in range(args.matrices)]
        heur = [_timed(d, exact=False) for d in mats]
        h_ms = np.array([t for _, t in heur])
        row = {"F": f, "heuristic_ms_median": float(np.median(h_ms)),
               "heuristic_ms_max": float(h_ms.max())}  # fmt: skip
        exact_cell, gap_cell = "-", "- | -"
        if f <= EXACT_FORCE_MAX:
            exact = [_timed(d, exact=True) for d in mats]
            e_ms = np.array([t for _, t in exact])
            h_len, e_len = np.array([h for h, _ in heur]), np.array([e for e, _ in exact])
            gap = 100.0 * (h_len / e_len - 1.0)
            row |= {"exact_ms_median": float(np.median(e_ms)), "exact_ms_max": float(e_ms.max()),
                    "gap_pct_mean": float(gap.mean()), "gap_pct_max": float(gap.max()),
                    "misses": int((gap >= _MISS_PCT).sum())}  # fmt: skip
            exact_cell = f"{np.median(e_ms):.2f} / {e_ms.max():.2f}"
            gap_cell = _gap_cells(gap)
        print(f"| {f:2d} | {exact_cell} | {np.median(h_ms):.2f} / {h_ms.max():.2f} "
              f"| {gap_cell} |")  # fmt: skip
        rows.append(row)
    if args.preset is not None:
        rows += _houses(args.preset, args.houses, args.sizes, args.seed)
    return rows


def _houses(preset_name: str, houses: int, sizes: list[int], seed: int) -> list[dict[str, float]]:
    """Count the instances per target category in ``houses`` generated houses (the
    evaluation's own count), then compare the heuristic with Held-Karp (lengths, no timing)
    on the evaluation's matrices: a random F of a category's instances per house-category
    pair with at least F, from the episode's start. Returns one row per F compared."""
    import jax

    from bfsop_jax.config import EVAL_SEED_START, get_preset
    from bfsop_jax.env import sample_start_pose
    from bfsop_jax.eval.navigation import Episode, HouseSet, target_distances
    from bfsop_jax.world.constants import TARGET_NAMES

    preset = get_preset(preset_name)
    house_set = HouseSet(preset)
    seeds = range(EVAL_SEED_START, EVAL_SEED_START + houses)
    counts = np.stack([house_set.counts(h) for h in seeds])  # [H, N_TARGETS]
    print(
        f"{preset_name}, {houses} houses: instances per house (largest) "
        + ", ".join(f"{n} {m}" for n, m in zip(TARGET_NAMES, counts.max(0), strict=True))
    )
    print(f"house-category pairs with more than EXACT_MAX = {EXACT_MAX} targets: "
          f"{100 * (counts > EXACT_MAX).mean():.1f} %")  # fmt: skip

    compared = [f for f in sizes if 2 <= f <= EXACT_FORCE_MAX]
    if not compared:
        return []
    start = jax.jit(lambda k, h: sample_start_pose(k, h, preset)[:2])
    rng = np.random.default_rng(seed)
    mats: dict[int, list[np.ndarray]] = {f: [] for f in compared}
    for row, house_id in enumerate(seeds):
        house = house_set[house_id]
        for cat in np.flatnonzero(counts[row] >= min(compared)):
            episode = Episode(house_id, int(cat))
            xy = np.asarray(start(episode.key, house))[None]
            (idx,), (dist,) = target_distances([episode], house_set, xy)
            for f in compared:
                if f <= len(idx):
                    sel = np.concatenate([[0], 1 + np.sort(rng.choice(len(idx), f, replace=False))])
                    d = dist[np.ix_(sel, sel)]
                    if np.isfinite(d).all():
                        mats[f].append(d)
    print(f"{preset_name}, evaluation matrices (random F of a category's instances, "
          "from the episode start):")  # fmt: skip
    print("|  F | heuristic above optimum % (mean / max) | misses |")
    print("|---:|---:|---:|")
    out = []
    for f in compared:
        if not mats[f]:
            print(f"| {f:2d} | - | 0 / 0 |")
            continue
        gap = _gap_pct(mats[f])
        print(f"| {f:2d} | {_gap_cells(gap)} |")
        out.append({"F": f, "preset": preset_name, "pairs": len(gap),
                    "gap_pct_mean": float(gap.mean()), "gap_pct_max": float(gap.max()),
                    "misses": int((gap >= _MISS_PCT).sum())})  # fmt: skip
    return out


if __name__ == "__main__":
    run_main(main)
