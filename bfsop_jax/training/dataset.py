"""The behaviour-cloning trainer's data: dataset dicts, their checks and their batches.

A dataset is a dict of NumPy arrays with a leading axis D (the table is
:data:`bfsop_jax.data.schema.RECORD_FIELDS`): ``coords [D, N, 2]``, ``cost [D, N, N]``,
``set_id [D, N]``, ``set_reward [D, K]``, ``budget [D]``, ``teacher_nodes [D, K + 1]``;
node 0 is the start, paths are open. Here: the checked, typed copy the trainer uses, the
conversions between datasets and batched :class:`~bfsop_jax.sop.types.SOPInstance`,
their sizes, and the padded minibatches that cover every instance once. Importable from
:mod:`bfsop_jax.training.bc` too.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from bfsop_jax.data.schema import check_records, make_records
from bfsop_jax.parallel import place
from bfsop_jax.sop.types import Solution, SOPInstance, plan_length, validate

__all__ = [
    "dataset_from_instances",
    "dataset_info",
    "instances_from_dataset",
    "padded_batches",
]


def _check_dataset(ds: Mapping[str, Any], name: str = "dataset") -> dict[str, np.ndarray]:
    """Typed copy of the arrays the trainer uses; ValueError naming the problem.

    Keys, dtypes and shapes come from :data:`bfsop_jax.data.schema.RECORD_FIELDS`, the
    instances are checked by :func:`bfsop_jax.sop.types.validate` (start 0, open path), the
    teacher plans here.
    """
    out = check_records(ds, name)
    d, n = out["set_id"].shape
    if d == 0:
        raise ValueError(f"{name} is empty (D = 0)")
    try:
        validate(_dataset_instances(out))
    except ValueError as err:
        raise ValueError(f"{name}: {err}") from None
    teacher = out["teacher_nodes"]
    if (teacher[:, 0] != 0).any():
        raise ValueError(f"{name}: teacher_nodes must start at node 0 (the start)")
    if ((teacher < -1) | (teacher >= n)).any():
        raise ValueError(f"{name}: teacher_nodes outside [-1, {n})")
    return out


def _dataset_instances(data: Mapping[str, np.ndarray]) -> SOPInstance:
    """Batched instances [D] of typed dataset arrays: start node 0, open paths."""
    d = data["set_id"].shape[0]
    return SOPInstance(
        cost=data["cost"],
        set_id=data["set_id"],
        set_reward=data["set_reward"],
        start=np.zeros(d, np.int32),
        end=np.full(d, -1, np.int32),
        budget=data["budget"],
        coords=data["coords"],
    )


def instances_from_dataset(ds: Mapping[str, Any]) -> SOPInstance:
    """Batched :class:`SOPInstance` (NumPy leaves, leading axis D) of a dataset dict.

    Start node 0, open paths (end = -1). Extra keys of ``ds`` are ignored.
    """
    return _dataset_instances(_check_dataset(ds))


def dataset_from_instances(
    instances: Sequence[SOPInstance], solutions: Sequence[Solution]
) -> dict[str, np.ndarray]:
    """Dataset dict (the format above) from single open-path instances and their plans.

    Every instance must have the same N and K, start node 0 and ``end == -1``; a plan is
    start first, then visited nodes (``Solution.nodes`` may be padded with -1).
    """
    if len(instances) != len(solutions) or not instances:
        raise ValueError("need one solution per instance and at least one instance")
    insts = [inst.to_numpy() for inst in instances]
    k = insts[0].num_sets
    for i, inst in enumerate(insts):
        if int(inst.start) != 0 or int(inst.end) != -1:
            raise ValueError(f"instance {i}: the dataset format needs start 0 and an open path")
    teacher = np.stack([np.asarray(sol.padded(plan_length(k)).nodes) for sol in solutions])
    ds = {  # typed by the record table (dtypes and order)
        "coords": np.stack([inst.coords for inst in insts]),
        "cost": np.stack([inst.cost for inst in insts]),
        "set_id": np.stack([inst.set_id for inst in insts]),
        "set_reward": np.stack([inst.set_reward for inst in insts]),
        "budget": np.stack([inst.budget for inst in insts]),
        "teacher_nodes": teacher,
        "teacher_reward": np.asarray([sol.reward for sol in solutions]),
        "teacher_cost": np.asarray([sol.cost for sol in solutions]),
    }
    ds = make_records(ds, complete=False)
    _check_dataset(ds)
    return ds


def _instances(batch: Mapping[str, jax.Array]) -> SOPInstance:
    b = batch["set_id"].shape[0]
    return SOPInstance(
        cost=batch["cost"],
        set_id=batch["set_id"],
        set_reward=batch["set_reward"],
        start=jnp.zeros(b, jnp.int32),
        end=jnp.full(b, -1, jnp.int32),
        budget=batch["budget"],
        coords=batch["coords"],
    )


def dataset_info(ds: Mapping[str, Any]) -> dict[str, int]:
    """Sizes of a dataset: instances D, nodes N, sets K, step-level transitions."""
    data = _check_dataset(ds)
    d, n = data["set_id"].shape
    return {
        "instances": int(d),
        "num_nodes": int(n),
        "num_sets": int(data["set_reward"].shape[1]),
        "transitions": int(np.sum(data["teacher_nodes"] >= 0)),  # m nodes + END each
    }


def padded_batches(num_instances: int, batch_size: int) -> tuple[jax.Array, jax.Array]:
    """Minibatches covering every instance once: index [M, batch] int32 (the last batch
    padded with repeated instances) and weight [M, batch] float32 (0 on the padding)."""
    num_batches = math.ceil(num_instances / batch_size)
    slots = np.arange(num_batches * batch_size)
    index = jnp.asarray((slots % num_instances).reshape(num_batches, batch_size), jnp.int32)
    weight = jnp.asarray((slots < num_instances).reshape(num_batches, batch_size), jnp.float32)
    return index, weight


def _device_data(ds: Mapping[str, Any]) -> dict[str, jax.Array]:
    return place(_check_dataset(ds), None)
