"""Runs of the scale-out tests in a fresh process (device count and distributed setup are
fixed when JAX starts): ``python -m tests.scale_out_worker MODE OUT``.

Modes: ``devices`` (with 4 forced CPU devices: sharded training and rollouts against the
single-device run) and ``process I N PORT`` (one of N processes of a ``jax.distributed``
run with 2 CPU devices each, training on a mesh over all of them).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np


def labelled_data(n: int = 32, seed: int = 0):
    """A small teacher-labelled dataset (greedy-insertion plans: fast and deterministic)."""
    from bfsop_jax.sop.io import random_instance
    from bfsop_jax.sop.vns import solve_greedy
    from bfsop_jax.training import dataset_from_instances

    insts = [random_instance(seed + s, num_sets=5, viewpoints=3) for s in range(n)]
    return dataset_from_instances(insts, [solve_greedy(i) for i in insts])


def train_case(out: Path, replicas: int, mesh, epochs: int = 2):
    """The tiny model, ``replicas`` seeds, batch 16: final parameters as NumPy leaves."""
    import jax

    from bfsop_jax.model import ModelConfig
    from bfsop_jax.training import RunConfig, TrainConfig, train

    config = RunConfig(
        model=ModelConfig(d_model=32, n_layers=1, n_heads=2, d_ff=64),
        train=TrainConfig(epochs=epochs, batch_size=16, decay_every=1),
        preset="smoke",
    )
    result = train(config, labelled_data(), labelled_data(8, 100), out,
                   seeds=range(replicas), lrs=(3e-3,), progress=False, mesh=mesh)  # fmt: skip
    return [np.asarray(x) for x in jax.tree_util.tree_leaves(result.states.params)]


def max_diff(a, b) -> float:
    return max(float(np.max(np.abs(x - y))) for x, y in zip(a, b, strict=True))


def rollout_case(mesh, out: Path):
    """FBE on 4 smoke episodes (one chunk split over the devices): per-episode records."""
    from bfsop_jax.config import EVAL_SEED_START, get_preset
    from bfsop_jax.eval import navigation as nav

    houses = nav.HouseSet(get_preset("smoke"))
    episodes = nav.protocol_episodes(houses, range(EVAL_SEED_START, EVAL_SEED_START + 1),
                                     list(range(4)))  # fmt: skip
    result = nav.evaluate_navigation(
        ["fbe"], episodes, houses, out, batch=4, progress=False, mesh=mesh
    )
    keys = ("found", "path_length", "ppl", "switches")
    return [[e[k] for k in keys] for e in result["episodes"]]


def devices_mode(out: Path) -> dict:
    import jax

    from bfsop_jax.parallel import data_mesh

    assert len(jax.devices()) == 4, jax.devices()
    mesh = data_mesh()
    single = train_case(out / "one", 4, None)
    by_replica = train_case(out / "four", 4, mesh)  # 4 replicas: one per device
    by_batch = train_case(out / "batch", 2, mesh)  # 2 replicas: minibatches split in 4
    single2 = [x[:2] for x in single]  # replicas are independent: seeds 0 and 1 of the 4
    roll_one = rollout_case(None, out / "nav1")
    roll_four = rollout_case(mesh, out / "nav4")
    return {
        "replica_sharded_max_diff": max_diff(single, by_replica),
        "batch_sharded_max_diff": max_diff(single2, by_batch),
        "rollouts_equal": roll_one == roll_four,
        "episodes": len(roll_one),
    }


def process_mode(out: Path, index: int, count: int, port: int) -> dict:
    import os

    os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=2"
    from bfsop_jax import parallel

    assert parallel.initialize(f"localhost:{port}", count, index)
    import jax

    assert jax.process_count() == count and len(jax.local_devices()) == 2
    params = train_case(out / "run", 2 * count, parallel.data_mesh())
    if index == 0:  # one process alone reads a model (no collective restore)
        from bfsop_jax.policy import StrategicPolicy

        StrategicPolicy.load(out / "run" / "replicas" / "001")
        np.savez(out / "params.npz", *params)
    parallel.barrier("worker:done")
    jax.distributed.shutdown()
    return {"process": index, "devices": len(jax.devices())}


def main(argv: list[str]) -> None:
    mode, out = argv[0], Path(argv[1])
    if mode == "devices":
        info = devices_mode(out)
    elif mode == "process":
        info = process_mode(out, int(argv[2]), int(argv[3]), int(argv[4]))
    else:
        raise SystemExit(f"unknown mode {mode!r}")
    print("RESULT " + json.dumps(info), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
