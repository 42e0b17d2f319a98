"""Planning grid and geodesic distances: parity with NumPy / SciPy references."""

from __future__ import annotations

import math

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from bfsop_jax.config import get_preset
from bfsop_jax.navigation import (
    distance_field,
    distance_fields,
    distance_fields_from_cells,
    distance_matrix,
    plan_cell_to_xy,
    planning_blocked,
    true_blocked,
    xy_to_plan_cell,
)
from bfsop_jax.navigation.distance import (
    MATRIX_CHUNK,
    METHOD_ENV,
    RELAX_STEPS,
    geodesic_method,
    sweep_rounds,
)

PRESET = get_preset("smoke")
PC = PRESET.plan_cell_size


# --- hand-made worlds ---------------------------------------------------------------------


def fine_house(rng: np.random.Generator, preset=PRESET, n_splits: int = 5) -> np.ndarray:
    """[H, W] bool occupancy: outer wall, rooms split by 2-cell walls with 1 m doors, boxes."""
    h, w = preset.grid_shape
    occ = np.zeros((h, w), bool)
    occ[:2], occ[-2:], occ[:, :2], occ[:, -2:] = True, True, True, True
    rooms = [(2, h - 2, 2, w - 2)]
    for _ in range(n_splits):
        rooms.sort(key=lambda r: (r[1] - r[0]) * (r[3] - r[2]))
        i0, i1, j0, j1 = rooms.pop()
        if j1 - j0 >= i1 - i0:  # vertical wall at column c with a door
            c = int(rng.integers(j0 + 25, j1 - 25))
            occ[i0:i1, c : c + 2] = True
            d = int(rng.integers(i0 + 2, i1 - 12))
            occ[d : d + 10, c : c + 2] = False
            rooms += [(i0, i1, j0, c), (i0, i1, c + 2, j1)]
        else:
            c = int(rng.integers(i0 + 25, i1 - 25))
            occ[c : c + 2, j0:j1] = True
            d = int(rng.integers(j0 + 2, j1 - 12))
            occ[c : c + 2, d : d + 10] = False
            rooms += [(i0, c, j0, j1), (c + 2, i1, j0, j1)]
    for _ in range(6):  # furniture
        a, b = int(rng.integers(3, h - 12)), int(rng.integers(3, w - 12))
        occ[a : a + int(rng.integers(3, 9)), b : b + int(rng.integers(3, 9))] = True
    return occ


def random_blocked(rng: np.random.Generator, density: float, shape=None) -> np.ndarray:
    """[Hp, Wp] bool planning map of random rectangles."""
    hp, wp = shape or PRESET.plan_shape
    b = np.zeros((hp, wp), bool)
    n = int(density * hp * wp / 6)
    for _ in range(n):
        a, c = rng.integers(0, hp), rng.integers(0, wp)
        b[a : a + rng.integers(1, 4), c : c + rng.integers(1, 4)] = True
    return b


def random_free_cells(rng, blocked: np.ndarray, n: int) -> np.ndarray:
    free = np.argwhere(~blocked)
    return free[rng.choice(len(free), n, replace=False)].astype(np.int32)


def cells_to_xy(cells: np.ndarray) -> np.ndarray:
    return np.stack([(cells[:, 1] + 0.5) * PC, (cells[:, 0] + 0.5) * PC], -1).astype(np.float32)


# --- references -----------------------------------------------------------------------------


def reference_blocked(occupied: np.ndarray, preset=PRESET) -> np.ndarray:
    """Brute force: a planning cell is blocked when an occupied fine square (or the
    outside) comes strictly closer than the robot radius to its centre."""
    h, w = occupied.shape
    hp, wp = preset.plan_shape
    f, cs, r = preset.plan_factor, preset.cell_size, preset.robot_radius_m
    m = int(math.ceil(r / cs)) + 2
    occ = np.pad(occupied, m, constant_values=True)
    out = np.zeros((hp, wp), bool)
    for i in range(hp):
        for j in range(wp):
            cy, cx = (i + 0.5) * f * cs, (j + 0.5) * f * cs
            a0, b0 = int(cy / cs) - m, int(cx / cs) - m
            for a in range(a0, a0 + 2 * m + 1):
                for b in range(b0, b0 + 2 * m + 1):
                    if not occ[a + m, b + m]:
                        continue
                    dy = max(a * cs - cy, 0.0, cy - (a + 1) * cs)
                    dx = max(b * cs - cx, 0.0, cx - (b + 1) * cs)
                    if math.hypot(dx, dy) < r - 1e-6:
                        out[i, j] = True
    return out


