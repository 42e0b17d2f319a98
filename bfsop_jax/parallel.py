"""Scale-out helpers: a one-axis device mesh, placing pytrees on it, and bringing them back.

Every batched program of the project (training replicas, vmapped episodes) has one leading
axis that is embarrassingly parallel. A :class:`jax.sharding.Mesh` with one axis named
``"data"`` (:data:`DATA_AXIS`) over the devices spreads that axis; the programs themselves
are unchanged (GSPMD partitions them from the placement of their inputs).

The same code runs on one device, on several local devices, and on several hosts joined by
:func:`initialize` (``jax.distributed``): arrays are built with
``jax.make_array_from_callback`` from data that every process holds in full, and
:func:`to_host` gathers results from every process. See ``docs/scale-out.md``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

__all__ = [
    "DATA_AXIS",
    "ENV_COORDINATOR",
    "ENV_NUM_PROCESSES",
    "ENV_PROCESS_ID",
    "barrier",
    "is_primary",
    "data_mesh",
    "first_devices_mesh",
    "initialize",
    "mesh_size",
    "place",
    "replicated",
    "sharded",
    "to_host",
]

DATA_AXIS = "data"

ENV_COORDINATOR = "BFSOP_COORDINATOR"  # host:port of process 0
ENV_NUM_PROCESSES = "BFSOP_NUM_PROCESSES"
ENV_PROCESS_ID = "BFSOP_PROCESS_ID"


def is_primary() -> bool:
    """True in process 0 (the one that writes shared files in a multi-host run)."""
    return jax.process_index() == 0


def barrier(name: str) -> None:
    """Wait until every process reaches this point (a no-op with one process)."""
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices(name)


def data_mesh(devices: Sequence[jax.Device] | None = None) -> Mesh:
    """A one-axis mesh (axis ``"data"``) over ``devices`` (default: every global device)."""
    devices = list(jax.devices() if devices is None else devices)
    if not devices:
        raise ValueError("data_mesh needs at least one device")
    return Mesh(np.asarray(devices, dtype=object), (DATA_AXIS,))


def first_devices_mesh(count: int | None, local: bool = False) -> Mesh | None:
    """A mesh over the first ``count`` devices (all by default; ``local``: this process's
    only), or None when that is one device (the single-device path); ValueError naming
    ``--devices`` when ``count`` is out of range."""
    available = jax.local_devices() if local else jax.devices()
    n = len(available) if count is None else count
    if not 1 <= n <= len(available):
        raise ValueError(f"--devices must be in [1, {len(available)}], got {count}")
    return data_mesh(available[:n]) if n > 1 else None


def mesh_size(mesh: Mesh) -> int:
    """Devices along the mesh's ``data`` axis."""
    if DATA_AXIS not in mesh.axis_names:
        raise ValueError(f"the mesh needs an axis named {DATA_AXIS!r}, has {mesh.axis_names}")
    return int(mesh.shape[DATA_AXIS])


def sharded(mesh: Mesh) -> NamedSharding:
    """Leading axis split over ``data``, the rest replicated."""
    return NamedSharding(mesh, PartitionSpec(DATA_AXIS))


def replicated(mesh: Mesh) -> NamedSharding:
    """A full copy on every device of the mesh."""
    return NamedSharding(mesh, PartitionSpec())


def _put(x: Any, sharding: NamedSharding) -> jax.Array:
    if isinstance(x, jax.Array) and jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
        impl = jax.random.key_impl(x)
        return jax.random.wrap_key_data(_put(jax.random.key_data(x), sharding), impl=impl)
    host = np.asarray(x)
    return jax.make_array_from_callback(host.shape, sharding, lambda index: host[index])


def place(tree: Any, mesh: Mesh | None, leading: bool = True) -> Any:
    """Every leaf of ``tree`` as a global array on ``mesh``.

    ``leading``: split the leading axis over ``data`` (it must divide by the mesh size);
    otherwise replicate. Every process must pass the same full values. ``mesh=None``
    places on the default device (the single-device path).
    """
    if mesh is None:
        return jax.device_put(tree, jax.local_devices()[0])
    n = mesh_size(mesh)
    if leading:
        for leaf in jax.tree_util.tree_leaves(tree):
            if np.ndim(leaf) == 0 or np.shape(leaf)[0] % n:
                raise ValueError(
                    f"a leading axis of {np.shape(leaf)[:1]} does not split over {n} devices"
                )
    sharding = sharded(mesh) if leading else replicated(mesh)
    return jax.tree_util.tree_map(lambda x: _put(x, sharding), tree)


def to_host(tree: Any) -> Any:
    """NumPy copies of every leaf, gathered from every process when there are several."""

    def one(x):
        if not isinstance(x, jax.Array):
            return np.asarray(x)
        if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
            return jax.random.key_data(x)  # pragma: no cover - not used on the hot path
        if x.is_fully_addressable:
            return np.asarray(x)
        from jax.experimental import multihost_utils

        return np.asarray(multihost_utils.process_allgather(x, tiled=True))

    return jax.tree_util.tree_map(one, tree)


def initialize(
    coordinator: str | None = None,
    num_processes: int | None = None,
    process_id: int | None = None,
) -> bool:
    """Join a multi-host run through ``jax.distributed.initialize``.

    Arguments default to the environment variables ``BFSOP_COORDINATOR`` (``host:port`` of
    process 0), ``BFSOP_NUM_PROCESSES`` and ``BFSOP_PROCESS_ID``. Returns False (and does
    nothing) when neither arguments nor variables name a coordinator: a single-host run.
    Call it before anything else touches JAX.
    """
    coordinator = coordinator or os.environ.get(ENV_COORDINATOR)
    if not coordinator:
        return False
    try:
        if num_processes is None:
            num_processes = int(os.environ[ENV_NUM_PROCESSES])
        if process_id is None:
            process_id = int(os.environ[ENV_PROCESS_ID])
    except KeyError as err:
        raise ValueError(
            f"a multi-host run needs {err.args[0]} as well as {ENV_COORDINATOR}"
        ) from None
    except ValueError:
        raise ValueError(f"{ENV_NUM_PROCESSES} and {ENV_PROCESS_ID} must be integers") from None
    if not 0 <= process_id < num_processes:
        raise ValueError(f"process id {process_id} outside [0, {num_processes})")
    jax.distributed.initialize(
        coordinator_address=coordinator, num_processes=num_processes, process_id=process_id
    )
    return True
