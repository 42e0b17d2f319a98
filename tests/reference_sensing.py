"""Slow, straightforward NumPy / Python references of the sensing code (tests only).

They follow the documented rules of :mod:`bfsop_jax.sensing.mapping` (ray sampling in
fixed-point sub-cell units, per-scan cell sets) and :mod:`bfsop_jax.sensing.detection`
(line of sight to object centres), one ray and one sample at a time, with Python integers.
"""

from __future__ import annotations

import math

import numpy as np

from bfsop_jax.world.constants import is_receptacle

Q = 1 << 16  # sub-cell units per cell
A = 1 << 14  # angle units per turn


def step_table() -> list[tuple[int, int]]:
    """Half-cell step (SX, SY) in sub-cell units of every angle unit."""
    return [
        (round(math.cos(2 * math.pi * a / A) * Q / 2), round(math.sin(2 * math.pi * a / A) * Q / 2))
        for a in range(A)
    ]


_STEPS = step_table()


def fixed_point(v: float, upper_m: float, cell: float) -> int:
    """One coordinate in sub-cell units: clip to one cell around the grid, float32 multiply."""
    v32 = np.float32(min(max(np.float32(v), np.float32(-cell)), np.float32(upper_m + cell)))
    return int(np.floor(v32 * np.float32(Q / cell)))


def heading_unit(heading: float) -> int:
    return int(np.rint(np.float32(heading) * np.float32(A / (2 * math.pi)))) & (A - 1)


def ray_walk(occupied: np.ndarray, pose, preset):
    """Per ray: the list of free cells before the hit, the hit cell (or None) and hit index."""
    h, w = occupied.shape
    c = preset.cell_size
    x0 = fixed_point(pose[0], w * c, c)
    y0 = fixed_point(pose[1], h * c, c)
    hq = heading_unit(pose[2])
    n = preset.n_rays
    fov = math.radians(preset.fov_deg)
    k_max = round(preset.sensor_range_m / (c / 2))
    rays = []
    for r in range(n):
        off = 0 if n == 1 else round((-fov / 2 + r * fov / (n - 1)) * A / (2 * math.pi))
        sx, sy = _STEPS[(hq + off) % A]
        free, hit_cell, k_hit = [], None, None
        for k in range(k_max + 1):
            row = (y0 + k * sy) // Q
            col = (x0 + k * sx) // Q
            inside = 0 <= row < h and 0 <= col < w
            if not inside or occupied[row, col]:
                hit_cell, k_hit = (row, col), k
                break
            free.append((row, col))
        rays.append((free, hit_cell, k_hit))
    return rays


def reference_scan(occupied: np.ndarray, pose, preset) -> tuple[np.ndarray, np.ndarray]:
    """(free [H, W] bool, occupied [H, W] bool) per-scan sets; free excludes occupied."""
    h, w = occupied.shape
    free = np.zeros((h, w), bool)
    occ = np.zeros((h, w), bool)
    for cells, hit_cell, _ in ray_walk(occupied, pose, preset):
        for row, col in cells:
            free[row, col] = True
        if hit_cell is not None and 0 <= hit_cell[0] < h and 0 <= hit_cell[1] < w:
            occ[hit_cell] = True
    return free & ~occ, occ


def reference_update(belief: np.ndarray, occupied: np.ndarray, pose, preset) -> np.ndarray:
    free, occ = reference_scan(occupied, pose, preset)
    out = belief.astype(np.float64).copy()
    out[occ] += preset.logodds_occupied
    out[free] += preset.logodds_free
    touched = free | occ
    out[touched] = np.clip(out[touched], -preset.logodds_clamp, preset.logodds_clamp)
    return out


def reference_hit_dist(occupied: np.ndarray, pose, preset) -> tuple[np.ndarray, np.ndarray]:
    """(hit [n_rays] bool, hit_dist [n_rays] metres)."""
    hits, dists = [], []
    for _, _, k_hit in ray_walk(occupied, pose, preset):
        hits.append(k_hit is not None)
        dists.append(preset.sensor_range_m if k_hit is None else k_hit * preset.cell_size / 2)
    return np.array(hits), np.array(dists)


