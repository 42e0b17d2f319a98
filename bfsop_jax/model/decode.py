"""SOP decoding with the Strategic Transformer: teacher forcing, greedy and sampling.

The SOP rules (which entries may come next, the budget mask, start and end, the plan's
value) live in :mod:`bfsop_jax.sop.rules`; the decoder asks it for the mask of every step
(:func:`~bfsop_jax.sop.rules.next_mask`, with the model's ``budget_mask`` flag) and the
network applies the mask it is given. END (index ``N``) stops the plan.

A batch of B instances with N nodes and K sets gives plans of ``T = plan_length(K) = K + 1``
slots (start, at most K - 1 visited sets, and the end node of a closed tour), decoded in
``S = T - 1`` steps by one ``lax.scan``. Functions take batched instances (leading axis B)
and are pure, so callers ``jax.jit`` them (see :mod:`bfsop_jax.policy` and
:mod:`bfsop_jax.training.bc`). A model is passed as an NNX module; inside ``jax.jit`` use
``nnx.merge(graphdef, params)`` to rebuild it.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from bfsop_jax.model.features import (
    NodeFeatures,
    node_features,
    normalised_budget,
    step_features,
)
from bfsop_jax.model.transformer import DecoderCache, StrategicTransformer
from bfsop_jax.sop.rules import (
    advance,
    allowed_next,
    blocked_sets,
    close_plan,
    next_mask,
    plan_value,
    prefix_states,
)
from bfsop_jax.sop.types import Solution, SOPInstance, plan_length

__all__ = [
    "DecodeTrace",
    "TeacherForcing",
    "allowed_next",  # re-exported from bfsop_jax.sop.rules
    "decode",
    "greedy_decode",
    "plan_value",  # re-exported from bfsop_jax.sop.rules
    "sample_decode",
    "teacher_forced_logits",
]


@struct.dataclass
class TeacherForcing:
    """Per-step outputs of the decoder on a teacher's prefixes (S = T - 1 steps)."""

    log_probs: Any  # [B, S, N+1] float32: log-probabilities over nodes and END (index N)
    target: Any  # [B, S] int32: the teacher's next node, N for END
    valid: Any  # [B, S] bool: the step exists (the prefix ends at a real node)
    allowed: Any = None  # [B, S, N+1] bool: the entries the decoder could choose at a step


@struct.dataclass
class DecodeTrace:
    """A decoded plan with the decoder's distribution at every step."""

    solution: Solution  # nodes [B, T], reward [B], cost [B]
    probs: Any  # [B, S, N+1] float32: next-entry probabilities at each step (0 after END)
    allowed: Any  # [B, S, N+1] bool: the mask of each step


def _features(instance: SOPInstance, features: NodeFeatures | None) -> NodeFeatures:
    return node_features(instance) if features is None else features


def teacher_forced_logits(
    model: StrategicTransformer,
    instance: SOPInstance,
    teacher_nodes: jax.Array,
    features: NodeFeatures | None = None,
) -> TeacherForcing:
    """Decoder log-probabilities on every prefix of the teacher's plans, in parallel.

    Step ``s`` sees the prefix ``teacher_nodes[:, :s+1]`` (masks and, when budget-aware,
    the remaining budget induced by it) and is scored on ``teacher_nodes[:, s+1]``, or END
    after the last visited node. An instance visiting m sets gives m + 1 valid steps. The
    target is always kept allowed (a teacher step our masks would forbid, e.g. a zero-reward
    set, still gets a finite loss).

    Args:
        model: the network.
        instance: batch of B instances (N nodes, K sets).
        teacher_nodes: [B, T] int32, T = K + 1: start first, then visited nodes, -1 padding.
        features: precomputed :func:`node_features` (e.g. a coordinate symmetry).
    """
    b, t = teacher_nodes.shape
    n, k = instance.set_id.shape[-1], instance.set_reward.shape[-1]
    if t != plan_length(k):
        raise ValueError(f"teacher_nodes must have T = K + 1 = {plan_length(k)} slots, got {t}")
    features = _features(instance, features)
    cache = model.prepare(features, instance.start)

    safe_last, valid, visited, travelled = prefix_states(instance, teacher_nodes)  # [B, S]
    nxt = teacher_nodes[:, 1:]
    target = jnp.where(nxt >= 0, nxt, n).astype(jnp.int32)
    allowed = next_mask(instance, visited, safe_last, travelled, model.config.budget_mask)
    allowed = allowed | jax.nn.one_hot(target, n + 1, dtype=bool)

    budget_left = None
    if model.config.budget_aware:
        budget_left = normalised_budget(
            instance.budget[:, None] - travelled, features.cost_scale[:, None]
        )

    step = None
    if model.config.step_features:
        step = step_features(instance, features, safe_last, travelled)
    scores = model.decoder(cache, safe_last, allowed, budget_left, step)
    return TeacherForcing(
        log_probs=jax.nn.log_softmax(scores, axis=-1), target=target, valid=valid, allowed=allowed
    )


