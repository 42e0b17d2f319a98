"""Detection model: scripted scenes with known answers, parity with the NumPy reference."""

from __future__ import annotations

import dataclasses
import functools
import math

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bfsop_jax.config import get_preset
from bfsop_jax.sensing.detection import landmarks_of_interest, observe, verified_targets
from bfsop_jax.world.constants import (
    CATEGORY_SIZE_M,
    FIRST_RECEPTACLE,
    N_CATEGORIES,
    N_TARGETS,
    category_id,
)
from bfsop_jax.world.types import House
from tests.reference_sensing import reference_landmarks, reference_observe

# An 8 m x 6 m grid with 8 object slots keeps hand-made scenes small.
ROOM = dataclasses.replace(
    get_preset("smoke"), name="room", width_m=8.0, height_m=6.0, max_objects=8
)
CUP, APPLE = category_id("Cup"), category_id("Apple")
TABLE, SOFA = category_id("DiningTable"), category_id("Sofa")


def make_house(occupied: np.ndarray, objects: list[dict], preset=ROOM) -> House:
    """House with the given occupancy and objects; every footprint is rasterised as occupied.

    Each object: ``cat``, ``xy``, optional ``size`` (default: the category's), ``half``
    (footprint half sizes, default 0.05 m) and ``parent`` (slot index, default -1).
    """
    m = preset.max_objects
    occ = occupied.copy()
    cat = np.full(m, -1, np.int32)
    xy = np.zeros((m, 2), np.float32)
    size = np.zeros(m, np.float32)
    half = np.zeros((m, 2), np.float32)
    parent = np.full(m, -1, np.int32)
    c = preset.cell_size
    for k, ob in enumerate(objects):
        cat[k] = ob["cat"]
        xy[k] = ob["xy"]
        size[k] = ob.get("size", CATEGORY_SIZE_M[ob["cat"]])
        half[k] = ob.get("half", (0.05, 0.05))
        parent[k] = ob.get("parent", -1)
        (x0, y0), (x1, y1) = xy[k] - half[k], xy[k] + half[k]
        occ[int(y0 / c) : int(math.ceil(y1 / c)), int(x0 / c) : int(math.ceil(x1 / c))] = True
    h, w = preset.grid_shape
    return House(
        occupied=jnp.asarray(occ),
        room_of_cell=jnp.zeros((h, w), jnp.int32),
        room_type=jnp.full(preset.max_rooms, -1, jnp.int32).at[0].set(0),
        object_category=jnp.asarray(cat),
        object_xy=jnp.asarray(xy),
        object_size=jnp.asarray(size),
        object_half_extent=jnp.asarray(half),
        object_room=jnp.where(jnp.asarray(cat) >= 0, 0, -1),
        object_parent=jnp.asarray(parent),
        cell_size=c,
    )


def empty(preset=ROOM) -> np.ndarray:
    return np.zeros(preset.grid_shape, bool)


@functools.cache
def _observe(preset):
    return jax.jit(functools.partial(observe, preset=preset))


def pose(x, y, heading=0.0):
    return jnp.array([x, y, heading], jnp.float32)


def test_wall_between_agent_and_object_hides_it():
    occ = empty()
    objects = [{"cat": CUP, "xy": (4.0, 3.0)}]
    seen = _observe(ROOM)(make_house(occ, objects), pose(2.0, 3.0))
    assert bool(seen.in_view[0]) and bool(seen.line_of_sight[0])
    occ[:, 30] = True  # a wall at x = 3.0 .. 3.1 m
    hidden = _observe(ROOM)(make_house(occ, objects), pose(2.0, 3.0))
    assert bool(hidden.in_fov[0]) and not bool(hidden.line_of_sight[0])
    assert not bool(hidden.in_view[0])


