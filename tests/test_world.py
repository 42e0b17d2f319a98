"""Procedural house generator: shapes, determinism and the properties a house must have."""

from __future__ import annotations

import collections

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import ndimage

from bfsop_jax.config import PRESET_NAMES, get_preset
from bfsop_jax.world import (
    CATEGORY_NAMES,
    House,
    generate_house,
)
from bfsop_jax.world import constants as C
from bfsop_jax.world.generator import (
    fill_free_pockets,
    free_space_components,
    generate_floorplan,
    passage_m,
    sample_house_bias,
)

SMOKE = get_preset("smoke")
N_SMOKE = 24

generate_batch = jax.jit(jax.vmap(generate_house, in_axes=(0, None)), static_argnums=1)
generate_one = jax.jit(generate_house, static_argnums=1)  # compiles faster than the batch
floorplan_batch = jax.jit(jax.vmap(generate_floorplan, in_axes=(0, None)), static_argnums=1)


def _house_keys(n: int, seed: int = 0) -> jax.Array:
    return jax.random.split(jax.random.PRNGKey(seed), n)


@pytest.fixture(scope="module")
def smoke_houses():
    keys = _house_keys(N_SMOKE)
    return keys, jax.device_get(generate_batch(keys, SMOKE))


@pytest.fixture(scope="module")
def demo_houses():
    keys = _house_keys(3, seed=7)
    houses = [generate_one(k, "demo") for k in keys]
    return keys, jax.device_get(jax.tree_util.tree_map(lambda *x: jnp.stack(x), *houses))


def _unbatch(houses: House, b: int) -> House:
    return jax.tree_util.tree_map(lambda x: x[b], houses)


def _each(houses: House):
    for b in range(houses.occupied.shape[0]):
        yield _unbatch(houses, b)


# --- shapes and JAX behaviour --------------------------------------------------------------
@pytest.mark.parametrize("name", PRESET_NAMES)
def test_shapes_and_dtypes_per_preset(name):
    p = get_preset(name)
    h, w = p.grid_shape
    r, m = p.max_rooms, p.max_objects
    out = jax.eval_shape(lambda k: generate_house(k, p), jax.random.PRNGKey(0))
    expected = {
        "occupied": ((h, w), jnp.bool_),
        "room_of_cell": ((h, w), jnp.int32),
        "room_type": ((r,), jnp.int32),
        "object_category": ((m,), jnp.int32),
        "object_xy": ((m, 2), jnp.float32),
        "object_size": ((m,), jnp.float32),
        "object_half_extent": ((m, 2), jnp.float32),
        "object_room": ((m,), jnp.int32),
        "object_parent": ((m,), jnp.int32),
    }
    for field, (shape, dtype) in expected.items():
        leaf = getattr(out, field)
        assert leaf.shape == shape, field
        assert leaf.dtype == dtype, field
    assert out.cell_size == p.cell_size


def test_batched_generation_is_deterministic_per_key(smoke_houses):
    keys, houses = smoke_houses
    again = jax.device_get(generate_batch(keys[::-1], SMOKE))
    leaves = jax.tree_util.tree_leaves(houses), jax.tree_util.tree_leaves(again)
    for a, b in zip(*leaves, strict=True):
        np.testing.assert_array_equal(a, b[::-1])
    # Different keys give different houses.
    assert not np.array_equal(houses.occupied[0], houses.occupied[1])
    assert all(np.isfinite(x).all() for x in jax.tree_util.tree_leaves(houses))


# --- floorplan -----------------------------------------------------------------------------
def _check_rooms(house: House, preset) -> None:
    valid = house.room_type >= 0
    n = int(valid.sum())
    assert preset.min_rooms <= n <= preset.max_rooms
    assert valid[:n].all() and not valid[n:].any()  # valid rooms are a prefix
    for t in range(C.N_ROOM_TYPES):
        assert (house.room_type == t).any(), C.ROOM_TYPE_NAMES[t]
    free = ~house.occupied
    rooms = house.room_of_cell
    assert rooms.max() < n and rooms.min() >= -1
    assert (rooms[free] >= 0).all()  # every free cell lies in a room
    # Bathrooms are the smallest rooms.
    area = np.bincount(rooms[rooms >= 0], minlength=n)[:n]
    bath = house.room_type[:n] == C.BATHROOM
    assert area[bath].max() <= 1.15 * area[~bath].min()  # raster areas: walls differ a little


def _room_graph_connected(house: House) -> bool:
    """Rooms as nodes, an edge where free cells of two rooms touch (through a door gap)."""
    free = ~house.occupied
    rooms = np.where(free, house.room_of_cell, -1)
    n = int((house.room_type >= 0).sum())
    edges = collections.defaultdict(set)
    for a, b in ((rooms[:, :-1], rooms[:, 1:]), (rooms[:-1, :], rooms[1:, :])):
        sel = (a >= 0) & (b >= 0) & (a != b)
        for u, v in zip(a[sel], b[sel], strict=True):
            edges[u].add(v)
            edges[v].add(u)
    seen, todo = {0}, [0]
    while todo:
        for v in edges[todo.pop()]:
            if v not in seen:
                seen.add(v)
                todo.append(v)
    return len(seen) == n


