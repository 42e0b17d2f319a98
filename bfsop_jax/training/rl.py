"""Reward fine-tuning of a distilled model (docs/design.md §8.5).

Behaviour cloning teaches the decoder the teacher's next node, step by step; greedy
decoding then compounds its small errors, and it never learns what a wrong choice costs
in reward. This stage continues training from a behaviour-cloned run on the *reward* of
the model's own plans (REINFORCE with a shared baseline, as in Kool et al.'s attention
model and POMO):

* every minibatch instance is planned ``samples`` times by sampling the decoder (each
  sample under a random coordinate symmetry when ``augment``); a plan's reward is that of
  its budget-gated plan (:func:`bfsop_jax.sop.budget_gate`: what inference would run;
  with the model's budget mask every sampled plan fits already);
* a plan's advantage is its reward minus the mean reward of the instance's *other*
  samples (``baseline="leave_one_out"``: unbiased, no critic, as in POMO) or minus the
  reward of the instance's greedy plan (``baseline="greedy"``: the self-critical baseline
  of Rennie et al. and Kool et al.'s rollout baseline, which rewards exactly the samples
  that beat what greedy decoding would plan), divided by the teacher's reward on that
  instance (or the best sample's, where it is higher), so every instance weighs the same
  whatever its reward scale;
* the loss is ``-mean(advantage * log p(plan))`` plus ``bc_weight`` times the
  behaviour-cloning cross-entropy of the teacher's plans of the same minibatch (an anchor
  that keeps the policy near the teacher while it improves on its own plans).

``log p(plan)`` is the teacher-forced log-likelihood of the sampled plan, computed in
parallel over its steps with the same masks the sampler used. The model that leaves this
stage is the epoch with the best greedy reward (relative to the teacher) on the
*validation* instances, epoch 0 being the behaviour-cloned model itself: fine-tuning can
only replace the model when validation says it plans better.

Layout of ``out_dir`` (a run directory ``StrategicPolicy.load`` reads)::

    config.json        the base run's model and data description plus the "rl" recipe
    checkpoints/<e>/   the fine-tuning state after epoch e (resumable)
    rl_metrics.jsonl   one row per epoch (sampled / greedy reward ratios, losses, seconds)
    model/             the selected epoch's parameters
"""

from __future__ import annotations

import dataclasses
import functools
import json
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx, struct

from bfsop_jax import checkpoint as ckpt
from bfsop_jax.files import write_text
from bfsop_jax.model.decode import decode, forced_logits, plan_value, teacher_forced_logits
from bfsop_jax.model.features import node_features, random_symmetry
from bfsop_jax.model.transformer import ModelConfig, StrategicTransformer
from bfsop_jax.sop.two_opt import budget_gate
from bfsop_jax.training.dataset import (
    _check_dataset,
    _device_data,
    _instances,
    dataset_info,
    padded_batches,
)
from bfsop_jax.training.metrics import imitation_stats

__all__ = [
    "BASELINES",
    "RLConfig",
    "RLState",
    "finetune_rl",
    "greedy_reward_ratio",
    "make_rl_epoch",
]

RL_LOG = "rl_metrics.jsonl"
BASELINES = ("leave_one_out", "greedy")  # what a sampled plan's reward is measured against


@dataclasses.dataclass(frozen=True)
class RLConfig:
    """Recipe of reward fine-tuning (every number is per run; shapes: batch x samples)."""

    epochs: int = 3  # passes over the training instances
    batch_size: int = 32  # instances per optimiser step
    samples: int = 8  # sampled plans per instance (the shared baseline's group)
    lr: float = 1e-4  # Adam learning rate (constant)
    # weight of the teacher's cross-entropy next to the reward term (0.1 climbed faster on
    # the validation houses than 0.5: docs/results.md)
    bc_weight: float = 0.1
    temperature: float = 1.0  # softmax temperature of the sampler
    grad_clip: float = 1.0  # global-norm clipping threshold
    augment: bool = True  # each sample under a random coordinate symmetry
    # "leave_one_out": the mean of the instance's other samples; "greedy": the reward of
    # the instance's greedy plan (one more decoding per instance and step)
    baseline: str = "leave_one_out"

    def __post_init__(self) -> None:
        for name in ("epochs", "batch_size", "samples"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"RLConfig.{name} must be a positive int, got {value!r}")
        if self.samples < 2:
            raise ValueError(f"RLConfig.samples must be >= 2 (the baseline), got {self.samples}")
        for name in ("lr", "temperature", "grad_clip"):
            if not getattr(self, name) > 0:
                raise ValueError(f"RLConfig.{name} must be positive, got {getattr(self, name)}")
        if not self.bc_weight >= 0:
            raise ValueError(f"RLConfig.bc_weight must be >= 0, got {self.bc_weight}")
        if self.baseline not in BASELINES:
            raise ValueError(
                f"RLConfig.baseline must be one of {', '.join(BASELINES)}, got {self.baseline!r}"
            )

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@struct.dataclass
class RLState:
    """Fine-tuning state: parameters, clip + Adam state, optimiser steps taken."""

    params: Any
    opt_state: Any
    step: Any  # [] int32


