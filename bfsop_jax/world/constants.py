"""Object categories, room types and the placement tables of the house generator.

One id space covers every object: ids ``0 .. N_TARGETS-1`` are the nine target categories,
then the receptacles (landmarks; targets spawn on them), then plain obstacles (furniture
that never holds a target). ``-1`` marks an unused slot everywhere.

The receptacle -> target probabilities follow ProcTHOR's public placement facts
(per receptacle instance); the room-type shares and furniture lists are ProcTHOR-like.
"""

from __future__ import annotations

import numpy as np

# --- room types --------------------------------------------------------------------------
ROOM_TYPE_NAMES: tuple[str, ...] = ("Kitchen", "LivingRoom", "Bedroom", "Bathroom")
KITCHEN, LIVING_ROOM, BEDROOM, BATHROOM = range(4)
N_ROOM_TYPES = len(ROOM_TYPE_NAMES)

# --- categories --------------------------------------------------------------------------
TARGET_NAMES: tuple[str, ...] = (
    "Apple",
    "Bread",
    "Cup",
    "Laptop",
    "Book",
    "Potato",
    "SoapBottle",
    "Tomato",
    "HousePlant",
)
RECEPTACLE_NAMES: tuple[str, ...] = (
    "CounterTop",
    "Fridge",
    "DiningTable",
    "ShelvingUnit",
    "SideTable",
    "Sofa",
    "CoffeeTable",
    "TVStand",
    "Desk",
    "Dresser",
    "Bed",
    "Sink",
    "Toilet",
)
OBSTACLE_NAMES: tuple[str, ...] = ("ArmChair", "Chair", "Stool", "GarbageCan")

CATEGORY_NAMES: tuple[str, ...] = TARGET_NAMES + RECEPTACLE_NAMES + OBSTACLE_NAMES
N_TARGETS = len(TARGET_NAMES)
N_RECEPTACLES = len(RECEPTACLE_NAMES)
N_CATEGORIES = len(CATEGORY_NAMES)
FIRST_RECEPTACLE = N_TARGETS
FIRST_OBSTACLE = N_TARGETS + N_RECEPTACLES

CATEGORY_ID: dict[str, int] = {name: i for i, name in enumerate(CATEGORY_NAMES)}


def category_id(name: str) -> int:
    """Id of a category name (case-sensitive, ProcTHOR spelling); clear error otherwise."""
    try:
        return CATEGORY_ID[name]
    except KeyError:
        raise ValueError(
            f"unknown object category {name!r}; known categories are {', '.join(CATEGORY_NAMES)}"
        ) from None


def target_id(name: str | int) -> int:
    """Id of a target category given by name or id; clear error for anything else."""
    if isinstance(name, (int, np.integer)):
        if 0 <= int(name) < N_TARGETS:
            return int(name)
        raise ValueError(f"target category id {name} out of range 0..{N_TARGETS - 1}")
    if name not in TARGET_NAMES:
        raise ValueError(f"unknown target category {name!r}; targets are {', '.join(TARGET_NAMES)}")
    return TARGET_NAMES.index(name)


# --- physical sizes (metres; docs/design.md §2.3) -------------------------------------------------
TARGET_SIZE_M: dict[str, float] = {
    "Apple": 0.08,
    "Tomato": 0.08,
    "Potato": 0.10,
    "Cup": 0.10,
    "SoapBottle": 0.12,
    "Book": 0.22,
    "Bread": 0.25,
    "Laptop": 0.35,
    "HousePlant": 0.50,
}

# Footprint (width along the wall, depth away from it) in metres of furniture, used both by
# the generator and as the default size table of the ProcTHOR importer.
FOOTPRINT_M: dict[str, tuple[float, float]] = {
    "CounterTop": (2.0, 0.65),
    "Fridge": (0.8, 0.75),
    "DiningTable": (1.6, 0.9),
    "ShelvingUnit": (1.0, 0.4),
    "SideTable": (0.5, 0.45),
    "Sofa": (2.0, 0.9),
    "CoffeeTable": (1.1, 0.6),
    "TVStand": (1.5, 0.45),
    "Desk": (1.3, 0.65),
    "Dresser": (1.2, 0.5),
    "Bed": (1.6, 2.0),
    "Sink": (0.6, 0.5),
    "Toilet": (0.45, 0.7),
    "ArmChair": (0.85, 0.85),
    "Chair": (0.5, 0.5),
    "Stool": (0.4, 0.4),
    "GarbageCan": (0.35, 0.35),
}

# Detection size s (metres) of every category: targets per docs/design.md §2.3, furniture by its
# larger footprint side (landmarks 0.5-2 m).
CATEGORY_SIZE_M = np.array(
    [TARGET_SIZE_M[n] for n in TARGET_NAMES]
    + [float(np.clip(max(FOOTPRINT_M[n]), 0.5, 2.0)) for n in RECEPTACLE_NAMES + OBSTACLE_NAMES],
    dtype=np.float32,
)