def test_smoke_free_space_is_one_component_and_rooms_are_linked(smoke_houses):
    for house in _each(smoke_houses[1]):
        _, n_components = ndimage.label(~house.occupied)
        assert n_components == 1
        _check_rooms(house, SMOKE)
        assert _room_graph_connected(house)
        assert house.occupied[0].all() and house.occupied[-1].all()  # closed outline
        assert house.occupied[:, 0].all() and house.occupied[:, -1].all()


def test_demo_houses(demo_houses):
    demo = get_preset("demo")
    for house in _each(demo_houses[1]):
        _, n_components = ndimage.label(~house.occupied)
        assert n_components == 1
        _check_rooms(house, demo)
        assert _room_graph_connected(house)
        assert (house.room_type == C.KITCHEN).sum() >= 2  # large houses repeat room types


def test_every_door_gap_is_open_and_joins_two_rooms(smoke_houses):
    keys, houses = smoke_houses
    # generate_house draws its floorplan from the first of five subkeys.
    plans = jax.device_get(
        floorplan_batch(jax.vmap(lambda k: jax.random.split(k, 5)[0])(keys), SMOKE)
    )
    depth = int(round(passage_m(SMOKE) / SMOKE.cell_size))  # clear floor in front of the gap
    for b, house in enumerate(_each(houses)):
        n_lines = int(plans.wall_valid[b].sum())
        assert n_lines == int((house.room_type >= 0).sum()) - 1
        assert plans.door_valid[b][:n_lines].all()  # one door on every partition line
        for (vertical, c, lo, hi), ok in zip(plans.door[b], plans.door_valid[b], strict=True):
            if not ok:
                continue
            assert 9 <= hi - lo <= 12  # 0.9 - 1.2 m
            span = slice(lo, hi)
            if vertical:
                cells = house.occupied[span, c - depth : c + depth]
                sides = house.room_of_cell[span, c - depth], house.room_of_cell[span, c + depth - 1]
            else:
                cells = house.occupied[c - depth : c + depth, span]
                sides = house.room_of_cell[c - depth, span], house.room_of_cell[c + depth - 1, span]
            assert not cells.any()
            assert (sides[0] >= 0).all() and (sides[1] >= 0).all()
            assert not np.intersect1d(sides[0], sides[1]).size  # different rooms on each side


def test_rooms_stay_reachable_for_the_robot(smoke_houses, demo_houses):
    radius = int(round(SMOKE.robot_radius_m / SMOKE.cell_size))
    yy, xx = np.mgrid[-radius : radius + 1, -radius : radius + 1]
    disk = xx**2 + yy**2 <= radius**2
    houses = list(_each(smoke_houses[1])) + list(_each(demo_houses[1]))
    for house in houses:
        centre_free = ndimage.binary_erosion(~house.occupied, structure=disk, border_value=0)
        label, _ = ndimage.label(centre_free)
        main = np.argmax(np.bincount(label[label > 0]))
        n = int((house.room_type >= 0).sum())
        reached = np.unique(house.room_of_cell[label == main])
        assert set(range(n)) <= set(reached.tolist())


