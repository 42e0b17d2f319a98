"""Simulated instance segmentation: which objects the camera sees, and how large
(docs/design.md §3.2-3.3).

A pinhole camera ``image_width_px`` wide with focal length ``focal_px`` sees an object of
size ``s`` metres at distance ``d`` as ``A = (focal_px * s / d) ** 2`` pixels when its centre
is inside the field of view, within sensor range and in line of sight.

Line of sight is checked on the true occupancy grid. Every object centre lies inside an
occupied footprint (its own furniture rectangle, or the receptacle a target stands on), so
the object must not hide itself: the segment from the agent to the centre is sampled at
``j = 0 .. N`` (``N = 2 * ceil(sensor_range_m / cell_size)``, so at most half a cell apart
within range), and the object is visible when the first blocked sample (occupied or outside
the grid) lies at ``t >= d - slack``, with ``slack`` = the half-diagonal of the footprint
(the larger of the object's own and, for a target standing on a receptacle, its parent's)
plus one cell. Sample ``j`` is at ``A + (D * j) // N`` in the fixed-point sub-cell units of
:mod:`bfsop_jax.sensing.mapping` (``A`` the agent, ``D`` the offset to the centre, integer
floor division), i.e. ``t_j = j * d / N`` metres from the agent.

All functions handle every object slot at once (``M = preset.max_objects``) and take the
target ``category`` as a traced int32 scalar, so they jit once per preset and vmap over
agents, houses and categories.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from flax import struct

from bfsop_jax.config import Preset
from bfsop_jax.sensing.mapping import (
    ANGLE_UNITS,
    SUBCELL_BITS,
    quantised_heading,
    ray_offsets,
    step_table,
    subcell_origin,
)
from bfsop_jax.world.constants import N_CATEGORIES, N_TARGETS, is_receptacle
from bfsop_jax.world.types import House

__all__ = [
    "INTERACTION_PX_PER_M",
    "Detections",
    "landmarks_of_interest",
    "observe",
    "verified_targets",
]

# The paper's interaction threshold theta_c = 1000 * s_c, read as pixels per metre of size.
INTERACTION_PX_PER_M = 1000.0


@struct.dataclass
class Detections:
    """What one camera frame shows of every object slot."""

    in_view: jax.Array  # [M] bool: valid, centre inside the FoV, within range, in line of sight
    # [M] float32: metres from the agent to the object centre (read as range + 2 cells
    # beyond that)
    distance: jax.Array
    area_px: jax.Array  # [M] float32: apparent area (focal_px * s / d)^2 in pixels
    in_fov: jax.Array  # [M] bool: centre inside the horizontal field of view
    line_of_sight: jax.Array  # [M] bool: no obstacle before the object's footprint


def _n_los_samples(preset: Preset) -> int:
    """N: segments per line-of-sight ray (half a cell apart at full sensor range)."""
    return 2 * int(math.ceil(preset.sensor_range_m / preset.cell_size - 1e-6))


def _check_inputs(house: House, pose: jax.Array, preset: Preset) -> None:
    if not isinstance(preset, Preset):
        raise ValueError(f"preset must be a bfsop_jax.config.Preset, got {type(preset).__name__}")
    if tuple(jnp.shape(pose)) != (3,):
        raise ValueError(f"pose must have shape (3,) = (x, y, heading), got {jnp.shape(pose)}")
    if tuple(house.occupied.shape) != preset.grid_shape:
        raise ValueError(
            f"house.occupied has shape {tuple(house.occupied.shape)}, "
            f"expected preset.grid_shape {preset.grid_shape}"
        )
    if not math.isclose(house.cell_size, preset.cell_size):
        raise ValueError(
            f"house.cell_size {house.cell_size} differs from preset.cell_size {preset.cell_size}"
        )
    if _geom_limit(preset) >= 2**15:
        raise ValueError(
            f"sensor_range_m {preset.sensor_range_m} is too long for the integer detection "
            f"geometry (at most about {125 * preset.cell_size:.1f} m)"
        )
    m = house.object_category.shape[0]
    for name in ("object_xy", "object_size", "object_half_extent", "object_parent"):
        n = getattr(house, name).shape[0]
        if n != m:
            raise ValueError(f"house.{name} has {n} object slots, object_category has {m}")


# Object geometry is compared in integer units of 1/256 cell (0.39 mm at 0.1 m cells):
# the fixed-point sub-cell units of the mapping shifted right by this many bits.
_GEOM_SHIFT = SUBCELL_BITS - 8
_GEOM_PER_CELL = 1 << (SUBCELL_BITS - _GEOM_SHIFT)


def _geom_limit(preset: Preset) -> int:
    """Offsets (geometry units) are clipped here: 2 cells beyond the sensor range."""
    return (int(math.ceil(preset.sensor_range_m / preset.cell_size - 1e-6)) + 2) * _GEOM_PER_CELL


def _line_of_sight(
    house: House, agent: jax.Array, target: jax.Array, dist: jax.Array, preset: Preset
) -> jax.Array:
    """[M] bool: the first blocked sample towards each centre lies within its footprint slack.

    ``agent`` [2] and ``target`` [M, 2] are fixed-point sub-cell positions, ``dist`` [M]
    metres. The test ``t_first >= d - slack`` is evaluated as
    ``(N - j_first) * d <= N * slack``: products, a square root and one sum of exact
    values, so it cannot round differently in a batched program.
    """
    h, w = preset.grid_shape
    n = _n_los_samples(preset)
    # Clipping only touches objects beyond sensor range (never visible) and keeps D * j in int32.
    lim = 2 * n << SUBCELL_BITS
    offset = jnp.clip(target - agent[None, :], -lim, lim)
    j = jnp.arange(n + 1, dtype=jnp.int32)
    pts = agent[None, None, :] + (offset[:, None, :] * j[None, :, None]) // n  # [M, N+1, 2]
    cells = pts >> SUBCELL_BITS
    rows, cols = cells[..., 1], cells[..., 0]
    in_grid = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    flat = jnp.where(in_grid, rows * w + cols, h * w)
    blocked = house.occupied.reshape(-1).at[flat].get(mode="fill", fill_value=True)
    blocked = jnp.concatenate([blocked, jnp.ones((blocked.shape[0], 1), bool)], axis=1)
    j_first = jnp.argmax(blocked, axis=1)  # N + 1 when nothing blocks the segment

    # Half-diagonal of each footprint from integer half extents (geometry units).
    ext = jnp.round(house.object_half_extent * jnp.float32(_GEOM_PER_CELL / preset.cell_size))
    ext = jnp.minimum(ext, 2**14).astype(jnp.int32)
    own = jnp.sqrt((ext[:, 0] * ext[:, 0] + ext[:, 1] * ext[:, 1]).astype(jnp.float32))
    own = own * jnp.float32(preset.cell_size / _GEOM_PER_CELL)
    parent = house.object_parent
    parent_ext = jnp.where(parent >= 0, own[jnp.clip(parent, 0, own.shape[0] - 1)], 0.0)
    slack = jnp.maximum(own, parent_ext) + jnp.float32(preset.cell_size)
    ahead = jnp.maximum(n - j_first, 0).astype(jnp.float32)
    return ahead * dist <= jnp.float32(n) * slack


def observe(house: House, pose: jax.Array, preset: Preset) -> Detections:
    """Detect every object from ``pose`` (docs/design.md §3.2).

    Args:
      house: the true house (occupancy [H, W], M object slots).
      pose: [3] float32 (x m, y m, heading rad).
      preset: static configuration (FoV, range, focal length, grid).

    Returns:
      :class:`Detections` with [M] fields; invalid slots (category -1) are never in view
      and have area 0.

    Geometry is exact integer arithmetic (module docstring): the offset to each centre in
    1/256 cell units, its squared length, and the field of view as the wedge between the
    ray table's directions of the first and last ray of the scan.
    """
    _check_inputs(house, pose, preset)
    pose = jnp.asarray(pose, jnp.float32)
    agent = subcell_origin(pose[:2], preset)  # [2] int32
    target = subcell_origin(house.object_xy, preset)  # [M, 2] int32
    lim = _geom_limit(preset)
    rel = jnp.clip((target - agent[None, :]) >> _GEOM_SHIFT, -lim, lim)  # [M, 2] int32
    d2 = rel[:, 0] * rel[:, 0] + rel[:, 1] * rel[:, 1]  # <= 2 lim^2 < 2^31
    unit_m = jnp.float32(preset.cell_size / _GEOM_PER_CELL)
    dist = jnp.sqrt(d2.astype(jnp.float32)) * unit_m
    range_units = int(round(preset.sensor_range_m / preset.cell_size * _GEOM_PER_CELL))
    in_range = d2 <= range_units * range_units
    # Field of view: between the directions of the scan's outermost rays.
    h = quantised_heading(pose[2])
    offsets = ray_offsets(preset)
    table = jnp.asarray(step_table())
    right = table[(h + int(offsets[0])) & (ANGLE_UNITS - 1)]
    left = table[(h + int(offsets[-1])) & (ANGLE_UNITS - 1)]
    c_right = right[0] * rel[:, 1] - right[1] * rel[:, 0]  # >= 0: counter-clockwise of it
    c_left = rel[:, 0] * left[1] - rel[:, 1] * left[0]  # >= 0: clockwise of it
    if preset.fov_deg <= 180.0:
        in_fov = (c_right >= 0) & (c_left >= 0)
    else:
        in_fov = (c_right >= 0) | (c_left >= 0)
    los = _line_of_sight(house, agent, target, dist, preset)
    valid = house.object_valid
    in_view = valid & in_fov & in_range & los
    # A = (f s / d)^2 from products only; d clamped so an object at the agent is finite.
    fs = jnp.float32(preset.focal_px) * house.object_size
    d2_m = jnp.maximum(d2.astype(jnp.float32) * (unit_m * unit_m), jnp.float32(1e-6))
    area = jnp.where(valid, (fs * fs) / d2_m, 0.0).astype(jnp.float32)
    return Detections(
        in_view=in_view, distance=dist, area_px=area, in_fov=in_fov, line_of_sight=los
    )


def landmarks_of_interest(
    det: Detections, house: House, prior: jax.Array, category: jax.Array, preset: Preset
) -> jax.Array:
    """[M] bool: receptacles seen large enough whose prior with ``category`` is positive.

    Args:
      det: detections of one frame.
      house: the house the detections come from (object categories).
      prior: [N_CATEGORIES, N_TARGETS] float32 co-occurrence table P(target | landmark
        category), estimated from training houses (docs/design.md §3.4).
      category: int32 scalar target category id (may be traced).
    """
    if tuple(prior.shape) != (N_CATEGORIES, N_TARGETS):
        raise ValueError(
            f"prior must have shape (N_CATEGORIES, N_TARGETS) = ({N_CATEGORIES}, {N_TARGETS}), "
            f"got {tuple(prior.shape)}"
        )
    cat = house.object_category
    co_occurs = prior[jnp.clip(cat, 0, N_CATEGORIES - 1), category] > 0
    return is_receptacle(cat) & det.in_view & (det.area_px >= preset.landmark_px) & co_occurs


def verified_targets(
    det: Detections,
    house: House,
    category: jax.Array,
    preset: Preset,
    use_interaction_threshold: bool = False,
) -> jax.Array:
    """[M] bool: instances of ``category`` verified in this frame (docs/design.md §3.3).

    An instance is verified when it is in view, within ``verify_distance_m`` and at least
    ``noise_filter_px`` large. With ``use_interaction_threshold`` (static) it must also
    reach the paper's interaction threshold ``theta_c = 1000 * s_c`` pixels, with ``s_c``
    the instance's size in metres (``house.object_size``).

    Args:
      det: detections of one frame.
      house: the house the detections come from.
      category: int32 scalar target category id (may be traced).
    """
    ok = (
        (house.object_category == category)
        & det.in_view
        & (det.distance <= preset.verify_distance_m)
        & (det.area_px >= preset.noise_filter_px)
    )
    if use_interaction_threshold:
        ok = ok & (det.area_px >= INTERACTION_PX_PER_M * house.object_size)
    return ok
