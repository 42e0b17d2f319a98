"""The functional training program of behaviour cloning (docs/design.md §8.3).

The model is ``nnx.split`` into a graph definition and a parameter state; every replica's
recipe numbers are traced scalars (:class:`Hyper`) in its :class:`TrainState`, so replicas
that differ only in them train side by side in one ``jax.vmap``-ed program. Here: the
optimiser and its learning-rate schedule, the replicas' initial states, the losses
(teacher forcing, label smoothing, the student's own states), one epoch as a jitted
``lax.scan`` over shuffled minibatches (:func:`make_train_epoch`) and the evaluation over
every instance (:func:`make_evaluate`, :func:`evaluate_imitation`). The run around it
(checkpoints, metrics, model choice) is :func:`bfsop_jax.training.bc.train`; everything
here is importable from :mod:`bfsop_jax.training.bc` too.
"""

from __future__ import annotations

import collections
import functools
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx, struct
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from bfsop_jax.model.decode import decode, forced_logits, teacher_forced_logits
from bfsop_jax.model.features import node_features, random_symmetry
from bfsop_jax.model.transformer import ModelConfig, StrategicTransformer
from bfsop_jax.parallel import DATA_AXIS, place
from bfsop_jax.training.config import Replica, TrainConfig
from bfsop_jax.training.dataset import _device_data, _instances, padded_batches
from bfsop_jax.training.metrics import imitation_stats

__all__ = [
    "Hyper",
    "TRACE_COUNTS",
    "TrainState",
    "evaluate_imitation",
    "init_states",
    "learning_rate",
    "lr_factor",
    "make_evaluate",
    "make_optimizer",
    "make_train_epoch",
]


@struct.dataclass
class Hyper:
    """One replica's recipe numbers as traced scalars (stacked: a leading replica axis)."""

    lr: Any  # [] float32: base learning rate
    grad_clip: Any  # [] float32: global-norm clipping threshold
    lr_decay: Any  # [] float32: staircase decay factor ...
    decay_every: Any  # [] float32: ... every this many epochs
    warmup_epochs: Any  # [] float32: linear warm-up length (0: none)
    label_smoothing: Any  # [] float32: uniform-target weight over the allowed entries
    augment: Any  # [] bool: show instances under random coordinate symmetries
    on_policy: Any  # [] float32: weight of the loss on the student's own states

    @classmethod
    def of(cls, replica: Replica) -> Hyper:
        f32 = jnp.float32
        return cls(
            lr=f32(replica.lr),
            grad_clip=f32(replica.grad_clip),
            lr_decay=f32(replica.lr_decay),
            decay_every=f32(replica.decay_every),
            warmup_epochs=f32(replica.warmup_epochs),
            label_smoothing=f32(replica.label_smoothing),
            augment=jnp.bool_(replica.augment),
            on_policy=f32(replica.on_policy),
        )


@struct.dataclass
class TrainState:
    """One replica's training state (a leading replica axis when stacked)."""

    params: Any  # nnx.State of the model's nnx.Param leaves
    opt_state: Any  # clip + Adam state (moments, counts)
    step: Any  # [] int32: optimiser steps taken
    hyper: Hyper  # this replica's recipe numbers


def make_optimizer(grad_clip: float | jax.Array) -> optax.GradientTransformation:
    """Clip by global norm, then Adam's scaling; the learning rate is applied per replica."""
    return optax.chain(optax.clip_by_global_norm(grad_clip), optax.scale_by_adam())


def lr_factor(step: Any, decay_steps: Any, lr_decay: Any) -> jax.Array:
    """Staircase step decay: ``lr_decay ** floor(step / decay_steps)`` (optimiser steps)."""
    return lr_decay ** jnp.floor(step / decay_steps)


