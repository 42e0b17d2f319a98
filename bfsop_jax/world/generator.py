"""Procedural ProcTHOR-like houses in pure JAX (docs/design.md §2.2).

:func:`generate_house` builds a :class:`House` from a PRNG key in five stages, all with static
shapes so that one preset compiles once and ``jax.vmap`` over keys batches whole houses:

1. **Floorplan** (:func:`generate_floorplan`): recursive binary partition of the footprint.
   Each step splits a large room (area-weighted random choice) across its longer side; the
   partition line becomes a wall. After all splits, one door is cut in every partition line
   (by induction over the partition tree this connects the house) plus ``preset.extra_doors``
   second doors on long lines, which add loops. Doors keep away from T-junctions.
2. **Room types**: the smallest rooms become bathrooms; living rooms are the hubs (most
   doors, then large rooms); kitchens and bedrooms share the rest at random, with counts from
   ``ROOM_TYPE_SHARE``; every house with >= 4 rooms has at least one room of each type.
3. **Furniture**: a fixed plan of slots per room type (required pieces first). For every slot
   a batch of candidate rectangles (every wall corner, then random spots along the walls;
   tables free-standing) is tested against the room interior, the pieces already placed and
   the clearance zones in front of every door; a random valid candidate wins (full size
   preferred, then shrunk copies). Any two pieces, and a piece and a wall it does not touch,
   keep a passage of ``2 * robot_radius_m + 0.2`` m, and the zone in front of a door is a
   passage deep, so furniture never cuts a room in two for the robot. A required piece
   (kitchen CounterTop, bathroom Toilet and Sink, bedroom Bed) that fits nowhere else stands
   in the middle of the room, shrunk to leave a passage all round (a last resort, rarely
   used).
4. **Targets** spawn on receptacles by ProcTHOR's rule (see ``constants`` and
   ``procthor/spawn_facts.md``); a HousePlant may also stand on the floor. The per-house bias
   0.4 * Beta(3.5, 1.9) - 0.3 is drawn by inverse CDF from a quantile table
   (:func:`sample_house_bias`), which compiles far smaller than ``jax.random.beta``.
5. **Raster**: walls, door gaps and furniture are rasterised by broadcasting rectangle
   bounds (a [N, H] x [N, W] matrix product), then every free cell outside the largest
   4-connected free component is marked occupied (:func:`fill_free_pockets`), so all free
   cells are mutually reachable by construction.

Randomness: each stage draws all its uniforms in one ``jax.random`` call (every call inlines
its own hash, and the program must stay small: it is compiled on 2-core CI machines).

Geometry: walls lie on integer cell boundaries ("lines"); a wall on line ``c`` occupies cells
``c - tl .. c + tr - 1`` (``tl + tr`` = wall thickness in cells). Furniture and targets live in
metres; a cell belongs to a rectangle when its centre does.

Capacity: objects are stored as furniture first (room by room), then targets in random
order. Anything beyond ``preset.max_objects`` slots is not created: such furniture is not
rasterised either, and targets whose receptacle was dropped are dropped with it, so the
object arrays always describe the grid exactly.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from bfsop_jax.config import Preset, get_preset, require_preset
from bfsop_jax.world import constants as C
from bfsop_jax.world.types import House

__all__ = [
    "Floorplan",
    "fill_free_pockets",
    "free_space_components",
    "generate_floorplan",
    "generate_house",
    "sample_house_bias",
]

# --- furniture plan ----------------------------------------------------------------------
# Per room type: (category, probability, free-standing). Required pieces come first with
# probability 1 (they are placed while the room is still empty); large before small.
_FURNITURE_PLAN: dict[str, tuple[tuple[str, float, bool], ...]] = {
    "Kitchen": (
        ("CounterTop", 1.0, False), ("Fridge", 0.9, False), ("CounterTop", 0.6, False),
        ("DiningTable", 0.6, True), ("ShelvingUnit", 0.35, False), ("SideTable", 0.3, False),
        ("GarbageCan", 0.6, False), ("Stool", 0.3, False), ("Chair", 0.3, False),
        ("HousePlant", 0.15, False),
    ),
    "LivingRoom": (
        ("Sofa", 0.95, False), ("TVStand", 0.85, False), ("CoffeeTable", 0.8, True),
        ("ShelvingUnit", 0.5, False), ("SideTable", 0.6, False), ("ArmChair", 0.5, False),
        ("Desk", 0.3, False), ("Dresser", 0.3, False), ("DiningTable", 0.3, True),
        ("HousePlant", 0.3, False),
    ),
    "Bedroom": (
        ("Bed", 1.0, False), ("SideTable", 0.8, False), ("Dresser", 0.7, False),
        ("Desk", 0.5, False), ("ShelvingUnit", 0.4, False), ("ArmChair", 0.3, False),
        ("SideTable", 0.3, False), ("HousePlant", 0.2, False),
    ),
    "Bathroom": (
        ("Toilet", 1.0, False), ("Sink", 1.0, False), ("SideTable", 0.3, False),
        ("GarbageCan", 0.5, False), ("HousePlant", 0.15, False),
    ),
}  # fmt: skip
for _room, _slots in _FURNITURE_PLAN.items():
    for _name, _, _ in _slots:
        assert _name in C.ROOM_FURNITURE[_room] or _name == "HousePlant", (_room, _name)

N_FURNITURE_SLOTS = max(len(s) for s in _FURNITURE_PLAN.values())  # S
_PLAN_CATEGORY = np.full((C.N_ROOM_TYPES, N_FURNITURE_SLOTS), -1, np.int32)
_PLAN_PROB = np.zeros((C.N_ROOM_TYPES, N_FURNITURE_SLOTS), np.float32)
_PLAN_FREE = np.zeros((C.N_ROOM_TYPES, N_FURNITURE_SLOTS), bool)
for _t, _room in enumerate(C.ROOM_TYPE_NAMES):
    for _s, (_name, _p, _free) in enumerate(_FURNITURE_PLAN[_room]):
        _PLAN_CATEGORY[_t, _s] = C.category_id(_name)
        _PLAN_PROB[_t, _s] = _p
        _PLAN_FREE[_t, _s] = _free

# Footprint (along the wall, away from it) of every category in metres; targets are square
# (only the floor HousePlant uses it).
_FOOTPRINT = np.array(
    [(C.TARGET_SIZE_M[n],) * 2 for n in C.TARGET_NAMES]
    + [C.FOOTPRINT_M[n] for n in C.RECEPTACLE_NAMES + C.OBSTACLE_NAMES],
    dtype=np.float32,
)
_ONE_PER_ROOM = np.array([n in C.ONE_PER_ROOM_TARGETS for n in C.TARGET_NAMES])
_HOUSE_PLANT = C.TARGET_NAMES.index("HousePlant")

_N_CANDIDATES = 32  # placements tried per furniture slot (corners, then random; half shrunk)
_N_DOOR_CANDIDATES = 32  # random door positions tried per partition line
_DOOR_WIDTH_M = (0.9, 1.2)
_DOOR_ZONE_SIDE_M = 0.1  # furniture-free margin beyond a door's jambs (its depth: a passage)
_DOOR_JUNCTION_M = 0.3  # door gap to a perpendicular wall, beyond the wall itself
_CORNER_SNAP = 0.35  # chance that a wall piece is pushed into a corner


def _beta_quantiles(a: float, b: float, n: int = 2049) -> tuple[np.ndarray, np.ndarray]:
    """(probabilities, quantiles) table of Beta(a, b), a, b > 1; probabilities are dense
    near 0 and 1, where the quantile function is steep."""
    x = np.linspace(0.0, 1.0, 200001)
    inner = x[1:-1]
    pdf = np.zeros_like(x)
    pdf[1:-1] = np.exp((a - 1) * np.log(inner) + (b - 1) * np.log1p(-inner))
    cdf = np.concatenate([[0.0], np.cumsum((pdf[1:] + pdf[:-1]) / 2)])
    prob = (1.0 - np.cos(np.linspace(0.0, np.pi, n))) / 2
    return prob.astype(np.float32), np.interp(prob, cdf / cdf[-1], x).astype(np.float32)


# ProcTHOR's house bias is 0.4 * Beta(3.5, 1.9) - 0.3. Drawn by inverse CDF from a table:
# exact to ~1e-4 and far cheaper to compile than jax.random.beta's rejection sampler.
_HOUSE_BETA_TABLE = _beta_quantiles(3.5, 1.9)


def sample_house_bias(u: jax.Array) -> jax.Array:
    """ProcTHOR's per-house placement bias 0.4 * Beta(3.5, 1.9) - 0.3 from uniforms ``u``."""
    prob, quantile = _HOUSE_BETA_TABLE
    return 0.4 * jnp.interp(u, prob, quantile) - 0.3