def test_object_behind_the_agent_is_not_in_view():
    house = make_house(empty(), [{"cat": CUP, "xy": (1.0, 3.0)}, {"cat": CUP, "xy": (3.0, 3.5)}])
    det = _observe(ROOM)(house, pose(2.0, 3.0, 0.0))  # facing +x
    assert not bool(det.in_fov[0]) and not bool(det.in_view[0])
    assert bool(det.in_view[1])  # 26.6 deg off the heading: inside the 90 deg FoV
    turned = _observe(ROOM)(house, pose(2.0, 3.0, math.pi))
    assert bool(turned.in_view[0]) and not bool(turned.in_view[1])


def test_objects_beyond_range_are_not_in_view():
    house = make_house(empty(), [{"cat": SOFA, "xy": (7.5, 3.0), "half": (0.45, 1.0)}])
    assert bool(_observe(ROOM)(house, pose(2.6, 3.0)).in_view[0])  # 4.9 m
    assert not bool(_observe(ROOM)(house, pose(2.4, 3.0)).in_view[0])  # 5.1 m


@pytest.mark.parametrize("distance,verified", [(0.9, True), (1.1, False)])
def test_verification_distance(distance, verified):
    house = make_house(empty(), [{"cat": CUP, "xy": (3.0 + distance, 3.0)}])
    det = _observe(ROOM)(house, pose(3.0, 3.0))
    np.testing.assert_allclose(float(det.distance[0]), distance, atol=1e-5)
    expected_area = (ROOM.focal_px * CATEGORY_SIZE_M[CUP] / distance) ** 2
    np.testing.assert_allclose(float(det.area_px[0]), expected_area, rtol=1e-5)
    assert bool(det.in_view[0])
    assert bool(verified_targets(det, house, jnp.int32(CUP), ROOM)[0]) == verified
    # Another category is never verified.
    assert not bool(verified_targets(det, house, jnp.int32(APPLE), ROOM)[0])


def test_small_objects_are_filtered_by_area():
    objects = [
        {"cat": APPLE, "xy": (3.8, 3.5), "size": 0.05},  # 0.94 m: 63 px < 100
        {"cat": APPLE, "xy": (3.8, 2.5)},  # 0.08 m at 0.94 m: 162 px
        {"cat": TABLE, "xy": (7.0, 3.0), "half": (0.3, 0.3), "size": 0.6},  # 4 m: 506 px
        {"cat": TABLE, "xy": (7.0, 4.0), "half": (0.2, 0.2), "size": 0.5},  # 4.1 m: 331 px
    ]
    house = make_house(empty(), objects)
    det = _observe(ROOM)(house, pose(3.0, 3.0))
    assert det.in_view[:4].all()
    np.testing.assert_array_equal(
        np.asarray(verified_targets(det, house, jnp.int32(APPLE), ROOM))[:4],
        [False, True, False, False],
    )
    prior = jnp.ones((N_CATEGORIES, N_TARGETS), jnp.float32)
    loi = np.asarray(landmarks_of_interest(det, house, prior, jnp.int32(APPLE), ROOM))
    np.testing.assert_array_equal(loi[:4], [False, False, True, False])


def test_landmark_needs_a_positive_prior():
    objects = [
        {"cat": TABLE, "xy": (5.0, 3.0), "half": (0.8, 0.45), "size": 1.6},
        {"cat": SOFA, "xy": (5.0, 4.5), "half": (1.0, 0.45), "size": 2.0},
    ]
    house = make_house(empty(), objects)
    det = _observe(ROOM)(house, pose(2.0, 3.5))
    assert det.in_view[:2].all()
    prior = np.zeros((N_CATEGORIES, N_TARGETS), np.float32)
    prior[TABLE, CUP] = 0.3  # cups co-occur with tables only
    loi_cup = landmarks_of_interest(det, house, jnp.asarray(prior), jnp.int32(CUP), ROOM)
    np.testing.assert_array_equal(np.asarray(loi_cup)[:2], [True, False])
    loi_apple = landmarks_of_interest(det, house, jnp.asarray(prior), jnp.int32(APPLE), ROOM)
    assert not np.asarray(loi_apple).any()