def dijkstra_fields(blocked: np.ndarray, cells: np.ndarray, pc: float = PC) -> np.ndarray:
    """SciPy Dijkstra on the 8-connected, no-corner-cutting graph: [S, Hp, Wp] float64."""
    hp, wp = blocked.shape
    free = ~blocked
    idx = np.arange(hp * wp).reshape(hp, wp)
    rows, cols, wts = [], [], []

    def add(ok, a, b, cost):
        rows.append(a[ok]), cols.append(b[ok]), wts.append(np.full(ok.sum(), cost))

    add(free[:, :-1] & free[:, 1:], idx[:, :-1], idx[:, 1:], pc)
    add(free[:-1] & free[1:], idx[:-1], idx[1:], pc)
    square = free[:-1, :-1] & free[1:, 1:] & free[1:, :-1] & free[:-1, 1:]
    add(square, idx[:-1, :-1], idx[1:, 1:], pc * math.sqrt(2))
    add(square, idx[:-1, 1:], idx[1:, :-1], pc * math.sqrt(2))
    r, c, wt = map(np.concatenate, (rows, cols, wts))
    graph = coo_matrix((wt, (r, c)), shape=(hp * wp, hp * wp)).tocsr()
    d = dijkstra(graph, directed=False, indices=idx[cells[:, 0], cells[:, 1]])
    d = d.reshape(-1, hp, wp)
    d[:, blocked] = np.inf
    return d


def assert_fields_equal(got, want):
    got = np.asarray(got)
    np.testing.assert_array_equal(np.isfinite(got), np.isfinite(want))
    fin = np.isfinite(want)
    np.testing.assert_allclose(got[fin], want[fin], rtol=1e-5, atol=1e-5)


_fields = jax.jit(distance_fields_from_cells, static_argnums=3)


# --- planning grid ---------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1])
def test_true_blocked_matches_brute_force(seed):
    occ = fine_house(np.random.default_rng(seed))
    got = np.asarray(jax.jit(true_blocked, static_argnums=1)(occ, PRESET))
    np.testing.assert_array_equal(got, reference_blocked(occ))


def test_planning_blocked_is_optimistic():
    rng = np.random.default_rng(3)
    occ = fine_house(rng)
    belief = np.where(occ, 2.0, -2.0).astype(np.float32)
    unknown = rng.random(occ.shape) < 0.5
    belief[unknown] = 0.0  # unknown (occupied or not) plans as free
    belief[~occ & (rng.random(occ.shape) < 0.2)] = 0.1  # weak evidence: still unknown
    got = np.asarray(planning_blocked(jnp.asarray(belief), PRESET))
    np.testing.assert_array_equal(got, reference_blocked(occ & ~unknown))


def test_door_leaves_three_cells():
    h, w = PRESET.grid_shape
    occ = np.zeros((h, w), bool)
    occ[:, 80:82] = True
    occ[50:59, 80:82] = False  # 0.9 m door
    blocked = np.asarray(true_blocked(occ, PRESET))
    assert blocked[:, 40].sum() == PRESET.plan_shape[0] - 3
    assert blocked[0].all() and blocked[:, 0].all()  # the map's own edge blocks


def test_cell_xy_round_trip():
    hp, wp = PRESET.plan_shape
    cells = np.stack(np.meshgrid(np.arange(hp), np.arange(wp), indexing="ij"), -1).reshape(-1, 2)
    xy = plan_cell_to_xy(cells, PRESET)
    np.testing.assert_array_equal(np.asarray(xy_to_plan_cell(xy, PRESET)), cells)
    out = xy_to_plan_cell(jnp.array([[-1.0, -1.0], [1e3, 1e3]]), PRESET)
    np.testing.assert_array_equal(np.asarray(out), [[0, 0], [hp - 1, wp - 1]])


