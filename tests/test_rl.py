"""Reward fine-tuning: the likelihood it trains is the sampler's, it raises the greedy reward,
it selects on validation, resumes, and refuses a changed recipe."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from bfsop_jax.checkpoint import save_model, write_config
from bfsop_jax.model import ModelConfig, StrategicTransformer
from bfsop_jax.model.decode import decode, teacher_forced_logits
from bfsop_jax.policy import StrategicPolicy
from bfsop_jax.sop import solve_vns
from bfsop_jax.sop.io import random_instance
from bfsop_jax.training import RunConfig, TrainConfig, dataset_from_instances, train
from bfsop_jax.training.bc import dataset_info, instances_from_dataset
from bfsop_jax.training.rl import RLConfig, _plan_log_prob, finetune_rl, greedy_reward_ratio
from tests.test_training import labelled  # random instances labelled by the VNS

TINY = ModelConfig(d_model=32, n_layers=2, n_heads=2, d_ff=64, budget_mask=True, step_features=True)


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A briefly behaviour-cloned tiny model (room left to improve) and its data."""
    train_ds, val_ds = labelled(range(64)), labelled(range(1000, 1016))
    run = tmp_path_factory.mktemp("rl") / "base"
    config = RunConfig(model=TINY, train=TrainConfig(epochs=2, batch_size=16), preset="smoke")
    train(config, train_ds, val_ds, run, lrs=(3e-3,), progress=False)
    return run, train_ds, val_ds


def test_config_errors():
    with pytest.raises(ValueError, match="samples must be >= 2"):
        RLConfig(samples=1)
    with pytest.raises(ValueError, match="lr must be positive"):
        RLConfig(lr=0.0)
    with pytest.raises(ValueError, match="bc_weight"):
        RLConfig(bc_weight=-1.0)
    with pytest.raises(ValueError, match="baseline must be one of leave_one_out, greedy"):
        RLConfig(baseline="critic")


def test_trained_likelihood_is_the_samplers(base):
    """The teacher-forced log-probability of a sampled plan is the sum of the log
    probabilities the sampler drew its entries with (same masks, same step features)."""
    run, train_ds, _ = base
    policy = StrategicPolicy.load(run)
    inst = jax.tree_util.tree_map(jnp.asarray, instances_from_dataset(train_ds))
    trace = decode(policy.model, inst, jax.random.key(3), greedy=False)
    nodes = trace.solution.nodes
    n = inst.set_id.shape[1]
    nxt = nodes[:, 1:]
    target = jnp.where(nxt >= 0, nxt, n)
    chosen = jnp.take_along_axis(trace.probs, target[..., None], axis=-1)[..., 0]
    steps = jnp.concatenate([jnp.ones_like(nxt[:, :1], bool), nxt[:, :-1] >= 0], axis=1)
    expected = jnp.sum(jnp.where(steps, jnp.log(chosen), 0.0), axis=-1)
    got = _plan_log_prob(teacher_forced_logits(policy.model, inst, nodes))
    np.testing.assert_allclose(np.asarray(got), np.asarray(expected), rtol=1e-4, atol=1e-4)
    assert float(jnp.min(got)) < -1.0  # the sampler had choices to make


