"""Presets: every number that fixes an array shape, plus the task's physical constants.

A :class:`Preset` is a frozen, hashable dataclass, so it can be passed to ``jax.jit`` as a
static argument: everything that sets a shape lives here, and one preset compiles once.
Values one might sweep at run time (budgets of individual episodes, PRNG keys) are array
arguments of the functions instead.

Units: metres, radians, pixels where stated. Grid cells are ``cell_size`` metres;
row ``i`` spans y in ``[i * cell_size, (i + 1) * cell_size)`` and column ``j`` spans x likewise.
"""

from __future__ import annotations

import dataclasses
import math

__all__ = [
    "EVAL_SEED_START",
    "PRESET_NAMES",
    "Preset",
    "VALIDATION_SEED_START",
    "get_preset",
    "parse_seed_range",
    "require_preset",
]

# House seeds: training houses use seeds below EVAL_SEED_START, evaluation houses start
# there, so the two never meet (docs/design.md §8.2).
EVAL_SEED_START = 1_000_000
# Validation houses (choosing baseline settings, budgets) start here: neither training
# houses nor the held-out test houses of the evaluation.
VALIDATION_SEED_START = 2_000_000


@dataclasses.dataclass(frozen=True)
class Preset:
    """Static configuration of one experimental scale (docs/design.md §2.1)."""

    name: str
    # --- house footprint and generator -------------------------------------------------
    width_m: float  # footprint along x (columns)
    height_m: float  # footprint along y (rows)
    min_rooms: int  # the generator aims for a room count in [min_rooms, max_rooms]
    max_rooms: int  # R: capacity of the per-room arrays
    max_objects: int  # M: capacity of the per-object arrays (landmarks + targets)
    budget_m: float  # default travel budget B of an episode
    min_room_side_m: float = 2.5
    wall_thickness_m: float = 0.15
    extra_doors: int = 2  # doors beyond the spanning partition doors (make loops)
    cell_size: float = 0.1  # occupancy grid resolution (paper value)
    # --- motion -------------------------------------------------------------------------
    robot_radius_m: float = 0.2
    micro_steps: int = 8  # motion steps (one planning cell each) per env.step (a macro action)
    plan_factor: int = 2  # planning grid cell = plan_factor * cell_size (0.2 m)
    # --- sensing (docs/design.md §3) --------------------------------------------------------------
    fov_deg: float = 90.0
    n_rays: int = 91  # ~1 ray per degree across the field of view
    sensor_range_m: float = 5.0
    logodds_free: float = -0.4
    logodds_occupied: float = 0.85
    logodds_clamp: float = 5.0
    logodds_known: float = 0.2  # |log-odds| above this counts as known
    image_width_px: int = 300
    focal_px: float = 150.0
    noise_filter_px: float = 100.0  # A < this: ignored
    landmark_px: float = 400.0  # A >= this: a landmark of interest
    verify_distance_m: float = 1.0
    # --- SOP (docs/design.md §7) ------------------------------------------------------------------
    n_loi: int = 15
    n_viewpoints: int = 5
    # Viewpoints keep this clearance (metres) from their landmark's footprint: close
    # enough to verify targets on it (1 m), far enough for the robot radius.
    viewpoint_min_m: float = 0.3
    viewpoint_max_m: float = 0.8
    # --- exploration (docs/design.md §5) ----------------------------------------------------------
    max_frontier_clusters: int = 32

    # Derived shapes ------------------------------------------------------------------------
    @property
    def grid_shape(self) -> tuple[int, int]:
        """(H, W) of the 0.1 m occupancy grid."""
        return (
            int(math.ceil(self.height_m / self.cell_size - 1e-6)),
            int(math.ceil(self.width_m / self.cell_size - 1e-6)),
        )

    @property
    def plan_cell_size(self) -> float:
        return self.cell_size * self.plan_factor

    @property
    def plan_shape(self) -> tuple[int, int]:
        """(Hp, Wp) of the coarser planning grid."""
        h, w = self.grid_shape
        return (-(-h // self.plan_factor), -(-w // self.plan_factor))

    @property
    def n_sop_nodes(self) -> int:
        """N = 1 start node + n_loi * n_viewpoints viewpoints."""
        return 1 + self.n_loi * self.n_viewpoints

    @property
    def fov_rad(self) -> float:
        return math.radians(self.fov_deg)


_PRESETS: dict[str, Preset] = {
    "smoke": Preset(
        name="smoke",
        width_m=16.0,
        height_m=12.0,
        min_rooms=4,
        max_rooms=6,
        max_objects=64,
        budget_m=60.0,
        extra_doors=1,
    ),
    "demo": Preset(
        name="demo",
        width_m=32.0,
        height_m=24.0,
        min_rooms=14,
        max_rooms=18,
        max_objects=192,
        budget_m=150.0,
        extra_doors=3,
    ),
    "paper": Preset(
        name="paper",
        width_m=52.0,
        height_m=44.0,
        min_rooms=44,
        max_rooms=56,
        max_objects=512,
        budget_m=400.0,
        extra_doors=8,
    ),
}

PRESET_NAMES: tuple[str, ...] = tuple(_PRESETS)


def get_preset(name: str | Preset) -> Preset:
    """Return the preset called ``name`` ("smoke", "demo" or "paper").

    A :class:`Preset` passes through unchanged. The public entry points (house generation
    and import, ``env.reset`` / ``env.step``, the command lines) accept either and convert
    once here; everything below them takes a :class:`Preset` (:func:`require_preset`).
    """
    if isinstance(name, Preset):
        return name
    try:
        return _PRESETS[name]
    except (KeyError, TypeError):
        valid = ", ".join(repr(n) for n in PRESET_NAMES)
        raise ValueError(f"unknown preset {name!r}; valid presets are {valid}") from None


def require_preset(preset: Preset) -> Preset:
    """``preset`` itself if it is a :class:`Preset`; a ValueError naming the type else
    (internal functions take presets; names are resolved once, by :func:`get_preset`)."""
    if not isinstance(preset, Preset):
        raise ValueError(
            f"preset must be a bfsop_jax.config.Preset, got {type(preset).__name__} "
            "(resolve names with bfsop_jax.config.get_preset)"
        )
    return preset


def parse_seed_range(text: str) -> range:
    """Parse "START:END" (END exclusive) into a range of house seeds, with a clear error."""
    try:
        start_s, end_s = text.split(":")
        start, end = int(start_s), int(end_s)
    except ValueError:
        raise ValueError(
            f"seed range must look like START:END (e.g. 1000000:1000010), got {text!r}"
        ) from None
    if start < 0 or end <= start:
        raise ValueError(f"seed range {text!r} is empty or negative")
    return range(start, end)