def test_bad_shapes_raise():
    with pytest.raises(ValueError, match="grid_shape"):
        true_blocked(np.zeros((10, 10), bool), PRESET)
    with pytest.raises(ValueError, match="plan_shape"):
        distance_field(jnp.zeros((10, 10), bool), jnp.zeros(2), PRESET)
    with pytest.raises(ValueError, match="sources_xy"):
        distance_fields(jnp.zeros(PRESET.plan_shape, bool), jnp.zeros(3), PRESET)


# --- distance fields -----------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fields_match_dijkstra_on_houses(seed):
    rng = np.random.default_rng(seed)
    blocked = np.asarray(true_blocked(fine_house(rng), PRESET))
    cells = random_free_cells(rng, blocked, 12)
    got = _fields(blocked, cells, np.ones(12, bool), PRESET)
    assert_fields_equal(got, dijkstra_fields(blocked, cells))


@pytest.mark.parametrize("density", [0.1, 0.25, 0.4])
def test_fields_match_dijkstra_on_random_obstacles(density):
    rng = np.random.default_rng(int(density * 100))
    blocked = random_blocked(rng, density)
    cells = random_free_cells(rng, blocked, 8)
    got = _fields(blocked, cells, np.ones(8, bool), PRESET)
    assert_fields_equal(got, dijkstra_fields(blocked, cells))


def test_open_grid_is_octile_distance():
    blocked = np.zeros(PRESET.plan_shape, bool)
    src = np.array([[7, 11]], np.int32)
    got = np.asarray(_fields(blocked, src, np.ones(1, bool), PRESET))[0]
    ii, jj = np.indices(blocked.shape)
    di, dj = np.abs(ii - 7), np.abs(jj - 11)
    want = PC * (np.maximum(di, dj) + (math.sqrt(2) - 1) * np.minimum(di, dj))
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)


def test_no_corner_cutting():
    blocked = np.ones(PRESET.plan_shape, bool)
    blocked[10, 10] = blocked[11, 11] = False  # touching only at a corner
    blocked[20, 20] = blocked[21, 21] = blocked[20, 21] = False  # one orthogonal cell free
    blocked[30:32, 30:32] = False  # a free 2 x 2 square
    src = np.array([[10, 10], [20, 20], [30, 30]], np.int32)
    f = np.asarray(_fields(blocked, src, np.ones(3, bool), PRESET))
    assert np.isinf(f[0, 11, 11])
    np.testing.assert_allclose(f[1, 21, 21], 2 * PC, rtol=1e-6)  # around, not across
    np.testing.assert_allclose(f[2, 31, 31], PC * math.sqrt(2), rtol=1e-6)


def test_blocked_source_snaps_to_nearest_free_cell():
    blocked = np.zeros(PRESET.plan_shape, bool)
    blocked[:, 30:33] = True  # a thick wall; source on its middle column
    blocked[10:13, 20:40] = True
    got = np.asarray(
        distance_field(jnp.asarray(blocked), plan_cell_to_xy(np.array([30, 31]), PRESET), PRESET)
    )
    # nearest free cells of (30, 31) are (30, 29) and (30, 33) at 2 cells; the fixed order
    # picks one of them, which then reads 0
    assert got[30, 29] == 0.0 or got[30, 33] == 0.0
    solid = np.ones(PRESET.plan_shape, bool)
    solid[0, 0] = False
    far = distance_field(jnp.asarray(solid), plan_cell_to_xy(np.array([30, 40]), PRESET), PRESET)
    assert np.isinf(np.asarray(far)).all()


