"""Behaviour cloning: dataset checks, learning, vmapped replicas, checkpoints and resume."""

from __future__ import annotations

import dataclasses
import json

import jax
import numpy as np
import pytest

from bfsop_jax.checkpoint import CheckpointStore
from bfsop_jax.model import ModelConfig
from bfsop_jax.sop import solve_vns
from bfsop_jax.sop.io import random_instance
from bfsop_jax.training import (
    RunConfig,
    TrainConfig,
    dataset_from_instances,
    dataset_info,
    instances_from_dataset,
    train,
)
from bfsop_jax.training.bc import init_states, make_evaluate, make_train_epoch

TINY = ModelConfig(d_model=32, n_layers=2, n_heads=2, d_ff=64)
RECIPE = TrainConfig(epochs=4, batch_size=16, decay_every=2)
SETS, VIEWPOINTS = 6, 3  # N = 19 nodes, K = 7 sets


def labelled(seeds: range) -> dict[str, np.ndarray]:
    insts = [
        random_instance(s, num_sets=SETS, viewpoints=VIEWPOINTS, masked_sets=s % 3) for s in seeds
    ]
    sols = [solve_vns(i, seed=0, max_iters=200, max_no_improve=100) for i in insts]
    return dataset_from_instances(insts, sols)


@pytest.fixture(scope="module")
def data() -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    return labelled(range(64)), labelled(range(1000, 1016))


def params_of(result) -> list[np.ndarray]:
    return [np.asarray(x) for x in jax.tree_util.tree_leaves(result.states.params)]


# -- data ------------------------------------------------------------------------------------
def test_dataset_format(data):
    train_ds, _ = data
    info = dataset_info(train_ds)
    assert info["instances"] == 64 and info["num_nodes"] == 19 and info["num_sets"] == 7
    # every instance with m visited sets gives m + 1 transitions (m nodes, then END)
    m = (train_ds["teacher_nodes"] >= 0).sum(1) - 1
    assert info["transitions"] == int((m + 1).sum())
    inst = instances_from_dataset(train_ds)
    assert inst.set_id.shape == (64, 19) and (inst.start == 0).all() and (inst.end == -1).all()


def test_dataset_errors(data):
    train_ds, _ = data
    with pytest.raises(ValueError, match="teacher_nodes"):
        instances_from_dataset({k: v for k, v in train_ds.items() if k != "teacher_nodes"})
    with pytest.raises(ValueError, match="cost must have shape"):
        instances_from_dataset({**train_ds, "cost": train_ds["cost"][:, :5]})
    bad = {**train_ds, "cost": train_ds["cost"].copy()}
    bad["cost"][0, 1, 2] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        instances_from_dataset(bad)
    with pytest.raises(ValueError, match="start at node 0"):
        instances_from_dataset({**train_ds, "teacher_nodes": train_ds["teacher_nodes"][:, ::-1]})


# -- learning --------------------------------------------------------------------------------
def test_training_learns_the_teacher(data, tmp_path):
    """Two learning rates train side by side; the loss falls and the trained model imitates
    the teacher better than the untrained one on held-out instances."""
    train_ds, val_ds = data
    config = RunConfig(model=TINY, train=dataclasses.replace(RECIPE, epochs=8), preset="smoke")
    lrs = (3e-3, 1e-3)
    result = train(config, train_ds, val_ds, tmp_path / "run", lrs=lrs, progress=False)
    assert result.complete and len(result.history) == 8 * 2
    best = result.best_replica
    mine = [r for r in result.history if r["replica"] == best]
    assert mine[-1]["train_loss"] < mine[0]["train_loss"] - 0.3
    assert mine[-1]["val_loss"] == min(r["val_loss"] for r in result.history if r["epoch"] == 8)

    graphdef, initial = init_states(TINY, RECIPE, seeds=[0, 0], lrs=lrs)
    evaluate = make_evaluate(graphdef, RECIPE.batch_size, 16)
    val = {k: jax.numpy.asarray(v) for k, v in val_ds.items()}
    before = np.asarray(evaluate(initial.params, val))
    after = np.asarray(evaluate(result.states.params, val))
    loss_before, loss_after = before[:, 0] / before[:, 2], after[:, 0] / after[:, 2]
    acc_before, acc_after = before[:, 1] / before[:, 2], after[:, 1] / after[:, 2]
    assert (loss_after < loss_before - 0.3).all()
    assert (acc_after > acc_before + 0.05).all()
    np.testing.assert_allclose(loss_after[best], mine[-1]["val_loss"], rtol=1e-5)

    # step decay: x0.5 every 2 epochs
    decayed = [r["lr"] for r in result.history if r["replica"] == 0][::2]
    np.testing.assert_allclose(decayed, [3e-3, 1.5e-3, 7.5e-4, 3.75e-4], rtol=1e-5)
    run = tmp_path / "run"
    for name in ("config.json", "metrics.jsonl", "metrics.csv", "training_curve.png"):
        assert (run / name).is_file(), name
    assert (run / "model").is_dir()
    config_json = json.loads((run / "config.json").read_text())
    assert config_json["run"]["model"] == TINY.to_dict()
    assert config_json["dataset"]["num_nodes"] == 19
    assert config_json["result"]["best_replica"] == best


