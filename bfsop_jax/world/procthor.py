"""Import a ProcTHOR house JSON into the same :class:`House` arrays as the generator
(docs/design.md §2.4).

Host-side NumPy (a house is imported once). ProcTHOR's floor plane is (x, z) in metres; it
becomes the grid's (x, y). The house is centred in the preset's grid.

What is read:

- ``rooms``: ``floorPolygon`` (room cells, point-in-polygon on cell centres) and ``roomType``.
- ``walls``: every wall's floor segment, plus every room polygon edge, rasterised as
  ``preset.wall_thickness_m`` thick lines (never thinner than a 4-connected cell line).
- ``doors``: the hole (``holePolygon`` x range, metres along ``wall0`` from its first polygon
  point) is cut through the wall. Exterior doors (``room0 == room1`` or an exterior wall)
  are left closed: the outside is occupied.
- ``objects``: the category comes from the ``assetId`` prefix (:func:`asset_category`).
  Furniture of a known category becomes an object slot and occupied cells; its footprint is
  ``FOOTPRINT_M`` (width along the asset's local x, depth along local z) or the asset
  database's ``boundingBox`` x/z, turned by the y rotation (axis-aligned bounding box).
  ``children`` of a target category become targets standing on their nearest receptacle
  ancestor (``object_parent``). A top-level HousePlant stands on the floor and occupies its
  cells. A few common floor items without a category (carts, floor lamps, ...) only occupy
  cells; every other asset (wall decor, small clutter, unknown names) is skipped.
- Free cells outside the largest 4-connected free component are marked occupied, as in the
  generator, so all free cells are mutually reachable.

Slots beyond ``preset.max_objects`` are dropped with a warning (furniture first, then
targets); rooms beyond ``preset.max_rooms`` or a house larger than the grid raise ValueError.
"""

from __future__ import annotations

import json
import math
import re
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np

from bfsop_jax.config import PRESET_NAMES, Preset, get_preset
from bfsop_jax.world import constants as C
from bfsop_jax.world.generator import fill_free_pockets
from bfsop_jax.world.types import House

__all__ = ["asset_category", "load_procthor_house"]

_MARGIN_M = 0.3  # free border kept around the house inside the grid

# Normalised assetId prefix (lower case, letters only, "robothor" dropped) -> category name,
# or None for assets that look like a category but are not one. Longest prefix wins.
_ASSET_PREFIXES: dict[str, str | None] = {
    # targets
    "apple": "Apple", "bread": "Bread", "cup": "Cup", "laptop": "Laptop", "book": "Book",
    "potato": "Potato", "soapbottle": "SoapBottle", "liquidsoap": "SoapBottle",
    "tomato": "Tomato", "houseplant": "HousePlant", "pottedplant": "HousePlant",
    # receptacles
    "countertop": "CounterTop", "counter": "CounterTop", "kitchencounter": "CounterTop",
    "fridge": "Fridge", "refrigerator": "Fridge",
    "diningtable": "DiningTable", "kitchentable": "DiningTable",
    "shelvingunit": "ShelvingUnit", "bookshelf": "ShelvingUnit", "bookcase": "ShelvingUnit",
    "shelf": "ShelvingUnit",
    "sidetable": "SideTable", "nightstand": "SideTable", "endtable": "SideTable",
    "sofa": "Sofa", "couch": "Sofa", "coffeetable": "CoffeeTable",
    "tvstand": "TVStand", "televisionstand": "TVStand",
    "desk": "Desk", "dresser": "Dresser", "bed": "Bed",
    "sink": "Sink", "bathroomsink": "Sink", "kitchensink": "Sink", "sinkbasin": "Sink",
    "toilet": "Toilet",
    # plain obstacles
    "armchair": "ArmChair", "chair": "Chair", "stool": "Stool",
    "garbagecan": "GarbageCan", "trashcan": "GarbageCan", "bin": "GarbageCan",
    # look-alikes that are none of the above
    "toiletpaper": None, "desklamp": None, "cupboard": None, "bedsheet": None,
    "booklet": None, "sinkfaucet": None, "counterweight": None,
}  # fmt: skip
# Floor items without a category that still block the robot: footprint (m) at rotation 0.
_FLOOR_OBSTACLE_M: dict[str, tuple[float, float]] = {
    "cart": (0.7, 0.45), "floorlamp": (0.4, 0.4), "ottoman": (0.6, 0.6),
    "laundryhamper": (0.45, 0.45), "dogbed": (0.7, 0.5), "safe": (0.5, 0.5),
    "garbagebag": (0.4, 0.4), "vacuumcleaner": (0.35, 0.35), "chest": (0.9, 0.5),
}  # fmt: skip