def test_distance_matrix_properties():
    rng = np.random.default_rng(7)
    blocked = np.array(true_blocked(fine_house(rng), PRESET))
    blocked[:, 60:62] = True  # cut the house in two: some pairs are unreachable
    cells = random_free_cells(rng, blocked, 10)
    valid = np.ones(10, bool)
    valid[[3, 8]] = False
    m = np.asarray(
        jax.jit(distance_matrix, static_argnums=3)(blocked, cells_to_xy(cells), valid, PRESET)
    )
    ref = dijkstra_fields(blocked, cells)[:, cells[:, 0], cells[:, 1]]
    ref[~valid] = np.inf
    ref[:, ~valid] = np.inf
    np.fill_diagonal(ref, np.where(valid, 0.0, np.inf))
    assert_fields_equal(m, ref)
    np.testing.assert_array_equal(m, m.T)
    assert np.isinf(m).any() and np.isfinite(m[valid][:, valid]).any()


def test_distance_matrix_solves_valid_sources_only_and_equals_dense_fields():
    """Batched matrices pool the valid sources of all rows into chunks (several chunks,
    rows with none): values equal the fields read at the cells, bit for bit."""
    rng = np.random.default_rng(21)
    n_maps, s = 3, 12
    maps = np.stack([random_blocked(rng, 0.2) for _ in range(n_maps)])
    cells = np.stack([random_free_cells(rng, b, s) for b in maps])
    valid = rng.random((n_maps, s)) < 0.7
    valid[:, 0] = True
    valid[2] = False  # a row with no valid point at all
    assert valid.sum() > MATRIX_CHUNK["sweeps"]  # more than one chunk of lanes
    xy = np.stack([cells_to_xy(c) for c in cells])
    matrices = jax.jit(jax.vmap(lambda b, p, v: distance_matrix(b, p, v, PRESET)))
    got = np.asarray(matrices(maps, xy, valid))
    fields = jax.jit(jax.vmap(lambda b, c, v: distance_fields_from_cells(b, c, v, PRESET)))(
        maps, cells, valid
    )
    for k in range(n_maps):
        f = np.asarray(fields[k])[:, cells[k, :, 0], cells[k, :, 1]]
        want = np.minimum(f, f.T)
        want[~valid[k]] = np.inf
        want[:, ~valid[k]] = np.inf
        np.fill_diagonal(want, np.where(valid[k], 0.0, np.inf))
        np.testing.assert_array_equal(got[k], want)
        alone = jax.jit(distance_matrix, static_argnums=3)(maps[k], xy[k], valid[k], PRESET)
        np.testing.assert_array_equal(np.asarray(alone), got[k])
    assert np.isinf(got[2]).all()


def test_vmap_over_maps_and_no_retrace():
    rng = np.random.default_rng(11)
    maps = np.stack([random_blocked(rng, 0.2) for _ in range(3)])
    srcs = np.stack([random_free_cells(rng, b, 4) for b in maps])
    ok = np.ones((3, 4), bool)
    batched = jax.jit(
        jax.vmap(distance_fields_from_cells, in_axes=(0, 0, 0, None)), static_argnums=3
    )(maps, srcs, ok, PRESET)
    for k in range(3):
        assert_fields_equal(batched[k], dijkstra_fields(maps[k], srcs[k]))

    @jax.jit
    @chex.assert_max_traces(n=1)
    def field(blocked, xy):
        return distance_field(blocked, xy, PRESET)

    for k in range(3):
        field(jnp.asarray(maps[k]), jnp.asarray(cells_to_xy(srcs[k])[0])).block_until_ready()


def test_nested_vmap_folds_batches_exactly():
    rng = np.random.default_rng(12)
    maps = np.stack([random_blocked(rng, 0.2) for _ in range(2)])
    srcs = np.stack([[random_free_cells(rng, b, 3) for _ in range(2)] for b in maps])  # [2,2,3,2]
    ok = np.ones((2, 2, 3), bool)
    ok[1, 0, 2] = False
    fn = lambda b, c, v: distance_fields_from_cells(b, c, v, PRESET)
    # outer vmap over maps, inner over source sets on the same map
    got = jax.jit(jax.vmap(jax.vmap(fn, in_axes=(None, 0, 0))))(maps, srcs, ok)
    assert got.shape == (2, 2, 3) + PRESET.plan_shape
    for a in range(2):
        for b in range(2):
            want = dijkstra_fields(maps[a], srcs[a, b])
            want[~ok[a, b]] = np.inf
            assert_fields_equal(got[a, b], want)
    # a shared map with a batch of single sources equals one multi-source call
    xy = cells_to_xy(srcs[0, 0])
    single = jax.vmap(lambda p: distance_field(jnp.asarray(maps[0]), p, PRESET))(xy)
    assert_fields_equal(single, dijkstra_fields(maps[0], srcs[0, 0]))


