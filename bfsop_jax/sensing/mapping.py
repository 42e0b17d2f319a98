"""Ray-cast occupancy mapping on the true grid (docs/design.md §3.1).

The agent's range sensor casts ``preset.n_rays`` rays over a ``preset.fov_deg`` field of
view centred on its heading, up to ``preset.sensor_range_m``. Cells a ray crosses before its
first obstacle are seen free, the obstacle cell is seen occupied, and the belief (a log-odds
grid) is updated once per scan.

Ray sampling rule
-----------------
Rays are sampled at fixed steps of half a cell, in *fixed-point* arithmetic, so the set of
cells a scan touches is bit-identical on every backend (CPU / GPU sin and cos differ in the
last bit) and can be reproduced exactly by an independent reference:

1. Sub-cell units: one cell = ``Q = 2**16`` units; ``scale = float32(Q / cell_size)``.
   The origin is ``X0 = floor(float32(x) * scale)``, ``Y0 = floor(float32(y) * scale)``
   (one float32 multiply, then floor, as int32); ``x`` and ``y`` are first clipped to
   ``[-cell_size, W * cell_size + cell_size]`` (resp. H), which keeps out-of-grid poses
   out of the grid.
2. Headings are quantised to ``A = 2**14`` angle units per turn:
   ``h = rint(float32(heading) * float32(A / (2 pi)))`` (round half to even) as int32,
   wrapped with ``h & (A - 1)``.
3. Ray ``r`` (``r = 0 .. n_rays-1``) has angle ``(h + o_r) & (A - 1)`` where
   ``o_r = round((-fov/2 + r * fov / (n_rays - 1)) * A / (2 pi))`` (``o_0 = 0`` if one ray;
   Python ``round``, half to even).
4. The half-cell step of angle unit ``a`` is ``(SX, SY) = (round(cos(t) * Q / 2),
   round(sin(t) * Q / 2))`` with ``t = 2 pi a / A`` in float64 (a static table).
5. Sample ``k = 0 .. K`` with ``K = round(sensor_range_m / (cell_size / 2))`` lies at
   ``(X0 + k * SX, Y0 + k * SY)`` units, i.e. ``k * cell_size / 2`` metres from the agent,
   in cell ``(row, col) = ((Y0 + k * SY) >> 16, (X0 + k * SX) >> 16)`` (floor division).

Scan semantics
--------------
A sample is *blocked* when its cell is occupied or outside the grid. The first blocked
sample of a ray is its hit (``k_hit``; ``K + 1`` when none). Per scan:

- the *occupied set* holds the in-grid hit cells of all rays;
- the *free set* holds the cells of all samples ``k < k_hit`` of all rays.

Each cell is updated at most once per scan: a cell in the occupied set gets
``+logodds_occupied``; otherwise a cell in the free set gets ``+logodds_free`` (occupied
wins); the result is clamped to ``[-logodds_clamp, logodds_clamp]``.

Implementation: all samples of a scan fall in a square window of ``2 * ceil(K / 2) + 1``
cells centred on the agent's cell (101 x 101 for a 5 m range), so the per-scan sets are
built by one scatter-max of codes (0 none, 1 free, 2 occupied) into that window and added
to the belief with one ``dynamic_update_slice``, instead of a scatter over the whole map.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from bfsop_jax.config import Preset, require_preset

__all__ = [
    "ANGLE_UNITS",
    "SUBCELL_BITS",
    "Rays",
    "ScanCells",
    "bearing_units",
    "cast_rays",
    "heading_from_units",
    "known_free",
    "known_occupied",
    "quantised_heading",
    "ray_offsets",
    "scan_cells",
    "step_table",
    "subcell_origin",
    "unknown",
    "update_belief",
]

SUBCELL_BITS = 16  # fixed-point sub-cell resolution: one cell = 2**16 units
ANGLE_UNITS = 2**14  # heading resolution: 2**14 units per turn (0.022 deg)
_Q = 1 << SUBCELL_BITS

# Codes of the per-scan window, combined with a scatter-max so that occupied wins.
_NONE, _FREE, _OCCUPIED = 0, 1, 2


@struct.dataclass
class Rays:
    """Result of one scan's ray cast (one entry per ray)."""

    angle: jax.Array  # [n_rays] float32: world angle of each ray (quantised), radians
    hit: jax.Array  # [n_rays] bool: the ray met an occupied / out-of-grid cell in range
    hit_dist: jax.Array  # [n_rays] float32: metres to the first blocked sample, range if none
    # [n_rays, 2] int32: (row, col) of the first blocked sample (may lie just outside the
    # grid); (-1, -1) where ``hit`` is False.
    hit_cell: jax.Array


