"""Latency of geodesic distance matrices and fields on house maps.

Usage::

    python -m benchmarks.bench_distance                  # smoke, demo and paper
    python -m benchmarks.bench_distance --preset demo --points 76 --repeats 20

For each preset it builds a few house maps (the procedural generator when available,
otherwise a hand-made recursive floorplan with doors and furniture), draws ``n_points``
random free planning cells, and times after compilation:

- ``distance_matrix`` for those points (the SOP cost matrix of docs/design.md §7.1),
- one ``distance_field`` (what the environment computes per macro step),
- ``jax.vmap`` of ``distance_field`` over a batch of 16 maps (batched rollouts),
- the in-loop case: ``jax.vmap`` of ``distance_matrix`` over 8 maps whose instances hold
  one to three landmarks' viewpoints (6-16 valid points of ``n_points``), against the
  dense layout that solves a field for every point slot (``distance_fields_from_cells``
  read at the points), side by side, with their ratio,

plus the iterations the solver needed (rounds of four sweeps, or relaxation steps: the
solver is ``geodesic_method()``, by backend or ``$BFSOP_GEODESICS``). Times are
wall-clock milliseconds with ``block_until_ready``; compile time is reported separately.
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.cli import positive_int, run_main
from benchmarks.timing import time_calls
from bfsop_jax.config import PRESET_NAMES, get_preset
from bfsop_jax.navigation import (
    distance_field,
    distance_fields_from_cells,
    distance_matrix,
    plan_cell_to_xy,
    true_blocked,
)
from bfsop_jax.navigation.distance import geodesic_method, sweep_rounds

ENV_BATCH = 16
SWITCH_BATCH = 8  # rows of one sparse_cond sub-batch (instances posed together)


def handmade_occupancy(preset, rng: np.random.Generator) -> np.ndarray:
    """[H, W] bool: recursive partition into rooms >= 3 m, 1 m doors, a few boxes."""
    h, w = preset.grid_shape
    occ = np.zeros((h, w), bool)
    occ[:2], occ[-2:], occ[:, :2], occ[:, -2:] = True, True, True, True
    side = 30  # fine cells
    rooms = [(2, h - 2, 2, w - 2)]
    target = preset.max_rooms
    while len(rooms) < target:
        rooms.sort(key=lambda r: (r[1] - r[0]) * (r[3] - r[2]))
        i0, i1, j0, j1 = rooms.pop()
        if max(i1 - i0, j1 - j0) < 2 * side + 2:
            rooms.append((i0, i1, j0, j1))
            break
        if j1 - j0 >= i1 - i0:
            c = int(rng.integers(j0 + side, j1 - side))
            occ[i0:i1, c : c + 2] = True
            d = int(rng.integers(i0 + 3, i1 - 13))
            occ[d : d + 10, c : c + 2] = False
            rooms += [(i0, i1, j0, c), (i0, i1, c + 2, j1)]
        else:
            c = int(rng.integers(i0 + side, i1 - side))
            occ[c : c + 2, j0:j1] = True
            d = int(rng.integers(j0 + 3, j1 - 13))
            occ[c : c + 2, d : d + 10] = False
            rooms += [(i0, c, j0, j1), (c + 2, i1, j0, j1)]
    for i0, i1, j0, _ in rooms:  # two pieces of furniture against walls per room
        for _ in range(2):
            a = int(rng.integers(i0, max(i0 + 1, i1 - 8)))
            occ[a : a + 6, j0 : j0 + int(rng.integers(5, 12))] = True
    return occ


def house_maps(preset, n: int, seed: int = 0) -> tuple[np.ndarray, str]:
    """[n, Hp, Wp] bool planning maps of true houses, and where they came from."""
    try:
        from bfsop_jax.world.generator import generate_house

        keys = jax.random.split(jax.random.PRNGKey(seed), n)
        occ = jax.vmap(lambda k: generate_house(k, preset).occupied)(keys)
        source = "generate_house"
    except Exception as err:  # the generator is optional for this benchmark
        rng = np.random.default_rng(seed)
        occ = np.stack([handmade_occupancy(preset, rng) for _ in range(n)])
        source = f"hand-made floorplans ({type(err).__name__} from generate_house)"
    blocked = jax.vmap(lambda o: true_blocked(o, preset))(jnp.asarray(occ))
    return np.asarray(blocked), source


def _time(fn, *args, repeats: int) -> tuple[float, list[float]]:
    """(compile + first run seconds, steady-state run times in ms)."""
    t = time_calls(fn, *args, repeats=repeats)
    return t.first_s, t.ms


def run(
    preset_name: str = "demo", n_points: int = 76, repeats: int = 10, n_houses: int = 3
) -> dict:
    """Benchmark one preset; returns a dict of figures (milliseconds unless named)."""
    preset = get_preset(preset_name)
    maps, source = house_maps(preset, max(n_houses, 1))
    rng = np.random.default_rng(1)
    points = []
    for b in maps:
        free = np.argwhere(~b)
        points.append(free[rng.choice(len(free), n_points, replace=False)])
    points = np.stack(points).astype(np.int32)
    xy = np.asarray(plan_cell_to_xy(points, preset))
    valid = np.ones(n_points, bool)

    matrix = jax.jit(distance_matrix, static_argnums=3)
    field = jax.jit(distance_field, static_argnums=2)
    batch = jax.jit(jax.vmap(distance_field, in_axes=(0, 0, None)), static_argnums=2)
    method = geodesic_method()
    rounds = jax.jit(lambda b, c, v: sweep_rounds(b, c, v, preset, method))

    compile_s, matrix_ms, field_ms, n_rounds = [], [], [], []
    for k in range(len(maps)):
        first, times = _time(matrix, maps[k], xy[k], valid, preset, repeats=repeats)
        compile_s.append(first - min(times) / 1e3)
        matrix_ms += times
        field_ms += _time(field, maps[k], xy[k, 0], preset, repeats=repeats)[1]
        n_rounds.append(int(rounds(maps[k], points[k], valid)))
    reps = -(-ENV_BATCH // len(maps))
    bmaps = np.concatenate([maps] * reps)[:ENV_BATCH]
    bxy = np.concatenate([xy[:, 0]] * reps)[:ENV_BATCH]
    batch_first, batch_ms = _time(batch, bmaps, bxy, preset, repeats=repeats)
    sparse_ms, dense_ms = _in_loop_matrices(preset, maps, points, repeats)
    return {
        "preset": preset.name,
        "plan_shape": preset.plan_shape,
        "maps": source,
        "n_points": n_points,
        "compile_s": float(np.mean(compile_s)),
        "matrix_ms_median": float(np.median(matrix_ms)),
        "matrix_ms_min": float(np.min(matrix_ms)),
        "sweep_rounds": n_rounds,
        "field_ms_median": float(np.median(field_ms)),
        f"vmap{ENV_BATCH}_fields_ms_median": float(np.median(batch_ms)),
        "in_loop_valid_lanes_ms_median": sparse_ms,
        "in_loop_dense_ms_median": dense_ms,
        "in_loop_speedup": dense_ms / sparse_ms,
        "device": jax.devices()[0].platform,
        "method": method,
    }


def _in_loop_matrices(preset, maps, points, repeats: int) -> tuple[float, float]:
    """Median ms of 8 vmapped in-loop matrices: valid lanes only, and the dense layout."""
    rng = np.random.default_rng(2)
    rows = [k % len(maps) for k in range(SWITCH_BATCH)]
    n = points.shape[1]
    valid = np.zeros((SWITCH_BATCH, n), bool)
    for r in range(SWITCH_BATCH):  # the start and one to three landmarks' viewpoints
        valid[r, : 1 + preset.n_viewpoints * int(rng.integers(1, 4))] = True
    bmaps, bpoints = maps[rows], points[rows]
    bxy = np.asarray(plan_cell_to_xy(bpoints, preset))

    def dense(blocked, cells, ok):
        f = distance_fields_from_cells(blocked, cells, ok, preset)[:, cells[:, 0], cells[:, 1]]
        return jnp.minimum(f, f.T)

    sparse = jax.jit(jax.vmap(lambda b, p, v: distance_matrix(b, p, v, preset)))
    sparse_ms = _time(sparse, bmaps, bxy, valid, repeats=repeats)[1]
    dense_ms = _time(jax.jit(jax.vmap(dense)), bmaps, bpoints, valid, repeats=repeats)[1]
    return float(np.median(sparse_ms)), float(np.median(dense_ms))


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m benchmarks.bench_distance`` (options: docs/cli.md)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", choices=PRESET_NAMES, action="append")
    parser.add_argument("--points", type=positive_int, default=76)
    parser.add_argument("--repeats", type=positive_int, default=10)
    parser.add_argument("--houses", type=positive_int, default=3)
    return parser


def main() -> None:
    args = build_parser().parse_args()
    for name in args.preset or PRESET_NAMES:
        r = run(name, args.points, args.repeats, args.houses)
        print(
            f"[{r['preset']}] plan grid {r['plan_shape']} ({r['maps']}), {r['device']}: "
            f"{r['n_points']}x{r['n_points']} distance matrix "
            f"{r['matrix_ms_median']:.1f} ms median ({r['matrix_ms_min']:.1f} min), "
            f"compile {r['compile_s']:.2f} s, {r['method']} iterations {r['sweep_rounds']}; "
            f"one field {r['field_ms_median']:.2f} ms; "
            f"vmap over {ENV_BATCH} maps {r[f'vmap{ENV_BATCH}_fields_ms_median']:.1f} ms; "
            f"in-loop matrices ({SWITCH_BATCH} rows, 6-16 valid points): valid lanes "
            f"{r['in_loop_valid_lanes_ms_median']:.1f} ms, dense "
            f"{r['in_loop_dense_ms_median']:.1f} ms, "
            f"dense/valid-lanes speedup {r['in_loop_speedup']:.1f}x"
        )


if __name__ == "__main__":
    run_main(main)