def _uniforms(key: jax.Array, *shapes: tuple[int, ...]) -> list[jax.Array]:
    """Uniform [0, 1) arrays of the given shapes from a single PRNG call.

    One call per generation stage keeps the compiled program small: every
    ``jax.random`` call inlines its own counter-based hash.
    """
    sizes = [math.prod(shape) for shape in shapes]
    flat = jax.random.uniform(key, (sum(sizes),))
    parts = jnp.split(flat, np.cumsum(sizes)[:-1]) if len(sizes) > 1 else [flat]
    return [part.reshape(shape) for part, shape in zip(parts, shapes, strict=True)]


def _gumbel(u: jax.Array) -> jax.Array:
    return -jnp.log(-jnp.log(jnp.clip(u, 1e-12, 1.0 - 1e-7)))


def _wall_cells(preset: Preset) -> tuple[int, int]:
    """(tl, tr): a wall on line c occupies cells c - tl .. c + tr - 1."""
    t = max(1, int(math.floor(preset.wall_thickness_m / preset.cell_size + 0.5 + 1e-6)))
    return t // 2, t - t // 2


def _n_doors(preset: Preset) -> int:
    return preset.max_rooms - 1 + preset.extra_doors


def passage_m(preset: Preset) -> float:
    """Minimum free gap (m) between furniture pieces: robot diameter plus a margin."""
    return 2.0 * preset.robot_radius_m + 0.2


