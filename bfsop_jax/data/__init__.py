"""Teacher-labelled datasets: generation from training houses and resumable shards.

The record format is :mod:`bfsop_jax.data.schema` (light, imported by the trainer); the
generator and the shard store load on first use, so importing the schema does not pull in
the simulator.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ["DataConfig", "ShardStore", "generate_dataset", "merge_datasets"]

_LAZY = {
    "DataConfig": "bfsop_jax.data.generate",
    "generate_dataset": "bfsop_jax.data.generate",
    "ShardStore": "bfsop_jax.data.shards",
    "merge_datasets": "bfsop_jax.data.shards",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
