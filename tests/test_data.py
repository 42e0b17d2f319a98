"""Datasets: atomic, resumable shards and teacher-labelled virtual tasks."""

from __future__ import annotations

import dataclasses
import json
import re
import zipfile

import numpy as np
import pytest

from bfsop_jax.data import DataConfig, ShardStore, generate_dataset, merge_datasets
from bfsop_jax.data.schema import (
    DATASET_KEYS,
    RECORD_FIELDS,
    check_records,
    field_shape,
    make_records,
)
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


def test_record_schema_types_and_checks():
    d, n, k = 3, 5, 2
    arrays = {f.name: np.zeros(field_shape(f, d, n, k), np.float64) for f in RECORD_FIELDS}
    rec = make_records(arrays)
    assert list(rec) == [f.name for f in RECORD_FIELDS]
    assert all(rec[f.name].dtype == f.dtype for f in RECORD_FIELDS)
    assert set(check_records(rec)) == set(DATASET_KEYS)
    with pytest.raises(ValueError, match="house_seed"):
        make_records({k: v for k, v in arrays.items() if k != "house_seed"})
    assert "house_seed" not in make_records(
        {k: v for k, v in arrays.items() if k != "house_seed"}, complete=False
    )
    with pytest.raises(ValueError, match=r"teacher_cost must have shape \(3,\)"):
        check_records({**rec, "teacher_cost": np.zeros(4)})
    with pytest.raises(ValueError, match="lacks the arrays"):
        check_records({k: v for k, v in rec.items() if k != "budget"})


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
    d, n, k = len(data["budget"]), data["set_id"].shape[1], data["set_reward"].shape[1]
    for field in RECORD_FIELDS:  # every record field, typed and shaped by the table
        assert data[field.name].dtype == field.dtype
        assert data[field.name].shape == field_shape(field, d, n, k)
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


def test_dataset_grows_to_more_houses_keeping_its_full_shards(tmp_path):
    """--houses raised on an existing dataset: full shards are kept, a partial last one
    is made again, and the result equals a dataset generated at the larger size."""
    cfg = DataConfig(
        preset="smoke", houses=3, houses_per_shard=2, tasks_per_house=2, vns_iters=20,
        vns_no_improve=10, on_trajectory=False,
    )  # fmt: skip
    store = generate_dataset(tmp_path / "ds", cfg, progress=False)
    assert store.meta["shards"]["1"]["house_seeds"] == [2, 2]
    mtime = store.shard_path(0).stat().st_mtime_ns
    bigger = dataclasses.replace(cfg, houses=4)
    grown = generate_dataset(tmp_path / "ds", bigger, progress=False)
    assert grown.config["houses"] == 4 and grown.complete_shards() == [0, 1]
    assert grown.meta["shards"]["1"]["house_seeds"] == [2, 3]
    assert grown.shard_path(0).stat().st_mtime_ns == mtime
    fresh = generate_dataset(tmp_path / "fresh", bigger, progress=False).load()
    got = grown.load()
    for k in fresh:
        assert np.array_equal(got[k], fresh[k]), k
    # fewer houses, or any other change, is still another configuration
    with pytest.raises(ValueError, match="another configuration"):
        generate_dataset(tmp_path / "ds", cfg, progress=False)
    with pytest.raises(ValueError, match="another configuration"):
        generate_dataset(tmp_path / "ds", dataclasses.replace(bigger, houses=6, vns_iters=30))


# -- generation over several machines: --shard I/N and merge_datasets ------------------------
def _rezip(path, date_time=(1980, 1, 1, 0, 0, 0)):
    """The same archive members with other zip timestamps (a shard made at another time)."""
    with zipfile.ZipFile(path) as z:
        members = [(n, z.read(n)) for n in z.namelist()]
    with zipfile.ZipFile(path, "w") as z:
        for name, data in members:
            z.writestr(zipfile.ZipInfo(name, date_time), data)


def test_shard_parts_from_two_machines_merge_into_the_whole_dataset(tmp_path, capsys):
    """Shards 0/2 and 1/2 generated apart (through the distill CLI) and merged equal one
    run of the whole configuration, array for array."""
    from experiments import distill

    a, b, c, d = (str(tmp_path / x) for x in "abcd")
    common = ["--preset", "smoke", "--tasks", "4", "--no-progress"]
    distill.main(common + ["--stage", "data", "--shard", "0/2", "--data-dir", a])
    # the train stage of one part generates that part, then stops: the rest is missing
    with pytest.raises(ValueError, match=r"lacks shards 0 of 2.*--shard 0/2.*--merge-data"):
        distill.main(common + ["--stage", "train", "--shard", "1/2", "--data-dir", b])
    assert ShardStore.open(a).complete_shards() == [0]
    assert ShardStore.open(b).complete_shards() == [1]
    distill.main(common + ["--merge-data", f"{a},{b}", "--data-dir", c])  # stops after it
    assert "2/2 shards" in capsys.readouterr().out
    cfg = distill._data_config(distill._parse(common), distill.PRESETS["smoke"])
    whole = generate_dataset(d, cfg, progress=False).load()
    merged = ShardStore(c, dataclasses.asdict(cfg))
    assert merged.complete_shards() == [0, 1]
    got = merged.load()
    assert sorted(got) == sorted(whole)
    for k in whole:
        assert got[k].dtype == whole[k].dtype and np.array_equal(got[k], whole[k]), k
    # merging into one of the sources works too, and a rerun copies nothing
    merge_datasets(a, [a, b])
    assert ShardStore.open(a).complete_shards() == [0, 1]
    mtime = merged.shard_path(0).stat().st_mtime_ns
    merge_datasets(c, [a, b, c])
    assert merged.shard_path(0).stat().st_mtime_ns == mtime