@struct.dataclass
class ScanCells:
    """The per-scan cell sets of docs/design.md §3.1 (see the module docstring)."""

    free: jax.Array  # [H, W] bool: seen free and not seen occupied (gets logodds_free)
    occupied: jax.Array  # [H, W] bool: first hit cell of some ray (gets logodds_occupied)


# --- the static sampling geometry ----------------------------------------------------------


@functools.cache
def step_table() -> np.ndarray:
    """[ANGLE_UNITS, 2] int32: half-cell step (SX, SY) in sub-cell units per angle unit."""
    t = 2.0 * np.pi * np.arange(ANGLE_UNITS, dtype=np.float64) / ANGLE_UNITS
    half = _Q / 2
    return np.stack([np.rint(np.cos(t) * half), np.rint(np.sin(t) * half)], -1).astype(np.int32)


def ray_offsets(preset: Preset) -> np.ndarray:
    """[n_rays] int32: angle units of each ray relative to the heading (static)."""
    n = preset.n_rays
    if n == 1:
        return np.zeros(1, np.int32)
    fov = preset.fov_rad
    return np.array(
        [round((-fov / 2 + r * fov / (n - 1)) * ANGLE_UNITS / (2 * math.pi)) for r in range(n)],
        dtype=np.int32,
    )


def _n_steps(preset: Preset) -> int:
    """K: index of the last sample; samples are half a cell apart up to the sensor range."""
    return int(round(preset.sensor_range_m / (preset.cell_size / 2)))


