"""The insertion decoder: feasible maximal plans, nearest insertion by hand-set weights,
teacher forcing on random orders of entry, the any-of-the-teacher's-nodes loss, training."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from bfsop_jax.model import ModelConfig, StrategicTransformer, decode, teacher_forced_logits
from bfsop_jax.model.decode import TeacherForcing, forced_logits
from bfsop_jax.sop import evaluate, solve_vns
from bfsop_jax.sop.io import random_instance
from bfsop_jax.training import TrainConfig, dataset_from_instances, instances_from_dataset
from bfsop_jax.training.bc import init_states, make_evaluate, make_train_epoch
from bfsop_jax.training.metrics import imitation_stats

INSERT = ModelConfig(
    d_model=32, n_layers=2, n_heads=2, d_ff=64, budget_mask=True, step_features=True,
    decoder="insertion",
)  # fmt: skip
SETS, VIEWPOINTS = 6, 3  # N = 19 nodes, K = 7 sets, T = 8 plan slots


def stack(instances):
    return jax.tree_util.tree_map(lambda *x: jnp.stack([jnp.asarray(v) for v in x]), *instances)


def instances(closed: bool, seeds=range(8)):
    return [
        random_instance(s, num_sets=SETS, viewpoints=VIEWPOINTS, masked_sets=s % 3, closed=closed)
        for s in seeds
    ]


def untrained(config: ModelConfig, seed: int) -> StrategicTransformer:
    """Random weights everywhere, the zero-initialised layers included."""
    model = StrategicTransformer(config, rngs=nnx.Rngs(seed))
    for layer in (model.decoder.project_glimpse, model.decoder.step_out):
        k = layer.kernel
        k[...] = jax.random.normal(jax.random.key(seed), k.shape) / np.sqrt(k.shape[0])
    return model


def run(model, inst, key=None, greedy=True):
    g, p = nnx.split(model, nnx.Param)
    fn = jax.jit(lambda p, i, k: decode(nnx.merge(g, p), i, k, 1.0, greedy))
    return fn(p, inst, jax.random.key(0) if key is None else key)


@pytest.mark.parametrize("closed,refine", [(False, False), (True, False), (False, True),
                                           (True, True)])  # fmt: skip
def test_insertion_plans_are_feasible_and_maximal(closed, refine):
    """Greedy and sampled insertion plans start at the start, visit each set once, end at a
    closed tour's end node, fit the budget without the gate, and stop only when no node
    fits; the plan's cost is the cost the decoder tracked. The same with the route
    improved after every insertion (``refine``)."""
    batch = stack(instances(closed))
    tight = batch.replace(budget=batch.budget * 0.6)
    model = untrained(dataclasses.replace(INSERT, refine=refine), 1)
    for seed, greedy in ((0, True), (1, False)):
        trace = run(model, tight, jax.random.key(seed), greedy)
        nodes = np.asarray(trace.solution.nodes)
        allowed = np.asarray(trace.allowed)
        for i in range(nodes.shape[0]):
            inst = jax.tree_util.tree_map(lambda x, i=i: np.asarray(x)[i], tight)
            real = nodes[i][nodes[i] >= 0]
            assert real[0] == int(inst.start)
            assert (nodes[i][len(real) :] == -1).all()
            if closed:
                assert real[-1] == int(inst.end)
            visited = real[1 : len(real) - int(closed)]
            sets = inst.set_id[visited].tolist()
            assert len(set(sets)) == len(sets) and int(inst.set_id[inst.start]) not in sets
            reward, cost, feasible = evaluate(inst, nodes[i])
            assert feasible and cost <= float(inst.budget) + 1e-3
            np.testing.assert_allclose(float(trace.solution.cost[i]), cost, rtol=1e-5)
            m = len(real) - 1 - int(closed)
            for t in range(m + 1):
                assert allowed[i, t, -1] == (not allowed[i, t, :-1].any())
        assert ((nodes >= 0).sum(1) > 1 + int(closed)).mean() > 0.5  # most plans visit sets


def _nearest_insertion(inst) -> list[int]:
    """NumPy reference: insert the open node of least added cost, where it adds least,
    while it fits the budget (one node per set)."""
    cost = np.asarray(inst.cost, np.float64)
    set_id = np.asarray(inst.set_id)
    route = [int(inst.start)]
    closed = int(inst.end) >= 0
    if closed:
        route.append(int(inst.end))
    used = {int(set_id[inst.start])} | ({int(set_id[inst.end])} if closed else set())
    length = sum(cost[a, b] for a, b in zip(route[:-1], route[1:], strict=True))
    while True:
        best = None
        for j in range(len(set_id)):
            if set_id[j] < 0 or int(set_id[j]) in used:
                continue
            for p in range(len(route)):
                if p + 1 < len(route):
                    a, b = route[p], route[p + 1]
                    d = cost[a, j] + cost[j, b] - cost[a, b]
                elif not closed:
                    d = cost[route[p], j]
                else:
                    continue
                if length + d <= float(inst.budget) + 1e-6 and (best is None or d < best[0]):
                    best = (d, j, p)
        if best is None:
            return route
        d, j, p = best
        route.insert(p + 1, j)
        used.add(int(set_id[j]))
        length += d


@pytest.mark.parametrize("closed", [False, True])
def test_hand_set_scores_give_nearest_insertion(closed):
    """With the pointer silent and the step MLP scoring ``10 - added cost``, greedy decoding
    is nearest insertion: the decoder's bookkeeping (positions, costs, masks) is checked
    against a NumPy reference."""
    model = StrategicTransformer(INSERT, rngs=nnx.Rngs(0))  # pointer scores start at 0
    hidden_in, out = model.decoder.step_in, model.decoder.step_out
    w = np.zeros(hidden_in.kernel.shape, np.float32)
    w[0, 0] = -1.0  # feature 0: added cost / largest cost
    hidden_in.kernel[...] = w
    bias = np.zeros(hidden_in.bias.shape, np.float32)
    bias[0] = 10.0  # hidden unit 0 = relu(10 - added cost) = 10 - added cost
    hidden_in.bias[...] = bias
    out.kernel[...] = np.eye(out.kernel.shape[0], 1, dtype=np.float32)
    insts = instances(closed, range(20, 28))
    trace = run(model, stack(insts))
    nodes = np.asarray(trace.solution.nodes)
    for i, inst in enumerate(insts):
        want = _nearest_insertion(inst)
        got = nodes[i][nodes[i] >= 0].tolist()
        assert got == want, (i, got, want)


@pytest.mark.parametrize("closed,refine", [(False, False), (True, True)])
def test_forced_logits_replay_the_decoding(closed, refine):
    """Scoring a model's own sampled choices replays its states: the same step
    distributions as while decoding, the same number of steps (the END included), with
    or without the route improvement."""
    batch = stack(instances(closed))
    model = untrained(dataclasses.replace(INSERT, refine=refine), 4)
    trace = run(model, batch, jax.random.key(2), greedy=False)
    tf = forced_logits(model, batch, trace.choices)
    choices = np.asarray(trace.choices)
    valid = np.asarray(tf.valid)
    stopped = (choices < 0).any(axis=1)
    steps = (choices >= 0).sum(axis=1) + stopped  # the END step counts when it was taken
    np.testing.assert_array_equal(valid.sum(1), steps)
    probs = np.exp(np.asarray(tf.log_probs))
    np.testing.assert_allclose(probs[valid], np.asarray(trace.probs)[valid], atol=1e-5)


@pytest.fixture(scope="module")
def labelled() -> dict[str, np.ndarray]:
    insts = instances(False, range(16))
    sols = [solve_vns(i, seed=0, max_iters=100, max_no_improve=50) for i in insts]
    return dataset_from_instances(insts, sols)


@pytest.fixture(scope="module")
def teacher(labelled):
    return instances_from_dataset(labelled), jnp.asarray(labelled["teacher_nodes"])


def test_teacher_forcing_states(teacher):
    """States follow a random order of entry: m + 1 valid steps, the right answers are the
    teacher's nodes not yet in (then END), all allowed, and the order depends on the key
    only."""
    inst, nodes = teacher
    model = untrained(INSERT, 2)
    tf = teacher_forced_logits(model, inst, nodes, order_key=jax.random.key(5))
    again = teacher_forced_logits(model, inst, nodes, order_key=jax.random.key(5))
    other = teacher_forced_logits(model, inst, nodes, order_key=jax.random.key(6))
    np.testing.assert_array_equal(np.asarray(tf.target), np.asarray(again.target))
    assert (np.asarray(tf.target) != np.asarray(other.target)).any()
    targets, valid = np.asarray(tf.targets), np.asarray(tf.valid)
    allowed, target = np.asarray(tf.allowed), np.asarray(tf.target)
    n = inst.set_id.shape[-1]
    for i in range(nodes.shape[0]):
        visits = [int(x) for x in np.asarray(nodes[i])[1:] if x >= 0]
        m = len(visits)
        assert valid[i].sum() == m + 1
        for s in range(m + 1):
            right = set(np.flatnonzero(targets[i, s, :n]).tolist())
            assert right <= set(visits) and len(right) == m - s
            assert targets[i, s, n] == (s == m)
            assert allowed[i, s][targets[i, s]].all()
            assert targets[i, s, target[i, s]]
        # the order of entry visits every teacher node once
        assert sorted(target[i, :m].tolist()) == sorted(visits)
    assert np.isfinite(np.asarray(imitation_stats(tf))).all()


def test_any_of_the_right_answers_loss():
    """With several right entries the likelihood is their summed probability, and an
    arg-max is right when it is any of them."""
    probs = np.array([[[0.5, 0.2, 0.2, 0.1], [0.1, 0.1, 0.7, 0.1]]], np.float32)
    targets = np.array([[[False, True, True, False], [True, False, False, False]]])
    tf = TeacherForcing(
        log_probs=jnp.log(probs), target=jnp.array([[1, 0]]), valid=jnp.array([[True, True]]),
        targets=jnp.asarray(targets),
    )  # fmt: skip
    nll, correct, steps = np.asarray(imitation_stats(tf))
    np.testing.assert_allclose(nll, -np.log(0.4) - np.log(0.1), rtol=1e-5)
    assert correct == 0 and steps == 2
    tf = tf.replace(targets=jnp.asarray(~targets))
    nll, correct, _ = np.asarray(imitation_stats(tf))
    np.testing.assert_allclose(nll, -np.log(0.6) - np.log(0.9), rtol=1e-5)
    assert correct == 2


def test_insertion_decoder_trains(labelled):
    """Behaviour cloning of the insertion decoder: the loss falls and the validation loss
    (a fixed order of entry) is deterministic."""
    data = {k: jnp.asarray(v) for k, v in labelled.items()}
    recipe = TrainConfig(epochs=4, batch_size=8, decay_every=2)
    graphdef, states = init_states(INSERT, recipe, seeds=[0], lrs=[3e-3])
    epoch = make_train_epoch(graphdef, recipe, 16)
    evaluate_fn = make_evaluate(graphdef, 8, 16)
    before = np.asarray(evaluate_fn(states.params, data))[0]
    keys = jnp.stack([jax.random.key(0)])
    for _ in range(6):
        states, _ = epoch(states, data, keys)
    after = np.asarray(evaluate_fn(states.params, data))[0]
    np.testing.assert_array_equal(after, np.asarray(evaluate_fn(states.params, data))[0])
    assert after[0] / after[2] < before[0] / before[2] - 0.2


def test_student_states_are_labelled_by_the_teacher(teacher):
    """Along a student's own choices, the right answers of a state are the teacher's nodes
    that state still allows; a state that allows none (its plan took their sets or budget)
    does not count, and the states are those of the decoding."""
    inst, nodes = teacher
    model = untrained(INSERT, 3)
    trace = run(model, inst, jax.random.key(1), greedy=False)
    tf = forced_logits(model, inst, trace.choices, teacher_nodes=nodes)
    plain = forced_logits(model, inst, trace.choices)
    n = inst.set_id.shape[-1]
    targets, valid, allowed = (np.asarray(x) for x in (tf.targets, tf.valid, tf.allowed))
    choices = np.asarray(trace.choices)
    for i in range(nodes.shape[0]):
        visits = {int(x) for x in np.asarray(nodes[i])[1:] if x >= 0}
        taken: set[int] = set()
        for s in range(choices.shape[1]):
            live = bool(np.asarray(plain.valid)[i, s])
            want = {j for j in visits if allowed[i, s, j]} if live else set()
            assert set(np.flatnonzero(targets[i, s]).tolist()) == want
            assert valid[i, s] == bool(want) and not targets[i, s, n]
            assert not want & taken
            if choices[i, s] >= 0:
                taken.add(int(choices[i, s]))
    # the student's states are the decoding's: same distributions where they count
    probs = np.exp(np.asarray(tf.log_probs))[valid]
    np.testing.assert_allclose(probs, np.asarray(trace.probs)[valid], atol=1e-5)
    assert valid.any() and np.isfinite(np.asarray(imitation_stats(tf))).all()
    append = dataclasses.replace(INSERT, decoder="append")
    with pytest.raises(ValueError, match="insertion decoder"):
        forced_logits(untrained(append, 0), inst, trace.choices, teacher_nodes=nodes)


def test_on_policy_training(labelled):
    """Training with the student's own states (on_policy > 0) compiles that term in, and
    lowers both the teacher-state loss and the loss on the student's greedy states; the
    append decoder is refused."""
    from bfsop_jax.training import RunConfig, train
    from bfsop_jax.training.bc import _student_forcing

    data = {k: jnp.asarray(v) for k, v in labelled.items()}
    recipe = TrainConfig(epochs=4, batch_size=8, decay_every=2, on_policy=1.0)
    graphdef, states = init_states(INSERT, recipe, seeds=[0], lrs=[3e-3])
    epoch = make_train_epoch(graphdef, recipe, 16)
    evaluate_fn = make_evaluate(graphdef, 8, 16)

    def own_loss(params):
        params = jax.tree_util.tree_map(lambda x: x[0], params)
        stats = imitation_stats(_student_forcing(graphdef, params, data, None, jax.random.key(3)))
        return float(stats[0] / stats[2])

    before = np.asarray(evaluate_fn(states.params, data))[0]
    own_before = own_loss(states.params)
    keys = jnp.stack([jax.random.key(0)])
    for _ in range(10):
        states, _ = epoch(states, data, keys)
    after = np.asarray(evaluate_fn(states.params, data))[0]
    own_after = own_loss(states.params)
    assert after[0] / after[2] < before[0] / before[2] - 0.15
    assert own_after < own_before - 0.2
    append = RunConfig(model=dataclasses.replace(INSERT, decoder="append"), train=recipe)
    with pytest.raises(ValueError, match="insertion decoder"):
        train(append, labelled, None, "unused-dir", progress=False)
    with pytest.raises(ValueError, match="on_policy"):
        TrainConfig(on_policy=-1.0)


def test_refined_routes_free_budget(teacher):
    """With the route improved after every insertion, greedy plans of the same network
    are never costlier for the same sets and, on these tight budgets, take more reward in
    all (the freed budget goes to more sets); the append decoder ignores the flag."""
    inst, _ = teacher
    inst = inst.replace(budget=inst.budget * 0.7)
    model = untrained(INSERT, 5)
    refined = untrained(dataclasses.replace(INSERT, refine=True), 5)
    plain = run(model, inst).solution
    better = run(refined, inst).solution
    assert float(jnp.sum(better.reward)) >= float(jnp.sum(plain.reward))
    append = dataclasses.replace(INSERT, decoder="append")
    a = run(untrained(append, 5), inst).solution
    b = run(untrained(dataclasses.replace(append, refine=True), 5), inst).solution
    np.testing.assert_array_equal(np.asarray(a.nodes), np.asarray(b.nodes))


def test_config_names_a_bad_decoder():
    with pytest.raises(ValueError, match="decoder"):
        dataclasses.replace(INSERT, decoder="prepend")


def test_top_first_sets_of_the_insertion_decoder():
    """``first_sets`` ranks sets by the insertion decoder's first-step scores (its greedy
    trace), leaving the greedy move's set out; decoding from them starts in them."""
    from bfsop_jax.model.decode import first_sets  # noqa: PLC0415

    batch = stack(instances(True))
    model = untrained(dataclasses.replace(INSERT, refine=True), 2)
    g, p = nnx.split(model, nnx.Param)
    top = np.asarray(jax.jit(lambda p, i: first_sets(nnx.merge(g, p), i, 3))(p, batch))
    probs = np.asarray(run(model, batch).probs[:, 0, :-1])  # [B, N] first step
    set_id = np.asarray(batch.set_id)
    for i in range(top.shape[0]):
        best = {s: probs[i][set_id[i] == s].max() for s in set(set_id[i].tolist()) if s >= 0}
        greedy_set = set_id[i][int(np.argmax(probs[i]))]
        ranked = sorted((s for s, q in best.items() if q > 0 and s != greedy_set),
                        key=lambda s: -best[s])[:3]  # fmt: skip
        np.testing.assert_array_equal(top[i][: len(ranked)], ranked)
    fn = jax.jit(lambda p, i, f: decode(nnx.merge(g, p), i, first_set=f))
    first = np.asarray(fn(p, batch, jnp.asarray(top[:, 0])).choices[:, 0])
    forced = top[:, 0] >= 0
    np.testing.assert_array_equal(set_id[np.arange(len(first)), first][forced], top[forced, 0])
