"""Datasets: atomic, resumable shards and teacher-labelled virtual tasks."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bfsop_jax.data import DataConfig, ShardStore, generate_dataset
from bfsop_jax.sop.types import SOPInstance, evaluate, validate


def _arrays(n, seed=0):
    rng = np.random.default_rng(seed)
    return {"x": rng.normal(size=(n, 3)).astype(np.float32), "y": np.arange(n)}


def test_shards_roundtrip_resume_and_config_guard(tmp_path):
    store = ShardStore(tmp_path / "ds", {"a": 1})
    store.write(0, _arrays(4))
    store.write(2, _arrays(3, 1))
    assert store.complete_shards() == [0, 2]
    again = ShardStore(tmp_path / "ds", {"a": 1})  # reopened: shards are remembered
    data = again.load()
    assert data["x"].shape == (7, 3) and list(data["y"]) == [0, 1, 2, 3, 0, 1, 2]
    with pytest.raises(ValueError, match="another configuration"):
        ShardStore(tmp_path / "ds", {"a": 2})
    with pytest.raises(ValueError, match="disagree"):
        store.write(3, {"x": np.zeros(2), "y": np.zeros(3)})


def test_half_written_or_unlisted_shards_are_not_complete(tmp_path):
    store = ShardStore(tmp_path / "ds", {})
    store.write(0, _arrays(4))
    # A file that was never recorded in meta.json (a run killed before the metadata
    # update) and a truncated recorded shard both count as missing.
    store.shard_path(1).write_bytes(store.shard_path(0).read_bytes())
    data = store.shard_path(0).read_bytes()
    store.shard_path(0).write_bytes(data[: len(data) // 2])
    assert store.complete_shards() == []
    assert not list(store.root.glob("*.tmp"))
    (store.root / "meta.json").write_text("{broken")
    with pytest.raises(ValueError, match="corrupt dataset metadata"):
        ShardStore(tmp_path / "ds", {})


def test_data_config_rejects_evaluation_seeds():
    with pytest.raises(ValueError, match="evaluation seeds"):
        DataConfig(seed_start=999_999, houses=5)


def test_generated_virtual_tasks_are_valid_and_labelled(tmp_path):
    cfg = DataConfig(
        preset="smoke", houses=1, houses_per_shard=1, tasks_per_house=4, vns_iters=50,
        vns_no_improve=25,
    )  # fmt: skip
    store = generate_dataset(tmp_path / "ds", cfg, progress=False)
    data = store.load()
    meta = json.loads((tmp_path / "ds" / "meta.json").read_text())
    assert meta["config"]["preset"] == "smoke" and meta["shards"]["0"]["rows"] == len(
        data["budget"]
    )
    assert len(data["budget"]) >= 1
    for i in range(len(data["budget"])):
        inst = SOPInstance.create(
            data["cost"][i], data["set_id"][i], data["set_reward"][i], 0, -1,
            data["budget"][i], data["coords"][i],
        )  # fmt: skip
        validate(inst)
        reward, cost, feasible = evaluate(inst, [n for n in data["teacher_nodes"][i] if n >= 0])
        assert feasible
        assert reward == pytest.approx(float(data["teacher_reward"][i]), abs=1e-4)
        assert cost == pytest.approx(float(data["teacher_cost"][i]), rel=1e-4, abs=1e-3)
        assert data["teacher_nodes"][i][0] == 0
    # A second call reuses the finished shards instead of recomputing them.
    mtime = store.shard_path(0).stat().st_mtime_ns
    generate_dataset(tmp_path / "ds", cfg, progress=False)
    assert store.shard_path(0).stat().st_mtime_ns == mtime
