"""Scale-out: training and rollouts sharded over forced CPU devices, two processes joined by
``jax.distributed``, and the mesh helpers. The multi-device runs happen in fresh processes
(``tests/scale_out_worker.py``): the device count is fixed when JAX starts."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bfsop_jax import parallel

REPO = Path(__file__).resolve().parents[1]
# Sharded programs are the same computation partitioned differently, so floating-point
# sums may be reordered: parameters after 4 Adam steps (lr 3e-3) agree to these bounds.
REPLICA_SHARDED_ATOL = 1e-4  # whole replicas per device: only fusion/vectorisation differ
BATCH_SHARDED_ATOL = 1e-3  # minibatch split: gradients summed across devices


def _worker(args: list[str], env_extra: dict[str, str], timeout: float):
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env.update(env_extra)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.Popen(
        [sys.executable, "-m", "tests.scale_out_worker", *args], cwd=REPO, env=env,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip


def _result(proc, timeout: float) -> dict:
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"worker timed out:\n{err[-3000:]}")
    assert proc.returncode == 0, err[-3000:]
    line = [x for x in out.splitlines() if x.startswith("RESULT ")][-1]
    return json.loads(line[len("RESULT ") :])


@pytest.mark.slow
def test_four_devices_match_one_device(tmp_path):
    """Training with the replicas or the minibatches split over 4 CPU devices, and a batch
    of episodes split over them, against the same runs on one device."""
    proc = _worker(["devices", str(tmp_path)],
                   {"XLA_FLAGS": "--xla_force_host_platform_device_count=4"}, 600)  # fmt: skip
    info = _result(proc, 600)
    assert info["replica_sharded_max_diff"] <= REPLICA_SHARDED_ATOL
    assert info["batch_sharded_max_diff"] <= BATCH_SHARDED_ATOL
    assert info["rollouts_equal"] and info["episodes"] == 4


@pytest.mark.slow
def test_two_processes_train_as_one_program(tmp_path):
    """Two local processes (2 CPU devices each) join through jax.distributed and train 4
    replicas on a mesh over all 4 devices; the result matches a one-device run here."""
    from tests.scale_out_worker import max_diff, train_case

    with socket.socket() as s:
        s.bind(("localhost", 0))
        port = s.getsockname()[1]
    procs = [_worker(["process", str(tmp_path), str(i), "2", str(port)], {}, 300)
             for i in range(2)]  # fmt: skip
    infos = [_result(p, 300) for p in procs]
    assert [i["devices"] for i in infos] == [4, 4]
    got = np.load(tmp_path / "params.npz")
    shared = [got[f"arr_{i}"] for i in range(len(got.files))]
    reference = train_case(tmp_path / "reference", 4, None)
    assert max_diff(reference, shared) <= REPLICA_SHARDED_ATOL
    # the run directory was written once, by process 0, and loads as a policy per replica
    from bfsop_jax.policy import StrategicPolicy

    assert (tmp_path / "run" / "model").is_dir()
    for i in range(4):
        StrategicPolicy.load(tmp_path / "run" / "replicas" / f"{i:03d}")


def test_mesh_helpers_and_errors(monkeypatch):
    mesh = parallel.data_mesh()
    assert parallel.mesh_size(mesh) == len(parallel.jax.devices())
    tree = {"a": np.arange(6.0).reshape(3, 2), "b": np.int32(4)}
    placed = parallel.place(tree, mesh, leading=False)
    np.testing.assert_array_equal(parallel.to_host(placed)["a"], tree["a"])
    if parallel.mesh_size(mesh) > 1:
        with pytest.raises(ValueError, match="does not split"):
            parallel.place({"a": np.zeros(3)}, mesh)
    # no coordinator: a single-host run, nothing happens
    monkeypatch.delenv(parallel.ENV_COORDINATOR, raising=False)
    assert parallel.initialize() is False
    monkeypatch.setenv(parallel.ENV_COORDINATOR, "localhost:1234")
    monkeypatch.delenv(parallel.ENV_NUM_PROCESSES, raising=False)
    with pytest.raises(ValueError, match=parallel.ENV_NUM_PROCESSES):
        parallel.initialize()
    monkeypatch.setenv(parallel.ENV_NUM_PROCESSES, "2")
    monkeypatch.setenv(parallel.ENV_PROCESS_ID, "two")
    with pytest.raises(ValueError, match="must be integers"):
        parallel.initialize()
    monkeypatch.setenv(parallel.ENV_PROCESS_ID, "5")
    with pytest.raises(ValueError, match="outside"):
        parallel.initialize()