def _normalise(asset_id: str) -> str:
    name = re.sub(r"[^a-z]", "", asset_id.lower())
    return name.removeprefix("robothor")


def asset_category(asset_id: str) -> str | None:
    """Category name of a ProcTHOR ``assetId`` from its prefix, or None if it has none.

    Case, digits, underscores and a ``RoboTHOR_`` prefix are ignored; the longest known
    prefix wins (so "Toilet_Paper" is not a Toilet and "Bookshelf_2" not a Book).
    """
    name = _normalise(asset_id)
    best = max((p for p in _ASSET_PREFIXES if name.startswith(p)), key=len, default=None)
    return None if best is None else _ASSET_PREFIXES[best]


def _floor_obstacle(asset_id: str) -> tuple[float, float] | None:
    name = _normalise(asset_id)
    best = max((p for p in _FLOOR_OBSTACLE_M if name.startswith(p)), key=len, default=None)
    return None if best is None else _FLOOR_OBSTACLE_M[best]


# --- parsing with clear errors ---------------------------------------------------------------
def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where}: expected a number, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def _field(obj: Any, key: str, where: str) -> Any:
    if not isinstance(obj, Mapping):
        raise ValueError(f"{where}: expected a JSON object, got {type(obj).__name__}")
    if key not in obj:
        raise ValueError(f"{where}: missing {key!r}")
    return obj[key]


def _list(obj: Any, key: str, where: str, required: bool = True) -> list:
    if not required and (not isinstance(obj, Mapping) or key not in obj):
        return []
    value = _field(obj, key, where)
    if not isinstance(value, list):
        raise ValueError(f"{where}.{key}: expected a list, got {type(value).__name__}")
    return value


def _xz(point: Any, where: str) -> tuple[float, float]:
    return _number(_field(point, "x", where), f"{where}.x"), _number(
        _field(point, "z", where), f"{where}.z"
    )


def _polygon(points: list, where: str, min_points: int) -> np.ndarray:
    xz = np.array([_xz(p, f"{where}[{i}]") for i, p in enumerate(points)], dtype=np.float64)
    if len(xz) < min_points:
        raise ValueError(f"{where}: needs at least {min_points} points, got {len(xz)}")
    return xz


def _read(path_or_dict: str | Path | Mapping) -> Mapping:
    if isinstance(path_or_dict, Mapping):
        return path_or_dict
    if not isinstance(path_or_dict, (str, Path)):
        raise ValueError(
            f"expected a house dict or a path to a JSON file, got {type(path_or_dict).__name__}"
        )
    path = Path(path_or_dict)
    text = path.read_text(encoding="utf-8")
    try:
        house = json.loads(text)
    except json.JSONDecodeError as err:
        raise ValueError(f"{path}: not valid JSON ({err})") from None
    if not isinstance(house, Mapping):
        raise ValueError(f"{path}: expected a JSON object at the top level")
    return house