def learning_rate(hyper: Hyper, step: Any, steps_per_epoch: int) -> jax.Array:
    """Learning rate of optimiser step ``step`` (0-based): warm-up, then staircase decay."""
    warm = jnp.minimum(1.0, (step + 1) / jnp.maximum(hyper.warmup_epochs * steps_per_epoch, 1.0))
    warm = jnp.where(hyper.warmup_epochs > 0, warm, 1.0)
    decay = lr_factor(step, hyper.decay_every * steps_per_epoch, hyper.lr_decay)
    return hyper.lr * warm * decay


def init_states(
    model_config: ModelConfig,
    train_config: TrainConfig,
    seeds: Sequence[int] = (),
    lrs: Sequence[float] = (),
    *,
    replicas: Sequence[Replica] | None = None,
    init_params: Any = None,
) -> tuple[nnx.GraphDef, TrainState]:
    """Graph definition and stacked initial states of the replicas.

    The replicas are ``replicas`` when given, otherwise ``zip(seeds, lrs)`` with the
    recipe's other numbers. ``init_params`` (the ``nnx.Param`` state of a model of the
    same config) starts every replica from those weights with a fresh optimiser
    (fine-tuning, DAgger rounds) instead of a seeded initialisation.
    """
    if replicas is None:
        replicas = [Replica.of(train_config, s, lr) for s, lr in zip(seeds, lrs, strict=True)]
    if not replicas:
        raise ValueError("init_states needs at least one replica")
    graphdef, states = None, []
    for rep in replicas:
        model = StrategicTransformer(model_config, rngs=nnx.Rngs(params=_init_key(rep.seed)))
        graphdef, params = nnx.split(model, nnx.Param)
        if init_params is not None:
            try:
                params = jax.tree_util.tree_map(
                    lambda fresh, given: jnp.asarray(given, fresh.dtype).reshape(fresh.shape),
                    params, init_params,
                )  # fmt: skip
            except (ValueError, TypeError) as err:
                raise ValueError(f"init_params do not match the model config: {err}") from None
        states.append(
            TrainState(
                params=params,
                opt_state=make_optimizer(rep.grad_clip).init(params),
                step=jnp.int32(0),
                hyper=Hyper.of(rep),
            )
        )
    stacked = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *states)
    return graphdef, _committed(stacked)


def _committed(tree: Any) -> Any:
    """Place arrays on the default device explicitly: jit caches committed and uncommitted
    inputs separately, and the epoch's outputs are committed."""
    return place(tree, None)


def _init_key(seed: int) -> jax.Array:
    return jax.random.fold_in(jax.random.key(seed), 0)


def _epoch_key(seed: int, epoch: int) -> jax.Array:
    """Shuffle key of an epoch: a function of (seed, epoch) only, so a resume is exact."""
    return jax.random.fold_in(jax.random.fold_in(jax.random.key(seed), 1), epoch)


def _teacher_forcing(
    graphdef: nnx.GraphDef,
    params: Any,
    batch: Mapping[str, jax.Array],
    key: jax.Array | None = None,
    features: Any = None,
):
    """Teacher-forced decoder outputs on a minibatch, with its ``features`` (e.g. from
    :func:`_augmented`; None: the plain ones); with ``key`` an insertion decoder sees the
    teacher's nodes enter in a random order drawn from it (without: a fixed order)."""
    model = nnx.merge(graphdef, params)
    order_key = None if key is None else jax.random.fold_in(key, 1)
    return teacher_forced_logits(model, _instances(batch), batch["teacher_nodes"], features,
                                 order_key)  # fmt: skip


def _augmented(batch: Mapping[str, jax.Array], key: jax.Array, augment: Any):
    """Every instance's features under a random one of the 8 coordinate symmetries drawn
    from ``key`` (``augment`` traced false: the identity)."""
    return random_symmetry(node_features(_instances(batch)), key, augment)


