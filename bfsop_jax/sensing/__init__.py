"""Sensing: ray-cast occupancy mapping and the simulated detection model (docs/design.md §3)."""

from bfsop_jax.sensing.detection import (
    Detections,
    landmarks_of_interest,
    observe,
    verified_targets,
)
from bfsop_jax.sensing.mapping import (
    Rays,
    ScanCells,
    cast_rays,
    known_free,
    known_occupied,
    scan_cells,
    unknown,
    update_belief,
)

__all__ = [
    "Detections",
    "Rays",
    "ScanCells",
    "cast_rays",
    "known_free",
    "known_occupied",
    "landmarks_of_interest",
    "observe",
    "scan_cells",
    "unknown",
    "update_belief",
    "verified_targets",
]