# --- stage 1: floorplan --------------------------------------------------------------------
@struct.dataclass
class Floorplan:
    """Rooms, walls and doors of a partitioned footprint, in cell units (wall lines).

    A line is ``(vertical, coord, lo, hi)``: a vertical line is the wall x = coord between
    y = lo and y = hi (cell boundaries); a horizontal one swaps x and y.
    """

    room_rect: jax.Array  # [R, 4] int32: (x0, y0, x1, y1) wall lines around the room
    room_valid: jax.Array  # [R] bool: slot holds a room (valid rooms are a prefix)
    wall_line: jax.Array  # [R - 1, 4] int32: partition lines, in split order
    wall_valid: jax.Array  # [R - 1] bool
    door: jax.Array  # [D, 4] int32: (vertical, coord, lo, hi), gap cells lo .. hi - 1
    door_valid: jax.Array  # [D] bool; D = R - 1 + extra_doors (one per line, then extras)


def generate_floorplan(key: jax.Array, preset: Preset) -> Floorplan:
    """Recursive binary partition of the footprint plus doors (shapes from ``preset``)."""
    preset = require_preset(preset)
    h_cells, w_cells = preset.grid_shape
    n_slots = preset.max_rooms
    tl, tr = _wall_cells(preset)
    min_side = int(math.ceil(preset.min_room_side_m / preset.cell_size - 1e-6))
    n_lines = n_slots - 1
    n_cand = _N_DOOR_CANDIDATES
    u_count, u_pick, u_pos, u_door, u_extra = _uniforms(
        key, (), (n_lines, n_slots), (n_lines,), (n_lines, 3, n_cand), (n_lines,)
    )
    n_rooms = preset.min_rooms + jnp.floor(u_count * (preset.max_rooms - preset.min_rooms + 1))
    n_rooms = n_rooms.astype(jnp.int32)

    rect = jnp.zeros((n_slots, 4), jnp.int32)
    rect = rect.at[0].set(jnp.array([tl, tl, w_cells - tr, h_cells - tr], jnp.int32))
    valid = jnp.zeros(n_slots, bool).at[0].set(True)
    lines = jnp.zeros((n_lines, 4), jnp.int32)
    line_valid = jnp.zeros(n_lines, bool)

    def split(i, carry):
        rect, valid, lines, line_valid = carry
        w = rect[:, 2] - rect[:, 0]
        h = rect[:, 3] - rect[:, 1]
        can = valid & (jnp.maximum(w, h) >= 2 * min_side) & (i + 1 < n_rooms)
        # Large rooms are split first, with some randomness (area^2-weighted choice).
        area = jnp.maximum(w * h, 1).astype(jnp.float32)
        score = jnp.where(can, 2.0 * jnp.log(area) + _gumbel(u_pick[i]), -jnp.inf)
        r = jnp.argmax(score)
        ok = can[r]
        x0, y0, x1, y1 = rect[r]
        vertical = w[r] >= h[r]  # split across the longer side with a vertical wall x = c
        start = jnp.where(vertical, x0, y0)
        length = jnp.where(vertical, w[r], h[r])
        frac = 0.25 + 0.5 * u_pos[i]
        offset = jnp.clip(jnp.round(frac * length).astype(jnp.int32), min_side, length - min_side)
        c = start + offset
        near = jnp.where(vertical, jnp.stack([x0, y0, c, y1]), jnp.stack([x0, y0, x1, c]))
        far = jnp.where(vertical, jnp.stack([c, y0, x1, y1]), jnp.stack([x0, c, x1, y1]))
        across = jnp.where(vertical, jnp.stack([y0, y1]), jnp.stack([x0, x1]))
        line = jnp.concatenate([jnp.stack([vertical.astype(jnp.int32), c]), across])
        # Selects instead of indexed updates: rect[r] is read and rewritten in one step.
        slot = jnp.arange(n_slots)[:, None]
        rect = jnp.where(ok & (slot == r), near, jnp.where(ok & (slot == i + 1), far, rect))
        valid = valid | (ok & (slot[:, 0] == i + 1))
        at_i = ok & (jnp.arange(n_lines) == i)
        lines = jnp.where(at_i[:, None], line, lines)
        line_valid = line_valid | at_i
        return rect, valid, lines, line_valid

    rect, valid, lines, line_valid = jax.lax.fori_loop(
        0, n_lines, split, (rect, valid, lines, line_valid)
    )

    # Obstacles along each line for door placement: its two ends and every perpendicular
    # wall ending on it (T-junction).
    vert, coord, lo, hi = lines.T
    ends_on = (lo[None, :] == coord[:, None]) | (hi[None, :] == coord[:, None])
    touches = (
        line_valid[None, :]
        & (vert[None, :] != vert[:, None])
        & ends_on
        & (coord[None, :] >= lo[:, None])
        & (coord[None, :] <= hi[:, None])
    )
    junction = jnp.where(touches, coord[None, :], -(10**6))
    junction = jnp.concatenate([junction, lo[:, None], hi[:, None]], axis=1).astype(jnp.float32)
    keep_out = float(tr + tl) + _DOOR_JUNCTION_M / preset.cell_size
    door_min = int(round(_DOOR_WIDTH_M[0] / preset.cell_size))
    door_max = int(round(_DOOR_WIDTH_M[1] / preset.cell_size))

    def place_doors(k, u):
        """Random door candidates on line k: the spanning door and a possible second one."""
        width = door_min + jnp.floor(u[0] * (door_max - door_min + 1)).astype(jnp.int32)
        half = (width + 1) // 2
        centre = jnp.round(lo[k] + (hi[k] - lo[k]) * u[1])
        clear = jnp.min(jnp.abs(centre[:, None] - junction[k][None, :]), axis=1) - half - keep_out
        fits = clear >= 0
        first = jnp.argmax(jnp.where(fits, u[2], clear - 1e4))  # best clearance if none fits
        # A second door keeps >= 1 m of wall from the first.
        apart = jnp.abs(centre - centre[first]) - half - half[first] - 1.0 / preset.cell_size
        second_fits = fits & (apart >= 0)
        second = jnp.argmax(jnp.where(second_fits, u[2], -1.0))
        gap = (centre - half).astype(jnp.int32)
        door = lambda j: jnp.stack([vert[k], coord[k], gap[j], gap[j] + width[j]])
        return door(first), door(second), second_fits[second]

    doors, seconds, second_ok = jax.vmap(place_doors)(jnp.arange(n_lines), u_door)
    # The spanning door of a line is always cut.
    door_valid = line_valid
    if preset.extra_doors > 0:
        # Extra doors: second doors on long lines (length-weighted, without replacement).
        length = (hi - lo).astype(jnp.float32)
        score = jnp.where(
            line_valid & second_ok & (length >= 2 * min_side),
            jnp.log(jnp.maximum(length, 1.0)) + _gumbel(u_extra),
            -jnp.inf,
        )
        n_extra = min(preset.extra_doors, n_lines)
        top_score, top = jax.lax.top_k(score, n_extra)
        pad = preset.extra_doors - n_extra
        doors = jnp.concatenate([doors, seconds[top], jnp.zeros((pad, 4), jnp.int32)])
        door_valid = jnp.concatenate([door_valid, jnp.isfinite(top_score), jnp.zeros(pad, bool)])
    doors = jnp.where(door_valid[:, None], doors, 0)
    return Floorplan(rect, valid, lines, line_valid, doors, door_valid)


