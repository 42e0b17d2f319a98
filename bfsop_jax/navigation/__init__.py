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
    frontier_mask,
    nearest_frontier,
    plan_cell_states,
    unknown_count,
    unknown_side,
)
from bfsop_jax.navigation.grid import (
    ESCAPE_RADIUS,
    cell_blocked,
    motion_blocked,
    plan_cell_to_xy,
    planning_blocked,
    true_blocked,
    xy_to_plan_cell,
)
from bfsop_jax.navigation.path import (
    NEIGHBOURS,
    geodesic_route,
    move_headings,
    move_lengths,
    next_cell,
)

__all__ = [
    "ESCAPE_RADIUS",
    "MIN_CLUSTER_CELLS",
    "NEIGHBOURS",
    "Frontiers",
    "cell_blocked",
    "cluster_frontier_cells",
    "frontier_cells",
    "frontier_clusters",
    "frontier_mask",
    "geodesic_route",
    "motion_blocked",
    "move_headings",
    "move_lengths",
    "nearest_frontier",
    "next_cell",
    "plan_cell_states",
    "unknown_count",
    "unknown_side",
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