def test_target_on_a_receptacle_is_seen_over_its_footprint():
    # A cup on a 1.6 m table, 0.8 m behind the table's near edge: its own footprint is tiny,
    # the table's half-diagonal (0.92 m) is not.
    objects = [
        {"cat": TABLE, "xy": (5.0, 3.0), "half": (0.8, 0.45), "size": 1.6},
        {"cat": CUP, "xy": (5.0, 3.1), "parent": 0},
        {"cat": CUP, "xy": (5.0, 3.1)},  # same place, not registered on the table
    ]
    det = _observe(ROOM)(make_house(empty(), objects), pose(2.0, 3.0))
    np.testing.assert_array_equal(np.asarray(det.in_view)[:3], [True, True, False])


def test_invalid_slots_are_never_visible():
    house = make_house(empty(), [{"cat": CUP, "xy": (4.0, 3.0)}])
    det = _observe(ROOM)(house, pose(3.0, 3.0))
    assert bool(det.in_view[0]) and not np.asarray(det.in_view)[1:].any()
    assert not np.asarray(det.area_px)[1:].any()
    # An invalid slot with a plausible position is still invisible.
    house = house.replace(object_xy=house.object_xy.at[1].set(jnp.array([4.0, 3.2])))
    assert not bool(_observe(ROOM)(house, pose(3.0, 3.0)).in_view[1])


def test_interaction_threshold_option():
    # The optional per-category threshold 1000 * s px (the paper's interaction threshold)
    # only binds once the noise filter is lowered.
    low = dataclasses.replace(ROOM, noise_filter_px=10.0)
    house = make_house(empty(), [{"cat": APPLE, "xy": (3.95, 3.0), "size": 0.04}])  # 39.9 px
    det = observe(house, pose(3.0, 3.0), low)
    assert bool(verified_targets(det, house, jnp.int32(APPLE), low)[0])
    assert not bool(
        verified_targets(det, house, jnp.int32(APPLE), low, use_interaction_threshold=True)[0]
    )


def random_scene(rng: np.random.Generator, preset) -> tuple[House, np.ndarray]:
    """Random walls, receptacles with targets on them, floor targets, invalid slots, poses."""
    h, w = preset.grid_shape
    c = preset.cell_size
    occ = np.zeros((h, w), bool)
    for _ in range(rng.integers(0, 6)):  # thin walls
        if rng.random() < 0.5:
            r = rng.integers(h)
            a, b = sorted(rng.integers(0, w, 2))
            occ[r : r + 2, a:b] = True
        else:
            col = rng.integers(w)
            a, b = sorted(rng.integers(0, h, 2))
            occ[a:b, col : col + 2] = True
    objects = []
    m = preset.max_objects
    while len(objects) < m - 2:
        hx, hy = rng.uniform(0.15, 0.8, 2)
        cx, cy = rng.uniform(hx, w * c - hx), rng.uniform(hy, h * c - hy)
        size = float(rng.uniform(0.5, 2.0))
        objects.append(
            {"cat": int(rng.integers(FIRST_RECEPTACLE, N_CATEGORIES)), "xy": (cx, cy),
             "half": (hx, hy), "size": size}
        )  # fmt: skip
        parent = len(objects) - 1
        for _ in range(rng.integers(0, 3)):
            if len(objects) >= m - 2:
                break
            tx, ty = cx + rng.uniform(-hx, hx), cy + rng.uniform(-hy, hy)
            objects.append({"cat": int(rng.integers(N_TARGETS)), "xy": (tx, ty), "parent": parent})
        if rng.random() < 0.3 and len(objects) < m - 2:
            objects.append(
                {"cat": int(rng.integers(N_TARGETS)),
                 "xy": tuple(rng.uniform(0.2, [w * c - 0.2, h * c - 0.2]))}
            )  # fmt: skip
    house = make_house(occ, objects, preset)
    free = np.argwhere(~np.asarray(house.occupied))
    cells = free[rng.integers(len(free), size=6)]
    poses = np.stack(
        [(cells[:, 1] + rng.random(6)) * c, (cells[:, 0] + rng.random(6)) * c,
         rng.uniform(-math.pi, math.pi, 6)], -1
    ).astype(np.float32)  # fmt: skip
    return house, poses