# --- objects -------------------------------------------------------------------------------
def _check_objects(house: House) -> None:
    cat = house.object_category
    valid = cat >= 0
    n = int(valid.sum())
    assert valid[:n].all() and not valid[n:].any()  # valid slots are a prefix
    # -1 / 0 padding is consistent.
    assert (house.object_parent[~valid] == -1).all() and (house.object_room[~valid] == -1).all()
    assert (house.object_xy[~valid] == 0).all() and (house.object_size[~valid] == 0).all()
    assert (house.object_half_extent[~valid] == 0).all()
    np.testing.assert_allclose(house.object_size[valid], C.CATEGORY_SIZE_M[cat[valid]])
    n_rooms = int((house.room_type >= 0).sum())
    assert ((house.object_room[valid] >= 0) & (house.object_room[valid] < n_rooms)).all()

    target = valid & (cat < C.N_TARGETS)
    furniture = valid & ~target | (target & (house.object_parent < 0))
    cs = house.cell_size
    for m in np.flatnonzero(furniture):
        # Furniture (and floor plants) is rasterised in its own room.
        i, j = (house.object_xy[m][::-1] / cs).astype(int)
        assert house.occupied[i, j]
        assert house.room_of_cell[i, j] == house.object_room[m]
    for m in np.flatnonzero(target):
        t, parent, room = cat[m], house.object_parent[m], house.object_room[m]
        kind = house.room_type[room]
        assert C.TARGET_ROOM_WEIGHT[t, kind] > 0, (CATEGORY_NAMES[t], C.ROOM_TYPE_NAMES[kind])
        np.testing.assert_allclose(house.object_half_extent[m], C.CATEGORY_SIZE_M[t] / 2)
        if parent < 0:
            assert CATEGORY_NAMES[t] == "HousePlant"  # only plants stand on the floor
            continue
        rec = cat[parent]
        assert C.is_receptacle(rec) and C.SPAWN_PROB[rec - C.FIRST_RECEPTACLE, t] > 0
        assert house.object_room[parent] == room
        offset = np.abs(house.object_xy[m] - house.object_xy[parent])
        assert (offset <= house.object_half_extent[parent] + 1e-5).all()  # on its receptacle
    # ProcTHOR's per-receptacle and per-room limits.
    on_receptacle = target & (house.object_parent >= 0)
    parents = house.object_parent[on_receptacle], cat[on_receptacle]
    pairs = collections.Counter(zip(*parents, strict=True))
    assert max(pairs.values(), default=0) <= C.MAX_COPIES_PER_RECEPTACLE
    per_room = collections.Counter(zip(house.object_room[target], cat[target], strict=True))
    for name in C.ONE_PER_ROOM_TARGETS:
        t = C.TARGET_NAMES.index(name)
        assert all(v <= 1 for (_, tt), v in per_room.items() if tt == t), name


def test_objects_are_consistent(smoke_houses, demo_houses):
    for house in list(_each(smoke_houses[1])) + list(_each(demo_houses[1])):
        _check_objects(house)


def test_required_furniture_in_every_room(smoke_houses, demo_houses):
    required = {
        C.KITCHEN: ["CounterTop"],
        C.BATHROOM: ["Sink", "Toilet"],
        C.BEDROOM: ["Bed"],
    }
    for house in list(_each(smoke_houses[1])) + list(_each(demo_houses[1])):
        names = collections.defaultdict(set)
        for m in np.flatnonzero(house.object_category >= 0):
            names[house.object_room[m]].add(CATEGORY_NAMES[house.object_category[m]])
        for r, kind in enumerate(house.room_type):
            for name in required.get(int(kind), []):
                assert name in names[r], (C.ROOM_TYPE_NAMES[kind], name)


def test_houses_hold_several_targets(smoke_houses, demo_houses):
    smoke_cat = smoke_houses[1].object_category
    demo_cat = demo_houses[1].object_category
    present = np.stack([(smoke_cat == t).any(axis=1) for t in range(C.N_TARGETS)], 1)
    assert present.mean() > 0.6  # most categories in most small houses
    assert (present.mean(axis=0) > 0.3).all()
    assert ((demo_cat >= 0) & (demo_cat < C.N_TARGETS)).sum(axis=1).min() >= 20


# --- connectivity helpers --------------------------------------------------------------------
@pytest.mark.parametrize("seed", range(4))
def test_components_match_scipy_on_random_grids(seed):
    rng = np.random.default_rng(seed)
    occupied = rng.random((37, 53)) < 0.42
    labels = np.asarray(jax.jit(free_space_components)(~occupied))
    ref, n = ndimage.label(~occupied)
    assert (labels[occupied] == -1).all()
    # Same partition: a bijection between our labels and scipy's.
    pairs = set(zip(labels[~occupied].tolist(), ref[~occupied].tolist(), strict=True))
    assert len(pairs) == n == len(np.unique(labels[~occupied]))
    filled = np.asarray(jax.jit(fill_free_pockets)(occupied))
    sizes = np.bincount(ref[~occupied])
    assert (~filled == (ref == np.argmax(sizes[1:]) + 1)).all()  # only the largest is kept


def test_house_bias_follows_the_procthor_beta():
    from scipy import stats

    u = np.linspace(1e-5, 1 - 1e-5, 2001)
    ours = np.asarray(sample_house_bias(jnp.asarray(u, jnp.float32)))
    expected = 0.4 * stats.beta(3.5, 1.9).ppf(u) - 0.3
    np.testing.assert_allclose(ours, expected, atol=1e-4)
    assert ours.min() >= -0.3 and ours.max() <= 0.1


def test_paper_house_is_ultra_large():
    paper = get_preset("paper")
    house = jax.device_get(generate_one(jax.random.PRNGKey(3), paper))
    floor_m2 = (house.room_of_cell >= 0).sum() * paper.cell_size**2
    assert floor_m2 >= 2000.0
    assert (house.room_type >= 0).sum() >= 40
    _, n_components = ndimage.label(~house.occupied)
    assert n_components == 1
    present = [(house.object_category == t).any() for t in range(C.N_TARGETS)]
    assert sum(present) >= 8