def test_a_diverged_run_says_so(data, tmp_path, monkeypatch):
    """When no replica's loss is finite, training stops with one clear line rather than
    NumPy's all-NaN error (the validation statistics stand in for a diverged model)."""
    from bfsop_jax.training import bc

    train_ds, val_ds = data
    config = RunConfig(model=TINY, train=dataclasses.replace(RECIPE, epochs=1), preset="smoke")
    nan = lambda *a, **k: (lambda params, data: np.full((2, 3), np.nan, np.float32))
    monkeypatch.setattr(bc, "make_evaluate", nan)
    with pytest.raises(ValueError, match="training diverged: no replica has a finite loss"):
        train(config, train_ds, val_ds, tmp_path / "run", lrs=(3e-3, 1e-3), progress=False)


def test_interrupted_run_resumes_to_the_same_parameters(data, tmp_path, monkeypatch):
    """Two replicas (seeds) in one vmapped program; an interrupted run, resumed, ends with
    exactly the parameters of an uninterrupted one."""
    train_ds, val_ds = data
    config = RunConfig(model=TINY, train=RECIPE, preset="smoke")
    kwargs = dict(seeds=(0, 1), lrs=(1e-3,), progress=False)
    full = train(config, train_ds, val_ds, tmp_path / "full", **kwargs)
    assert full.complete and len(full.replicas) == 2

    part = tmp_path / "part"
    first = train(config, train_ds, val_ds, part, max_epochs_this_call=1, **kwargs)
    assert not first.complete and first.epochs_done == 1 and not (part / "model").exists()

    def interrupt_at_2(rows):  # a KeyboardInterrupt after epoch 2, before its checkpoint
        if rows[0]["epoch"] == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(config, train_ds, val_ds, part, resume=True, on_epoch=interrupt_at_2, **kwargs)
    with CheckpointStore(part, read_only=True) as store:
        assert store.latest_epoch() == 2  # saved on the way out
    with pytest.raises(ValueError, match="resume=True"):
        train(config, train_ds, val_ds, part, **kwargs)
    other = RunConfig(model=dataclasses.replace(TINY, d_ff=32), train=RECIPE, preset="smoke")
    with pytest.raises(ValueError, match="cannot resume"):
        train(other, train_ds, val_ds, part, resume=True, **kwargs)

    # interrupted again in the last epoch, after its step but while its rows are logged:
    # the resumed run must still log that epoch and choose the same replica
    from bfsop_jax.training import bc

    append = bc.MetricsLog.append

    def interrupted_append(self, rows):
        if rows[0]["epoch"] == RECIPE.epochs:
            raise KeyboardInterrupt
        return append(self, rows)

    monkeypatch.setattr(bc.MetricsLog, "append", interrupted_append)
    with pytest.raises(KeyboardInterrupt):
        train(config, train_ds, val_ds, part, resume=True, **kwargs)
    monkeypatch.setattr(bc.MetricsLog, "append", append)

    resumed = train(config, train_ds, val_ds, part, resume=True, **kwargs)
    assert resumed.complete and resumed.epochs_done == RECIPE.epochs
    for a, b in zip(params_of(full), params_of(resumed), strict=True):
        np.testing.assert_array_equal(a, b)
    assert resumed.best_replica == full.best_replica
    rows = [json.loads(line) for line in (part / "metrics.jsonl").read_text().splitlines()]
    assert [(r["epoch"], r["replica"]) for r in rows] == [
        (e, i) for e in range(1, RECIPE.epochs + 1) for i in range(2)
    ]
    for a, b in zip(rows, full.history, strict=True):
        assert a["train_loss"] == b["train_loss"] and a["val_loss"] == b["val_loss"]
    # the two seeds give two different models
    leaf = params_of(full)[0]
    assert not np.array_equal(leaf[0], leaf[1])


