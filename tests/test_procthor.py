"""ProcTHOR house JSON importer: the shared samples, the assetId table and malformed input."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from scipy import ndimage

from bfsop_jax.config import get_preset
from bfsop_jax.world import CATEGORY_NAMES, load_procthor_house
from bfsop_jax.world import constants as C
from bfsop_jax.world.procthor import asset_category

SAMPLES = ("sample_house_2rooms.json", "sample_house_3rooms.json")


def _square_room(room_id: str, x0: float, z0: float, x1: float, z1: float, kind: str) -> dict:
    corners = [(x0, z0), (x0, z1), (x1, z1), (x1, z0)]
    return {
        "id": room_id,
        "roomType": kind,
        "floorPolygon": [{"x": x, "y": 0, "z": z} for x, z in corners],
    }


def _two_room_house() -> dict:
    """Two 4 x 4 m rooms sharing the wall x = 4 with a 1 m door, a bed and a laptop on it."""
    wall_points = [{"x": 4.0, "y": 0, "z": 1.0}, {"x": 4.0, "y": 0, "z": 3.0}]
    return {
        "rooms": [
            _square_room("room|1", 0, 0, 4, 4, "Bedroom"),
            _square_room("room|2", 4, 0, 8, 4, "Kitchen"),
        ],
        "walls": [
            {"id": "wall|1|4|1|4|3", "roomId": "room|1", "polygon": wall_points},
            {"id": "wall|2|4|1|4|3", "roomId": "room|2", "polygon": wall_points},
        ],
        "doors": [
            {
                "id": "door|1|2",
                "room0": "room|1",
                "room1": "room|2",
                "wall0": "wall|1|4|1|4|3",
                "wall1": "wall|2|4|1|4|3",
                "holePolygon": [{"x": 0.5, "y": 0, "z": 0}, {"x": 1.5, "y": 2.0, "z": 0}],
            }
        ],
        "objects": [
            {
                "assetId": "Bed_12",
                "position": {"x": 1.0, "y": 0.4, "z": 2.0},
                "rotation": {"x": 0, "y": 90, "z": 0},
                "children": [{"assetId": "Laptop_3", "position": {"x": 1.2, "y": 0.7, "z": 2.1}}],
            },
            {"assetId": "Fridge_1", "position": {"x": 7.5, "y": 0.9, "z": 3.5}},
        ],
    }


def _free_components(house) -> int:
    return ndimage.label(~np.asarray(house.occupied))[1]


@pytest.mark.parametrize("name", SAMPLES)
def test_samples_import_with_walls_doors_furniture(shared, name):
    path = shared("procthor", name)
    data = json.loads(path.read_text())
    house = load_procthor_house(path, "smoke")
    smoke = get_preset("smoke")
    occupied = np.asarray(house.occupied)
    rooms = np.asarray(house.room_of_cell)
    assert occupied.shape == smoke.grid_shape
    assert _free_components(house) == 1
    n_rooms = len(data["rooms"])
    assert (np.asarray(house.room_type)[:n_rooms] >= 0).all()
    for r in range(n_rooms):
        assert (~occupied & (rooms == r)).sum() > 50, f"room {r} has no floor"
    # Walls: occupied non-room cells inside the outline; doors: rooms touch through free cells.
    assert (occupied & (rooms < 0)).any()
    free_rooms = np.where(~occupied, rooms, -1)
    touching = {
        frozenset((int(a), int(b)))
        for a, b in zip(free_rooms[:, :-1].ravel(), free_rooms[:, 1:].ravel(), strict=True)
        if a >= 0 and b >= 0 and a != b
    } | {
        frozenset((int(a), int(b)))
        for a, b in zip(free_rooms[:-1].ravel(), free_rooms[1:].ravel(), strict=True)
        if a >= 0 and b >= 0 and a != b
    }
    index = {room["id"]: i for i, room in enumerate(data["rooms"])}
    interior = [d for d in data["doors"] if d["room0"] != d["room1"]]
    assert interior
    for door in interior:
        assert frozenset((index[door["room0"]], index[door["room1"]])) in touching, door["id"]
    # Furniture: object slots whose centre cells are occupied.
    category = np.asarray(house.object_category)
    furniture = np.flatnonzero(category >= C.N_TARGETS)
    assert furniture.size >= 3
    for m in furniture:
        i, j = (np.asarray(house.object_xy[m])[::-1] / smoke.cell_size).astype(int)
        assert occupied[i, j]


def test_sample_child_target_stands_on_its_receptacle(shared):
    house = load_procthor_house(shared("procthor", "sample_house_2rooms.json"), "smoke")
    category = np.asarray(house.object_category)
    parent = np.asarray(house.object_parent)
    books = np.flatnonzero(category == C.TARGET_NAMES.index("Book"))
    assert books.size == 1  # Book_9 is a child of the bed
    bed = parent[books[0]]
    assert CATEGORY_NAMES[category[bed]] == "Bed"
    assert house.object_room[books[0]] == house.object_room[bed]


def test_hand_made_house_geometry():
    house = load_procthor_house(_two_room_house(), "smoke")
    occupied = np.asarray(house.occupied)
    rooms = np.asarray(house.room_of_cell)
    assert _free_components(house) == 1
    category = [CATEGORY_NAMES[c] for c in np.asarray(house.object_category) if c >= 0]
    assert category == ["Bed", "Fridge", "Laptop"]
    # The bed turned by 90 deg: its 1.6 m width runs along y, its 2.0 m depth along x.
    np.testing.assert_allclose(np.asarray(house.object_half_extent[0]), [1.0, 0.8], atol=1e-6)
    assert house.object_parent[2] == 0 and house.object_room[2] == 0
    np.testing.assert_allclose(house.object_size[2], C.TARGET_SIZE_M["Laptop"])
    # The house (8 x 4 m) is centred in the 16 x 12 m grid: shifted by (4, 4) m. The shared
    # wall x = 8 m covers cell columns 79-80; the door opens y in [5.5, 6.5] m: rows 55-64.
    wall = occupied[40:80, 79:81]
    assert (rooms[40:80, 79:81] == -1).sum() == 2 * (40 - 10)
    np.testing.assert_array_equal(np.flatnonzero(~wall.any(axis=1)) + 40, np.arange(55, 65))
    assert (rooms[55:65, 78] == 0).all() and (rooms[55:65, 81] == 1).all()


def test_asset_sizes_override_the_default_footprint():
    data = _two_room_house()
    house = load_procthor_house(
        data, "smoke", asset_sizes={"Bed_12": {"boundingBox": {"x": 1.0, "z": 1.5}}}
    )
    np.testing.assert_allclose(np.asarray(house.object_half_extent[0]), [0.75, 0.5], atol=1e-6)


@pytest.mark.parametrize(
    ("asset_id", "category"),
    [
        ("Dining_Table_16_2", "DiningTable"),
        ("RoboTHOR_dining_table_extendable", "DiningTable"),
        ("RoboTHOR_dresser_aspelund", "Dresser"),
        ("Dresser_224_1", "Dresser"),
        ("Sink_26", "Sink"),
        ("Toilet_2", "Toilet"),
        ("Toilet_Paper", None),
        ("bin_20", "GarbageCan"),
        ("Chair_205_2", "Chair"),
        ("Armchair_208_3", "ArmChair"),
        ("Book_9", "Book"),
        ("Bookshelf_3", "ShelvingUnit"),
        ("Shelving_Unit_301_1", "ShelvingUnit"),
        ("Side_Table_316_1", "SideTable"),
        ("Coffee_Table_207_1", "CoffeeTable"),
        ("TV_Stand_222_1", "TVStand"),
        ("Desk_Lamp_2", None),
        ("Houseplant_8", "HousePlant"),
        ("Soap_Bottle_1", "SoapBottle"),
        ("Wall_Decor_Photo_3", None),
        ("Bathroom_Faucet_1", None),
    ],
)
def test_asset_category_from_prefix(asset_id, category):
    assert asset_category(asset_id) == category


def test_house_too_large_names_the_preset_needed():
    data = _two_room_house()
    data["rooms"].append(_square_room("room|3", 8, 0, 24, 20, "LivingRoom"))
    with pytest.raises(ValueError, match="use preset 'demo'"):
        load_procthor_house(data, "smoke")
    house = load_procthor_house(data, "demo")
    assert house.occupied.shape == get_preset("demo").grid_shape


def _broken(edit):
    data = _two_room_house()
    edit(data)
    return data


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"walls": []}, "missing 'rooms'"),
        ({"rooms": []}, "no rooms"),
        (
            _broken(lambda d: d["rooms"][0].pop("floorPolygon")),
            r"rooms\[0\]: missing 'floorPolygon'",
        ),
        (
            _broken(lambda d: d["rooms"][1]["floorPolygon"].__delitem__(slice(1, None))),
            "at least 3 points",
        ),
        (
            _broken(lambda d: d["rooms"][0]["floorPolygon"][1].update(x="wide")),
            r"floorPolygon\[1\]\.x",
        ),
        (_broken(lambda d: d["rooms"][0]["floorPolygon"][2].update(z=float("nan"))), "finite"),
        (_broken(lambda d: d["rooms"][0].update(roomType="Garage")), "unknown room type"),
        (
            _broken(lambda d: d["doors"][0].update(wall0="wall|9", wall1="wall|8")),
            "not in house.walls",
        ),
        (_broken(lambda d: d["objects"][0].pop("position")), r"objects\[0\]: missing 'position'"),
        (_broken(lambda d: d["objects"][0]["rotation"].update(y=None)), r"rotation\.y"),
        ("not a house", "not valid JSON"),
        (42, "expected a house dict or a path"),
    ],
)
def test_malformed_houses_raise_clear_errors(tmp_path, data, message):
    if isinstance(data, str):
        path = tmp_path / "house.json"
        path.write_text("{ this is not json")
        data = path
    with pytest.raises(ValueError, match=message):
        load_procthor_house(copy.deepcopy(data) if isinstance(data, dict) else data, "smoke")
