"""Ray-cast occupancy mapping: parity with the NumPy reference, scripted scans, properties."""

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
from bfsop_jax.sensing import mapping
from bfsop_jax.sensing.mapping import (
    cast_rays,
    known_free,
    known_occupied,
    scan_cells,
    unknown,
    update_belief,
)
from tests.reference_sensing import (
    reference_hit_dist,
    reference_scan,
    reference_update,
    step_table,
)

SMOKE = get_preset("smoke")
# A grid smaller than the scan window, a wide odd-range sensor, and a single ray.
TINY = dataclasses.replace(SMOKE, name="tiny", width_m=3.0, height_m=2.0)
WIDE = dataclasses.replace(
    SMOKE, name="wide", width_m=6.0, height_m=4.5, fov_deg=270.0, n_rays=37, sensor_range_m=2.55
)
ONE_RAY = dataclasses.replace(SMOKE, name="one_ray", width_m=5.0, height_m=5.0, n_rays=1)


@functools.cache
def _jitted(preset):
    return (
        jax.jit(functools.partial(update_belief, preset=preset)),
        jax.jit(functools.partial(scan_cells, preset=preset)),
        jax.jit(functools.partial(cast_rays, preset=preset)),
    )


def random_map(rng: np.random.Generator, preset, n_rect: int = 12) -> np.ndarray:
    """Random axis-aligned rectangles, sometimes inside an outer wall ring."""
    h, w = preset.grid_shape
    occ = np.zeros((h, w), bool)
    if rng.random() < 0.5:
        t = int(rng.integers(1, 3))
        occ[:t], occ[-t:], occ[:, :t], occ[:, -t:] = True, True, True, True
    for _ in range(n_rect):
        rh, rw = rng.integers(1, max(2, h // 4)), rng.integers(1, max(2, w // 4))
        r, c = rng.integers(0, h - rh + 1), rng.integers(0, w - rw + 1)
        occ[r : r + rh, c : c + rw] = True
    return occ


def random_poses(rng: np.random.Generator, occ: np.ndarray, preset, n: int) -> np.ndarray:
    """Free-cell poses: uniform, near the grid border, at inside corners, on cell edges."""
    h, w = occ.shape
    c = preset.cell_size
    free = np.argwhere(~occ)
    poses = []
    while len(poses) < n:
        kind = rng.integers(4)
        if kind == 0:  # anywhere free
            i, j = free[rng.integers(len(free))]
            x, y = (j + rng.random()) * c, (i + rng.random()) * c
        elif kind == 1:  # within 0.3 m of the grid border
            x, y = rng.uniform(0, w * c), rng.uniform(0, h * c)
            if rng.random() < 0.5:
                x = rng.choice([rng.uniform(0, 0.3), rng.uniform(w * c - 0.3, w * c)])
            else:
                y = rng.choice([rng.uniform(0, 0.3), rng.uniform(h * c - 0.3, h * c)])
        elif kind == 2:  # next to an inside corner: a free cell with occupied N/S and E/W
            pad = np.pad(occ, 1, constant_values=True)
            vert = pad[:-2, 1:-1] | pad[2:, 1:-1]
            horiz = pad[1:-1, :-2] | pad[1:-1, 2:]
            corners = np.argwhere(~occ & vert & horiz)
            if len(corners) == 0:
                continue
            i, j = corners[rng.integers(len(corners))]
            x, y = (j + rng.uniform(0.05, 0.95)) * c, (i + rng.uniform(0.05, 0.95)) * c
        else:  # exactly on cell edges / corners
            i, j = free[rng.integers(len(free))]
            x, y = j * c + rng.choice([0.0, 0.5 * c]), i * c + rng.choice([0.0, 0.5 * c])
        if rng.random() < 0.3:  # axis-aligned and diagonal headings hit cell edges exactly
            heading = rng.choice([0.0, 0.25, 0.5, 0.75, 1.0, -0.5, -0.25]) * math.pi
        else:
            heading = rng.uniform(-2 * math.pi, 2 * math.pi)
        poses.append((x, y, heading))
    return np.asarray(poses, np.float32)


def test_step_table_matches_reference():
    np.testing.assert_array_equal(mapping.step_table(), np.asarray(step_table(), np.int32))


@pytest.mark.parametrize(
    "preset,n_maps",
    [(SMOKE, 12), (TINY, 8), (WIDE, 8), (ONE_RAY, 4)],
    ids=["smoke", "tiny", "wide", "one_ray"],
)
def test_scan_parity_with_reference(preset, n_maps):
    """Same per-scan cell sets (exactly) and beliefs (allclose) over consecutive scans."""
    update, scan, cast = _jitted(preset)
    rng = np.random.default_rng(hash(preset.name) % 2**32)
    for _ in range(n_maps):
        occ = random_map(rng, preset)
        belief_jax = jnp.zeros(preset.grid_shape, jnp.float32)
        belief_ref = np.zeros(preset.grid_shape)
        for pose in random_poses(rng, occ, preset, 4):
            cells = scan(jnp.asarray(occ), jnp.asarray(pose))
            free_ref, occ_ref = reference_scan(occ, pose, preset)
            np.testing.assert_array_equal(np.asarray(cells.free), free_ref, err_msg=f"{pose}")
            np.testing.assert_array_equal(np.asarray(cells.occupied), occ_ref, err_msg=f"{pose}")

            rays = cast(jnp.asarray(occ), jnp.asarray(pose))
            hit_ref, dist_ref = reference_hit_dist(occ, pose, preset)
            np.testing.assert_array_equal(np.asarray(rays.hit), hit_ref)
            np.testing.assert_allclose(np.asarray(rays.hit_dist), dist_ref, atol=1e-5)

            belief_jax = update(belief_jax, jnp.asarray(occ), jnp.asarray(pose))
            belief_ref = reference_update(belief_ref, occ, pose, preset)
            np.testing.assert_array_equal(np.asarray(belief_jax) != 0, belief_ref != 0)
            np.testing.assert_allclose(np.asarray(belief_jax), belief_ref, atol=1e-5)


def _room(preset, wall_col: int | None = None) -> np.ndarray:
    """A walled box (1-cell walls on the grid edge), optionally with a wall at one column."""
    occ = np.zeros(preset.grid_shape, bool)
    occ[0], occ[-1], occ[:, 0], occ[:, -1] = True, True, True, True
    if wall_col is not None:
        occ[:, wall_col] = True
    return occ


def test_facing_a_wall_gives_its_distance():
    c = SMOKE.cell_size
    occ = _room(SMOKE, wall_col=40)  # wall face at x = 4.0 m
    pose = jnp.array([1.23, 3.07, 0.0], jnp.float32)
    rays = cast_rays(jnp.asarray(occ), pose, SMOKE)
    mid = SMOKE.n_rays // 2
    assert bool(rays.hit[mid])
    # The first blocked sample lies at most half a cell past the wall face.
    assert 4.0 - 1.23 - 1e-4 <= float(rays.hit_dist[mid]) <= 4.0 - 1.23 + c / 2 + 1e-4
    assert tuple(np.asarray(rays.hit_cell[mid])) == (30, 40)
    # Edge rays (+-45 deg) travel 1/cos(45 deg) further to the same wall.
    expected = (4.0 - 1.23) * math.sqrt(2)
    assert abs(float(rays.hit_dist[0]) - expected) <= c
    np.testing.assert_allclose(float(rays.angle[0]), -math.pi / 4 % (2 * math.pi), atol=1e-3)


def test_open_space_rays_reach_range_and_stay_in_fov():
    occ = np.zeros(SMOKE.grid_shape, bool)
    pose = jnp.array([8.0, 6.0, math.pi / 2], jnp.float32)  # facing +y
    rays = cast_rays(jnp.asarray(occ), pose, SMOKE)
    assert not bool(rays.hit.any())
    np.testing.assert_allclose(np.asarray(rays.hit_dist), SMOKE.sensor_range_m)
    np.testing.assert_array_equal(np.asarray(rays.hit_cell), -1)
    cells = scan_cells(jnp.asarray(occ), pose, SMOKE)
    free = np.asarray(cells.free)
    assert not np.asarray(cells.occupied).any()
    i, j = np.nonzero(free)
    cx, cy = (j + 0.5) * SMOKE.cell_size - 8.0, (i + 0.5) * SMOKE.cell_size - 6.0
    r = np.hypot(cx, cy)
    assert r.max() <= SMOKE.sensor_range_m + SMOKE.cell_size
    # Nothing behind the agent (beyond the cell it stands in).
    assert (cy[r > SMOKE.cell_size] > 0).all()
    bearing = np.arctan2(cy, cx) - math.pi / 2
    assert (np.abs(bearing[r > 0.5]) <= SMOKE.fov_rad / 2 + 0.02).all()
    assert free[60, 80]  # the agent's own cell


@pytest.mark.parametrize("seed", range(3))
def test_scan_sets_are_consistent_with_the_true_map(seed):
    rng = np.random.default_rng(seed)
    occ = random_map(rng, SMOKE)
    _, scan, _ = _jitted(SMOKE)
    for pose in random_poses(rng, occ, SMOKE, 5):
        cells = scan(jnp.asarray(occ), jnp.asarray(pose))
        free, hit = np.asarray(cells.free), np.asarray(cells.occupied)
        assert not (free & hit).any()
        assert not (free & occ).any(), "a free update on a true obstacle"
        assert (occ[hit]).all(), "an occupied update on a true free cell"


def test_each_cell_updated_once_per_scan_and_clamped():
    occ = _room(SMOKE, wall_col=40)
    pose = jnp.array([2.0, 6.0, 0.0], jnp.float32)
    update, _, _ = _jitted(SMOKE)
    b1 = np.asarray(update(jnp.zeros(SMOKE.grid_shape, jnp.float32), jnp.asarray(occ), pose))
    expected = np.float32([SMOKE.logodds_free, 0.0, SMOKE.logodds_occupied])
    np.testing.assert_array_equal(np.unique(b1), expected)
    b = jnp.zeros(SMOKE.grid_shape, jnp.float32)
    for _ in range(30):
        b = update(b, jnp.asarray(occ), pose)
    b = np.asarray(b)
    assert b.min() == pytest.approx(-SMOKE.logodds_clamp)
    assert b.max() == pytest.approx(SMOKE.logodds_clamp)


def test_known_unknown_partition_the_grid():
    rng = np.random.default_rng(0)
    belief = jnp.asarray(rng.choice([-1.0, -0.2, -0.1, 0.0, 0.1, 0.2, 1.0], SMOKE.grid_shape))
    kf, ko, un = known_free(belief, SMOKE), known_occupied(belief, SMOKE), unknown(belief, SMOKE)
    total = np.asarray(kf).astype(int) + np.asarray(ko) + np.asarray(un)
    np.testing.assert_array_equal(total, 1)
    np.testing.assert_array_equal(np.asarray(kf), np.asarray(belief) < -SMOKE.logodds_known)
    np.testing.assert_array_equal(np.asarray(un), np.abs(np.asarray(belief)) <= 0.2)


def test_pose_outside_the_grid_updates_nothing():
    occ = np.zeros(SMOKE.grid_shape, bool)
    update, _, _ = _jitted(SMOKE)
    for pose in ([-3.0, 5.0, 0.0], [-0.05, 5.0, 0.0], [30.0, 40.0, 3.0]):
        b = update(jnp.zeros(SMOKE.grid_shape, jnp.float32), jnp.asarray(occ), jnp.array(pose))
        assert not np.asarray(b).any()


def test_vmap_matches_single_updates_and_no_retrace():
    rng = np.random.default_rng(1)
    occs = np.stack([random_map(rng, SMOKE) for _ in range(3)])
    poses = np.stack([random_poses(rng, o, SMOKE, 1)[0] for o in occs])
    beliefs = jnp.zeros((3, *SMOKE.grid_shape), jnp.float32)

    @jax.jit
    @chex.assert_max_traces(n=1)
    def batched(b, o, p):
        return jax.vmap(functools.partial(update_belief, preset=SMOKE))(b, o, p)

    out = batched(beliefs, jnp.asarray(occs), jnp.asarray(poses))
    update, _, _ = _jitted(SMOKE)
    for k in range(3):
        single = update(beliefs[k], jnp.asarray(occs[k]), jnp.asarray(poses[k]))
        np.testing.assert_array_equal(np.asarray(out[k]), np.asarray(single))
    # New values, same shapes: no recompilation.
    batched(out, jnp.asarray(occs[::-1]), jnp.asarray(poses + 0.1))


def test_bad_inputs_raise_clear_errors():
    occ = jnp.zeros(SMOKE.grid_shape, bool)
    pose = jnp.zeros(3, jnp.float32)
    with pytest.raises(ValueError, match="belief has shape"):
        update_belief(jnp.zeros((5, 5)), occ, pose, SMOKE)
    with pytest.raises(ValueError, match="occupied has shape"):
        cast_rays(jnp.zeros((5, 5), bool), pose, SMOKE)
    with pytest.raises(ValueError, match="pose must have shape"):
        scan_cells(occ, jnp.zeros(2), SMOKE)
    with pytest.raises(ValueError, match="n_rays"):
        cast_rays(occ, pose, dataclasses.replace(SMOKE, n_rays=0))
    with pytest.raises(ValueError, match="Preset"):
        cast_rays(occ, pose, "smoke")


def test_heading_units_round_trip():
    units = jnp.arange(mapping.ANGLE_UNITS, dtype=jnp.int32)
    heading = mapping.heading_from_units(units)
    assert float(heading.min()) >= -np.float32(math.pi) and float(heading.max()) < math.pi
    np.testing.assert_array_equal(np.asarray(mapping.quantised_heading(heading)), np.asarray(units))


def test_bearing_units_is_the_best_aligned_ray_direction():
    """The integer search finds the globally best-aligned unit (ties: lowest), exactly."""
    table = np.asarray(mapping.step_table(), np.int64)
    rng = np.random.default_rng(0)
    vecs = np.concatenate(
        [
            rng.normal(size=(40, 2)) * rng.choice([0.05, 1.0, 6.0], (40, 1)),
            [[1, 0], [0, -2], [0, 0]],
        ]
    ).astype(np.float32)
    got = np.asarray(jax.jit(jax.vmap(mapping.bearing_units))(jnp.asarray(vecs)))
    for v, g in zip(vecs, got, strict=True):
        mm = np.clip(np.round(v.astype(np.float32) * np.float32(1000.0)), -16000, 16000)
        dot = table @ mm.astype(np.int64)
        assert g == int(np.flatnonzero(dot == dot.max())[0]), v
        if np.any(v != 0):
            err = (g * 2 * math.pi / mapping.ANGLE_UNITS - math.atan2(v[1], v[0])) % (2 * math.pi)
            # good to ~0.3 degrees (the table's integer rounding) plus 1 mm over the length
            assert min(err, 2 * math.pi - err) < 6e-3 + 1.0 / np.linalg.norm(mm)
    single = [int(mapping.bearing_units(jnp.asarray(v))) for v in vecs[:5]]
    np.testing.assert_array_equal(single, got[:5])
