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

from bfsop_jax import ops
from bfsop_jax.model.features import (
    NodeFeatures,
    insertion_step_features,
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
    insertion_mask,
    next_mask,
    plan_value,
    prefix_states,
)
from bfsop_jax.sop.two_opt import insert_after, insertion_costs, plan_route, refine_route
from bfsop_jax.sop.types import Solution, SOPInstance, plan_length

__all__ = [
    "DecodeTrace",
    "TeacherForcing",
    "allowed_next",  # re-exported from bfsop_jax.sop.rules
    "decode",
    "first_sets",
    "forced_logits",
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
    # [B, S, N+1] bool, insertion decoder: every entry that is right (any teacher node not
    # in the plan yet, END once all are); None: only ``target`` is
    targets: Any = None


@struct.dataclass
class DecodeTrace:
    """A decoded plan with the decoder's distribution at every step."""

    solution: Solution  # nodes [B, T], reward [B], cost [B]
    probs: Any  # [B, S, N+1] float32: next-entry probabilities at each step (0 after END)
    allowed: Any  # [B, S, N+1] bool: the mask of each step
    choices: Any = None  # [B, S] int32: the node chosen at each step, -1 for END and after


def _features(instance: SOPInstance, features: NodeFeatures | None) -> NodeFeatures:
    return node_features(instance) if features is None else features


def teacher_forced_logits(
    model: StrategicTransformer,
    instance: SOPInstance,
    teacher_nodes: jax.Array,
    features: NodeFeatures | None = None,
    order_key: jax.Array | None = None,
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
        order_key: insertion decoder only: the PRNG key of the random order in which the
            teacher's nodes enter the plan (default ``key(0)``, fixed, e.g. for validation).

    With the insertion decoder (``model.config.decoder == "insertion"``) the states are
    not the teacher's prefixes: the teacher's visited nodes enter the plan in a random
    order, each state's plan is the nodes in so far in the teacher's order, and every
    teacher node not yet in is a right answer (``TeacherForcing.targets``; END once all
    are in).
    """
    b, t = teacher_nodes.shape
    n, k = instance.set_id.shape[-1], instance.set_reward.shape[-1]
    if t != plan_length(k):
        raise ValueError(f"teacher_nodes must have T = K + 1 = {plan_length(k)} slots, got {t}")
    features = _features(instance, features)
    cache = model.prepare(features, instance.start)
    if model.config.decoder == "insertion":
        key = jax.random.key(0) if order_key is None else order_key
        return _insertion_teacher_forcing(model, instance, teacher_nodes, features, cache, key)

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


def _budget_left(model, instance, travelled, cost_scale):
    if not model.config.budget_aware:
        return None
    return normalised_budget(instance.budget[:, None] - travelled, cost_scale[:, None])


def _insertion_teacher_forcing(
    model: StrategicTransformer,
    instance: SOPInstance,
    teacher_nodes: jax.Array,
    features: NodeFeatures,
    cache: DecoderCache,
    key: jax.Array,
) -> TeacherForcing:
    """Teacher forcing of the insertion decoder (see :func:`teacher_forced_logits`)."""
    b, t = teacher_nodes.shape
    n, k = instance.set_id.shape[-1], instance.set_reward.shape[-1]
    teacher_nodes = jnp.asarray(teacher_nodes)
    pos = jnp.arange(t)
    end = instance.end
    has_end = end >= 0
    is_end = has_end[:, None] & (teacher_nodes == end[:, None]) & (pos > 0)
    visit = (teacher_nodes >= 0) & (pos > 0) & ~is_end  # [B, T] the teacher's set visits
    m_full = jnp.sum(visit, axis=-1)  # [B]
    # random order of entry: visits get ranks 0..m-1, the rest come after
    u = jnp.where(visit, jax.random.uniform(key, (b, t)), 2.0 + pos)
    rank = jnp.argsort(jnp.argsort(u, axis=-1), axis=-1)
    s = jnp.arange(t - 1)[None, :, None]  # state s: the first s nodes of the order are in
    included = (pos == 0) | (visit[:, None] & (rank[:, None] < s))  # [B, S, T]
    count = jnp.sum(included, axis=-1)  # [B, S] start + min(s, m) nodes
    idx = jnp.argsort(jnp.where(included, pos, t + pos), axis=-1)  # in-plan nodes first
    ordered = jnp.take_along_axis(jnp.broadcast_to(teacher_nodes[:, None], idx.shape), idx, -1)
    tail = jnp.where(has_end, end, n)[:, None, None]
    slot = jnp.arange(t + 1)
    ordered = jnp.pad(ordered, ((0, 0), (0, 0), (0, 1)), constant_values=n)
    route = jnp.where(
        slot < count[..., None], ordered, jnp.where(slot == count[..., None], tail, n)
    ).astype(jnp.int32)  # [B, S, T+1]
    m = count - 1
    delta, _, travelled = jax.vmap(jax.vmap(insertion_costs, in_axes=(None, 0, 0)))(
        instance, route, m
    )

    node_sets = jnp.take_along_axis(instance.set_id, jnp.clip(teacher_nodes, 0), axis=-1)
    sets_in = included[..., None] & (node_sets[:, None, :, None] == jnp.arange(k))
    visited = blocked_sets(instance)[:, None] | jnp.any(sets_in, axis=2)  # [B, S, K]
    last_pos = ops.argmax(visit[:, None] & (rank[:, None] == s - 1), axis=-1)  # [B, S]
    last = jnp.where(
        s[..., 0] == 0,
        instance.start[:, None],
        jnp.take_along_axis(teacher_nodes, last_pos, axis=1),
    )
    next_pos = ops.argmax(visit[:, None] & (rank[:, None] == s), axis=-1)
    at_end = s[..., 0] >= m_full[:, None]  # [B, S] every teacher node is in
    target = jnp.where(at_end, n, jnp.take_along_axis(teacher_nodes, next_pos, axis=1)).astype(
        jnp.int32
    )
    remaining = visit[:, None] & (rank[:, None] >= s)  # [B, S, T]
    hits = remaining[..., None] & (teacher_nodes[:, None, :, None] == jnp.arange(n))
    targets = jnp.concatenate([jnp.any(hits, axis=2), at_end[..., None]], axis=-1)
    valid = s[..., 0] <= m_full[:, None]

    scores, allowed = _score_insertion_states(
        model, instance, features, cache, visited, delta, travelled, last, lambda a: a | targets
    )
    return TeacherForcing(
        log_probs=jax.nn.log_softmax(scores, axis=-1),
        target=target,
        valid=valid,
        allowed=allowed,
        targets=targets & valid[..., None],
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
        first_only = None
    else:  # the first move's extra mask: nodes of the row's set (END too, see below)
        first_set = jnp.broadcast_to(jnp.asarray(first_set, jnp.int32), (b,))
        in_set = (instance.set_id == first_set[:, None]) & (first_set[:, None] >= 0)
        first_only = jnp.concatenate([in_set, jnp.zeros((b, 1), bool)], axis=-1)

    def restrict_first(allowed, index):
        """[B, N+1] mask of a step; the first move goes into ``first_set`` where it can."""
        if first_only is None:
            return allowed
        forced = allowed & first_only
        use = (index == 0) & jnp.any(forced, axis=-1, keepdims=True)
        return jnp.where(use, forced, allowed)

    def choose(scores, step_key, done):
        # jax.random.categorical's Gumbel-max draw, with the CPU-friendly arg-max
        noise = jax.random.gumbel(step_key, scores.shape, scores.dtype)
        sampled = ops.argmax(scores / temperature + noise, axis=-1)
        choice = jnp.where(greedy, ops.argmax(scores, axis=-1), sampled)
        stop = done | (choice == n)
        probs = jnp.where(done[:, None], 0.0, jax.nn.softmax(scores, axis=-1))
        return jnp.where(stop, -1, choice).astype(jnp.int32), stop, probs

    if model.config.decoder == "insertion":
        return _decode_insertion(
            model, instance, features, cache, keys, restrict_first, choose, steps
        )

    def step(carry, inputs):
        step_key, index = inputs
        last, visited, done, travelled = carry
        scores, allowed = _append_scores(
            model, instance, features, cache, carry, lambda a: restrict_first(a, index)
        )
        node, stop, probs = choose(scores, step_key, done)
        new_last, visited, travelled = advance(instance, last, visited, travelled, node, stop)
        return (new_last, visited, stop, travelled), (node, probs, allowed)

    carry0 = _append_start(instance)
    _, (chosen, probs, allowed) = jax.lax.scan(step, carry0, (keys, jnp.arange(steps)))
    nodes = jnp.concatenate([instance.start[:, None], chosen.T], axis=1).astype(jnp.int32)
    nodes = close_plan(instance, nodes)  # a closed tour or fixed goal ends at its end node
    reward, cost = plan_value(instance, nodes)
    return DecodeTrace(
        solution=Solution(nodes=nodes, reward=reward, cost=cost),
        probs=jnp.swapaxes(probs, 0, 1),
        allowed=jnp.swapaxes(allowed, 0, 1),
        choices=chosen.T,
    )


def _append_start(instance: SOPInstance):
    """Carry of an append decoding before its first step: last node [B], visited sets
    [B, K], done [B], travelled [B]."""
    b = instance.set_id.shape[0]
    return (
        instance.start.astype(jnp.int32),
        blocked_sets(instance),
        jnp.zeros((b,), bool),
        jnp.zeros((b,), jnp.float32),
    )


def _append_scores(model, instance, features, cache, carry, adjust):
    """The append decoder's scores [B, N+1] in one state, with its mask (``adjust`` edits
    the mask first)."""
    last, visited, _, travelled = carry
    allowed = next_mask(  # [B, 1, N+1]
        instance, visited[:, None], last[:, None], travelled[:, None], model.config.budget_mask
    )
    allowed = adjust(allowed[:, 0])
    budget_left = None
    if model.config.budget_aware:
        budget_left = normalised_budget(instance.budget - travelled, cache.cost_scale)[:, None]
    step_in = None
    if model.config.step_features:
        step_in = step_features(instance, features, last[:, None], travelled[:, None])
    scores = model.decoder(cache, last[:, None], allowed[:, None], budget_left, step_in)
    return scores[:, 0], allowed


def first_sets(
    model: StrategicTransformer,
    instance: SOPInstance,
    count: int,
    features: NodeFeatures | None = None,
    cache: DecoderCache | None = None,
) -> jax.Array:
    """The ``count`` sets the decoder scores highest for its first move, after the greedy
    choice's own set: the starts of a top-M multi-start decoding.

    A set's score is the best score of its allowed nodes in the first decoding state. The
    greedy rollout already starts in the arg-max's set, so that set is left out.

    Returns:
        [B, count] int32 set indices, best first; -1 where fewer sets have an allowed node
        (a free first move).
    """
    n = instance.set_id.shape[-1]
    k = instance.set_reward.shape[-1]
    features = _features(instance, features)
    if cache is None:
        cache = model.prepare(features, instance.start)
    if model.config.decoder == "insertion":
        carry = _insertion_start(instance, plan_length(k) - 1)
        scores, allowed, _ = _insertion_scores(
            model, instance, features, cache, carry, 0, lambda a, i: a
        )
    else:
        scores, allowed = _append_scores(
            model, instance, features, cache, _append_start(instance), lambda a: a
        )
    scores = jnp.where(allowed, scores, -jnp.inf)
    greedy = ops.argmax(scores, axis=-1)  # [B]
    set_id = jnp.asarray(instance.set_id)
    greedy_set = jnp.where(
        greedy < n, jnp.take_along_axis(set_id, jnp.clip(greedy, 0, n - 1)[:, None], 1)[:, 0], -1
    )
    member = set_id[:, :, None] == jnp.arange(k)  # [B, N, K]
    per_set = jnp.max(jnp.where(member, scores[:, :n, None], -jnp.inf), axis=1)  # [B, K]
    per_set = jnp.where(jnp.arange(k) == greedy_set[:, None], -jnp.inf, per_set)
    best, index = jax.lax.top_k(per_set, count)
    return jnp.where(jnp.isfinite(best), index, -1).astype(jnp.int32)


def _insertion_start(instance: SOPInstance, steps: int):
    """Carry of an insertion decoding before its first step: route [B, T+1], m [B],
    visited sets [B, K], done [B], last inserted node [B]."""
    b = instance.set_id.shape[0]
    empty = jnp.full((b, steps + 1), -1, jnp.int32).at[:, 0].set(instance.start)
    route, m = jax.vmap(plan_route)(instance, empty)  # start (and a closed tour's end)
    return route, m, blocked_sets(instance), jnp.zeros((b,), bool), jnp.asarray(instance.start)


def _insert(instance: SOPInstance, carry, after: jax.Array, node: jax.Array, stop: jax.Array,
            refine: bool = False):  # fmt: skip
    """Put ``node`` [B] into each route right after position ``after[node]`` (rows that
    stop keep theirs); with ``refine``, then improve the route
    (:func:`~bfsop_jax.sop.two_opt.refine_route`). Returns the next carry; its last node
    is the node of ``node``'s set on the route."""
    route, m, visited, _, last = carry
    j = jnp.clip(node, 0)
    p = jnp.take_along_axis(after, j[:, None], axis=1)
    grown = insert_after(route, p, j[:, None]).astype(jnp.int32)
    m = m + (~stop)
    set_id = jnp.asarray(instance.set_id)
    sets = jnp.take_along_axis(set_id, j[:, None], axis=1)[:, 0]
    if refine:
        grown = jax.vmap(refine_route)(instance, grown, m)
        on_route = jnp.take_along_axis(set_id, jnp.clip(grown, 0, set_id.shape[-1] - 1), axis=1)
        slot = jnp.arange(grown.shape[-1])
        here = (on_route == sets[:, None]) & (slot >= 1) & (slot <= m[:, None])
        j = jnp.take_along_axis(grown, ops.argmax(here, axis=1)[:, None], axis=1)[:, 0]
    route = jnp.where(stop[:, None], route, grown)
    visited = visited | (jax.nn.one_hot(sets, visited.shape[-1], dtype=bool) & ~stop[:, None])
    return route, m, visited, stop, jnp.where(stop, last, j)


def _score_insertion_states(model, instance, features, cache, visited, delta, travelled, last,
                            adjust):  # fmt: skip
    """Scores [B, S, N+1] and mask of S insertion states per instance (visited [B, S, K],
    delta [B, S, N], travelled and last [B, S]); ``adjust`` edits the mask first."""
    allowed = adjust(insertion_mask(instance, visited, delta, travelled, model.config.budget_mask))
    step = None
    if model.config.step_features:
        step = insertion_step_features(instance, features, delta, travelled)
    budget_left = _budget_left(model, instance, travelled, cache.cost_scale)
    scores = model.decoder(cache, last.astype(jnp.int32), allowed, budget_left, step)
    return scores, allowed


def _insertion_scores(model, instance, features, cache, carry, index, restrict_first):
    """The decoder's scores [B, N+1] in one insertion state, with its mask and moves."""
    route, m, visited, _, last = carry
    delta, after, travelled = jax.vmap(insertion_costs)(instance, route, m)  # [B, N]
    scores, allowed = _score_insertion_states(
        model, instance, features, cache, visited[:, None], delta[:, None], travelled[:, None],
        last[:, None], lambda a: restrict_first(a[:, 0], index)[:, None],
    )  # fmt: skip
    return scores[:, 0], allowed[:, 0], after


def _decode_insertion(model, instance, features, cache, keys, restrict_first, choose, steps):
    """:func:`decode` for the insertion decoder: each chosen node goes into the plan where
    it adds the least cost (``bfsop_jax.sop.two_opt.insertion_costs``)."""
    n = instance.set_id.shape[-1]
    t = steps + 1

    def step(carry, inputs):
        step_key, index = inputs
        scores, allowed, after = _insertion_scores(
            model, instance, features, cache, carry, index, restrict_first
        )
        node, stop, probs = choose(scores, step_key, carry[3])
        carry = _insert(instance, carry, after, node, stop, model.config.refine)
        return carry, (node, probs, allowed)

    carry0 = _insertion_start(instance, steps)
    (route, m, _, _, _), (chosen, probs, allowed) = jax.lax.scan(
        step, carry0, (keys, jnp.arange(steps))
    )
    slot = jnp.arange(t)
    keep = (slot <= m[:, None]) | ((slot == m[:, None] + 1) & (route[:, :t] < n))
    nodes = jnp.where(keep, route[:, :t], -1).astype(jnp.int32)
    reward, cost = plan_value(instance, nodes)
    return DecodeTrace(
        solution=Solution(nodes=nodes, reward=reward, cost=cost),
        probs=jnp.swapaxes(probs, 0, 1),
        allowed=jnp.swapaxes(allowed, 0, 1),
        choices=chosen.T,
    )


def forced_logits(
    model: StrategicTransformer,
    instance: SOPInstance,
    choices: jax.Array,
    features: NodeFeatures | None = None,
    teacher_nodes: jax.Array | None = None,
) -> TeacherForcing:
    """Decoder log-probabilities along a given sequence of choices (e.g. sampled plans'
    :attr:`DecodeTrace.choices`, for reward fine-tuning).

    Args:
        model: the network (either decoder).
        instance: batch of B instances.
        choices: [B, S] int32, the node chosen at each step, -1 for END and after.
        features: precomputed :func:`node_features` (e.g. a coordinate symmetry).
        teacher_nodes: insertion decoder only: [B, T] teacher plans (T = K + 1, start
            first, -1 padding) that label the states the choices lead to (the student's
            own states, DAgger-style): every teacher node the state's mask still allows is
            a right answer (``targets``); a state where none is (the plan has taken their
            sets or their budget) is not valid. None: the choices are the targets.

    Returns:
        :class:`TeacherForcing` with ``target`` the choice (N for END); a step is valid
        until and including the END. For the append decoder this is
        :func:`teacher_forced_logits` of the plan; the insertion decoder replays the
        insertions (no network) and scores every state in one pass.
    """
    b, steps = choices.shape
    n = instance.set_id.shape[-1]
    choices = jnp.asarray(choices, jnp.int32)
    if teacher_nodes is not None and model.config.decoder != "insertion":
        raise ValueError("forced_logits: teacher_nodes labels need the insertion decoder")
    if model.config.decoder == "append":
        nodes = jnp.concatenate([jnp.asarray(instance.start)[:, None], choices], axis=1)
        return teacher_forced_logits(model, instance, nodes, features)
    features = _features(instance, features)
    cache = model.prepare(features, instance.start)

    def replay(carry, node):
        delta, after, travelled = jax.vmap(insertion_costs)(instance, carry[0], carry[1])
        stop = carry[3] | (node < 0)
        state = (carry[2], delta, travelled, carry[4], carry[3])
        return _insert(instance, carry, after, node, stop, model.config.refine), state

    _, states = jax.lax.scan(replay, _insertion_start(instance, steps), choices.T)
    visited, delta, travelled, last, done = (jnp.swapaxes(x, 0, 1) for x in states)
    target = jnp.where(choices >= 0, choices, n).astype(jnp.int32)
    chosen = jax.nn.one_hot(target, n + 1, dtype=bool)
    scores, allowed = _score_insertion_states(
        model, instance, features, cache, visited, delta, travelled, last,
        (lambda a: a | chosen) if teacher_nodes is None else (lambda a: a),
    )  # fmt: skip
    tf = TeacherForcing(
        log_probs=jax.nn.log_softmax(scores, axis=-1), target=target, valid=~done,
        allowed=allowed,
    )  # fmt: skip
    if teacher_nodes is None:
        return tf
    targets = allowed & _teacher_members(instance, teacher_nodes)[:, None]  # [B, S, N+1]
    valid = ~done & jnp.any(targets, axis=-1)
    return tf.replace(valid=valid, targets=targets & valid[..., None])


def _teacher_members(instance: SOPInstance, teacher_nodes: jax.Array) -> jax.Array:
    """[B, N+1] bool: the nodes a teacher plan visits for a set (not its start or the end
    node of a closed tour); END (index N) is never one."""
    n = instance.set_id.shape[-1]
    pos = jnp.arange(teacher_nodes.shape[-1])
    visit = (teacher_nodes >= 0) & (pos > 0) & (teacher_nodes != instance.end[:, None])
    hits = visit[..., None] & (teacher_nodes[..., None] == jnp.arange(n + 1))
    return jnp.any(hits, axis=1)


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
