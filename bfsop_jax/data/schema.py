"""The dataset record format: one typed table used by the data generator and the trainer.

A dataset is a dict of NumPy arrays with a leading record axis D. Every field has a dtype
and a per-record shape in terms of N (nodes), K (sets) and T = K + 1 (plan slots). The
instance is stored without ``start`` / ``end``: start node 0, open path (end -1).

Training fields (the trainer needs them): ``coords``, ``cost``, ``set_id``, ``set_reward``,
``budget`` (the SOP instance), ``teacher_nodes`` (the teacher's plan). Provenance fields
(kept for analysis, optional for the trainer): ``teacher_reward``, ``teacher_cost``,
``house_seed``, ``category``, ``source``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = [
    "DATASET_KEYS",
    "PROVENANCE_KEYS",
    "RECORD_FIELDS",
    "Field",
    "check_records",
    "field_shape",
    "make_records",
]


@dataclasses.dataclass(frozen=True)
class Field:
    """One array of a record: name, dtype, per-record shape and whether training needs it."""

    name: str
    dtype: type
    shape: tuple[str | int, ...]  # symbols "N", "K", "T" (= K + 1) or sizes
    training: bool  # read by the trainer (else provenance)
    doc: str


RECORD_FIELDS: tuple[Field, ...] = (
    Field("coords", np.float32, ("N", 2), True, "node positions (metres)"),
    Field("cost", np.float32, ("N", "N"), True, "travel cost i -> j (metres), inf unreachable"),
    Field("set_id", np.int32, ("N",), True, "set of each node, -1 padding; node 0 the start"),
    Field("set_reward", np.float32, ("K",), True, "reward of each set"),
    Field("budget", np.float32, (), True, "maximal tour cost (metres)"),
    Field("teacher_nodes", np.int32, ("T",), True, "teacher plan, start 0 first, -1 padding"),
    Field("teacher_reward", np.float32, (), False, "reward of the teacher plan"),
    Field("teacher_cost", np.float32, (), False, "cost of the teacher plan (metres)"),
    Field("house_seed", np.int64, (), False, "seed of the house the instance comes from"),
    Field("category", np.int32, (), False, "target category of the task"),
    Field("source", np.int32, (), False, "how the instance was made (generator constants)"),
)
DATASET_KEYS = tuple(f.name for f in RECORD_FIELDS if f.training)
PROVENANCE_KEYS = tuple(f.name for f in RECORD_FIELDS if not f.training)
_FIELDS = {f.name: f for f in RECORD_FIELDS}


def field_shape(field: Field, d: int, n: int, k: int) -> tuple[int, ...]:
    """Full shape ``(D, ...)`` of ``field`` for D records, N nodes and K sets."""
    sizes = {"N": n, "K": k, "T": k + 1}
    return (d,) + tuple(sizes[s] if isinstance(s, str) else s for s in field.shape)


def make_records(arrays: Mapping[str, Any], complete: bool = True) -> dict[str, np.ndarray]:
    """Typed record dict (the table's dtypes and order) of ``arrays``.

    Args:
        arrays: field name -> array with leading axis D.
        complete: every field is needed; False lets provenance fields be left out.

    Raises ``ValueError`` for a missing or unknown field (shapes: :func:`check_records`).
    """
    needed = [f.name for f in RECORD_FIELDS if complete or f.training]
    missing = [name for name in needed if name not in arrays]
    unknown = [name for name in arrays if name not in _FIELDS]
    if missing or unknown:
        raise ValueError(f"records lack the fields {missing} or have unknown ones {unknown}")
    return {
        f.name: np.asarray(arrays[f.name]).astype(f.dtype, copy=False)
        for f in RECORD_FIELDS
        if f.name in arrays
    }


def check_records(ds: Mapping[str, Any], name: str = "dataset") -> dict[str, np.ndarray]:
    """Typed copy of the training fields of ``ds``, shapes checked against the table.

    The training fields must be present; provenance fields, when present, must have
    shape [D]. Other keys are ignored. Values are not checked here (see
    :func:`bfsop_jax.sop.types.validate`). Raises ``ValueError`` naming the problem.
    """
    if not isinstance(ds, Mapping):
        raise ValueError(f"{name} must be a dict of arrays, got {type(ds).__name__}")
    missing = [k for k in DATASET_KEYS if k not in ds]
    if missing:
        raise ValueError(f"{name} lacks the arrays {missing} (needs {list(DATASET_KEYS)})")
    out = {k: np.asarray(ds[k]).astype(_FIELDS[k].dtype, copy=False) for k in DATASET_KEYS}
    set_id, reward = out["set_id"], out["set_reward"]
    if set_id.ndim != 2:
        raise ValueError(f"{name}: set_id must be [D, N], got shape {set_id.shape}")
    d, n = set_id.shape
    if reward.ndim != 2 or reward.shape[0] != d:
        raise ValueError(f"{name}: set_reward must be [D, K] with D = {d}, got {reward.shape}")
    k = reward.shape[1]
    for field in RECORD_FIELDS:
        if field.training or field.name in ds:
            shape = field_shape(field, d, n, k)
            got = out[field.name].shape if field.training else np.shape(ds[field.name])
            if got != shape:
                raise ValueError(f"{name}: {field.name} must have shape {shape}, got {got}")
    return out