def reference_observe(house, pose, preset) -> dict[str, np.ndarray]:
    """In-view set, distances and areas of every object slot, one object at a time.

    Follows the integer rule of :func:`bfsop_jax.sensing.detection.observe` (offsets in
    1/256 cell, field of view between the outermost rays' directions) with Python ints.
    """
    occupied = np.asarray(house.occupied)
    h, w = occupied.shape
    c = preset.cell_size
    cats = np.asarray(house.object_category)
    xy = np.asarray(house.object_xy, np.float64)
    size = np.asarray(house.object_size, np.float64)
    ext = np.asarray(house.object_half_extent, np.float64)
    parent = np.asarray(house.object_parent)
    x, y, heading = (float(v) for v in pose)
    n = 2 * math.ceil(preset.sensor_range_m / c - 1e-6)
    ax, ay = fixed_point(x, w * c, c), fixed_point(y, h * c, c)
    m = len(cats)
    in_view = np.zeros(m, bool)
    dist = np.zeros(m)
    area = np.zeros(m)
    g = 256  # geometry units per cell
    lim = (math.ceil(preset.sensor_range_m / c - 1e-6) + 2) * g
    range_u = round(preset.sensor_range_m / c * g)
    unit = np.float32(c / g)
    hq = heading_unit(heading)
    offs = (
        [0]
        if preset.n_rays == 1
        else [
            round(
                (
                    -math.radians(preset.fov_deg) / 2
                    + r * math.radians(preset.fov_deg) / (preset.n_rays - 1)
                )
                * A
                / (2 * math.pi)
            )
            for r in (0, preset.n_rays - 1)
        ]
    )
    rsx, rsy = _STEPS[(hq + offs[0]) % A]
    lsx, lsy = _STEPS[(hq + offs[-1]) % A]
    for i in range(m):
        ox, oy = fixed_point(xy[i, 0], w * c, c), fixed_point(xy[i, 1], h * c, c)
        rx = min(max((ox - ax) >> 8, -lim), lim)
        ry = min(max((oy - ay) >> 8, -lim), lim)
        d2 = rx * rx + ry * ry
        d = float(np.sqrt(np.float32(d2)) * unit)
        dist[i] = d
        if cats[i] < 0:
            continue
        d2_m = max(np.float32(d2) * (unit * unit), np.float32(1e-6))
        fs = np.float32(preset.focal_px) * np.float32(size[i])
        area[i] = (fs * fs) / d2_m
        c_right = rsx * ry - rsy * rx
        c_left = rx * lsy - ry * lsx
        if not (c_right >= 0 and c_left >= 0):
            continue
        if d2 > range_u * range_u:
            continue
        j_first = n + 1
        for j in range(n + 1):
            row = (ay + (oy - ay) * j // n) // Q
            col = (ax + (ox - ax) * j // n) // Q
            if not (0 <= row < h and 0 <= col < w) or occupied[row, col]:
                j_first = j
                break

        def half_diag(k):
            ex, ey = (min(round(float(np.float32(e) * np.float32(g / c))), 2**14) for e in ext[k])
            return float(np.sqrt(np.float32(ex * ex + ey * ey)) * unit)

        slack = half_diag(i)
        if parent[i] >= 0:
            slack = max(slack, half_diag(parent[i]))
        slack = float(np.float32(slack) + np.float32(c))
        in_view[i] = np.float32(max(n - j_first, 0)) * np.float32(d) <= np.float32(n) * np.float32(
            slack
        )
    return {"in_view": in_view, "distance": dist, "area_px": area}


def reference_landmarks(in_view, area, cats, prior, category, preset) -> np.ndarray:
    out = np.zeros(len(cats), bool)
    for i, cat in enumerate(cats):
        out[i] = (
            bool(is_receptacle(cat))
            and in_view[i]
            and area[i] >= preset.landmark_px
            and prior[cat, category] > 0
        )
    return out