def _line_rect(line: jax.Array, tl: int, tr: int, pad_lo: int, pad_hi: int) -> jax.Array:
    """[N, 4] (x0, y0, x1, y1) cell rectangles of line segments (thickness tl + tr cells)."""
    vert, c, lo, hi = line.T
    across = jnp.stack([c - tl, c + tr], axis=1)
    along = jnp.stack([lo - pad_lo, hi + pad_hi], axis=1)
    v = (vert == 1)[:, None]
    x = jnp.where(v, across, along)
    y = jnp.where(v, along, across)
    return jnp.stack([x[:, 0], y[:, 0], x[:, 1], y[:, 1]], axis=1)


def _rasterise(rects: jax.Array, weight: jax.Array, shape: tuple[int, int]) -> jax.Array:
    """Sum of ``weight`` over the rectangles containing each cell centre -> [H, W] float32.

    ``rects`` [N, 4] holds (x0, y0, x1, y1) in cell units (floats allowed); cell (i, j) is
    inside when x0 <= j + 0.5 < x1 and y0 <= i + 0.5 < y1. A rectangle is separable, so the
    whole raster is one [H, N] x [N, W] matrix product.
    """
    h, w = shape
    yc = jnp.arange(h, dtype=jnp.float32) + 0.5
    xc = jnp.arange(w, dtype=jnp.float32) + 0.5
    rows = (yc[None, :] >= rects[:, 1:2]) & (yc[None, :] < rects[:, 3:4])
    cols = (xc[None, :] >= rects[:, 0:1]) & (xc[None, :] < rects[:, 2:3])
    return jnp.matmul(
        rows.T.astype(jnp.float32),
        cols.astype(jnp.float32) * weight[:, None],
        precision=jax.lax.Precision.HIGHEST,
    )


# --- stage 2: room types -------------------------------------------------------------------
def _door_degree(plan: Floorplan, preset: Preset) -> jax.Array:
    """[R] int32 number of door gaps opening into each room."""
    vert, c, lo, hi = plan.door.astype(jnp.float32).T
    mid = (lo + hi) / 2
    side = jnp.stack([c - 1.5, c + 1.5], axis=1)  # a point just beyond the wall on each side
    px = jnp.where(vert[:, None] == 1, side, mid[:, None])  # [D, 2]
    py = jnp.where(vert[:, None] == 1, mid[:, None], side)
    x0, y0, x1, y1 = plan.room_rect.astype(jnp.float32).T
    inside = (
        (px[..., None] >= x0) & (px[..., None] < x1) & (py[..., None] >= y0) & (py[..., None] < y1)
    )  # [D, 2, R]
    return jnp.sum(inside & plan.door_valid[:, None, None], axis=(0, 1)).astype(jnp.int32)


