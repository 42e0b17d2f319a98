"""Worker for tests/test_checkpoint_devices.py: save or load a model in a fresh process.

The device count is fixed when JAX starts, so each side of a save/load pair runs in its
own process (``XLA_FLAGS=--xla_force_host_platform_device_count=N``). Prints one line
``RESULT {json}`` with the plans of fixed instances.

Usage::

    python -m tests.checkpoint_worker save DIR    # write DIR/host (save_model) and
                                                  # DIR/devices (raw Orbax, device arrays)
    python -m tests.checkpoint_worker load DIR... # plan with each run's model
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import jax
import numpy as np
import orbax.checkpoint as ocp
from flax import nnx

from bfsop_jax.checkpoint import MODEL_DIR, save_model, write_config
from bfsop_jax.model import ModelConfig, StrategicTransformer
from bfsop_jax.policy import StrategicPolicy
from bfsop_jax.sop.io import random_instance
from bfsop_jax.training import RunConfig, TrainConfig

CONFIG = ModelConfig(d_model=32, n_layers=1, n_heads=2, d_ff=64)


def _plans(run_dir: str) -> list[list[int]]:
    policy = StrategicPolicy.load(run_dir)
    out = []
    for seed in range(3):
        inst = random_instance(seed, num_sets=6, viewpoints=3, masked_sets=seed % 3)
        out.append(np.asarray(policy.plan(inst).nodes).tolist())
    return out


def _params():
    model = StrategicTransformer(CONFIG, rngs=nnx.Rngs(0))
    kernel = model.decoder.project_glimpse.kernel  # zero at init: make the scores non-uniform
    kernel[...] = jax.random.normal(jax.random.key(1), kernel.shape) / np.sqrt(kernel.shape[0])
    return nnx.split(model, nnx.Param)[1]


def save(root: Path) -> dict:
    devices = jax.devices()
    # the last device (cpu:3 under a 4-device mesh), and replicated over a mesh of all
    last = jax.device_put(_params(), devices[-1])
    mesh = jax.sharding.Mesh(np.array(devices), ("d",))
    spread = jax.device_put(
        _params(), jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec())
    )
    config = {
        "run": RunConfig(model=CONFIG, train=TrainConfig(epochs=1)).to_dict(),
        "replicas": [{"seed": 0, "lr": 1e-3}],
        "dataset": {"num_nodes": 25, "num_sets": 9},
    }
    for name, params in (("host", last), ("devices", last), ("mesh", spread)):
        write_config(root / name, config)
        if name == "host":
            save_model(root / name, params)
        else:  # what older versions wrote: arrays with the devices they lived on
            with ocp.StandardCheckpointer() as ckptr:
                ckptr.save((root / name / MODEL_DIR).absolute(), params)
                ckptr.wait_until_finished()
    return {"devices": len(devices), "plans": _plans(str(root / "host"))}


def main() -> None:
    mode, *dirs = sys.argv[1:]
    if mode == "save":
        result = save(Path(dirs[0]))
    else:
        result = {"devices": len(jax.devices()), "plans": {d: _plans(d) for d in dirs}}
    print("RESULT " + json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