def _student_forcing(graphdef: nnx.GraphDef, params: Any, batch: Mapping[str, jax.Array],
                     features, key: jax.Array):  # fmt: skip
    """The insertion decoder on its own states: half the minibatch's plans greedy, half
    sampled (temperature 1) by the current parameters (no gradient through the plans),
    each state labelled by the teacher's nodes it still allows (DAgger at the level of
    decoding steps, with the teacher's plan as the oracle)."""
    inst = _instances(batch)
    rows = inst.set_id.shape[0]
    frozen = nnx.merge(graphdef, jax.lax.stop_gradient(params))
    trace = decode(frozen, inst, key, greedy=jnp.arange(rows) % 2 == 0, features=features)
    model = nnx.merge(graphdef, params)
    return forced_logits(model, inst, trace.choices, features, teacher_nodes=batch["teacher_nodes"])


def _batch_stats(graphdef: nnx.GraphDef, params: Any, batch: Mapping[str, jax.Array], weight=None):
    """Summed imitation stats [3] of a minibatch (see ``imitation_stats``)."""
    return imitation_stats(_teacher_forcing(graphdef, params, batch), weight)


def _smoothing_nll(tf) -> jax.Array:
    """Summed cross-entropy of the uniform distribution over each valid step's allowed
    entries (the label-smoothing term)."""
    allowed = tf.allowed
    count = jnp.maximum(jnp.sum(allowed, axis=-1), 1)
    uniform = -jnp.sum(jnp.where(allowed, tf.log_probs, 0.0), axis=-1) / count
    return jnp.sum(jnp.where(tf.valid, uniform, 0.0))


TRACE_COUNTS: collections.Counter[str] = collections.Counter()
"""How often each training program was traced (a test that a sweep group compiles once)."""


def make_train_epoch(
    graphdef: nnx.GraphDef,
    config: TrainConfig,
    num_instances: int,
    *,
    augment: bool | None = None,
    smoothing: bool | None = None,
    on_policy: bool | None = None,
    mesh: Mesh | None = None,
    shard: str = "replicas",
) -> Callable[[TrainState, dict[str, jax.Array], jax.Array], tuple[TrainState, jax.Array]]:
    """Jitted ``train_epoch(states, data, keys) -> (states, stats)`` over stacked replicas.

    ``states``: :class:`TrainState` with a leading replica axis R; ``data``: dataset dict of
    device arrays (shared by the replicas); ``keys``: [R] shuffle keys. ``stats`` [R, 3]:
    summed NLL, correct arg-max steps, valid steps over the epoch. The program is compiled
    once per (model graph, batch size, D, replica count, the two flags below, placement):
    every recipe number lives in ``states.hyper``, so replicas that differ only in them, or
    runs that differ in epochs, share it.

    ``augment`` / ``smoothing`` / ``on_policy``: compile the symmetry augmentation / the
    label-smoothing term / the loss on the student's own states (insertion decoder) in
    (default: the recipe's setting); each replica's ``hyper`` then says whether it
    augments, how much it smooths and what weight its own states get. ``mesh`` with
    ``shard="batch"``: every minibatch is split over the mesh's ``data`` axis
    (``shard="replicas"`` needs nothing inside the program: the placement of ``states``
    decides).
    """
    batch_size = min(config.batch_size, num_instances)
    return functools.partial(
        _train_epoch,
        graphdef=graphdef,
        batch_size=batch_size,
        num_instances=num_instances,
        augment=config.augment if augment is None else bool(augment),
        smoothing=config.label_smoothing > 0 if smoothing is None else bool(smoothing),
        on_policy=config.on_policy > 0 if on_policy is None else bool(on_policy),
        batch_mesh=mesh if shard == "batch" else None,
    )