def _optimizer(rl: RLConfig) -> optax.GradientTransformation:
    return optax.chain(optax.clip_by_global_norm(rl.grad_clip), optax.adam(rl.lr))


def _plan_log_prob(tf) -> jax.Array:
    """[B] summed log-probability of each forced plan (its valid steps)."""
    picked = jnp.take_along_axis(tf.log_probs, tf.target[..., None], axis=-1)[..., 0]
    return jnp.sum(jnp.where(tf.valid, picked, 0.0), axis=-1)


def make_rl_epoch(graphdef: nnx.GraphDef, rl: RLConfig, num_instances: int):
    """Jitted ``epoch(state, data, key) -> (state, stats [4])`` of reward fine-tuning.

    ``data``: dataset dict of device arrays (the training records); ``stats``: summed
    reward of the sampled plans, the same sum for the teacher's plans (x samples), summed
    teacher cross-entropy, valid teacher steps.
    """
    batch_size = min(rl.batch_size, num_instances)
    # the epoch count is no part of the program: runs that differ in it (a finished run
    # extended to more epochs) share one compilation
    step_recipe = dataclasses.replace(rl, epochs=1)
    return functools.partial(
        _rl_epoch,
        graphdef=graphdef,
        rl=step_recipe,
        batch_size=batch_size,
        num_instances=num_instances,
    )


@functools.partial(jax.jit, static_argnames=("graphdef", "rl", "batch_size", "num_instances"))
def _rl_epoch(state: RLState, data, key, *, graphdef, rl: RLConfig, batch_size, num_instances):
    num_batches = num_instances // batch_size
    m = rl.samples
    tx = _optimizer(rl)

    def loss(params, inst, tiled, feats, trace, adv, teacher_nodes, order_key):
        model = nnx.merge(graphdef, params)
        if model.config.decoder == "append":
            tf = teacher_forced_logits(model, tiled, trace.solution.nodes, feats)
        else:  # the insertion decoder's states follow its choices, not the plan's order
            tf = forced_logits(model, tiled, trace.choices, feats)
        rl_loss = -jnp.mean(adv * _plan_log_prob(tf))
        bc = imitation_stats(teacher_forced_logits(model, inst, teacher_nodes, None, order_key))
        bc_loss = bc[0] / jnp.maximum(bc[2], 1.0)
        return rl_loss + rl.bc_weight * bc_loss, bc

    def minibatch(state: RLState, xs):
        idx, step_key = xs
        batch = jax.tree_util.tree_map(lambda x: x[idx], data)
        inst = _instances(batch)
        tiled = jax.tree_util.tree_map(lambda x: jnp.repeat(x, m, axis=0), inst)  # [B*M]
        sym_key, sample_key = jax.random.split(step_key)
        feats = random_symmetry(node_features(tiled), sym_key, rl.augment)
        model = nnx.merge(graphdef, state.params)
        sample_key, order_key = jax.random.split(sample_key)
        trace = decode(model, tiled, sample_key, rl.temperature, greedy=False, features=feats)
        plans = jax.lax.stop_gradient(trace.solution)
        teacher_reward, _ = plan_value(inst, batch["teacher_nodes"])  # [B]
        reward = budget_gate(tiled, plans).reward.reshape(-1, m)  # [B, M]: what would run
        if rl.baseline == "greedy":  # what greedy decoding plans (no symmetry, as at inference)
            baseline = _greedy_reward(model, inst)[:, None]
        else:
            baseline = (jnp.sum(reward, axis=1, keepdims=True) - reward) / (m - 1)
        # the instance's reward scale: the teacher's (or a sample's, where one beats it)
        scale = jnp.maximum(jnp.maximum(teacher_reward, jnp.max(reward, axis=1)), 1e-6)[:, None]
        adv = ((reward - baseline) / scale).reshape(-1)
        forced = jax.lax.stop_gradient(trace)
        grads, bc = jax.grad(loss, has_aux=True)(
            state.params, inst, tiled, feats, forced, adv, batch["teacher_nodes"], order_key
        )
        updates, opt_state = tx.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        stats = jnp.stack([jnp.sum(reward), m * jnp.sum(teacher_reward), bc[0], bc[2]])
        return RLState(params=params, opt_state=opt_state, step=state.step + 1), stats

    shuffle, steps = jax.random.split(key)
    order = jax.random.permutation(shuffle, num_instances)[: num_batches * batch_size]
    keys = jax.random.split(steps, num_batches)
    state, stats = jax.lax.scan(minibatch, state, (order.reshape(num_batches, batch_size), keys))
    return state, jnp.sum(stats, axis=0)


