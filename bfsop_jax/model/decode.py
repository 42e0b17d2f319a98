"""SOP decoding with the Strategic Transformer: masks, teacher forcing, greedy and sampling.

The SOP rules live here, not in the network. At every step the next entry may be

* a node that is not padding (``set_id >= 0``), whose set is not visited yet, that is not
  in the start set (nor in the end node's set for a closed tour or fixed goal), and that is
  reachable from the last node (finite cost);
* END (index ``N``), always: it stops the plan.

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

from bfsop_jax.model.features import NodeFeatures, node_features, normalised_budget
from bfsop_jax.model.transformer import DecoderCache, StrategicTransformer
from bfsop_jax.sop.types import Solution, SOPInstance, plan_length

__all__ = [
    "DecodeTrace",
    "TeacherForcing",
    "allowed_next",
    "decode",
    "greedy_decode",
    "plan_value",
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


def _blocked_sets(instance: SOPInstance) -> jax.Array:
    """[B, K] bool: sets that are never rewarding choices (start set, end node's set)."""
    k = instance.set_reward.shape[-1]
    sets = jnp.arange(k)
    start_set = jnp.take_along_axis(instance.set_id, instance.start[:, None], axis=1)
    end_node = jnp.clip(instance.end, 0)[:, None]
    end_set = jnp.where(
        instance.end[:, None] >= 0, jnp.take_along_axis(instance.set_id, end_node, axis=1), -2
    )
    return (sets[None] == start_set) | (sets[None] == end_set)


def allowed_next(instance: SOPInstance, visited_sets: jax.Array, last: jax.Array) -> jax.Array:
    """Mask of the next entry for S states per instance.

    Args:
        instance: batch of B instances.
        visited_sets: [B, S, K] bool, sets already used (blocked sets included).
        last: [B, S] int32, the last node of each state.

    Returns:
        [B, S, N+1] bool: allowed nodes, and END (always True) at index N.
    """
    set_id = instance.set_id  # [B, N]
    node_set_used = jnp.take_along_axis(
        visited_sets,
        jnp.broadcast_to(jnp.clip(set_id, 0)[:, None], last.shape + set_id.shape[-1:]),
        axis=2,
    )  # [B, S, N]
    reachable = jnp.isfinite(jnp.take_along_axis(instance.cost, last[..., None], axis=1))
    nodes = (set_id[:, None] >= 0) & ~node_set_used & reachable
    return jnp.concatenate([nodes, jnp.ones(last.shape + (1,), bool)], axis=-1)


def fits_budget(
    instance: SOPInstance, allowed: jax.Array, last: jax.Array, travelled: jax.Array
) -> jax.Array:
    """The budget rule of ``ModelConfig.budget_mask`` applied to a mask from
    :func:`allowed_next`: a node stays allowed only if going there (and on to the end node
    of a closed tour or goal path) keeps the plan within the budget; END is allowed only
    when no node is.

    Args:
        instance: batch of B instances.
        allowed: [B, S, N+1] mask (END at index N).
        last: [B, S] int32 last node of each state.
        travelled: [B, S] cost of each state's plan so far.
    """
    n = instance.set_id.shape[-1]
    step = jnp.take_along_axis(instance.cost, last[..., None], axis=1)  # [B, S, N]
    end = jnp.clip(instance.end, 0)
    to_end = jax.vmap(lambda c, e: c[:, e])(instance.cost, end)  # [B, N]: node -> end
    to_end = jnp.where(instance.end[:, None] >= 0, to_end, 0.0)
    left = instance.budget[:, None, None] - travelled[..., None]
    tol = 1e-5 * jnp.maximum(1.0, instance.budget)[:, None, None]
    nodes = allowed[..., :n] & (step + to_end[:, None, :] <= left + tol)
    end_ok = ~jnp.any(nodes, axis=-1, keepdims=True)
    return jnp.concatenate([nodes, end_ok], axis=-1)


def plan_value(instance: SOPInstance, nodes: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Reward and cost of padded plans, exactly from the instance (JAX).

    Args:
        instance: batch of B instances.
        nodes: [B, T] int32 plans (start first, -1 padding at the end).

    Returns:
        reward [B] (sum of the set rewards of the nodes after the start, the start and end
        sets being zero-reward) and cost [B] (float32 sum of the edge costs along the plan).
    """
    valid = nodes >= 0
    safe = jnp.clip(nodes, 0)
    sets = jnp.take_along_axis(instance.set_id, safe, axis=1)
    rewards = jnp.take_along_axis(instance.set_reward, jnp.clip(sets, 0), axis=1)
    first = jnp.arange(nodes.shape[1])[None] == 0
    reward = jnp.sum(jnp.where(valid & ~first & (sets >= 0), rewards, 0.0), axis=1)
    edge = jax.vmap(lambda c, a, b: c[a, b])(instance.cost, safe[:, :-1], safe[:, 1:])
    cost = jnp.sum(jnp.where(valid[:, :-1] & valid[:, 1:], edge, 0.0), axis=1)
    return reward.astype(jnp.float32), cost.astype(jnp.float32)


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

    last = teacher_nodes[:, :-1]  # [B, S]
    nxt = teacher_nodes[:, 1:]
    valid = last >= 0
    target = jnp.where(nxt >= 0, nxt, n).astype(jnp.int32)
    safe_last = jnp.clip(last, 0)

    sets = jnp.take_along_axis(instance.set_id, safe_last, axis=1)  # [B, S]
    used = jax.nn.one_hot(jnp.where(valid & (sets >= 0), sets, k), k + 1, dtype=bool)[..., :k]
    visited = jnp.cumsum(used, axis=1) > 0  # sets of teacher_nodes[:, :s+1]
    visited = visited | _blocked_sets(instance)[:, None]
    allowed = allowed_next(instance, visited, safe_last)
    edge = jax.vmap(lambda c, a, b: c[a, b])(instance.cost, safe_last, jnp.clip(nxt, 0))
    edge = jnp.where(valid & (nxt >= 0), edge, 0.0)
    travelled = jnp.cumsum(edge, axis=1) - edge  # cost of the prefix up to step s
    if model.config.budget_mask:
        allowed = fits_budget(instance, allowed, safe_last, travelled)
    allowed = allowed | jax.nn.one_hot(target, n + 1, dtype=bool)

    budget_left = None
    if model.config.budget_aware:
        budget_left = normalised_budget(
            instance.budget[:, None] - travelled, features.cost_scale[:, None]
        )

    scores = model.decoder(cache, safe_last, allowed, budget_left)
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
            encoding several times (then ``features`` is not used).

    Returns:
        A :class:`DecodeTrace`; the plan is [start, chosen nodes..., (end node when the
        instance has one)] padded with -1, reward and cost from :func:`plan_value`.
    """
    b, n = instance.set_id.shape
    k = instance.set_reward.shape[-1]
    steps = plan_length(k) - 1
    if cache is None:
        cache = model.prepare(_features(instance, features), instance.start)
    greedy = jnp.broadcast_to(jnp.asarray(greedy, bool), (b,))
    if key is None:
        key = jax.random.key(0)  # unused by greedy rows; keeps one code path
    keys = jax.random.split(key, steps)
    rows = jnp.arange(b)

    def step(carry, step_key):
        last, visited, done, travelled = carry
        allowed = allowed_next(instance, visited[:, None], last[:, None])  # [B, 1, N+1]
        if model.config.budget_mask:
            allowed = fits_budget(instance, allowed, last[:, None], travelled[:, None])
        budget_left = None
        if model.config.budget_aware:
            budget_left = normalised_budget(instance.budget - travelled, cache.cost_scale)
            budget_left = budget_left[:, None]
        scores = model.decoder(cache, last[:, None], allowed, budget_left)[:, 0]
        sampled = jax.random.categorical(step_key, scores / temperature, axis=-1)
        choice = jnp.where(greedy, jnp.argmax(scores, axis=-1), sampled)
        stop = done | (choice == n)
        node = jnp.where(stop, -1, choice).astype(jnp.int32)
        safe = jnp.clip(node, 0)
        node_set = instance.set_id[rows, safe]
        visited = visited | (jax.nn.one_hot(node_set, k, dtype=bool) & ~stop[:, None])
        travelled = travelled + jnp.where(stop, 0.0, instance.cost[rows, last, safe])
        probs = jnp.where(done[:, None], 0.0, jax.nn.softmax(scores, axis=-1))
        new_last = jnp.where(stop, last, node)
        return (new_last, visited, stop, travelled), (node, probs, allowed[:, 0])

    carry0 = (
        instance.start.astype(jnp.int32),
        _blocked_sets(instance),
        jnp.zeros((b,), bool),
        jnp.zeros((b,), jnp.float32),
    )
    _, (chosen, probs, allowed) = jax.lax.scan(step, carry0, keys)
    nodes = jnp.concatenate([instance.start[:, None], chosen.T], axis=1).astype(jnp.int32)
    # a closed tour or fixed goal ends at its end node, in the first free slot
    count = jnp.sum(nodes >= 0, axis=1)
    slot = jnp.arange(nodes.shape[1])[None] == count[:, None]
    nodes = jnp.where(slot & (instance.end[:, None] >= 0), instance.end[:, None], nodes)
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