def _window_half(preset: Preset) -> int:
    """Cells either side of the agent's cell reached by a sample: |k * SX| <= K * Q / 2."""
    return -(-_n_steps(preset) // 2)


def _window_shape(preset: Preset) -> tuple[int, int]:
    """(rows, cols) of the window holding every sample of a scan, capped by the grid."""
    side = 2 * _window_half(preset) + 1
    h, w = preset.grid_shape
    return min(side, h), min(side, w)


def _check_preset(preset: Preset) -> None:
    require_preset(preset)
    if preset.n_rays < 1:
        raise ValueError(f"preset.n_rays must be >= 1, got {preset.n_rays}")
    if not preset.sensor_range_m > 0:
        raise ValueError(f"preset.sensor_range_m must be > 0, got {preset.sensor_range_m}")
    h, w = preset.grid_shape
    if max(h, w) + _n_steps(preset) >= 2 ** (31 - SUBCELL_BITS):
        raise ValueError(f"grid {h}x{w} too large for {SUBCELL_BITS}-bit sub-cell coordinates")


def _check_grid(name: str, grid: jax.Array, preset: Preset) -> None:
    if tuple(grid.shape) != preset.grid_shape:
        raise ValueError(
            f"{name} has shape {tuple(grid.shape)}, expected preset.grid_shape {preset.grid_shape}"
        )


def _check_pose(pose: jax.Array) -> None:
    if tuple(jnp.shape(pose)) != (3,):
        raise ValueError(f"pose must have shape (3,) = (x, y, heading), got {jnp.shape(pose)}")


def subcell_origin(xy: jax.Array, preset: Preset) -> jax.Array:
    """Fixed-point position of points: ``[..., 2]`` metres (x, y) -> ``[..., 2]`` int32 units.

    Points are clipped to one cell outside the grid (step 1 of the sampling rule).
    """
    h, w = preset.grid_shape
    c = preset.cell_size
    lim = jnp.array([w * c + c, h * c + c], jnp.float32)
    xy = jnp.clip(jnp.asarray(xy, jnp.float32), -c, lim)
    return jnp.floor(xy * jnp.float32(_Q / c)).astype(jnp.int32)


def quantised_heading(heading: jax.Array) -> jax.Array:
    """Heading in radians -> int32 angle unit in ``[0, ANGLE_UNITS)`` (step 2 of the rule)."""
    h = jnp.round(jnp.asarray(heading, jnp.float32) * jnp.float32(ANGLE_UNITS / (2 * math.pi)))
    return h.astype(jnp.int32) & (ANGLE_UNITS - 1)


def heading_from_units(units: jax.Array) -> jax.Array:
    """Angle units -> heading in radians, float32 in ``[-pi, pi)``.

    One multiply of an exact integer, so :func:`quantised_heading` gives ``units`` back
    and the float is the same in every program that computes it.
    """
    u = (jnp.asarray(units, jnp.int32) + ANGLE_UNITS // 2) & (ANGLE_UNITS - 1)
    return (u - ANGLE_UNITS // 2).astype(jnp.float32) * jnp.float32(2 * math.pi / ANGLE_UNITS)


_BEARING_COARSE = 128  # angle units between the candidates of the coarse search


def bearing_units(vec_m: jax.Array) -> jax.Array:
    """Direction of a vector as an angle unit, by integer arithmetic only.

    ``vec_m`` [2] float32 metres (x, y) -> int32 unit in ``[0, ANGLE_UNITS)``: the unit
    whose half-cell step (the ray table) has the largest dot product with the vector in
    whole millimetres (clipped to +-16 m), found by a coarse search every
    ``_BEARING_COARSE`` units and a fine search around the best (ties: lowest unit). No
    ``atan2``: its last bit may differ between a batched and an unbatched program, and a
    heading decides which cells the next scan touches. The result is within about 0.3
    degrees of the true direction (the table's integer rounding); the zero vector gives 0.
    """
    v = jnp.clip(jnp.round(jnp.asarray(vec_m, jnp.float32) * 1000.0), -16000, 16000)
    v = v.astype(jnp.int32)
    table = jnp.asarray(step_table())

    def best(units):
        st = table[units]  # dot <= 2 * 16000 * 32768 < 2**31
        dot = v[0] * st[:, 0] + v[1] * st[:, 1]
        top = jnp.max(dot)
        return jnp.min(jnp.where(dot == top, units, ANGLE_UNITS))

    coarse = best(jnp.arange(0, ANGLE_UNITS, _BEARING_COARSE, dtype=jnp.int32))
    fine = coarse + jnp.arange(-2 * _BEARING_COARSE, 2 * _BEARING_COARSE + 1, dtype=jnp.int32)
    return best(fine & (ANGLE_UNITS - 1))


def _sample_cells(pose: jax.Array, preset: Preset) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Cells of every ray sample: rows, cols ``[n_rays, K+1]`` int32 and angle units [n_rays]."""
    origin = subcell_origin(pose[:2], preset)
    units = (quantised_heading(pose[2]) + jnp.asarray(ray_offsets(preset))) & (ANGLE_UNITS - 1)
    step = jnp.asarray(step_table())[units]  # [n_rays, 2]
    k = jnp.arange(_n_steps(preset) + 1, dtype=jnp.int32)
    x = origin[0] + k[None, :] * step[:, 0:1]
    y = origin[1] + k[None, :] * step[:, 1:2]
    return y >> SUBCELL_BITS, x >> SUBCELL_BITS, units


def _window_corner(pose: jax.Array, preset: Preset) -> tuple[jax.Array, jax.Array]:
    """Top-left (row, col) of the scan window: centred on the agent, clamped into the grid."""
    h, w = preset.grid_shape
    wh, ww = _window_shape(preset)
    half = _window_half(preset)
    cell = subcell_origin(pose[:2], preset) >> SUBCELL_BITS
    r0 = jnp.clip(cell[1] - half, 0, h - wh)
    c0 = jnp.clip(cell[0] - half, 0, w - ww)
    return r0, c0


def _scan_samples(occupied: jax.Array, pose: jax.Array, preset: Preset):
    """Sample cells of a scan and the first blocked sample of each ray.

    Returns ``(rows, cols, units, k_hit)``: rows, cols ``[n_rays, K+1]`` int32 cells of the
    samples (possibly outside the grid), ``units [n_rays]`` int32 ray angles, and
    ``k_hit [n_rays]`` int32 (``K + 1`` when the ray is free over its whole range).
    """
    h, w = preset.grid_shape
    rows, cols, units = _sample_cells(pose, preset)
    in_grid = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    # Out-of-grid samples index past the end and read the fill value: outside is occupied.
    flat = jnp.where(in_grid, rows * w + cols, h * w)
    blocked = occupied.reshape(-1).at[flat].get(mode="fill", fill_value=True)
    # argmax finds the first True; the appended column makes "no hit" read as K + 1.
    blocked = jnp.concatenate([blocked, jnp.ones((blocked.shape[0], 1), bool)], axis=1)
    k_hit = jnp.argmax(blocked, axis=1).astype(jnp.int32)
    return rows, cols, units, k_hit


def _scan_window(occupied: jax.Array, pose: jax.Array, preset: Preset):
    """Codes ``[wh, ww]`` uint8 (0 none, 1 free, 2 occupied) of one scan, and the corner."""
    wh, ww = _window_shape(preset)
    rows, cols, _, k_hit = _scan_samples(occupied, pose, preset)
    r0, c0 = _window_corner(pose, preset)
    lr, lc = rows - r0, cols - c0
    # In-grid samples always fall in the window; the others get an out-of-range index and
    # are dropped by the scatter.
    in_window = (lr >= 0) & (lr < wh) & (lc >= 0) & (lc < ww)
    flat = jnp.where(in_window, lr * ww + lc, wh * ww)
    k = jnp.arange(flat.shape[1], dtype=jnp.int32)[None, :]
    kh = k_hit[:, None]
    codes = ((k <= kh).astype(jnp.uint8) + (k == kh).astype(jnp.uint8)).astype(jnp.uint8)
    # Scatter-max: duplicates (several samples per cell, crossing rays) merge and occupied
    # wins. uint8 keeps the scatter, the largest cost of an update on CPU, cheap.
    win = jnp.zeros(wh * ww, jnp.uint8).at[flat.reshape(-1)].max(codes.reshape(-1), mode="drop")
    return win.reshape(wh, ww), r0, c0


# --- public API -------------------------------------------------------------------------------


def cast_rays(occupied: jax.Array, pose: jax.Array, preset: Preset) -> Rays:
    """Cast the scan's rays on the true grid.

    Args:
      occupied: [H, W] bool true occupancy (cells outside the grid count as occupied).
      pose: [3] float32 (x m, y m, heading rad).
      preset: static configuration (grid shape, FoV, ray count, range).

    Returns:
      :class:`Rays`; ``hit_dist`` is the distance of the first blocked sample
      (a multiple of half a cell), or ``sensor_range_m`` when the ray is free.
    """
    _check_preset(preset)
    _check_grid("occupied", occupied, preset)
    _check_pose(pose)
    n_samples = _n_steps(preset) + 1
    rows, cols, units, k_hit = _scan_samples(occupied, pose, preset)
    hit = k_hit < n_samples
    k_safe = jnp.minimum(k_hit, n_samples - 1)[:, None]
    cell = jnp.stack(
        [jnp.take_along_axis(rows, k_safe, 1)[:, 0], jnp.take_along_axis(cols, k_safe, 1)[:, 0]],
        -1,
    )
    return Rays(
        angle=units.astype(jnp.float32) * jnp.float32(2 * math.pi / ANGLE_UNITS),
        hit=hit,
        hit_dist=jnp.where(
            hit,
            k_hit.astype(jnp.float32) * jnp.float32(preset.cell_size / 2),
            jnp.float32(preset.sensor_range_m),
        ),
        hit_cell=jnp.where(hit[:, None], cell, -1),
    )


def scan_cells(occupied: jax.Array, pose: jax.Array, preset: Preset) -> ScanCells:
    """The per-scan free and occupied cell sets on the full grid (module docstring).

    Args:
      occupied: [H, W] bool true occupancy.
      pose: [3] float32 (x m, y m, heading rad).

    Returns:
      :class:`ScanCells` of [H, W] bool masks; ``free`` excludes cells in ``occupied``.
    """
    _check_preset(preset)
    _check_grid("occupied", occupied, preset)
    _check_pose(pose)
    win, r0, c0 = _scan_window(occupied, pose, preset)
    codes = jax.lax.dynamic_update_slice(jnp.zeros(preset.grid_shape, jnp.uint8), win, (r0, c0))
    return ScanCells(free=codes == _FREE, occupied=codes == _OCCUPIED)


def update_belief(
    belief: jax.Array, occupied: jax.Array, pose: jax.Array, preset: Preset
) -> jax.Array:
    """Apply one scan to the log-odds belief.

    Each cell changes at most once per scan: ``+logodds_occupied`` if it is the first hit
    of some ray, else ``+logodds_free`` if some ray crossed it before its hit; then the
    value is clamped to ``+-logodds_clamp``. Only the window around the agent is touched.

    Args:
      belief: [H, W] float32 log-odds, 0 = unknown.
      occupied: [H, W] bool true occupancy.
      pose: [3] float32 (x m, y m, heading rad).

    Returns:
      [H, W] float32 updated belief.
    """
    _check_preset(preset)
    _check_grid("belief", belief, preset)
    _check_grid("occupied", occupied, preset)
    _check_pose(pose)
    win, r0, c0 = _scan_window(occupied, pose, preset)
    wh, ww = win.shape
    delta = jnp.where(
        win == _OCCUPIED,
        jnp.float32(preset.logodds_occupied),
        jnp.where(win == _FREE, jnp.float32(preset.logodds_free), jnp.float32(0)),
    )
    old = jax.lax.dynamic_slice(belief, (r0, c0), (wh, ww))
    clamp = jnp.float32(preset.logodds_clamp)
    new = jnp.where(win != _NONE, jnp.clip(old + delta, -clamp, clamp), old).astype(belief.dtype)
    return jax.lax.dynamic_update_slice(belief, new, (r0, c0))


def known_free(belief: jax.Array, preset: Preset) -> jax.Array:
    """[H, W] bool: log-odds below ``-logodds_known`` (confidently free)."""
    return belief < -preset.logodds_known


def known_occupied(belief: jax.Array, preset: Preset) -> jax.Array:
    """[H, W] bool: log-odds above ``logodds_known`` (confidently occupied)."""
    return belief > preset.logodds_known


def unknown(belief: jax.Array, preset: Preset) -> jax.Array:
    """[H, W] bool: neither known free nor known occupied (``|l| <= logodds_known``)."""
    return jnp.abs(belief) <= preset.logodds_known