def _assign_room_types(key: jax.Array, plan: Floorplan, preset: Preset) -> jax.Array:
    """[R] int32 room types, -1 for unused slots.

    The smallest rooms are bathrooms; living rooms are the hubs (most doors, then larger
    rooms first), which also leaves the quieter rooms, with more free wall, to kitchens and
    bedrooms; kitchens and bedrooms share the rest at random.
    """
    valid = plan.room_valid
    area = (plan.room_rect[:, 2] - plan.room_rect[:, 0]) * (
        plan.room_rect[:, 3] - plan.room_rect[:, 1]
    )
    area = area.astype(jnp.float32)
    n = jnp.sum(valid)
    share = jnp.asarray(C.ROOM_TYPE_SHARE)
    quota = jnp.maximum(1, jnp.round(share * n).astype(jnp.int32))
    n_bath = quota[C.BATHROOM]
    bath_rank = jnp.argsort(jnp.argsort(jnp.where(valid, area, jnp.inf)))
    bath = valid & (bath_rank < n_bath)
    u_size, u_kitchen = _uniforms(key, area.shape, area.shape)
    hub = _door_degree(plan, preset) + area / jnp.max(area) * (0.5 + u_size)
    living_rank = jnp.argsort(jnp.argsort(jnp.where(valid & ~bath, -hub, jnp.inf)))
    living = valid & ~bath & (living_rank < quota[C.LIVING_ROOM])
    kitchen_rank = jnp.argsort(jnp.argsort(jnp.where(valid & ~bath & ~living, u_kitchen, 2.0)))
    kitchen = valid & ~bath & ~living & (kitchen_rank < quota[C.KITCHEN])
    room_type = jnp.where(
        bath, C.BATHROOM, jnp.where(living, C.LIVING_ROOM, jnp.where(kitchen, C.KITCHEN, C.BEDROOM))
    )
    return jnp.where(valid, room_type, -1).astype(jnp.int32)


# --- stage 3: furniture --------------------------------------------------------------------
@struct.dataclass
class _Furniture:
    category: jax.Array  # [R, S] int32, -1 = not placed
    centre: jax.Array  # [R, S, 2] float32 metres
    half: jax.Array  # [R, S, 2] float32 half sizes (x, y) metres


def _door_zones(plan: Floorplan, preset: Preset) -> jax.Array:
    """[D, 4] (x0, y0, x1, y1) metres kept free of furniture in front of each door."""
    tl, tr = _wall_cells(preset)
    cs = preset.cell_size
    depth = passage_m(preset) / cs
    side = _DOOR_ZONE_SIDE_M / cs
    vert, c, lo, hi = plan.door.astype(jnp.float32).T
    across = jnp.stack([c - tl - depth, c + tr + depth], axis=1)
    along = jnp.stack([lo - side, hi + side], axis=1)
    v = (vert == 1)[:, None]
    x = jnp.where(v, across, along)
    y = jnp.where(v, along, across)
    zones = jnp.stack([x[:, 0], y[:, 0], x[:, 1], y[:, 1]], axis=1) * cs
    # An invalid door gets an empty zone far away.
    return jnp.where(plan.door_valid[:, None], zones, -1e3)


