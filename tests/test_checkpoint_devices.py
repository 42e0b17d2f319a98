"""Models load on any device set: saved under a forced 4-device CPU mesh, loaded in a
1-device process, and the other way round, with the same plans. Each side runs in a
fresh process (``tests/checkpoint_worker.py``): the device count is fixed when JAX starts.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _run(args: list[str], devices: int, extra_env: dict | None = None) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    if devices > 1:
        env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}"
    env.update(extra_env or {})
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.run(
        [sys.executable, "-m", "tests.checkpoint_worker", *args], cwd=REPO, env=env,
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    line = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")][-1]
    return json.loads(line[len("RESULT ") :])


@pytest.mark.slow
def test_models_saved_on_four_devices_load_on_one_and_back(tmp_path):
    four, one = tmp_path / "four", tmp_path / "one"
    saved = _run(["save", str(four)], devices=4)
    assert saved["devices"] == 4
    runs = [str(four / name) for name in ("host", "devices", "mesh")]
    loaded = _run(["load", *runs], devices=1)
    assert loaded["devices"] == 1
    for run in runs:  # save_model's host arrays, and device arrays of cpu:3 / of the mesh
        assert loaded["plans"][run] == saved["plans"], run
    # the reverse: saved in a 1-device process, loaded where 4 devices exist
    saved_one = _run(["save", str(one)], devices=1)
    assert saved_one["plans"] == saved["plans"]
    runs = [str(one / name) for name in ("host", "devices")]
    back = _run(["load", *runs], devices=4)
    assert back["devices"] == 4
    for run in runs:
        assert back["plans"][run] == saved["plans"], run


@pytest.mark.parametrize("name", ["demo", "paper"])
def test_shipped_models_record_no_device(name):
    """The shipped models are host arrays: nothing in them names the devices they were
    saved from (Orbax writes a ``_sharding`` file for device arrays)."""
    model = REPO / "bfsop_jax" / "assets" / f"policy_{name}" / "model"
    assert model.is_dir()
    assert not (model / "_sharding").exists()
    metadata = json.loads((model / "_METADATA").read_text())["tree_metadata"]
    assert {v["value_metadata"]["value_type"] for v in metadata.values()} == {"np.ndarray"}