def test_variants_build_and_train(data):
    """Geometric bias off and the budget-aware decoder (the other two settings are trained
    above): the model builds and its loss falls."""
    train_ds, _ = data
    config = dataclasses.replace(TINY, n_layers=1, geometric_bias=False, budget_aware=True)
    graphdef, states = init_states(config, RECIPE, seeds=[0], lrs=[3e-3])
    epoch = make_train_epoch(graphdef, RECIPE, 64)
    data_dev = {k: jax.numpy.asarray(v) for k, v in train_ds.items()}
    keys = jax.numpy.stack([jax.random.key(0)])
    losses = []
    for _ in range(3):
        states, stats = epoch(states, data_dev, keys)
        losses.append(float(stats[0, 0] / stats[0, 2]))
    assert np.isfinite(losses).all() and losses[-1] < losses[0]


def test_symmetry_augmentation_trains_and_is_seeded(data):
    """``augment=True`` shows instances under random coordinate symmetries: a different
    program from the plain one, deterministic for a key, and its loss falls."""
    train_ds, _ = data
    recipe = dataclasses.replace(RECIPE, augment=True)
    data_dev = {k: jax.numpy.asarray(v) for k, v in train_ds.items()}
    keys = jax.numpy.stack([jax.random.key(0)])
    runs = []
    for cfg in (recipe, recipe, RECIPE):
        graphdef, states = init_states(TINY, cfg, seeds=[0], lrs=[3e-3])
        epoch = make_train_epoch(graphdef, cfg, 64)
        losses = []
        for _ in range(3):
            states, stats = epoch(states, data_dev, keys)
            losses.append(float(stats[0, 0] / stats[0, 2]))
        runs.append(losses)
    assert np.isfinite(runs[0]).all() and runs[0][-1] < runs[0][0]
    assert runs[0] == runs[1]  # same key, same symmetries
    assert runs[0] != runs[2]  # the symmetries change what the model sees


def test_replicas_with_different_recipes_match_separate_runs(data, tmp_path):
    """Clip, decay, warm-up, label smoothing and augmentation are per-replica values of one
    program: three different replicas trained together end where each ends alone."""
    from bfsop_jax.training import Replica

    train_ds, val_ds = data
    small = dataclasses.replace(TINY, n_layers=1)  # the rule, not the model, is under test
    config = RunConfig(model=small, train=dataclasses.replace(RECIPE, epochs=2), preset="smoke")
    members = [
        Replica.of(config.train, 0, 3e-3, grad_clip=0.05, lr_decay=0.3),
        Replica.of(config.train, 1, 1e-3, warmup_epochs=1.5, label_smoothing=0.2),
        Replica.of(config.train, 2, 2e-3, augment=True, decay_every=1),
    ]
    together = train(config, train_ds, val_ds, tmp_path / "all", replicas=members,
                     progress=False)  # fmt: skip
    assert len(together.replica_dirs) == 3
    for i, rep in enumerate(members):
        alone = train(config, train_ds, val_ds, tmp_path / f"r{i}", replicas=[rep],
                      progress=False)  # fmt: skip
        for a, b in zip(
            jax.tree_util.tree_leaves(together.states.params),
            jax.tree_util.tree_leaves(alone.states.params),
            strict=True,
        ):
            np.testing.assert_allclose(np.asarray(a)[i], np.asarray(b)[0], rtol=2e-4, atol=2e-6)
        # the replica's own directory loads as a policy and is that replica
        saved = json.loads((together.replica_dirs[i] / "config.json").read_text())
        assert saved["replicas"] == [rep.to_dict()]
    # the recipes differ: warm-up starts low, the learning rates logged follow each schedule
    first = [r for r in together.history if r["epoch"] == 1]
    steps = 64 // RECIPE.batch_size
    assert first[1]["lr"] == pytest.approx(1e-3 * steps / (1.5 * steps))
    second = [r for r in together.history if r["epoch"] == 2]
    assert (first[2]["lr"], second[2]["lr"]) == pytest.approx((2e-3, 1e-3))  # x0.5 each epoch
