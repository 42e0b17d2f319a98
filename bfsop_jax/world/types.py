"""The ``House`` pytree: the true world an episode runs in.

Shapes are static per preset: H, W = ``preset.grid_shape`` (0.1 m cells), R =
``preset.max_rooms``, M = ``preset.max_objects``. Unused room / object slots hold -1
(ids) and 0 (geometry). Row ``i`` is y, column ``j`` is x; the centre of cell (i, j)
is at ``((j + 0.5) * cell_size, (i + 0.5) * cell_size)`` metres.
"""

from __future__ import annotations

import jax
from flax import struct


@struct.dataclass
class House:
    """A house rasterised on the occupancy grid, plus its rooms and objects."""

    occupied: jax.Array  # [H, W] bool: wall, furniture or outside the house
    room_of_cell: jax.Array  # [H, W] int32: room slot of each floor cell, -1 = none
    room_type: jax.Array  # [R] int32: index into ROOM_TYPE_NAMES, -1 = unused slot
    object_category: jax.Array  # [M] int32: index into CATEGORY_NAMES, -1 = unused slot
    object_xy: jax.Array  # [M, 2] float32: centre (x, y) in metres
    object_size: jax.Array  # [M] float32: detection size s in metres (docs/design.md §2.3)
    object_half_extent: jax.Array  # [M, 2] float32: footprint half sizes (x, y), metres
    object_room: jax.Array  # [M] int32: room slot holding the object, -1 = none
    object_parent: jax.Array  # [M] int32: receptacle slot a target stands on, -1 = floor/none
    cell_size: float = struct.field(pytree_node=False, default=0.1)  # metres per cell

    @property
    def grid_shape(self) -> tuple[int, int]:
        return tuple(self.occupied.shape[-2:])

    @property
    def object_valid(self) -> jax.Array:
        """[M] bool: slot holds an object."""
        return self.object_category >= 0