def _furnish(key: jax.Array, plan: Floorplan, room_type: jax.Array, preset: Preset) -> _Furniture:
    tl, tr = _wall_cells(preset)
    cs = preset.cell_size
    clear = passage_m(preset)
    n_rooms, n_cand = preset.max_rooms, _N_CANDIDATES
    x0, y0, x1, y1 = plan.room_rect.astype(jnp.float32).T
    lo = jnp.stack([x0 + tr, y0 + tr], axis=1) * cs  # [R, 2] interior bounds, metres
    hi = jnp.stack([x1 - tl, y1 - tl], axis=1) * cs
    zones = _door_zones(plan, preset)
    safe_type = jnp.maximum(room_type, 0)
    slot_cat = jnp.where(room_type[:, None] >= 0, jnp.asarray(_PLAN_CATEGORY)[safe_type], -1)
    slot_prob = jnp.asarray(_PLAN_PROB)[safe_type]
    slot_free = jnp.asarray(_PLAN_FREE)[safe_type]
    footprint = jnp.asarray(_FOOTPRINT)
    eps = 1e-4

    n_slot = N_FURNITURE_SLOTS
    u_cand, u_axis, u_want = _uniforms(
        key, (n_slot, 4, n_rooms, n_cand), (n_slot, 3, n_rooms, n_cand, 2), (n_slot, n_rooms)
    )

    def place(carry, xs):
        centre, half, placed = carry  # [R, S, 2], [R, S, 2], [R, S]
        s, u_c, u_a, u_w = xs  # slot, then its uniforms [4, R, K], [3, R, K, 2], [R]
        cat = slot_cat[:, s]
        free = slot_free[:, s][:, None]
        # Candidates: the second half are shrunk copies (never a plant: a target keeps its
        # size); in each half the first 8 try every corner of every wall, the rest roam.
        k = jnp.arange(n_cand)
        shrinkable = (k >= n_cand // 2)[None, :] & (cat >= C.N_TARGETS)[:, None]
        scale = jnp.where(shrinkable, 0.65 + 0.3 * u_c[0], 1.0)
        corner = (k % (n_cand // 2) < 8)[None, :]
        along = footprint[jnp.maximum(cat, 0), 0][:, None] * scale
        depth = footprint[jnp.maximum(cat, 0), 1][:, None] * scale
        side = jnp.where(corner, k % 4, jnp.floor(u_c[1] * 4).astype(jnp.int32))  # -y +y -x +x
        on_y_wall = side < 2
        turned = jnp.where(free, u_c[2] < 0.5, ~on_y_wall)
        h = jnp.stack([jnp.where(turned, depth, along), jnp.where(turned, along, depth)], -1) / 2
        flush_lo = ~free[..., None] & jnp.stack([side == 2, side == 0], -1)
        flush_hi = ~free[..., None] & jnp.stack([side == 3, side == 1], -1)
        snap = (
            ~free[..., None]
            & jnp.stack([on_y_wall, ~on_y_wall], -1)
            & (corner[..., None] | (u_a[0] < _CORNER_SNAP))
        )
        to_lo = jnp.where(corner[..., None], (k % 8 < 4)[None, :, None], u_a[1] < 0.5)
        lo_, hi_ = lo[:, None, :], hi[:, None, :]
        roam = lo_ + clear + h + u_a[2] * jnp.maximum(hi_ - lo_ - 2 * (clear + h), 0.0)
        c = jnp.where(
            flush_lo | (snap & to_lo),
            lo_ + h,
            jnp.where(flush_hi | (snap & ~to_lo), hi_ - h, roam),
        )  # [R, K, 2]
        # Last resort for a required piece: free-standing in the middle of the room, shrunk
        # to leave a passage all round (always valid while the room is still empty).
        required = slot_prob[:, s] >= 1.0
        room_span = hi - lo - 2 * clear  # [R, 2]
        size = footprint[jnp.maximum(cat, 0)]  # [R, 2] (along, depth)
        fit_plain = jnp.min(room_span / size, axis=1)
        fit_turned = jnp.min(room_span / size[:, ::-1], axis=1)
        fit = 0.98 * jnp.minimum(jnp.maximum(fit_plain, fit_turned), 1.0)
        h_mid = jnp.where((fit_turned > fit_plain)[:, None], size[:, ::-1], size) * fit[:, None] / 2
        last = required[:, None] & (k == n_cand - 1)[None, :]
        c = jnp.where(last[..., None], ((lo + hi) / 2)[:, None, :], c)
        h = jnp.where(last[..., None], h_mid[:, None, :], h)
        # Each gap to a wall is either zero (flush) or a full passage; never flush on two
        # opposite walls (the piece would span the room).
        gap_lo = c - h - lo_
        gap_hi = hi_ - c - h
        touch_lo, touch_hi = jnp.abs(gap_lo) < eps, jnp.abs(gap_hi) < eps
        gap_ok = (touch_lo | (gap_lo >= clear - eps)) & (touch_hi | (gap_hi >= clear - eps))
        ok = jnp.all(gap_ok & ~(touch_lo & touch_hi), axis=-1)
        # Passage to every piece already placed in the room.
        dist = jnp.abs(c[:, :, None, :] - centre[:, None, :, :]) - h[:, :, None, :] - half[:, None]
        blocked = jnp.all(dist < clear - eps, axis=-1) & placed[:, None, :]
        ok &= ~jnp.any(blocked, axis=-1)
        # Door clearance zones.
        in_zone = (
            (c[..., None, 0] + h[..., None, 0] > zones[:, 0])
            & (c[..., None, 0] - h[..., None, 0] < zones[:, 2])
            & (c[..., None, 1] + h[..., None, 1] > zones[:, 1])
            & (c[..., None, 1] - h[..., None, 1] < zones[:, 3])
        )
        ok &= ~jnp.any(in_zone, axis=-1)
        preference = jnp.where(last, -0.5, u_c[3] + (scale == 1.0))
        best = jnp.argmax(jnp.where(ok, preference, -1.0), axis=1)
        wanted = (cat >= 0) & (u_w < slot_prob[:, s])
        put = wanted & jnp.take_along_axis(ok, best[:, None], 1)[:, 0]
        rows = jnp.arange(n_rooms)
        this_slot = (jnp.arange(n_slot) == s)[None, :]
        centre = jnp.where(
            this_slot[..., None], jnp.where(put[:, None], c[rows, best], 0.0)[:, None], centre
        )
        half = jnp.where(
            this_slot[..., None], jnp.where(put[:, None], h[rows, best], 0.0)[:, None], half
        )
        placed = jnp.where(this_slot, put[:, None], placed)
        return (centre, half, placed), None

    init = (
        jnp.zeros((n_rooms, n_slot, 2)),
        jnp.zeros((n_rooms, n_slot, 2)),
        jnp.zeros((n_rooms, n_slot), bool),
    )
    xs = (jnp.arange(n_slot), u_cand, u_axis, u_want)
    (centre, half, placed), _ = jax.lax.scan(place, init, xs)
    return _Furniture(jnp.where(placed, slot_cat, -1), centre, half)


# --- stage 4: targets ----------------------------------------------------------------------
def _spawn_targets(
    key: jax.Array, category: jax.Array, room: jax.Array, room_type: jax.Array, n_rooms: int
) -> jax.Array:
    """[P, N_TARGETS, copies] bool: copy k of target t stands on piece p.

    ProcTHOR's rule per (receptacle, target) pair in a room of an allowed type: keep when
    ``u <= p + parent_bias + child_bias + house_bias``; further copies while ``u <= p`` (at
    most ``MAX_COPIES_PER_RECEPTACLE``); Apple, Laptop, SoapBottle and HousePlant at most
    once per room (a floor HousePlant counts).
    """
    n_pieces = category.shape[0]
    copies = C.MAX_COPIES_PER_RECEPTACLE
    shape = (n_pieces, C.N_TARGETS)
    u_bias, u_pair, u_more = _uniforms(key, (), (3, *shape), (*shape, copies - 1))
    house_bias = sample_house_bias(u_bias)
    receptacle = C.is_receptacle(category)
    rec = jnp.clip(category - C.FIRST_RECEPTACLE, 0, C.N_RECEPTACLES - 1)
    p = jnp.where(receptacle[:, None], jnp.asarray(C.SPAWN_PROB)[rec], 0.0)  # [P, T]
    kind = jnp.maximum(room_type[jnp.maximum(room, 0)], 0)
    room_weight = jnp.asarray(C.TARGET_ROOM_WEIGHT).T[kind]  # [P, T]
    bias = jnp.asarray(C.PARENT_BIAS)[rec][:, None] + jnp.asarray(C.CHILD_BIAS)[None, :]
    u_first = u_pair[0]
    first = (p > 0) & (u_pair[1] < room_weight) & (u_first <= p + bias + house_bias)
    # One-per-room targets: keep the pair with the smallest draw in each room.
    slot_room = jnp.where(receptacle, room, n_rooms)  # non-receptacles go to a dummy segment
    draw = jnp.where(first, u_pair[2], 2.0)
    room_min = jax.ops.segment_min(draw, slot_room, num_segments=n_rooms + 1)
    floor_plant = jax.ops.segment_max(
        (category == _HOUSE_PLANT).astype(jnp.int32),
        jnp.where(room >= 0, room, n_rooms),
        num_segments=n_rooms + 1,
    )
    single = (draw <= room_min[slot_room]) & ~(
        (jnp.arange(C.N_TARGETS) == _HOUSE_PLANT)[None, :] & (floor_plant[slot_room] > 0)[:, None]
    )
    one = jnp.asarray(_ONE_PER_ROOM)[None, :]
    first &= ~one | single
    more = u_more <= p[..., None]
    more = (
        jnp.cumprod(more.astype(jnp.int32), axis=-1).astype(bool)
        & first[..., None]
        & ~one[..., None]
    )
    return jnp.concatenate([first[..., None], more], axis=-1)


# --- stage 5: raster and connectivity ------------------------------------------------------
def _run_min(label: jax.Array, free: jax.Array, axis: int) -> jax.Array:
    """Minimum label over each run of free cells along ``axis``; occupied cells get INT_MAX.

    A forward running minimum restarts after every occupied cell; a backward pass then
    spreads each run's minimum (reached at its last cell) over the whole run. Two sequential
    scans along the axis: tiny to compile and, on CPU, faster than parallel prefix scans.
    """
    top = jnp.iinfo(jnp.int32).max
    cells = jnp.moveaxis(label, axis, 0), jnp.moveaxis(free, axis, 0)

    def running_min(carry, x):
        value, is_free = x
        carry = jnp.where(is_free, jnp.minimum(carry, value), top)
        return carry, carry

    start = jnp.full(cells[0].shape[1:], top, jnp.int32)
    _, prefix = jax.lax.scan(running_min, start, cells)
    _, run_min = jax.lax.scan(running_min, start, (prefix, cells[1]), reverse=True)
    return jnp.moveaxis(run_min, 0, axis)


def free_space_components(free: jax.Array) -> jax.Array:
    """[H, W] int32 component label of every free cell (4-connectivity), -1 elsewhere.

    Labels are the smallest flat cell index of the component. Minimum labels propagate along
    whole row and column runs per iteration, so the loop runs about as many times as a path
    has turns, not as many cells as it is long.
    """
    h, w = free.shape
    label0 = jnp.where(free, jnp.arange(h * w, dtype=jnp.int32).reshape(h, w), -1)

    def sweep(state):
        label, _ = state
        new = _run_min(_run_min(label, free, axis=1), free, axis=0)
        new = jnp.where(free, new, -1)
        return new, jnp.any(new != label)

    label, _ = jax.lax.while_loop(lambda s: s[1], sweep, (label0, jnp.array(True)))
    return label


def fill_free_pockets(occupied: jax.Array) -> jax.Array:
    """Mark every free cell outside the largest 4-connected free component as occupied."""
    free = ~occupied
    label = free_space_components(free)
    count = jnp.bincount(
        jnp.where(free, label, 0).ravel(),
        weights=free.ravel().astype(jnp.float32),
        length=free.size,
    )
    main = jnp.argmax(count)
    return occupied | (free & (label != main))


def generate_house(key: jax.Array, preset: Preset | str = "demo") -> House:
    """Random ProcTHOR-like house (docs/design.md §2.2); pure, jit-able and vmappable over ``key``.

    ``preset`` (a :class:`Preset` or its name) is static: it fixes the grid shape (H, W) =
    ``preset.grid_shape`` (cells of ``preset.cell_size`` m), R = ``preset.max_rooms`` room
    slots and M = ``preset.max_objects`` object slots. Batched use::

        jax.jit(jax.vmap(generate_house, in_axes=(0, None)), static_argnums=1)(keys, preset)
    """
    preset = get_preset(preset)
    shape = preset.grid_shape
    cs = preset.cell_size
    n_rooms, n_obj = preset.max_rooms, preset.max_objects
    tl, tr = _wall_cells(preset)
    k_plan, k_type, k_furn, k_spawn, k_place = jax.random.split(key, 5)

    plan = generate_floorplan(k_plan, preset)
    room_type = _assign_room_types(k_type, plan, preset)
    furniture = _furnish(k_furn, plan, room_type, preset)

    # Furniture slots in room order; slots beyond capacity are dropped entirely.
    piece_cat = furniture.category.reshape(-1)  # [P]
    piece_room = jnp.repeat(jnp.arange(n_rooms), N_FURNITURE_SLOTS)
    piece_centre = furniture.centre.reshape(-1, 2)
    piece_half = furniture.half.reshape(-1, 2)
    piece_slot = jnp.cumsum(piece_cat >= 0) - 1
    piece_valid = (piece_cat >= 0) & (piece_slot < n_obj)
    piece_cat = jnp.where(piece_valid, piece_cat, -1)
    n_pieces = jnp.sum(piece_valid)

    on = _spawn_targets(k_spawn, piece_cat, piece_room, room_type, n_rooms)  # [P, T, copies]
    n_pc, n_t, n_copy = on.shape
    tgt_parent = jnp.broadcast_to(jnp.arange(n_pc)[:, None, None], on.shape).reshape(-1)
    tgt_cat = jnp.broadcast_to(jnp.arange(n_t)[None, :, None], on.shape).reshape(-1)
    tgt_valid = on.reshape(-1)
    size = jnp.asarray(C.CATEGORY_SIZE_M)
    # A target stands anywhere on its receptacle's top (fully inside the footprint if it fits).
    room_to_spare = jnp.maximum(piece_half[tgt_parent] - size[tgt_cat, None] / 2, 0.0)
    u_xy, u_order = _uniforms(k_place, (tgt_cat.shape[0], 2), (tgt_cat.shape[0],))
    u = 2.0 * u_xy - 1.0
    tgt_xy = piece_centre[tgt_parent] + u * room_to_spare
    # Targets fill the remaining slots in random order (a full house drops a random subset).
    tgt_order = jnp.argsort(jnp.where(tgt_valid, u_order, 2.0))
    n_targets = jnp.sum(tgt_valid)

    slot = jnp.arange(n_obj)
    is_piece = slot < n_pieces
    piece_idx = jnp.argsort(~piece_valid, stable=True)[jnp.minimum(slot, n_pc - 1)]
    tgt_idx = tgt_order[jnp.clip(slot - n_pieces, 0, tgt_order.shape[0] - 1)]
    used = slot < n_pieces + n_targets
    t_par = tgt_parent[tgt_idx]
    category = jnp.where(is_piece, piece_cat[piece_idx], tgt_cat[tgt_idx])
    xy = jnp.where(is_piece[:, None], piece_centre[piece_idx], tgt_xy[tgt_idx])
    half = jnp.where(is_piece[:, None], piece_half[piece_idx], size[tgt_cat[tgt_idx], None] / 2)
    room = jnp.where(is_piece, piece_room[piece_idx], piece_room[t_par])
    parent = jnp.where(is_piece, -1, piece_slot[t_par])
    category = jnp.where(used, category, -1).astype(jnp.int32)
    obj_valid = category >= 0

    # Raster: rooms tile the footprint; walls on every line; doors cut last.
    room_id = _rasterise(
        plan.room_rect.astype(jnp.float32), (jnp.arange(n_rooms) + 1.0) * plan.room_valid, shape
    )
    room_of_cell = jnp.round(room_id).astype(jnp.int32) - 1
    h_cells, w_cells = shape
    outer = jnp.array(
        [[1, tl, tl, h_cells - tr], [1, w_cells - tr, tl, h_cells - tr],
         [0, tl, tl, w_cells - tr], [0, h_cells - tr, tl, w_cells - tr]],
        jnp.int32,
    )  # fmt: skip
    lines = jnp.concatenate([outer, plan.wall_line])
    line_valid = jnp.concatenate([jnp.ones(4, bool), plan.wall_valid])
    walls = (
        _rasterise(_line_rect(lines, tl, tr, tl, tr).astype(jnp.float32), line_valid * 1.0, shape)
        > 0.5
    )
    gaps = (
        _rasterise(
            _line_rect(plan.door, tl, tr, 0, 0).astype(jnp.float32), plan.door_valid * 1.0, shape
        )
        > 0.5
    )
    walls &= ~gaps
    piece_rect = jnp.concatenate([xy - half, xy + half], axis=1) / cs
    furniture_cells = _rasterise(piece_rect, (is_piece & obj_valid) * 1.0, shape) > 0.5
    room_of_cell = jnp.where(walls, -1, room_of_cell)
    occupied = walls | furniture_cells | (room_of_cell < 0)
    occupied = fill_free_pockets(occupied)

    return House(
        occupied=occupied,
        room_of_cell=room_of_cell,
        room_type=room_type,
        object_category=category,
        object_xy=jnp.where(obj_valid[:, None], xy, 0.0).astype(jnp.float32),
        object_size=jnp.where(obj_valid, size[jnp.maximum(category, 0)], 0.0).astype(jnp.float32),
        object_half_extent=jnp.where(obj_valid[:, None], half, 0.0).astype(jnp.float32),
        object_room=jnp.where(obj_valid, room, -1).astype(jnp.int32),
        object_parent=jnp.where(obj_valid, parent, -1).astype(jnp.int32),
        cell_size=cs,
    )
