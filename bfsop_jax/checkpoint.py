"""Orbax checkpoints of a training run, in one small module.

Layout of a run directory::

    run_dir/
      config.json            model + training config, preset, dataset info, seeds, lrs
      checkpoints/<epoch>/   one per completed epoch (the last few kept):
        state/               TrainState of every replica (params, Adam moments, step, lr)
        meta/                JSON: epoch, per-replica losses, best replica so far
      model/                 parameters of the chosen replica (what the policy loads)

Saves are synchronous: a save that returns is on disk, and Orbax writes each checkpoint to
a temporary directory that is renamed only when complete, so an interruption never leaves
a half-written checkpoint that :meth:`CheckpointStore.latest_epoch` would report.
Any failure to read a checkpoint (missing files, truncated or garbled data, a tree that
does not match the model) becomes a ``ValueError`` naming the path.

Checkpoints load on any device set: a restore never goes back to the devices a checkpoint
was written from (a model trained on a GPU, or under a forced multi-device CPU mesh, loads
on one CPU and the other way round). Every array is restored where its target says: the
target's own sharding for concrete arrays, the current default device for abstract ones
(``jax.ShapeDtypeStruct`` without a sharding, e.g. from ``nnx.eval_shape``). Models are
written as host (NumPy) arrays, so ``model/`` records no device at all.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp

from bfsop_jax import files
from bfsop_jax.parallel import barrier, is_primary

__all__ = [
    "CheckpointStore",
    "CONFIG_FILE",
    "MODEL_DIR",
    "CHECKPOINT_DIR",
    "differing",
    "export_policy",
    "load_model",
    "local_target",
    "read_config",
    "save_model",
    "write_config",
]

CONFIG_FILE = "config.json"
MODEL_DIR = "model"
CHECKPOINT_DIR = "checkpoints"


class CheckpointStore:
    """Epoch checkpoints under ``run_dir/checkpoints`` (Orbax ``CheckpointManager``)."""

    def __init__(
        self, run_dir: str | os.PathLike, max_to_keep: int = 3, read_only: bool = False
    ) -> None:
        """``read_only``: open an existing directory to restore (ValueError if missing)."""
        self.directory = Path(run_dir).absolute() / CHECKPOINT_DIR
        if read_only and not self.directory.is_dir():
            raise ValueError(f"no checkpoints in {Path(run_dir)} (missing {CHECKPOINT_DIR}/)")
        # a reader opens the manager without creating anything (Orbax's read_only mode
        # only logs warnings about its options)
        options = ocp.CheckpointManagerOptions(
            max_to_keep=max_to_keep, create=not read_only, enable_async_checkpointing=False
        )
        self._manager = ocp.CheckpointManager(
            self.directory, options=options, item_names=("state", "meta")
        )

    def latest_epoch(self) -> int | None:
        """Last completed epoch on disk (None when there is none)."""
        return self._manager.latest_step()

    def epochs(self) -> list[int]:
        return sorted(self._manager.all_steps())

    def save(self, epoch: int, state: Any, meta: dict[str, Any]) -> None:
        """Write the checkpoint of ``epoch`` (no-op if it exists); returns once on disk."""
        if epoch in self._manager.all_steps():
            return
        self._manager.save(
            epoch,
            args=ocp.args.Composite(
                state=ocp.args.StandardSave(state), meta=ocp.args.JsonSave(meta)
            ),
            force=True,
        )
        self._manager.wait_until_finished()

    def restore(self, target: Any, epoch: int | None = None) -> tuple[Any, dict[str, Any]]:
        """Read ``(state, meta)`` of ``epoch`` (default: the latest).

        ``target``: a pytree of arrays or ``jax.ShapeDtypeStruct`` with the saved structure
        (e.g. ``jax.eval_shape`` of the initial state).
        """
        if epoch is None:
            epoch = self.latest_epoch()
            if epoch is None:
                raise ValueError(f"no checkpoint in {self.directory}")
        path = self.directory / str(epoch)
        try:
            out = self._manager.restore(
                epoch,
                args=ocp.args.Composite(
                    state=ocp.args.StandardRestore(local_target(target)),
                    meta=ocp.args.JsonRestore(),
                ),
            )
        except Exception as err:  # Orbax / TensorStore raise many types for bad data
            raise ValueError(f"cannot read checkpoint {path}: {_short(err)}") from None
        return out.state, dict(out.meta)

    def close(self) -> None:
        self._manager.close()

    def __enter__(self) -> CheckpointStore:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _short(err: BaseException, limit: int = 400) -> str:
    text = f"{type(err).__name__}: {err}"
    return text if len(text) <= limit else text[:limit] + " ..."


def _default_device() -> jax.Device:
    device = getattr(jax.config, "jax_default_device", None)
    if isinstance(device, jax.Device):
        return device
    if isinstance(device, str):  # a platform name
        return jax.local_devices(backend=device)[0]
    return jax.local_devices()[0]


def local_target(target: Any) -> Any:
    """A restore target that places every array on this process's devices.

    Concrete ``jax.Array`` leaves keep their own sharding (e.g. training replicas placed
    on a mesh); abstract leaves without a sharding go to the default device; NumPy
    leaves stay host arrays. Without this, Orbax restores an abstract leaf onto the
    devices recorded in the checkpoint, which fails on another machine ("topology
    mismatch").
    """
    here = jax.sharding.SingleDeviceSharding(_default_device())

    def leaf(x: Any) -> Any:
        if isinstance(x, jax.Array):
            return jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=x.sharding)
        if isinstance(x, jax.ShapeDtypeStruct) and x.sharding is None:
            return jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=here)
        return x

    return jax.tree_util.tree_map(leaf, target)


def _host_arrays(tree: Any) -> Any:
    """Fully addressable arrays as NumPy (a checkpoint that records no device); arrays
    spread over several hosts stay as they are (Orbax writes them collectively)."""

    def leaf(x: Any) -> Any:
        if isinstance(x, jax.Array) and x.is_fully_addressable:
            return np.asarray(jax.device_get(x))
        return x

    return jax.tree_util.tree_map(leaf, tree)


def save_model(run_dir: str | os.PathLike, params: Any) -> Path:
    """Write the chosen parameters to ``run_dir/model`` (replacing an older copy).

    Arrays are written from the host (NumPy), so the model loads on any device set. In a
    multi-host run every process calls it (Orbax saves collectively); process 0 swaps
    the directories.
    """
    path = Path(run_dir).absolute() / MODEL_DIR
    tmp = path.with_name(MODEL_DIR + ".tmp")
    if is_primary():
        shutil.rmtree(tmp, ignore_errors=True)
    barrier(f"save_model:clean:{path}")
    with ocp.StandardCheckpointer() as ckptr:
        ckptr.save(tmp, _host_arrays(params))
        ckptr.wait_until_finished()
    if is_primary():
        # swap in the complete copy: a reader sees the old model or the new one, never half
        old = path.with_name(MODEL_DIR + ".old")
        shutil.rmtree(old, ignore_errors=True)
        if path.exists():
            path.rename(old)
        tmp.rename(path)
        shutil.rmtree(old, ignore_errors=True)
    barrier(f"save_model:done:{path}")
    return path


def load_model(run_dir: str | os.PathLike, target: Any) -> Any:
    """Read ``run_dir/model`` into the structure of ``target`` (ValueError if unreadable).

    Arrays land where :func:`local_target` puts them (the default device for abstract
    leaves), whatever devices the model was saved from.
    """
    path = Path(run_dir).absolute() / MODEL_DIR
    if not path.is_dir():
        raise ValueError(f"no saved model in {Path(run_dir)} (missing {MODEL_DIR}/)")
    try:
        with ocp.StandardCheckpointer(multiprocessing_options=_this_process_only()) as ckptr:
            return ckptr.restore(path, local_target(target))
    except Exception as err:
        raise ValueError(f"cannot read model checkpoint {path}: {_short(err)}") from None


def _this_process_only() -> ocp.options.MultiprocessingOptions:
    """Reading a model is local: in a multi-host run one process may load a policy alone
    (Orbax would otherwise wait for the others at its barriers)."""
    if jax.process_count() == 1:
        return ocp.options.MultiprocessingOptions()
    me = jax.process_index()
    return ocp.options.MultiprocessingOptions(primary_host=me, active_processes={me})


def write_config(run_dir: str | os.PathLike, config: dict[str, Any]) -> None:
    """Write ``config.json`` atomically (temporary file, then rename); in a multi-host run
    only process 0 writes."""
    if not is_primary():
        return
    files.write_json(Path(run_dir) / CONFIG_FILE, config)


def read_config(run_dir: str | os.PathLike) -> dict[str, Any]:
    """Read ``config.json`` of a run directory (ValueError if missing or not JSON)."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ValueError(f"run directory {run_dir} does not exist")
    path = run_dir / CONFIG_FILE
    if not path.is_file():
        raise ValueError(f"{run_dir} is not a run directory (missing {CONFIG_FILE})")
    try:
        config = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ValueError(f"corrupt {path}: {err}") from None
    if not isinstance(config, dict):
        raise ValueError(f"corrupt {path}: expected a JSON object")
    return config


def differing(checks: dict[str, tuple[Any, Any]]) -> list[str]:
    """The names of ``checks`` (name -> (recorded, wanted)) whose two values differ once
    both are written as JSON would store them (tuples as lists, and so on): what a kept
    run directory was made with against what this call would make it with."""
    as_json = lambda x: json.loads(json.dumps(x))
    return [name for name, (kept, wanted) in checks.items() if as_json(kept) != as_json(wanted)]


def export_policy(run_dir: str | os.PathLike, dest: str | os.PathLike) -> Path:
    """Copy what the policy needs (``config.json`` and ``model/``) into ``dest``.

    ``dest`` is replaced. Used to ship a trained model, e.g. into
    ``bfsop_jax/assets/policy_demo``.
    """
    run_dir, dest = Path(run_dir), Path(dest)
    read_config(run_dir)
    if not (run_dir / MODEL_DIR).is_dir():
        raise ValueError(f"no saved model in {run_dir} (missing {MODEL_DIR}/); train it first")
    tmp = dest.with_name(dest.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    shutil.copy2(run_dir / CONFIG_FILE, tmp / CONFIG_FILE)
    shutil.copytree(run_dir / MODEL_DIR, tmp / MODEL_DIR)
    shutil.rmtree(dest, ignore_errors=True)
    tmp.rename(dest)
    return dest
