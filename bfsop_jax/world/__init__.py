"""The true world: procedural ProcTHOR-like houses and the ProcTHOR JSON importer."""

from bfsop_jax.world.constants import (
    CATEGORY_NAMES,
    RECEPTACLE_NAMES,
    ROOM_TYPE_NAMES,
    TARGET_NAMES,
    category_id,
    target_id,
)
from bfsop_jax.world.generator import generate_house
from bfsop_jax.world.procthor import load_procthor_house
from bfsop_jax.world.types import House

__all__ = [
    "CATEGORY_NAMES",
    "RECEPTACLE_NAMES",
    "ROOM_TYPE_NAMES",
    "TARGET_NAMES",
    "House",
    "category_id",
    "generate_house",
    "load_procthor_house",
    "target_id",
]
