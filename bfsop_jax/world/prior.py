"""The co-occurrence prior P(target c | landmark category) (docs/design.md §3.4).

It is estimated from *training* houses only (seeds disjoint from evaluation seeds) and
stored as JSON under ``data/``; an episode never reads statistics of its own house.

P(c | k) = share of landmark instances of category k that hold at least one instance of
c, counting a target as held when it stands on the landmark (``object_parent``) or its
centre lies within ``radius_m`` of the landmark's footprint.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from bfsop_jax import files
from bfsop_jax.world.constants import CATEGORY_NAMES, N_CATEGORIES, N_TARGETS, TARGET_NAMES
from bfsop_jax.world.types import House

__all__ = [
    "DATA_DIR",
    "DEFAULT_PRIOR_PATH",
    "default_prior",
    "estimate_prior",
    "load_prior",
    "save_prior",
]

DEFAULT_PRIOR_FILE = "cooccurrence_prior.json"
# The project's data folder (next to the package in a checkout / editable install);
# BFSOP_DATA overrides it.
DATA_DIR = Path(os.environ.get("BFSOP_DATA", Path(__file__).resolve().parents[2] / "data"))
DEFAULT_PRIOR_PATH = DATA_DIR / DEFAULT_PRIOR_FILE


def estimate_prior(houses: House, radius_m: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """Estimate P(c | k) from a batch of houses (leading batch axis, NumPy or JAX arrays).

    Returns ``(prior [N_CATEGORIES, N_TARGETS] float32, landmark_count [N_CATEGORIES])``.
    Rows of categories never seen as a landmark are zero (no evidence, no LOI).
    """
    cat = np.asarray(houses.object_category)
    if cat.ndim == 1:  # a single house
        houses = _expand(houses)
        cat = np.asarray(houses.object_category)
    xy = np.asarray(houses.object_xy, np.float32)
    half = np.asarray(houses.object_half_extent, np.float32)
    parent = np.asarray(houses.object_parent)

    is_target = (cat >= 0) & (cat < N_TARGETS)
    is_landmark = cat >= N_TARGETS
    # [B, M(landmark), M(target)]: target near or on landmark.
    gap = np.abs(xy[:, None, :, :] - xy[:, :, None, :]) - half[:, :, None, :]
    near = np.all(gap <= radius_m, axis=-1)
    on = parent[:, None, :] == np.arange(cat.shape[1])[None, :, None]
    holds = (near | on) & is_landmark[:, :, None] & is_target[:, None, :]

    held = np.zeros((cat.shape[0], cat.shape[1], N_TARGETS), bool)  # [B, M, C]
    tcat = np.where(is_target, cat, 0)
    for c in range(N_TARGETS):  # nine categories: a tiny host-side loop
        held[..., c] = np.any(holds & (tcat[:, None, :] == c), axis=-1)

    counts = np.zeros(N_CATEGORIES, np.float64)
    hits = np.zeros((N_CATEGORIES, N_TARGETS), np.float64)
    lm = np.where(is_landmark, cat, 0)
    np.add.at(counts, lm[is_landmark], 1.0)
    np.add.at(hits, lm[is_landmark], held[is_landmark].astype(np.float64))
    prior = np.where(counts[:, None] > 0, hits / np.maximum(counts[:, None], 1.0), 0.0)
    return prior.astype(np.float32), counts.astype(np.int64)


def save_prior(path: str | os.PathLike, prior: np.ndarray, meta: dict | None = None) -> None:
    """Write the prior as JSON (atomically: a crash never leaves a half-written file)."""
    prior = np.asarray(prior, np.float32)
    _check_shape(prior, str(path))
    doc = {
        "version": 1,
        "description": "P(target | landmark category) estimated from training houses",
        "categories": list(CATEGORY_NAMES),
        "targets": list(TARGET_NAMES),
        "prior": {
            CATEGORY_NAMES[k]: {
                TARGET_NAMES[c]: round(float(prior[k, c]), 6) for c in range(N_TARGETS)
            }
            for k in range(N_CATEGORIES)
            if prior[k].any()
        },
        "meta": meta or {},
    }
    files.atomic_write(path, lambda f: json.dump(doc, f, indent=1))


def load_prior(path: str | os.PathLike) -> np.ndarray:
    """Read a prior JSON written by :func:`save_prior` -> float32 [N_CATEGORIES, N_TARGETS]."""
    try:
        doc = json.loads(Path(path).read_text())
        table = doc["prior"]
    except FileNotFoundError:
        raise ValueError(f"co-occurrence prior file not found: {path}") from None
    except (json.JSONDecodeError, KeyError, TypeError) as e:
        raise ValueError(f"malformed co-occurrence prior file {path}: {e}") from None
    prior = np.zeros((N_CATEGORIES, N_TARGETS), np.float32)
    for name, row in table.items():
        if name not in CATEGORY_NAMES:
            raise ValueError(f"{path}: unknown landmark category {name!r}")
        for target, p in row.items():
            if target not in TARGET_NAMES:
                raise ValueError(f"{path}: unknown target category {target!r}")
            if not (0.0 <= float(p) <= 1.0):
                raise ValueError(f"{path}: P({target} | {name}) = {p} is not a probability")
            prior[CATEGORY_NAMES.index(name), TARGET_NAMES.index(target)] = float(p)
    return prior


def default_prior() -> np.ndarray:
    """The prior estimated from training houses by ``python -m experiments.estimate_prior``."""
    if not DEFAULT_PRIOR_PATH.exists():
        raise ValueError(
            f"no co-occurrence prior at {DEFAULT_PRIOR_PATH}; run "
            "`python -m experiments.estimate_prior` (or set BFSOP_DATA) first"
        )
    return load_prior(DEFAULT_PRIOR_PATH)


def _check_shape(prior: np.ndarray, where: str) -> None:
    if prior.shape != (N_CATEGORIES, N_TARGETS):
        raise ValueError(
            f"{where}: prior must have shape [{N_CATEGORIES}, {N_TARGETS}], got {prior.shape}"
        )


def _expand(house: House) -> House:
    import jax

    return jax.tree_util.tree_map(lambda a: np.asarray(a)[None], house)