def _greedy_reward(model: StrategicTransformer, inst) -> jax.Array:
    """[B] reward of the budget-gated greedy plans (no 2-opt)."""
    return budget_gate(inst, decode(model, inst, greedy=True).solution).reward


@functools.partial(jax.jit, static_argnames=("graphdef", "batch_size", "num_instances"))
def _greedy_sums(params, data, *, graphdef, batch_size: int, num_instances: int):
    index, weight = padded_batches(num_instances, batch_size)
    model = nnx.merge(graphdef, params)

    def minibatch(total, xs):
        idx, w = xs
        batch = jax.tree_util.tree_map(lambda x: x[idx], data)
        inst = _instances(batch)
        greedy = _greedy_reward(model, inst)
        teacher, _ = plan_value(inst, batch["teacher_nodes"])
        return total + jnp.stack([jnp.sum(w * greedy), jnp.sum(w * teacher)]), None

    total, _ = jax.lax.scan(minibatch, jnp.zeros(2, jnp.float32), (index, weight))
    return total


def greedy_reward_ratio(
    graphdef: nnx.GraphDef, params: Any, data: Mapping[str, Any], batch_size: int = 64
) -> float:
    """Mean reward of the budget-gated greedy plans (no 2-opt) over the mean teacher
    reward of a dataset."""
    device = _device_data(data)
    d = int(device["set_id"].shape[0])
    sums = np.asarray(
        _greedy_sums(params, device, graphdef=graphdef, batch_size=min(batch_size, d),
                     num_instances=d)
    )  # fmt: skip
    return float(sums[0] / max(sums[1], 1e-9))


def _read_rows(path: Path) -> list[dict[str, Any]]:
    if not path.is_file():
        return []
    rows = []
    for line in path.read_text().splitlines():
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            continue  # a line cut by an interruption
    return rows


