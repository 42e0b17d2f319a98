"""Navigation on the planning grid: inflation, geodesic distances, path following, frontiers."""

from bfsop_jax.navigation.distance import (
    distance_field,
    distance_fields,
    distance_fields_from_cells,
    distance_matrix,
    snap_to_free,
)
from bfsop_jax.navigation.frontiers import (
    MIN_CLUSTER_CELLS,
    Frontiers,
    cluster_frontier_cells,
    frontier_cells,
    frontier_clusters,
    nearest_frontier,
)
from bfsop_jax.navigation.grid import (
    plan_cell_to_xy,
    planning_blocked,
    true_blocked,
    xy_to_plan_cell,
)
from bfsop_jax.navigation.path import advance, default_max_moves, is_traversable, next_cell

__all__ = [
    "MIN_CLUSTER_CELLS",
    "Frontiers",
    "cluster_frontier_cells",
    "frontier_cells",
    "frontier_clusters",
    "nearest_frontier",
    "advance",
    "default_max_moves",
    "is_traversable",
    "next_cell",
    "distance_field",
    "distance_fields",
    "distance_fields_from_cells",
    "distance_matrix",
    "plan_cell_to_xy",
    "planning_blocked",
    "snap_to_free",
    "true_blocked",
    "xy_to_plan_cell",
]