def test_finetuning_raises_the_greedy_reward_and_resumes(base, tmp_path):
    run, train_ds, val_ds = base
    rl = RLConfig(epochs=3, batch_size=16, samples=8, lr=3e-3, bc_weight=0.1)
    # validate on the training instances: the test asks whether the reward on the
    # instances it trains on rises (selection then must pick a fine-tuned epoch)
    rows = finetune_rl(run, train_ds, train_ds, tmp_path / "rl", rl, seed=0, progress=False)
    assert [r["epoch"] for r in rows] == [0, 1, 2, 3]
    assert max(r["val_greedy_ratio"] for r in rows[1:]) > rows[0]["val_greedy_ratio"] + 0.02
    selected = [r for r in rows if r["selected"]]
    assert len(selected) == 1 and selected[0]["epoch"] > 0
    assert selected[0]["val_greedy_ratio"] == max(r["val_greedy_ratio"] for r in rows)

    tuned = StrategicPolicy.load(tmp_path / "rl")  # the selected epoch, loadable as a policy
    graphdef, params = nnx.split(tuned.model, nnx.Param)
    assert greedy_reward_ratio(graphdef, params, train_ds) == pytest.approx(
        selected[0]["val_greedy_ratio"], abs=1e-5
    )
    log = (tmp_path / "rl" / "rl_metrics.jsonl").read_text()
    logged = [json.loads(x) for x in log.splitlines()]
    assert logged == rows

    again = finetune_rl(run, train_ds, train_ds, tmp_path / "rl", rl, seed=0, progress=False)
    assert again == rows  # finished: nothing retrained
    longer = finetune_rl(run, train_ds, train_ds, tmp_path / "rl",
                         dataclasses.replace(rl, epochs=4), seed=0, progress=False)  # fmt: skip
    assert [r["epoch"] for r in longer] == [0, 1, 2, 3, 4]  # extended from epoch 3
    assert [r["val_greedy_ratio"] for r in longer[:4]] == [r["val_greedy_ratio"] for r in rows]
    with pytest.raises(ValueError, match="another recipe"):
        finetune_rl(run, train_ds, train_ds, tmp_path / "rl", dataclasses.replace(rl, lr=1e-3),
                    progress=False)  # fmt: skip
    with pytest.raises(ValueError, match="has run 4 epochs already"):
        finetune_rl(run, train_ds, train_ds, tmp_path / "rl", rl, seed=0, progress=False)
    # other validation records (the epochs' selection would mix two sets): not this run
    half = {k: v[: len(v) // 2] for k, v in train_ds.items()}
    with pytest.raises(ValueError, match="another recipe"):
        finetune_rl(run, train_ds, half, tmp_path / "rl", dataclasses.replace(rl, epochs=4),
                    seed=0, progress=False)  # fmt: skip


def test_selection_keeps_the_base_model_when_validation_says_so(base, tmp_path, monkeypatch):
    """When no fine-tuned epoch plans better on validation, epoch 0 (the behaviour-cloned
    model) stays the run's model, parameter for parameter."""
    from bfsop_jax.training import rl as rl_module

    run, train_ds, val_ds = base
    scores = iter([0.9, 0.5, 0.7])  # epoch 0 best on validation
    monkeypatch.setattr(rl_module, "greedy_reward_ratio", lambda *a, **k: next(scores))
    # the recipe of the test above but for its epochs: the same compiled epoch
    rl = RLConfig(epochs=2, batch_size=16, samples=8, lr=3e-3, bc_weight=0.1)
    rows = finetune_rl(run, train_ds, val_ds, tmp_path / "rl", rl, progress=False)
    assert [r["selected"] for r in rows] == [True, False, False]
    before = StrategicPolicy.load(run).params
    after = StrategicPolicy.load(tmp_path / "rl").params
    leaves = jax.tree_util.tree_leaves
    for a, b in zip(leaves(before), leaves(after), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_mismatched_records_are_refused(base, tmp_path):
    run, _, val_ds = base
    other = dataset_from_instances(
        [random_instance(1, num_sets=4, viewpoints=3)],
        [solve_vns(random_instance(1, num_sets=4, viewpoints=3), seed=0, max_iters=50)],
    )
    with pytest.raises(ValueError, match="num_nodes"):
        finetune_rl(run, other, val_ds, tmp_path / "rl", RLConfig(epochs=1), progress=False)
    with pytest.raises(ValueError, match="needs a trained run"):
        finetune_rl(tmp_path, other, val_ds, tmp_path / "rl", RLConfig(epochs=1), progress=False)


def test_insertion_decoder_with_route_improvement_finetunes(base, tmp_path):
    """The insertion decoder (route improved after every insertion) trains on the
    likelihood of its own choices against the greedy (self-critical) baseline: fine-tuning
    raises its greedy reward on the instances it trains on, and the selected epoch loads as
    a policy that decodes the same way. (A one-layer model from random weights: the RL
    path is under test, not behaviour cloning.)"""
    _, train_ds, _ = base
    config = dataclasses.replace(TINY, n_layers=1, decoder="insertion", refine=True)
    model = StrategicTransformer(config, rngs=nnx.Rngs(0))
    kernel = model.decoder.project_glimpse.kernel  # zero at init: make the scores non-uniform
    kernel[...] = jax.random.normal(jax.random.key(1), kernel.shape) / np.sqrt(kernel.shape[0])
    run = tmp_path / "base"
    info = dataset_info(train_ds)
    write_config(run, {
        "run": RunConfig(model=config, train=TrainConfig(epochs=1), preset="smoke").to_dict(),
        "dataset": {"num_nodes": info["num_nodes"], "num_sets": info["num_sets"]},
    })  # fmt: skip
    save_model(run, nnx.split(model, nnx.Param)[1])
    rl = RLConfig(epochs=2, batch_size=16, samples=4, lr=3e-3, baseline="greedy")
    rows = finetune_rl(run, train_ds, train_ds, tmp_path / "rl", rl, seed=0, progress=False)
    assert max(r["val_greedy_ratio"] for r in rows[1:]) > rows[0]["val_greedy_ratio"]
    tuned = StrategicPolicy.load(tmp_path / "rl")
    assert tuned.model.config.decoder == "insertion" and tuned.model.config.refine
    graphdef, params = nnx.split(tuned.model, nnx.Param)
    selected = next(r for r in rows if r["selected"])
    assert greedy_reward_ratio(graphdef, params, train_ds) == pytest.approx(
        selected["val_greedy_ratio"], abs=1e-5
    )