def decode(
    model: StrategicTransformer,
    instance: SOPInstance,
    key: jax.Array | None = None,
    temperature: float | jax.Array = 1.0,
    greedy: jax.Array | bool = True,
    features: NodeFeatures | None = None,
    cache: DecoderCache | None = None,
    first_set: jax.Array | None = None,
) -> DecodeTrace:
    """Decode plans step by step (``lax.scan`` over S = K steps, vectorised over B).

    Args:
        model: the network.
        instance: batch of B instances.
        key: PRNG key for sampling (needed unless every row is greedy).
        temperature: softmax temperature of sampled rows.
        greedy: bool or [B] bool, rows that take the arg-max instead of sampling.
        features: precomputed :func:`node_features` (e.g. a coordinate symmetry).
        cache: precomputed ``model.prepare(features, instance.start)``, to decode one
            encoding several times (then ``features`` is only used for the step
            features; their costs and rewards do not depend on the coordinate symmetry).
        first_set: [B] int32, multi-start decoding (POMO-style): row ``i`` makes its first
            move into set ``first_set[i]`` (its best-scored allowed node there); ``-1``, or
            a set with no allowed node, leaves the first move free.

    Returns:
        A :class:`DecodeTrace`; the plan is [start, chosen nodes..., (end node when the
        instance has one)] padded with -1, reward and cost from :func:`plan_value`.
    """
    b, n = instance.set_id.shape
    k = instance.set_reward.shape[-1]
    steps = plan_length(k) - 1
    uses_step = model.config.step_features
    if cache is None or uses_step:
        features = _features(instance, features)
    if cache is None:
        cache = model.prepare(features, instance.start)
    greedy = jnp.broadcast_to(jnp.asarray(greedy, bool), (b,))
    if key is None:
        key = jax.random.key(0)  # unused by greedy rows; keeps one code path
    keys = jax.random.split(key, steps)
    if first_set is None:
        first_only = jnp.ones((b, n + 1), bool)
    else:  # the first move's extra mask: nodes of the row's set (END too, see below)
        first_set = jnp.broadcast_to(jnp.asarray(first_set, jnp.int32), (b,))
        in_set = (instance.set_id == first_set[:, None]) & (first_set[:, None] >= 0)
        first_only = jnp.concatenate([in_set, jnp.zeros((b, 1), bool)], axis=-1)

    def step(carry, inputs):
        step_key, index = inputs
        last, visited, done, travelled = carry
        allowed = next_mask(  # [B, 1, N+1]
            instance, visited[:, None], last[:, None], travelled[:, None], model.config.budget_mask
        )
        if first_set is not None:  # restrict the first move where the set has a choice
            forced = allowed[:, 0] & first_only
            use = (index == 0) & jnp.any(forced, axis=-1, keepdims=True)
            allowed = jnp.where(use, forced, allowed[:, 0])[:, None]
        budget_left = None
        if model.config.budget_aware:
            budget_left = normalised_budget(instance.budget - travelled, cache.cost_scale)
            budget_left = budget_left[:, None]
        step_in = None
        if uses_step:
            step_in = step_features(instance, features, last[:, None], travelled[:, None])
        scores = model.decoder(cache, last[:, None], allowed, budget_left, step_in)[:, 0]
        sampled = jax.random.categorical(step_key, scores / temperature, axis=-1)
        choice = jnp.where(greedy, jnp.argmax(scores, axis=-1), sampled)
        stop = done | (choice == n)
        node = jnp.where(stop, -1, choice).astype(jnp.int32)
        new_last, visited, travelled = advance(instance, last, visited, travelled, node, stop)
        probs = jnp.where(done[:, None], 0.0, jax.nn.softmax(scores, axis=-1))
        return (new_last, visited, stop, travelled), (node, probs, allowed[:, 0])

    carry0 = (
        instance.start.astype(jnp.int32),
        blocked_sets(instance),
        jnp.zeros((b,), bool),
        jnp.zeros((b,), jnp.float32),
    )
    _, (chosen, probs, allowed) = jax.lax.scan(step, carry0, (keys, jnp.arange(steps)))
    nodes = jnp.concatenate([instance.start[:, None], chosen.T], axis=1).astype(jnp.int32)
    nodes = close_plan(instance, nodes)  # a closed tour or fixed goal ends at its end node
    reward, cost = plan_value(instance, nodes)
    return DecodeTrace(
        solution=Solution(nodes=nodes, reward=reward, cost=cost),
        probs=jnp.swapaxes(probs, 0, 1),
        allowed=jnp.swapaxes(allowed, 0, 1),
    )


def greedy_decode(
    model: StrategicTransformer, instance: SOPInstance, features: NodeFeatures | None = None
) -> Solution:
    """Greedy (arg-max) plans of a batch: Solution with nodes [B, T], reward [B], cost [B]."""
    return decode(model, instance, greedy=True, features=features).solution


def sample_decode(
    model: StrategicTransformer,
    instance: SOPInstance,
    key: jax.Array,
    temperature: float = 1.0,
    features: NodeFeatures | None = None,
) -> Solution:
    """Plans sampled from the decoder's distribution (softmax of scores / temperature)."""
    return decode(model, instance, key, temperature, greedy=False, features=features).solution