def test_merge_errors_and_interrupted_merge(tmp_path):
    a, b = ShardStore(tmp_path / "a", {"k": 1}), ShardStore(tmp_path / "b", {"k": 1})
    a.write(0, _arrays(4))
    a.write(1, _arrays(2, 1))
    b.write(1, _arrays(2, 1))
    _rezip(b.shard_path(1))  # same data, other zip timestamps: not a conflict
    b.write(2, _arrays(3, 2))
    c = merge_datasets(tmp_path / "c", [tmp_path / "a", tmp_path / "b"])
    assert c.complete_shards() == [0, 1, 2] and len(c.load()["y"]) == 9
    assert not list(c.root.glob("*.tmp"))
    # killed after a copy, before meta.json listed it: the rerun copies that shard again
    meta = json.loads((c.root / "meta.json").read_text())
    del meta["shards"]["2"]
    (c.root / "meta.json").write_text(json.dumps(meta))
    c.shard_path(2).write_bytes(b"partial")
    c = merge_datasets(c.root, [a.root, b.root])
    assert c.complete_shards() == [0, 1, 2]
    assert np.array_equal(c.load([2])["x"], _arrays(3, 2)["x"])

    other = ShardStore(tmp_path / "other", {"k": 2})
    other.write(5, _arrays(1))
    with pytest.raises(ValueError, match=re.escape(f"{other.root} was made with another")):
        merge_datasets(tmp_path / "new", [a.root, other.root])
    with pytest.raises(ValueError, match=re.escape(f"{c.root} was made with another")):
        merge_datasets(c.root, [other.root])  # an existing destination must agree too
    with pytest.raises(ValueError, match="requested configuration"):
        merge_datasets(tmp_path / "new", [a.root], config={"k": 3})
    assert not (tmp_path / "new").exists()  # nothing is created on a refused merge
    bad = ShardStore(tmp_path / "bad", {"k": 1})
    bad.write(1, _arrays(2, 7))  # shard 1 with other data than a's
    with pytest.raises(ValueError, match="shard 1 differs"):
        merge_datasets(tmp_path / "new", [a.root, bad.root])
    with pytest.raises(ValueError, match="not a dataset directory"):
        merge_datasets(tmp_path / "new", [tmp_path / "missing"])


def test_shards_labelled_with_another_prior_or_teacher_are_not_mixed(tmp_path):
    """Shards record the co-occurrence prior and the teacher that labelled them: a dataset
    is not grown, resumed or merged across either (shards recorded before are taken)."""
    from bfsop_jax.data.generate import _refuse_other_labels

    mine = {"prior": "p1", "vns_config": {"iters": 5}}
    a, b = ShardStore(tmp_path / "a", {"k": 1}), ShardStore(tmp_path / "b", {"k": 1})
    a.write(0, _arrays(4), mine)
    a.write(1, _arrays(2, 1))  # written before labels were recorded
    _refuse_other_labels(a, mine)
    for other, what in (({"prior": "p2"}, "co-occurrence prior"),
                        ({"vns_config": {"iters": 6}}, "VNS teacher configuration")):  # fmt: skip
        with pytest.raises(ValueError, match=f"shard 0 was labelled with another {what}"):
            _refuse_other_labels(a, {**mine, **other})
    b.write(2, _arrays(3, 2), {**mine, "prior": "p2"})
    with pytest.raises(ValueError, match="labelled with another co-occurrence prior"):
        merge_datasets(tmp_path / "c", [a.root, b.root])
    assert not (tmp_path / "c").exists()


@pytest.mark.parametrize("value", ["3/2", "a/b", "0/0", "-1/2", "1", "0/2/3", ""])
def test_distill_shard_flag_rejects_bad_values(value):
    from experiments import distill

    with pytest.raises(ValueError, match="--shard"):
        distill._parse([f"--shard={value}"])


def test_distill_shard_and_merge_flags_parse(capsys):
    from experiments import distill

    args = distill._parse(["--shard", "1/3"])
    assert args.shard == (1, 3) and args.stage == "all"
    args = distill._parse(["--merge-data", "x, y,"])
    assert args.merge_data == ["x", "y"] and args.stage == "data"
    with pytest.raises(ValueError, match="--merge-data and --shard"):
        distill._parse(["--merge-data", "x", "--shard", "0/2"])
    with pytest.raises(ValueError, match="--stage eval"):
        distill._parse(["--shard", "0/2", "--stage", "eval"])
    with pytest.raises(SystemExit):  # argparse takes "-1/2" for an option: its own error
        distill._parse(["--shard", "-1/2"])
    assert "argument --shard" in capsys.readouterr().err


def test_a_student_that_plans_nothing_is_a_clear_error(monkeypatch):
    """DAgger: when the student planned no tour there is nothing for the teacher to label."""
    import jax.numpy as jnp

    from bfsop_jax.config import get_preset
    from bfsop_jax.data import generate

    none = lambda keys, *a: (None, np.zeros((keys.shape[0], 3), bool))
    monkeypatch.setattr(generate, "_student_jit", none)
    cfg = DataConfig(preset="smoke", houses=1, tasks_per_house=2)
    with pytest.raises(ValueError, match="the student planned no tour in houses \\[3\\]"):
        generate.student_records(np.asarray([3]), None, get_preset("smoke"), cfg,
                                 jnp.zeros((1, 1)), categories_per_house=1)  # fmt: skip
