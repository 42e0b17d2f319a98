"""Frontier cells, clusters and the nearest frontier on hand-made beliefs."""

from __future__ import annotations

import dataclasses

import chex
import jax
import jax.numpy as jnp
import numpy as np
from scipy import ndimage

from bfsop_jax.config import get_preset
from bfsop_jax.navigation import (
    cluster_frontier_cells,
    distance_field,
    frontier_cells,
    frontier_clusters,
    nearest_frontier,
    plan_cell_states,
    planning_blocked,
    unknown_count,
    xy_to_plan_cell,
)

PRESET = get_preset("smoke")
FREE, OCC = -2.0, 2.0


def walled_room(rows, cols) -> np.ndarray:
    """Belief: unknown everywhere, a known-free room with a 2-cell known wall ring."""
    h, w = PRESET.grid_shape
    b = np.zeros((h, w), np.float32)
    r0, r1 = rows
    c0, c1 = cols
    b[r0 - 2 : r1 + 2, c0 - 2 : c1 + 2] = OCC
    b[r0:r1, c0:c1] = FREE
    return b


def one_door_room() -> np.ndarray:
    b = walled_room((20, 80), (20, 100))
    b[40:50, 100:102] = FREE  # 1 m door in the right wall, unknown beyond
    return b


_clusters = jax.jit(frontier_clusters, static_argnums=1)


def test_one_door_gives_one_frontier_in_the_door():
    b = one_door_room()
    cells = np.asarray(frontier_cells(b, PRESET))
    assert cells.any()
    rows, cols = np.nonzero(cells)
    assert set(cols) == {50} and rows.min() >= 20 and rows.max() <= 24  # the door's cells
    fr = _clusters(b, PRESET)
    assert int(fr.valid.sum()) == 1
    assert int(fr.size[0]) == cells.sum()
    x, y = np.asarray(fr.xy[0])
    assert 9.9 < x < 10.3 and 4.0 < y < 5.0  # in the doorway
    assert cells[tuple(np.asarray(xy_to_plan_cell(fr.xy[0], PRESET)))]  # a frontier cell


def test_fully_known_map_has_no_frontier():
    b = one_door_room()
    b[b == 0.0] = FREE  # everything beyond the door is now known free
    assert not np.asarray(frontier_cells(b, PRESET)).any()
    fr = _clusters(b, PRESET)
    assert not np.asarray(fr.valid).any()
    index, dist = nearest_frontier(fr, jnp.zeros(PRESET.plan_shape), PRESET)
    assert int(index) == -1 and np.isinf(float(dist))


def two_door_room() -> tuple[np.ndarray, np.ndarray]:
    """Door A 2 m left of the agent behind an internal wall; door B 5 m right, in the open."""
    b = walled_room((10, 110), (10, 80))
    b[55:65, 8:10] = FREE  # door A (left wall)
    b[55:65, 80:82] = FREE  # door B (right wall)
    b[10:100, 18:20] = OCC  # internal wall; the way to A goes round its far end
    agent = np.array([3.0, 6.0], np.float32)
    return b, agent


def test_nearest_frontier_is_geodesic_not_euclidean():
    b, agent = two_door_room()
    fr = _clusters(b, PRESET)
    assert int(fr.valid.sum()) == 2
    xy = np.asarray(fr.xy)[:2]
    field = distance_field(planning_blocked(b, PRESET), agent, PRESET)
    index, dist = nearest_frontier(fr, field, PRESET)
    euclid = np.linalg.norm(xy - agent, axis=1)
    door_b = int(np.argmax(xy[:, 0]))
    assert int(index) == door_b
    assert int(np.argmin(euclid)) != door_b
    cell = np.asarray(xy_to_plan_cell(xy[door_b], PRESET))
    np.testing.assert_allclose(float(dist), float(np.asarray(field)[cell[0], cell[1]]))
    assert 4.5 < float(dist) < 5.5


def test_unreachable_frontier_is_not_chosen():
    b, agent = two_door_room()
    fr = _clusters(b, PRESET)
    index, dist = nearest_frontier(fr, jnp.full(PRESET.plan_shape, jnp.inf), PRESET)
    assert int(index) == -1 and np.isinf(float(dist))


def pocket_and_door_room() -> tuple[np.ndarray, np.ndarray]:
    """The one-door room with a small unknown pocket (0.6 m square) near the agent, more
    than 2 m from every wall (the unknown space outside the room is out of its reach)."""
    b = one_door_room()
    b[50:56, 56:62] = 0.0  # unseen floor behind, say, a chair
    return b, np.array([5.0, 5.3], np.float32)


def test_unknown_count_matches_a_box_sum():
    b, _ = pocket_and_door_room()
    _, unknown = plan_cell_states(b, PRESET)
    unknown = np.asarray(unknown)
    cells = np.array([[26, 29], [22, 49], [0, 0], [5, 77]], np.int32)
    got = np.asarray(unknown_count(unknown, cells, 4))
    hp, wp = unknown.shape
    for (r, c), n in zip(cells, got, strict=True):
        box = unknown[max(r - 4, 0) : min(r + 5, hp), max(c - 4, 0) : min(c + 5, wp)]
        assert n == box.sum()  # cells beyond the map edge do not count
    assert got[0] == 9 and got[1] > 20  # the pocket's 3 x 3 cells; the open door