def test_observe_parity_with_reference():
    preset = dataclasses.replace(get_preset("smoke"), max_objects=24)
    run = _observe(preset)
    rng = np.random.default_rng(7)
    n_visible = n_hidden = 0
    for _ in range(12):
        house, poses = random_scene(rng, preset)
        for p in poses:
            det = run(house, jnp.asarray(p))
            ref = reference_observe(house, p, preset)
            np.testing.assert_array_equal(np.asarray(det.in_view), ref["in_view"], err_msg=f"{p}")
            np.testing.assert_allclose(np.asarray(det.distance), ref["distance"], atol=1e-4)
            np.testing.assert_allclose(np.asarray(det.area_px), ref["area_px"], rtol=1e-4)
            prior = (rng.random((N_CATEGORIES, N_TARGETS)) < 0.5).astype(np.float32)
            cat = int(rng.integers(N_TARGETS))
            loi = landmarks_of_interest(det, house, jnp.asarray(prior), jnp.int32(cat), preset)
            cats = np.asarray(house.object_category)
            expected = reference_landmarks(ref["in_view"], ref["area_px"], cats, prior, cat, preset)
            np.testing.assert_array_equal(np.asarray(loi), expected)
            n_visible += int(ref["in_view"].sum())
            in_sight_cone = det.in_fov & (det.distance <= preset.sensor_range_m)
            n_hidden += int((in_sight_cone & ~det.line_of_sight & house.object_valid).sum())
    # The scenes exercise visible objects as well as objects hidden by obstacles.
    assert n_visible > 20 and n_hidden > 20, (n_visible, n_hidden)


def test_no_recompilation_and_vmap_over_categories():
    rng = np.random.default_rng(3)
    preset = ROOM

    @jax.jit
    @chex.assert_max_traces(n=1)
    def frame(house, p, prior, category):
        det = observe(house, p, preset)
        return (
            det,
            landmarks_of_interest(det, house, prior, category, preset),
            verified_targets(det, house, category, preset),
        )

    prior = jnp.ones((N_CATEGORIES, N_TARGETS), jnp.float32)
    for _ in range(3):
        house, poses = random_scene(rng, preset)
        for p in poses[:2]:
            det, _, _ = frame(house, jnp.asarray(p), prior, jnp.int32(rng.integers(N_TARGETS)))
    # Verification vmapped over all categories equals one call per category.
    cats = jnp.arange(N_TARGETS, dtype=jnp.int32)
    all_cats = jax.vmap(lambda c: verified_targets(det, house, c, preset))(cats)
    for c in range(N_TARGETS):
        single = verified_targets(det, house, jnp.int32(c), preset)
        np.testing.assert_array_equal(np.asarray(all_cats[c]), np.asarray(single))


def test_bad_inputs_raise_clear_errors():
    house = make_house(empty(), [{"cat": CUP, "xy": (4.0, 3.0)}])
    with pytest.raises(ValueError, match="pose must have shape"):
        observe(house, jnp.zeros(2), ROOM)
    with pytest.raises(ValueError, match="grid_shape"):
        observe(house, pose(1.0, 1.0), get_preset("smoke"))
    with pytest.raises(ValueError, match="cell_size"):
        observe(house.replace(cell_size=0.2), pose(1.0, 1.0), ROOM)
    det = observe(house, pose(3.0, 3.0), ROOM)
    with pytest.raises(ValueError, match="prior must have shape"):
        landmarks_of_interest(det, house, jnp.ones((N_TARGETS, N_TARGETS)), jnp.int32(0), ROOM)