def finetune_rl(
    base_run: str | Path,
    train_ds: Mapping[str, Any],
    val_ds: Mapping[str, Any],
    out_dir: str | Path,
    rl: RLConfig = RLConfig(),
    seed: int = 0,
    progress: bool = True,
) -> list[dict[str, Any]]:
    """Fine-tune the model of ``base_run`` on the reward of its own plans (resumable).

    Args:
        base_run: a behaviour-cloning run directory (``config.json`` + ``model/``).
        train_ds: the records whose instances the student plans (their teacher plans give
            the reward scale and the anchor term).
        val_ds: validation records (never evaluation houses): the greedy reward ratio on
            them picks the epoch that becomes ``out_dir/model`` (epoch 0: the base model).
        out_dir: the fine-tuning run directory; an existing one with the same recipe
            resumes after its last checkpoint (a larger ``rl.epochs`` extends a finished
            run), another recipe is refused.
        rl: the recipe.
        seed: sampling, symmetry and shuffle seed (the same seed gives the same run).
        progress: a progress bar over epochs.

    Returns:
        One row per epoch 0..E: ``epoch``, ``val_greedy_ratio`` and, for E >= 1,
        ``train_sample_ratio`` (mean sampled reward / mean teacher reward), ``train_bc_loss``,
        ``seconds``; the selected epoch is marked ``"selected": true``.
    """
    base_run, out = Path(base_run), Path(out_dir)
    if not (base_run / ckpt.MODEL_DIR).is_dir():
        raise ValueError(f"reward fine-tuning needs a trained run with model/ in {base_run}")
    base_config = ckpt.read_config(base_run)
    model_config = ModelConfig.from_dict(base_config["run"]["model"])
    info = dataset_info(train_ds)
    for key in ("num_nodes", "num_sets"):
        if info[key] != int(base_config["dataset"][key]):
            raise ValueError(
                f"the records have {key} = {info[key]}, the model of {base_run} "
                f"{base_config['dataset'][key]}"
            )
    abstract = nnx.eval_shape(lambda: StrategicTransformer(model_config, rngs=nnx.Rngs(0)))
    graphdef, target = nnx.split(abstract, nnx.Param)
    params = ckpt.load_model(base_run, target)

    from bfsop_jax.policy import model_fingerprint

    # the recipe names what the run's epochs depend on: a resumed run must share all of it
    recipe = {
        "rl": rl.to_dict(), "seed": int(seed), "base_run": str(base_run),
        "base_model": model_fingerprint(model_config, info["num_nodes"], info["num_sets"], params),
        "records": {"train": info, "val": None if val_ds is None else dataset_info(val_ds)},
    }  # fmt: skip
    config = {**base_config, "rl": recipe}
    config["dataset"] = {**base_config["dataset"], "rl_train": info}
    out.mkdir(parents=True, exist_ok=True)
    if (out / ckpt.CONFIG_FILE).is_file():  # resuming: the same recipe (more epochs allowed)
        old = ckpt.read_config(out).get("rl")

        defaults = RLConfig().to_dict()  # runs written before a field existed ran with it

        def same(r):
            return r is not None and {**r, "rl": {**defaults, **r["rl"], "epochs": None}}

        if same(old) != same(recipe):
            raise ValueError(f"{out} holds a fine-tuning run of another recipe: {old}")
    ckpt.write_config(out, config)

    train_data = _device_data(train_ds)
    _check_dataset(val_ds, "validation records")
    state = RLState(params=params, opt_state=_optimizer(rl).init(params), step=jnp.int32(0))
    epoch_fn = make_rl_epoch(graphdef, rl, info["instances"])
    log_path = out / RL_LOG
    store = ckpt.CheckpointStore(out, max_to_keep=rl.epochs + 1)
    start = store.latest_epoch() or 0
    if start > rl.epochs:
        raise ValueError(f"{out} has run {start} epochs already: ask for {start} or more")
    rows = [r for r in _read_rows(log_path) if r["epoch"] <= start]
    if start:
        state, _ = store.restore(state)
    if not rows:
        rows = [{"epoch": 0, "val_greedy_ratio": greedy_reward_ratio(graphdef, params, val_ds)}]
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=rl.epochs, initial=start, desc="reward fine-tuning", unit="epoch")
    try:
        for epoch in range(start + 1, rl.epochs + 1):
            t0 = time.perf_counter()
            key = jax.random.fold_in(jax.random.key(seed), epoch)
            state, stats = epoch_fn(state, train_data, key)
            stats = np.asarray(stats)
            val = greedy_reward_ratio(graphdef, state.params, val_ds)
            row = {
                "epoch": epoch,
                "val_greedy_ratio": val,
                "train_sample_ratio": float(stats[0] / max(stats[1], 1e-9)),
                "train_bc_loss": float(stats[2] / max(stats[3], 1.0)),
                "seconds": round(time.perf_counter() - t0, 1),
            }
            store.save(epoch, state, {"epoch": epoch, "val_greedy_ratio": val})
            rows.append(row)
            write_text(log_path, "".join(json.dumps(r) + "\n" for r in rows))
            if bar is not None:
                bar.set_postfix(val=f"{val:.3f}", sample=f"{row['train_sample_ratio']:.3f}")
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()

    best = max(rows, key=lambda r: (r["val_greedy_ratio"], -r["epoch"]))["epoch"]
    if best > 0:
        state, _ = store.restore(state, epoch=best)
        params = state.params
    store.close()
    for r in rows:
        r["selected"] = r["epoch"] == best
    write_text(log_path, "".join(json.dumps(r) + "\n" for r in rows))
    ckpt.save_model(out, params)
    config["result"] = {**base_config.get("result", {}), "rl_selected_epoch": best}
    ckpt.write_config(out, config)
    return rows