@functools.partial(
    jax.jit,
    static_argnames=(
        "graphdef", "batch_size", "num_instances", "augment", "smoothing", "on_policy",
        "batch_mesh",
    ),
)  # fmt: skip
def _train_epoch(
    states,
    data,
    keys,
    *,
    graphdef,
    batch_size: int,
    num_instances: int,
    augment: bool,
    smoothing: bool,
    on_policy: bool,
    batch_mesh: Mesh | None,
):
    TRACE_COUNTS["train_epoch"] += 1
    num_batches = num_instances // batch_size

    def loss(params, batch, key, hyper: Hyper):
        # one symmetry per instance for both losses (left out of the program unless some
        # replica augments); the key also draws an insertion decoder's order of entry
        features = _augmented(batch, key, hyper.augment) if augment else None
        tf = _teacher_forcing(graphdef, params, batch, key=key, features=features)
        stats = imitation_stats(tf)
        total, steps = stats[0], stats[2]
        if smoothing:
            eps = hyper.label_smoothing
            total = (1.0 - eps) * total + eps * _smoothing_nll(tf)
        if on_policy:  # the student's own states join with weight hyper.on_policy
            own = imitation_stats(
                _student_forcing(graphdef, params, batch, features, jax.random.fold_in(key, 2))
            )
            total = total + hyper.on_policy * own[0]
            steps = steps + hyper.on_policy * own[2]
        return total / jnp.maximum(steps, 1.0), stats

    def epoch(state: TrainState, key: jax.Array):
        shuffle, sym = jax.random.split(key)
        order = jax.random.permutation(shuffle, num_instances)[: num_batches * batch_size]
        sym_keys = jax.random.split(sym, num_batches)
        tx = make_optimizer(state.hyper.grad_clip)

        def minibatch(state: TrainState, xs):
            idx, sym_key = xs
            batch = jax.tree_util.tree_map(lambda x: x[idx], data)
            if batch_mesh is not None:
                batch = jax.lax.with_sharding_constraint(
                    batch, NamedSharding(batch_mesh, PartitionSpec(DATA_AXIS))
                )
            grads, stats = jax.grad(loss, has_aux=True)(state.params, batch, sym_key, state.hyper)
            updates, opt_state = tx.update(grads, state.opt_state, state.params)
            lr = learning_rate(state.hyper, state.step, num_batches)
            updates = jax.tree_util.tree_map(lambda u: -lr * u, updates)
            params = optax.apply_updates(state.params, updates)
            return state.replace(params=params, opt_state=opt_state, step=state.step + 1), stats

        state, stats = jax.lax.scan(
            minibatch, state, (order.reshape(num_batches, batch_size), sym_keys)
        )
        return state, jnp.sum(stats, axis=0)

    return jax.vmap(epoch)(states, keys)


def make_evaluate(
    graphdef: nnx.GraphDef, batch_size: int, num_instances: int
) -> Callable[[Any, dict[str, jax.Array]], jax.Array]:
    """Jitted ``evaluate(params, data) -> stats [R, 3]`` over every instance of ``data``.

    The last minibatch is padded with repeated instances of weight 0, so all count once.
    """
    return functools.partial(
        _evaluate, graphdef=graphdef, batch_size=batch_size, num_instances=num_instances
    )


@functools.partial(jax.jit, static_argnames=("graphdef", "batch_size", "num_instances"))
def _evaluate(params, data, *, graphdef, batch_size: int, num_instances: int):
    index, weight = padded_batches(num_instances, min(batch_size, num_instances))

    def evaluate(params):
        def minibatch(total, xs):
            idx, w = xs
            batch = jax.tree_util.tree_map(lambda x: x[idx], data)
            return total + _batch_stats(graphdef, params, batch, w), None

        total, _ = jax.lax.scan(minibatch, jnp.zeros(3, jnp.float32), (index, weight))
        return total

    return jax.vmap(evaluate)(params)


def evaluate_imitation(
    model: StrategicTransformer, ds: Mapping[str, Any], batch_size: int = 64
) -> dict[str, float]:
    """Teacher-forced loss and next-node accuracy of one model on a dataset."""
    data = _device_data(ds)
    graphdef, params = nnx.split(model, nnx.Param)
    fn = make_evaluate(graphdef, batch_size, data["set_id"].shape[0])
    stats = np.asarray(fn(jax.tree_util.tree_map(lambda x: x[None], params), data))[0]
    return {"loss": float(stats[0] / max(stats[2], 1)), "acc": float(stats[1] / max(stats[2], 1))}