# --- geometry ----------------------------------------------------------------------------------
def _inside(px: np.ndarray, py: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Even-odd point-in-polygon test of points (px, py) against polygon [N, 2]."""
    inside = np.zeros(px.shape, bool)
    x0, y0 = polygon[:, 0], polygon[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    for ax, ay, bx, by in zip(x0, y0, x1, y1, strict=True):
        crosses = (ay > py) != (by > py)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_cross = ax + (py - ay) * (bx - ax) / (by - ay)
        inside ^= crosses & (px < x_cross)
    return inside


def _segment_frame(
    px: np.ndarray, py: np.ndarray, a: np.ndarray, b: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    """(position along a->b in metres, distance off the line, segment length)."""
    d = b - a
    length = float(np.hypot(*d))
    u = d / length
    rx, ry = px - a[0], py - a[1]
    return rx * u[0] + ry * u[1], np.abs(rx * u[1] - ry * u[0]), length


def _footprint_half(width: float, depth: float, yaw_deg: float) -> tuple[float, float]:
    """Axis-aligned half extents (x, y) of a width x depth rectangle turned by yaw."""
    c, s = abs(math.cos(math.radians(yaw_deg))), abs(math.sin(math.radians(yaw_deg)))
    return 0.5 * (c * width + s * depth), 0.5 * (s * width + c * depth)


def _smallest_fitting_preset(width: float, height: float, n_rooms: int) -> str | None:
    for name in PRESET_NAMES:
        p = get_preset(name)
        if width <= p.width_m and height <= p.height_m and n_rooms <= p.max_rooms:
            return name
    return None


def load_procthor_house(
    path_or_dict: str | Path | Mapping,
    preset: Preset | str = "demo",
    asset_sizes: Mapping[str, Any] | None = None,
) -> House:
    """Rasterise a ProcTHOR house (JSON file path or parsed dict) into :class:`House` arrays.

    Shapes come from ``preset`` exactly as for ``generate_house``: grid (H, W) =
    ``preset.grid_shape``, R = ``preset.max_rooms``, M = ``preset.max_objects``.
    ``asset_sizes`` optionally maps ``assetId`` to ``{"boundingBox": {"x": w, "z": d}}``
    (metres, the asset's local frame) and overrides the default footprint table.
    Malformed input raises ValueError naming the offending field.
    """
    preset = get_preset(preset)
    data = _read(path_or_dict)
    cs = preset.cell_size
    h_cells, w_cells = preset.grid_shape

    # Rooms.
    rooms_json = _list(data, "rooms", "house")
    if not rooms_json:
        raise ValueError("house.rooms: the house has no rooms")
    room_ids, room_types, polygons = [], [], []
    for i, room in enumerate(rooms_json):
        where = f"rooms[{i}]"
        kind = _field(room, "roomType", where)
        if kind not in C.ROOM_TYPE_NAMES:
            raise ValueError(
                f"{where}.roomType: unknown room type {kind!r}; "
                f"known: {', '.join(C.ROOM_TYPE_NAMES)}"
            )
        room_types.append(C.ROOM_TYPE_NAMES.index(kind))
        room_ids.append(room.get("id", f"room{i}"))
        polygons.append(_polygon(_list(room, "floorPolygon", where), f"{where}.floorPolygon", 3))

    lo = np.min([p.min(axis=0) for p in polygons], axis=0)
    hi = np.max([p.max(axis=0) for p in polygons], axis=0)
    size = hi - lo
    need = size + 2 * _MARGIN_M
    if need[0] > preset.width_m or need[1] > preset.height_m or len(polygons) > preset.max_rooms:
        fits = _smallest_fitting_preset(need[0], need[1], len(polygons))
        hint = f"use preset {fits!r}" if fits else "no preset is large enough"
        raise ValueError(
            f"house is {size[0]:.1f} x {size[1]:.1f} m with {len(polygons)} rooms; preset "
            f"{preset.name!r} holds {preset.width_m - 2 * _MARGIN_M:.1f} x "
            f"{preset.height_m - 2 * _MARGIN_M:.1f} m and {preset.max_rooms} rooms: {hint}"
        )
    # House frame -> grid frame (metres): centre the house in the grid.
    offset = np.array([preset.width_m, preset.height_m]) / 2 - (lo + hi) / 2
    polygons = [p + offset for p in polygons]
    px = (np.arange(w_cells) + 0.5)[None, :] * cs * np.ones((h_cells, 1))
    py = (np.arange(h_cells) + 0.5)[:, None] * cs * np.ones((1, w_cells))

    room_of_cell = np.full((h_cells, w_cells), -1, np.int32)
    for r, poly in enumerate(polygons):
        room_of_cell[(room_of_cell < 0) & _inside(px, py, poly)] = r

    # Walls: room outlines plus the listed walls.
    segments: list[tuple[np.ndarray, np.ndarray]] = []
    for poly in polygons:
        segments += [(poly[k], poly[(k + 1) % len(poly)]) for k in range(len(poly))]
    walls: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for i, wall in enumerate(_list(data, "walls", "house", required=False)):
        where = f"walls[{i}]"
        points = _polygon(_list(wall, "polygon", where), f"{where}.polygon", 2) + offset
        distinct = np.unique(np.round(points, 6), axis=0)
        if len(distinct) < 2:
            raise ValueError(f"{where}.polygon: all points coincide, no wall segment")
        start = points[0]
        end = points[np.argmax(np.hypot(*(points - start).T))]
        walls[str(_field(wall, "id", where))] = (start, end)
        segments.append((start, end))
    half_wall = max(preset.wall_thickness_m / 2, 0.75 * cs)  # closed for 4-connectivity
    wall = np.zeros((h_cells, w_cells), bool)
    for a, b in segments:
        if np.hypot(*(b - a)) < 1e-9:
            continue
        along, off, length = _segment_frame(px, py, a, b)
        wall |= (off <= half_wall) & (along >= -half_wall) & (along <= length + half_wall)

    # Door holes, cut after all walls.
    for i, door in enumerate(_list(data, "doors", "house", required=False)):
        where = f"doors[{i}]"
        wall_ids = [str(door.get(k)) for k in ("wall0", "wall1") if k in door]
        if not wall_ids:
            raise ValueError(f"{where}: missing 'wall0'")
        exterior = door.get("room0") == door.get("room1") or any("exterior" in w for w in wall_ids)
        if exterior:
            continue  # the outside is occupied: a front door leads nowhere
        known = [w for w in wall_ids if w in walls]
        if not known:
            raise ValueError(f"{where}: wall {wall_ids[0]!r} is not in house.walls")
        hole = _list(door, "holePolygon", where)
        if len(hole) < 2:
            raise ValueError(f"{where}.holePolygon: needs 2 points, got {len(hole)}")
        t0, t1 = sorted(
            _number(_field(p, "x", f"{where}.holePolygon[{k}]"), f"{where}.holePolygon[{k}].x")
            for k, p in enumerate(hole[:2])
        )
        a, b = walls[known[0]]
        along, off, length = _segment_frame(px, py, a, b)
        t0, t1 = max(t0, 0.0), min(t1, length)
        if t1 <= t0:
            raise ValueError(f"{where}.holePolygon: hole lies outside its wall {known[0]!r}")
        wall &= ~((off <= half_wall + cs) & (along >= t0) & (along <= t1))

    # Objects.
    size_db = asset_sizes or {}
    footprints = {
        n: C.FOOTPRINT_M.get(n, (C.TARGET_SIZE_M.get(n, 0.0),) * 2) for n in C.CATEGORY_NAMES
    }

    def footprint(asset_id: str, default: tuple[float, float], where: str) -> tuple[float, float]:
        if asset_id not in size_db:
            return default
        box = _field(size_db[asset_id], "boundingBox", f"asset_sizes[{asset_id!r}]")
        w = _number(_field(box, "x", f"asset_sizes[{asset_id!r}].boundingBox"), where)
        d = _number(_field(box, "z", f"asset_sizes[{asset_id!r}].boundingBox"), where)
        if w <= 0 or d <= 0:
            raise ValueError(f"asset_sizes[{asset_id!r}].boundingBox: sizes must be positive")
        return w, d

    furniture: list[tuple[int, float, float, float, float]] = []  # (cat, x, y, hx, hy)
    targets: list[tuple[int, float, float, int]] = []  # (cat, x, y, parent furniture index)
    blockers: list[tuple[float, float, float, float]] = []  # occupied, no object slot

    def visit(obj: Any, where: str, parent: int, on_floor: bool) -> None:
        asset_id = _field(obj, "assetId", where)
        if not isinstance(asset_id, str):
            raise ValueError(f"{where}.assetId: expected a string, got {asset_id!r}")
        x, y = np.array(_xz(_field(obj, "position", where), f"{where}.position")) + offset
        rotation = obj.get("rotation") or {}
        yaw = _number(rotation.get("y", 0.0), f"{where}.rotation.y")
        name = asset_category(asset_id)
        child_parent = parent
        if name is not None and on_floor and (name not in C.TARGET_NAMES or name == "HousePlant"):
            # Furniture, or a plant standing on the floor: a slot and occupied cells.
            hx, hy = _footprint_half(*footprint(asset_id, footprints[name], where), yaw)
            furniture.append((C.category_id(name), x, y, hx, hy))
            if name in C.RECEPTACLE_NAMES:
                child_parent = len(furniture) - 1
        elif name in C.TARGET_NAMES:
            targets.append((C.category_id(name), x, y, parent))
        elif name is None and on_floor:
            default = _floor_obstacle(asset_id)
            if default is not None:
                blockers.append((x, y, *_footprint_half(*footprint(asset_id, default, where), yaw)))
        for k, child in enumerate(_list(obj, "children", where, required=False)):
            visit(child, f"{where}.children[{k}]", child_parent, False)

    for i, obj in enumerate(_list(data, "objects", "house", required=False)):
        visit(obj, f"objects[{i}]", -1, True)

    n_slots = preset.max_objects
    dropped = max(0, len(furniture) - n_slots)
    furniture = furniture[:n_slots]
    targets = [t for t in targets if t[3] < len(furniture)]
    room_left = n_slots - len(furniture)
    dropped += max(0, len(targets) - room_left)
    targets = targets[:room_left]
    if dropped:
        warnings.warn(
            f"house has more objects than preset {preset.name!r} holds "
            f"({n_slots} slots): dropped {dropped}",
            stacklevel=2,
        )

    occupied = wall | (room_of_cell < 0)
    for _, x, y, hx, hy in furniture:
        occupied |= (np.abs(px - x) <= hx) & (np.abs(py - y) <= hy)
    for x, y, hx, hy in blockers:
        occupied |= (np.abs(px - x) <= hx) & (np.abs(py - y) <= hy)
    room_of_cell[wall] = -1
    occupied = np.asarray(fill_free_pockets(jnp.asarray(occupied)))

    def room_at(x: float, y: float) -> int:
        for r, poly in enumerate(polygons):
            if _inside(np.array([x]), np.array([y]), poly)[0]:
                return r
        return -1

    category = np.full(n_slots, -1, np.int32)
    xy = np.zeros((n_slots, 2), np.float32)
    half = np.zeros((n_slots, 2), np.float32)
    obj_room = np.full(n_slots, -1, np.int32)
    obj_parent = np.full(n_slots, -1, np.int32)
    for m, (cat, x, y, hx, hy) in enumerate(furniture):
        category[m], xy[m], half[m], obj_room[m] = cat, (x, y), (hx, hy), room_at(x, y)
    for k, (cat, x, y, parent) in enumerate(targets):
        m = len(furniture) + k
        category[m], xy[m] = cat, (x, y)
        half[m] = C.CATEGORY_SIZE_M[cat] / 2
        obj_parent[m] = parent
        obj_room[m] = obj_room[parent] if parent >= 0 else room_at(x, y)
    valid = category >= 0
    room_type = np.full(preset.max_rooms, -1, np.int32)
    room_type[: len(room_types)] = room_types

    return House(
        occupied=jnp.asarray(occupied),
        room_of_cell=jnp.asarray(room_of_cell),
        room_type=jnp.asarray(room_type),
        object_category=jnp.asarray(category),
        object_xy=jnp.asarray(xy),
        object_size=jnp.asarray(np.where(valid, C.CATEGORY_SIZE_M[np.maximum(category, 0)], 0)),
        object_half_extent=jnp.asarray(half),
        object_room=jnp.asarray(obj_room),
        object_parent=jnp.asarray(obj_parent),
        cell_size=cs,
    )