def test_unknown_count_equals_counting_the_square_cell_by_cell():
    """The box filter against the plain count, for centres inside and beyond the map."""
    from bfsop_jax.navigation.frontiers import _unknown_around

    rng = np.random.default_rng(0)
    unknown = jnp.asarray(rng.random((30, 40)) < 0.4)
    cells = np.stack([rng.integers(-12, 45, 300), rng.integers(-12, 55, 300)], -1)
    for radius in (0, 2, 10):
        got = unknown_count(unknown, cells.astype(np.int32), radius)
        plain = _unknown_around(unknown, cells.astype(np.int32), radius)[0].sum(-1)
        np.testing.assert_array_equal(np.asarray(got), np.asarray(plain))


def test_gain_bonus_prefers_the_door_to_a_nearer_pocket():
    b, agent = pocket_and_door_room()
    fr = _clusters(b, PRESET)
    field = distance_field(planning_blocked(b, PRESET), agent, PRESET)
    xy = np.asarray(fr.xy)
    door = int(np.argmax(np.where(np.asarray(fr.valid), xy[:, 0], -1.0)))
    nearest, _ = nearest_frontier(fr, field, PRESET)
    assert int(nearest) != door  # the pocket is nearer
    _, unknown = plan_cell_states(b, PRESET)
    count = unknown_count(unknown, xy_to_plan_cell(fr.xy, PRESET), 10)
    bonus = count.astype(jnp.float32) * np.float32(20.0 / 21**2)
    index, dist = nearest_frontier(fr, field, PRESET, bonus)
    assert int(index) == door
    cell = np.asarray(xy_to_plan_cell(xy[door], PRESET))
    assert float(dist) == float(np.asarray(field)[cell[0], cell[1]])  # still the geodesic
    small, _ = nearest_frontier(fr, field, PRESET, bonus * np.float32(0.01))
    assert int(small) == int(nearest)  # a weak bonus does not outweigh the distance


def reference_clusters(mask: np.ndarray, min_size: int):
    lab, n = ndimage.label(mask, structure=np.ones((3, 3)))
    out = []
    for k in range(1, n + 1):
        members = np.argwhere(lab == k)
        if len(members) >= min_size:
            out.append(members)
    return out


def test_clusters_match_scipy_components():
    rng = np.random.default_rng(0)
    hp, wp = PRESET.plan_shape
    mask = ndimage.binary_opening(rng.random((hp, wp)) < 0.35) & (rng.random((hp, wp)) < 0.8)
    preset = dataclasses.replace(PRESET, max_frontier_clusters=512)
    fr = jax.jit(cluster_frontier_cells, static_argnums=1)(mask, preset)
    ref = reference_clusters(mask, 3)
    assert int(fr.valid.sum()) == len(ref) > 10
    sizes = np.asarray(fr.size)[np.asarray(fr.valid)]
    assert list(sizes) == sorted((len(m) for m in ref), reverse=True)
    cells = np.asarray(xy_to_plan_cell(fr.xy, preset))[np.asarray(fr.valid)]
    by_cell = {tuple(c): m for m in ref for c in map(tuple, m)}
    for c, s in zip(cells, sizes, strict=True):
        members = by_cell[tuple(c)]  # the representative is a member of a cluster
        assert len(members) == s
        n = len(members)
        centroid = (2 * members.sum(0) + n) // (2 * n)  # rounded half up to a cell
        d2 = ((members - centroid) ** 2).sum(1)
        assert ((c - centroid) ** 2).sum() == d2.min()


def test_keeps_the_largest_clusters():
    hp, wp = PRESET.plan_shape
    mask = np.zeros((hp, wp), bool)
    mask[5, 5:8] = True  # 3
    mask[20, 5:10] = True  # 5
    mask[40, 5:7] = True  # 2: noise
    mask[50, 5:12] = True  # 7
    preset = dataclasses.replace(PRESET, max_frontier_clusters=2)
    fr = cluster_frontier_cells(jnp.asarray(mask), preset)
    assert list(np.asarray(fr.size)) == [7, 5] and np.asarray(fr.valid).all()
    preset = dataclasses.replace(PRESET, max_frontier_clusters=4)
    fr = cluster_frontier_cells(jnp.asarray(mask), preset)
    assert list(np.asarray(fr.size)) == [7, 5, 3, 0]
    assert list(np.asarray(fr.valid)) == [True, True, True, False]


def test_no_retrace_on_new_beliefs():
    @jax.jit
    @chex.assert_max_traces(n=1)
    def explore_target(belief, agent):
        fr = frontier_clusters(belief, PRESET)
        field = distance_field(planning_blocked(belief, PRESET), agent, PRESET)
        return nearest_frontier(fr, field, PRESET)

    b1 = one_door_room()
    b2, agent = two_door_room()
    i1, _ = explore_target(b1, jnp.array([5.0, 5.0]))
    i2, _ = explore_target(b2, jnp.asarray(agent))
    assert int(i1) == 0 and int(i2) >= 0


def test_long_winding_frontier_is_one_cluster():
    hp, wp = PRESET.plan_shape
    mask = np.zeros((hp, wp), bool)
    # a serpentine whose smallest index sits at the far end of the chain
    for k, r in enumerate(range(4, hp - 4, 4)):
        mask[r, 4 : wp - 4] = True
        c = wp - 5 if k % 2 == 0 else 4
        mask[r : r + 4, c] = True
    mask[hp - 4 :, :] = False
    fr = cluster_frontier_cells(jnp.asarray(mask), PRESET)
    lab, n = ndimage.label(mask, structure=np.ones((3, 3)))
    assert n == 1
    assert int(fr.valid.sum()) == 1 and int(fr.size[0]) == mask.sum()