# --- placement tables ---------------------------------------------------------------------
# SPAWN_PROB[r, t]: probability p(R, C) that receptacle r (index into RECEPTACLE_NAMES)
# holds target t, per receptacle instance.
_SPAWN: dict[str, dict[str, float]] = {
    "Apple": {
        "DiningTable": 0.238, "Fridge": 0.167, "CounterTop": 0.158, "Desk": 0.158,
        "SideTable": 0.084, "CoffeeTable": 0.079, "Sink": 0.041, "ShelvingUnit": 0.026,
    },
    "Bread": {"CounterTop": 0.208, "DiningTable": 0.107},
    "Cup": {
        "CounterTop": 0.158, "DiningTable": 0.143, "CoffeeTable": 0.079, "Desk": 0.079,
        "SideTable": 0.073, "Dresser": 0.067, "TVStand": 0.053, "Sink": 0.041,
    },
    "Laptop": {
        "Desk": 0.434, "DiningTable": 0.238, "Bed": 0.220, "Sofa": 0.197,
        "CoffeeTable": 0.188, "Dresser": 0.107, "TVStand": 0.053, "SideTable": 0.022,
    },
    "Book": {
        "Desk": 0.474, "Dresser": 0.253, "CoffeeTable": 0.238, "Bed": 0.183,
        "DiningTable": 0.179, "Sofa": 0.079, "SideTable": 0.077, "ShelvingUnit": 0.053,
        "CounterTop": 0.020,
    },
    "Potato": {"CounterTop": 0.178, "DiningTable": 0.095, "Fridge": 0.067, "Sink": 0.027},
    "SoapBottle": {"CounterTop": 0.505, "Toilet": 0.033, "Sink": 0.027, "SideTable": 0.011},
    "Tomato": {"Fridge": 0.200, "CounterTop": 0.129, "DiningTable": 0.071, "Sink": 0.068},
    "HousePlant": {
        "DiningTable": 0.179, "CoffeeTable": 0.168, "SideTable": 0.146, "Dresser": 0.133,
        "TVStand": 0.132, "CounterTop": 0.089, "Desk": 0.053, "ShelvingUnit": 0.053,
    },
}  # fmt: skip
SPAWN_PROB = np.zeros((N_RECEPTACLES, N_TARGETS), dtype=np.float32)
for _t, _row in _SPAWN.items():
    for _r, _p in _row.items():
        SPAWN_PROB[RECEPTACLE_NAMES.index(_r), TARGET_NAMES.index(_t)] = _p

# TARGET_ROOM_ALLOWED[t, room_type]: may target t appear in a room of that type.
# "rare" (Book in kitchens) is allowed with a reduced probability (TARGET_ROOM_WEIGHT).
TARGET_ROOM_WEIGHT = np.array(
    [
        # Kitchen LivingRoom Bedroom Bathroom
        [1.0, 0.0, 0.0, 0.0],  # Apple
        [1.0, 0.0, 0.0, 0.0],  # Bread
        [1.0, 0.0, 0.0, 0.0],  # Cup
        [0.0, 1.0, 1.0, 0.0],  # Laptop
        [0.15, 1.0, 1.0, 0.0],  # Book (rare in kitchens)
        [1.0, 0.0, 0.0, 0.0],  # Potato
        [1.0, 0.0, 0.0, 1.0],  # SoapBottle
        [1.0, 0.0, 0.0, 0.0],  # Tomato
        [1.0, 1.0, 1.0, 1.0],  # HousePlant
    ],
    dtype=np.float32,
)

# Placement bias terms of ProcTHOR's rule u <= p + parent_bias + child_bias + house_bias.
PARENT_BIAS = np.array(
    [0.4 if n == "ShelvingUnit" else 0.2 for n in RECEPTACLE_NAMES], dtype=np.float32
)
CHILD_BIAS = np.array([0.25 if n == "HousePlant" else 0.0 for n in TARGET_NAMES], np.float32)
MAX_COPIES_PER_RECEPTACLE = 3
ONE_PER_ROOM_TARGETS: tuple[str, ...] = ("Apple", "Laptop", "SoapBottle", "HousePlant")

# Furniture that each room type may contain (names from CATEGORY_NAMES).
ROOM_FURNITURE: dict[str, tuple[str, ...]] = {
    "Kitchen": (
        "CounterTop", "Fridge", "DiningTable", "ShelvingUnit", "SideTable",
        "Stool", "Chair", "GarbageCan",
    ),
    "LivingRoom": (
        "Sofa", "CoffeeTable", "TVStand", "Desk", "Dresser", "ShelvingUnit",
        "SideTable", "DiningTable", "ArmChair",
    ),
    "Bedroom": ("Bed", "Desk", "Dresser", "SideTable", "ShelvingUnit", "ArmChair"),
    "Bathroom": ("Sink", "Toilet", "SideTable", "GarbageCan"),
}  # fmt: skip

# Share of each room type among a house's rooms (ProcTHOR-like; bathrooms are small).
ROOM_TYPE_SHARE = np.array([0.18, 0.22, 0.35, 0.25], dtype=np.float32)


def is_receptacle(category: np.ndarray) -> np.ndarray:
    """True for receptacle (landmark) category ids; works on NumPy and JAX arrays."""
    return (category >= FIRST_RECEPTACLE) & (category < FIRST_OBSTACLE)


def is_target(category: np.ndarray) -> np.ndarray:
    """True for target category ids (0 .. N_TARGETS-1)."""
    return (category >= 0) & (category < N_TARGETS)