# --- the two solvers: sweeps (CPU) and whole-grid relaxation (accelerators) ---------------


def _both(fn):
    """fn(method) for both solvers, as NumPy arrays."""
    return [np.asarray(fn(m)) for m in ("sweeps", "relax")]


@pytest.mark.parametrize("seed", [0, 1])
def test_relaxation_equals_sweeps_bit_for_bit_on_houses(seed):
    rng = np.random.default_rng(100 + seed)
    blocked = np.array(true_blocked(fine_house(rng), PRESET))
    blocked[rng.integers(0, blocked.shape[0]), :] = True  # an unreachable part
    cells = random_free_cells(rng, blocked, 6)
    valid = np.ones(6, bool)
    valid[4] = False
    fields = jax.jit(distance_fields_from_cells, static_argnums=(3, 4))
    sweeps, relax = _both(lambda m: fields(blocked, cells, valid, PRESET, m))
    np.testing.assert_array_equal(relax, sweeps)
    assert np.isinf(relax[4]).all() and np.isinf(relax).any() and np.isfinite(relax).any()
    assert_fields_equal(relax[valid], dijkstra_fields(blocked, cells[valid]))
    # the relaxation stops at the first block of steps that changes nothing
    steps = int(
        jax.jit(sweep_rounds, static_argnums=(3, 4))(blocked, cells, valid, PRESET, "relax")
    )
    assert steps % RELAX_STEPS == 0 and steps >= RELAX_STEPS


def test_relaxation_batched_equals_alone_and_sweeps(monkeypatch):
    """Batched matrices with several chunks of lanes (the accelerator chunk shrunk to 8)
    and batched single fields: every row equals the row alone and the sweeps' value."""
    monkeypatch.setitem(MATRIX_CHUNK, "relax", 8)
    rng = np.random.default_rng(31)
    maps = np.stack([random_blocked(rng, 0.25) for _ in range(3)])
    cells = np.stack([random_free_cells(rng, b, 9) for b in maps])
    valid = rng.random((3, 9)) < 0.7
    valid[:, 0] = True
    assert valid.sum() > 8
    xy = np.stack([cells_to_xy(c) for c in cells])
    batched = lambda m: jax.jit(jax.vmap(lambda b, p, v: distance_matrix(b, p, v, PRESET, m)))(
        maps, xy, valid
    )
    sweeps, relax = _both(batched)
    np.testing.assert_array_equal(relax, sweeps)
    alone = jax.jit(distance_matrix, static_argnums=(3, 4))
    for k in range(3):
        np.testing.assert_array_equal(
            np.asarray(alone(maps[k], xy[k], valid[k], PRESET, "relax")), relax[k]
        )
    field = lambda m: jax.jit(jax.vmap(lambda b, p: distance_field(b, p, PRESET, m)))(
        maps, xy[:, 0]
    )
    f_sweeps, f_relax = _both(field)
    np.testing.assert_array_equal(f_relax, f_sweeps)
    one = jax.jit(distance_field, static_argnums=(2, 3))(maps[1], xy[1, 0], PRESET, "relax")
    np.testing.assert_array_equal(np.asarray(one), f_relax[1])


def test_geodesic_method_choice(monkeypatch):
    monkeypatch.delenv(METHOD_ENV, raising=False)
    assert geodesic_method() == ("sweeps" if jax.default_backend() == "cpu" else "relax")
    assert geodesic_method("relax") == "relax"
    monkeypatch.setenv(METHOD_ENV, "relax")
    assert geodesic_method() == "relax" and geodesic_method("sweeps") == "sweeps"
    monkeypatch.setenv(METHOD_ENV, "dijkstra")
    with pytest.raises(ValueError, match="BFSOP_GEODESICS must be"):
        geodesic_method()
    with pytest.raises(ValueError, match="method must be"):
        geodesic_method("fast")
