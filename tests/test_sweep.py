"""experiments.sweep: grids, one compiled program per group, outputs, resume."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from bfsop_jax.policy import StrategicPolicy
from bfsop_jax.training import RunConfig
from bfsop_jax.training.bc import TRACE_COUNTS, evaluate_imitation
from bfsop_jax.training.sweep import (
    combinations,
    groups,
    merge_grids,
    parse_grid_args,
    read_grid_file,
)


def test_grid_parsing_types_and_groups():
    grid = parse_grid_args(["lr=3e-4,1e-3", "seed=0,1", "layers=1,2", "augment=true,false"])
    assert grid == {"lr": [3e-4, 1e-3], "seed": [0, 1], "layers": [1, 2],
                    "augment": [True, False]}  # fmt: skip
    combos = combinations(grid)
    assert len(combos) == 16 and len({c.name for c in combos}) == 16
    # replica keys share a program; layers (a shape) makes two groups of 8
    parts = groups(grid)
    assert [g.name for g in parts] == ["layers-1", "layers-2"]
    assert [len(g.members) for g in parts] == [8, 8]
    base = RunConfig.named("tiny")
    combo = parts[1].members[3]
    config = combo.run_config(base)
    assert config.model.n_layers == 2 and config.model.d_model == base.model.d_model
    replica = combo.replica(config)
    assert (replica.seed, replica.lr, replica.augment) == (
        combo.settings["seed"], combo.settings["lr"], combo.settings["augment"])  # fmt: skip
    # the decoder changes the program: one group per decoder
    parts = groups(parse_grid_args(["decoder=append,insertion", "lr=1e-3,3e-3"]))
    assert [g.name for g in parts] == ["decoder-append", "decoder-insertion"]
    assert parts[1].members[0].run_config(base).model.decoder == "insertion"


@pytest.mark.parametrize(
    "items, message",
    [
        (["depth=1,2"], "unknown grid key 'depth'"),
        (["lr="], "grid key 'lr' has an empty list"),
        (["lr=fast"], "grid key 'lr': 'fast' is not a number"),
        (["seed=0.5"], "grid key 'seed': '0.5' is not an integer"),
        (["augment=maybe"], "grid key 'augment'"),
        (["lr=1e-3,0.001"], "grid key 'lr' lists a value twice"),
        (["lr=1e-3", "lr=3e-3"], "grid key 'lr' is given twice"),
        (["heads=3"], "heads-3"),  # does not divide the width
        (["lr=-1"], "Replica.lr must be positive"),
        (["lr"], "expected key=v1,v2"),
        (["decoder=append,prepend"], "decoder-prepend"),  # not a decoder
    ],
)
def test_bad_grids_name_the_key(items, message):
    with pytest.raises(ValueError, match=message):
        parse_grid_args(items)


def test_grid_file(tmp_path):
    path = tmp_path / "grid.toml"
    path.write_text("[grid]\nlr = [1e-3, 3e-3]\nlabel_smoothing = [0.0, 0.1]\n")
    grid = read_grid_file(path)
    assert grid == {"lr": [1e-3, 3e-3], "label_smoothing": [0.0, 0.1]}
    with pytest.raises(ValueError, match="'lr' is given twice"):
        merge_grids(grid, parse_grid_args(["lr=1e-4"]))
    path.write_text("[grid]\nlr = ['x']\n")
    with pytest.raises(ValueError, match="'lr'"):
        read_grid_file(path)
    with pytest.raises(ValueError, match="does not exist"):
        read_grid_file(tmp_path / "missing.toml")


@pytest.mark.slow
def test_sweep_end_to_end_compiles_once_per_group_and_resumes(tmp_path, smoke_data_dir):
    from experiments import sweep

    out = tmp_path / "sweep"
    argv = ["--preset", "smoke", "--grid", "lr=1e-3,3e-3", "--grid", "layers=1,2",
            "--epochs", "1", "--out", str(out), "--data-dir", str(smoke_data_dir),
            "--no-progress"]  # fmt: skip
    traces = TRACE_COUNTS["train_epoch"]
    summary = sweep.main(argv)
    assert TRACE_COUNTS["train_epoch"] - traces == 2  # two groups, one program each
    results = summary["results"]
    assert len(results) == 4 and summary["groups"] == ["layers-1", "layers-2"]
    for name in ("sweep.csv", "sweep.md", "sweep.png", "eval_set.npz"):
        assert (out / name).is_file(), name
    rows = list(csv.DictReader((out / "sweep.csv").open()))
    ratios = [float(r["reward_ratio"]) for r in rows]
    assert [int(r["rank"]) for r in rows] == [1, 2, 3, 4] and ratios == sorted(ratios)[::-1]
    assert all(0 < x <= 1.0 + 1e-6 for x in ratios)

    # every combination's directory loads, and holds that replica (its validation loss)
    import dataclasses

    from bfsop_jax.data.shards import ShardStore
    from experiments.distill import PRESETS, _split

    cfg = PRESETS["smoke"].data
    store = ShardStore(smoke_data_dir, dataclasses.asdict(cfg))
    _, val_ds = _split(store, cfg, PRESETS["smoke"].val_houses)
    for res in results:
        policy = StrategicPolicy.load(res["run_dir"])
        assert policy.model.config.n_layers == res["settings"]["layers"]
        stats = evaluate_imitation(policy.model, val_ds, batch_size=16)
        assert stats["loss"] == pytest.approx(res["val_loss"], rel=1e-4)
        saved = json.loads((out / "runs" / res["name"] / "config.json").read_text())
        assert saved["replicas"][0]["lr"] == res["settings"]["lr"]
    assert results[0]["val_loss"] != results[1]["val_loss"]  # two replicas, two models

    # a rerun skips every finished combination: nothing is traced, the table is the same
    table = (out / "sweep.csv").read_text()
    sweep.main(argv)
    assert TRACE_COUNTS["train_epoch"] - traces == 2
    assert (out / "sweep.csv").read_text().splitlines()[0] == table.splitlines()[0]
    # an unfinished combination is redone (its group's models are missing)
    victim = out / "runs" / results[0]["name"]
    (victim / "sweep_result.json").unlink()
    again = sweep.main(argv)
    assert len(again["results"]) == 4
    assert TRACE_COUNTS["train_epoch"] - traces == 2  # trained models kept: evaluation only

    # the same sweep directory with another run length would reuse 1-epoch models: refused
    longer = [a if a != "1" else "2" for a in argv]
    with pytest.raises(ValueError, match="other fixed settings \\(--epochs 1, now 2\\)"):
        sweep.main(longer)

    with pytest.raises(ValueError, match="unknown grid key"):
        sweep.main(["--preset", "smoke", "--grid", "depth=2", "--out", str(tmp_path / "x")])
    assert not (tmp_path / "x").exists()  # a bad grid stops before anything is written
    with pytest.raises(ValueError, match="no grid"):
        sweep.main(["--preset", "smoke", "--out", str(tmp_path / "x")])
    np.testing.assert_allclose(
        again["results"][0]["reward_ratio"], results[0]["reward_ratio"], rtol=1e-6
    )


def test_sweep_data_overrides_reach_the_dataset(tmp_path, smoke_data_dir):
    """``--houses`` / ``--tasks`` select the dataset as in ``experiments.distill``: the
    smoke cache (6 tasks per house) is refused for a 5-task configuration, before any
    training and without touching the cache (a larger ``--houses`` alone would grow it)."""
    from experiments import sweep

    argv = ["--preset", "smoke", "--grid", "lr=1e-3", "--out", str(tmp_path / "s"),
            "--data-dir", str(smoke_data_dir), "--tasks", "5", "--no-progress"]  # fmt: skip
    with pytest.raises(ValueError, match="another configuration"):
        sweep.main(argv)
