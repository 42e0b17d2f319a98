"""Strategic Transformer: features, masks, padding and permutation properties, decoding."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from bfsop_jax.model import (
    ModelConfig,
    StrategicTransformer,
    decode,
    node_features,
    step_features,
    symmetric_features,
    teacher_forced_logits,
)
from bfsop_jax.model.features import BUDGET_CLIP, FAR, NUM_STEP_FEATURES
from bfsop_jax.sop import SOPInstance, evaluate
from bfsop_jax.sop.io import random_instance

TINY = ModelConfig(d_model=32, n_layers=2, n_heads=2, d_ff=64)
SETS, VIEWPOINTS = 6, 3  # N = 19 nodes, K = 7 sets, T = 8 plan slots


def stack(instances: list[SOPInstance]) -> SOPInstance:
    return jax.tree_util.tree_map(lambda *x: jnp.stack([jnp.asarray(v) for v in x]), *instances)


def with_unreachable(inst: SOPInstance, node: int) -> SOPInstance:
    """Make ``node`` unreachable from every other node (a wall in between)."""
    cost = np.array(inst.cost)
    cost[:, node] = np.inf
    cost[node, node] = 0.0
    return inst.replace(cost=cost)


@pytest.fixture(scope="module")
def batch() -> SOPInstance:
    insts = [
        random_instance(seed, num_sets=SETS, viewpoints=VIEWPOINTS, masked_sets=seed % 3)
        for seed in range(8)
    ]
    insts[1] = with_unreachable(insts[1], 4)
    return stack(insts)


def untrained(config: ModelConfig, seed: int) -> StrategicTransformer:
    """A model with random weights everywhere (the glimpse output projection starts at zero,
    which would make every initial distribution uniform)."""
    model = StrategicTransformer(config, rngs=nnx.Rngs(seed))
    kernel = model.decoder.project_glimpse.kernel
    kernel[...] = jax.random.normal(jax.random.key(seed), kernel.shape) / np.sqrt(kernel.shape[0])
    return model


@pytest.fixture(scope="module")
def model() -> StrategicTransformer:
    return untrained(TINY, 3)


def _split(model):
    return nnx.split(model, nnx.Param)


_encode = jax.jit(
    lambda params, inst, graphdef: nnx.merge(graphdef, params).encode(node_features(inst)),
    static_argnames="graphdef",
)
_decode = jax.jit(
    lambda params, inst, key, greedy, graphdef: decode(
        nnx.merge(graphdef, params), inst, key, 1.0, greedy
    ),
    static_argnames="graphdef",
)
_teacher = jax.jit(
    lambda params, inst, nodes, graphdef: teacher_forced_logits(
        nnx.merge(graphdef, params), inst, nodes
    ),
    static_argnames="graphdef",
)


def encode(model, inst):
    g, p = _split(model)
    return _encode(p, inst, graphdef=g)


def run_decode(model, inst, key=None, greedy=True):
    g, p = _split(model)
    key = jax.random.key(0) if key is None else key
    b = inst.set_id.shape[0]
    return _decode(p, inst, key, jnp.broadcast_to(jnp.asarray(greedy), (b,)), graphdef=g)


def check_plan(inst: SOPInstance, nodes: np.ndarray) -> None:
    """Start first, padding only at the end, no padding node, <= 1 node per set."""
    n = inst.set_id.shape[0]
    real = nodes[nodes >= 0]
    assert nodes[0] == int(inst.start)
    assert (nodes[len(real) :] == -1).all(), "padding inside the plan"
    assert (real < n).all()
    sets = np.asarray(inst.set_id)[real]
    assert (sets >= 0).all(), "a padding node was chosen"
    assert len(set(sets.tolist())) == len(sets), "a set was visited twice"
    assert len(set(real.tolist())) == len(real), "a node was revisited"
    # every edge finite: no unreachable node
    cost = np.asarray(inst.cost)
    assert np.isfinite(cost[real[:-1], real[1:]]).all()


# -- features --------------------------------------------------------------------------------
def test_features_normalisation():
    inst = random_instance(5, num_sets=SETS, viewpoints=VIEWPOINTS, masked_sets=2)
    inst = with_unreachable(inst, 3)
    f = jax.tree_util.tree_map(np.asarray, node_features(stack([inst])))
    valid = np.asarray(inst.set_id) >= 0
    xy = f.nodes[0, :, :2]
    coords = np.asarray(inst.coords)[valid]
    side = (coords.max(0) - coords.min(0)).max()
    np.testing.assert_allclose(xy[valid], (coords - coords.min(0)) / side, atol=1e-6)
    assert xy[valid].min() == 0.0 and np.isclose(xy[valid].max(), 1.0)  # larger side -> 1
    assert (f.nodes[0, ~valid] == 0).all()
    reward = np.asarray(inst.set_reward)
    expect_r = np.where(valid, reward[np.clip(inst.set_id, 0, None)] / reward.max(), 0.0)
    np.testing.assert_allclose(f.nodes[0, :, 2], expect_r, atol=1e-6)
    assert f.nodes[0, 0, 3] == 1.0 and f.nodes[0, 1:, 3].sum() == 0
    cost = np.asarray(inst.cost)
    finite = np.isfinite(cost) & valid[:, None] & valid[None, :]
    scale = cost[finite].max()
    assert np.isclose(f.cost_scale[0], scale)
    np.testing.assert_allclose(
        f.bias[0][finite], np.log(cost[finite] / scale + 1e-9), rtol=1e-5, atol=1e-5
    )
    assert np.allclose(f.bias[0][~finite], np.log(1.0 + 1e-9))  # unreachable: c^ = 1
    assert np.isfinite(f.bias).all()


def test_symmetries_stay_in_unit_square():
    inst = random_instance(6, num_sets=SETS, viewpoints=VIEWPOINTS, masked_sets=1)
    f = node_features(stack([inst]))
    sym = symmetric_features(f)
    assert sym.nodes.shape == (8,) + f.nodes.shape
    np.testing.assert_array_equal(sym.nodes[0], f.nodes)
    xy = np.asarray(sym.nodes[..., :2])
    assert xy.min() >= 0.0 and xy.max() <= 1.0 + 1e-6
    flat = xy[:, 0][:, np.asarray(inst.set_id) >= 0].reshape(8, -1)
    assert len({tuple(np.round(v, 5)) for v in flat}) == 8  # eight distinct views
    np.testing.assert_array_equal(
        sym.nodes[..., 2:], jnp.broadcast_to(f.nodes[..., 2:], (8,) + f.nodes[..., 2:].shape)
    )


# -- masks and decoding ----------------------------------------------------------------------
def test_masks_never_violated(model, batch):
    b = batch.set_id.shape[0]
    greedy = np.arange(b) % 2 == 0  # half greedy, half sampled
    for seed in range(3):
        trace = run_decode(model, batch, jax.random.key(seed), greedy)
        nodes = np.asarray(trace.solution.nodes)
        for i in range(b):
            check_plan(batch[i], nodes[i])
            reward, cost, _ = evaluate(batch[i], nodes[i])
            assert np.isclose(trace.solution.reward[i], reward, rtol=1e-5, atol=1e-5)
            assert np.isclose(trace.solution.cost[i], cost, rtol=1e-5, atol=1e-4)
        # probability mass only on allowed entries, END always allowed
        probs, allowed = np.asarray(trace.probs), np.asarray(trace.allowed)
        assert (probs[~allowed] == 0).all()
        assert allowed[..., -1].all()


def test_sampling_differs_from_greedy_and_is_seeded(model, batch):
    b = batch.set_id.shape[0]
    a = run_decode(model, batch, jax.random.key(7), np.zeros(b, bool)).solution.nodes
    a2 = run_decode(model, batch, jax.random.key(7), np.zeros(b, bool)).solution.nodes
    c = run_decode(model, batch, jax.random.key(8), np.zeros(b, bool)).solution.nodes
    np.testing.assert_array_equal(a, a2)
    assert not np.array_equal(a, c)


def pad_instance(inst: SOPInstance, extra_nodes: int, extra_sets: int) -> SOPInstance:
    n = inst.set_id.shape[0]
    cost = np.full((n + extra_nodes, n + extra_nodes), np.inf, np.float32)
    cost[:n, :n] = inst.cost
    return SOPInstance(
        cost=cost,
        set_id=np.concatenate([inst.set_id, np.full(extra_nodes, -1, np.int32)]),
        set_reward=np.concatenate([inst.set_reward, np.zeros(extra_sets, np.float32)]),
        start=inst.start,
        end=inst.end,
        budget=inst.budget,
        coords=np.concatenate([inst.coords, np.full((extra_nodes, 2), 99.0, np.float32)]),
    )


def test_padding_does_not_change_the_output(model, batch):
    small = batch
    big = stack([pad_instance(batch[i], 6, 2) for i in range(batch.set_id.shape[0])])
    n = small.set_id.shape[1]
    h_big = encode(model, big)
    np.testing.assert_allclose(h_big[:, :n], encode(model, small), atol=1e-5)
    assert (h_big[:, n:] == 0).all()
    plan_small = run_decode(model, small).solution
    plan_big = run_decode(model, big).solution
    t = plan_small.nodes.shape[1]
    np.testing.assert_array_equal(plan_big.nodes[:, :t], plan_small.nodes)
    assert (plan_big.nodes[:, t:] == -1).all()
    np.testing.assert_allclose(plan_big.cost, plan_small.cost, rtol=1e-6)


def test_encoder_is_permutation_equivariant(model, batch):
    n = batch.set_id.shape[1]
    perm = np.concatenate([[0], 1 + np.random.default_rng(0).permutation(n - 1)])
    permuted = batch.replace(
        cost=batch.cost[:, perm][:, :, perm],
        set_id=batch.set_id[:, perm],
        coords=batch.coords[:, perm],
    )
    np.testing.assert_allclose(encode(model, permuted), encode(model, batch)[:, perm], atol=1e-5)


@pytest.mark.parametrize(
    ("budget_aware", "budget_mask", "step"),
    [(False, False, False), (True, False, False), (False, True, False), (False, True, True)],
)
def test_teacher_forcing_matches_decoding(batch, budget_aware, budget_mask, step):
    """Feeding a model its own greedy plans as teacher gives the decoder's step
    distributions, and every target is the arg-max (masks, budget and step features agree
    in both paths)."""
    config = dataclasses.replace(
        TINY, budget_aware=budget_aware, budget_mask=budget_mask, step_features=step
    )
    model = untrained(config, 5)
    if step:  # the MLP's output layer starts at zero: give it weights
        out = model.decoder.step_out.kernel
        out[...] = jax.random.normal(jax.random.key(7), out.shape)
    trace = run_decode(model, batch)
    g, p = _split(model)
    tf = _teacher(p, batch, trace.solution.nodes, graphdef=g)
    valid = np.asarray(tf.valid)
    counts = (np.asarray(trace.solution.nodes) >= 0).sum(1)  # m + 1 steps: m nodes, END
    np.testing.assert_array_equal(valid.sum(1), counts)
    probs = np.exp(np.asarray(tf.log_probs))
    np.testing.assert_allclose(probs[valid], np.asarray(trace.probs)[valid], atol=1e-5)
    np.testing.assert_array_equal(np.argmax(tf.log_probs, -1)[valid], np.asarray(tf.target)[valid])


def test_budget_mask_keeps_plans_feasible_and_maximal(batch):
    """With ``budget_mask`` every decoded plan (greedy or sampled) fits the budget without
    the gate, and END is chosen only when no allowed node fits any more."""
    model = untrained(dataclasses.replace(TINY, budget_mask=True), 5)
    b = batch.set_id.shape[0]
    tight = batch.replace(budget=batch.budget * 0.5)
    for seed in range(2):
        trace = run_decode(model, tight, jax.random.key(seed), np.arange(b) % 2 == 0)
        nodes = np.asarray(trace.solution.nodes)
        allowed = np.asarray(trace.allowed)
        for i in range(b):
            check_plan(tight[i], nodes[i])
            _, cost, feasible = evaluate(tight[i], nodes[i])
            assert feasible and cost <= float(tight.budget[i]) + 1e-3
            # END is allowed exactly at the steps where no node is
            m = int((nodes[i] >= 0).sum()) - 1
            for t in range(m + 1):
                assert allowed[i, t, -1] == (not allowed[i, t, :-1].any())


def test_budget_aware_decoder_reads_the_budget(batch):
    model = untrained(dataclasses.replace(TINY, budget_aware=True), 5)
    a = run_decode(model, batch).probs
    b = run_decode(model, batch.replace(budget=batch.budget * 0.2)).probs
    assert not np.allclose(a, b)


def test_geometric_bias_switch(batch):
    off = StrategicTransformer(dataclasses.replace(TINY, geometric_bias=False), rngs=nnx.Rngs(0))
    on = StrategicTransformer(TINY, rngs=nnx.Rngs(0))
    assert off.layers[0].attention.bias_scale is None
    assert on.layers[0].attention.bias_scale[...].shape == (TINY.n_heads,)
    # without the bias the encoder ignores costs; with it, costs change the embeddings
    factor = np.random.default_rng(0).uniform(0.5, 1.5, batch.cost.shape[1:])
    scaled = batch.replace(cost=batch.cost * factor)
    np.testing.assert_allclose(encode(off, batch), encode(off, scaled), atol=1e-6)
    assert not np.allclose(encode(on, batch), encode(on, scaled), atol=1e-4)


def test_config_validation():
    with pytest.raises(ValueError, match="divisible"):
        ModelConfig(d_model=30, n_heads=4)
    with pytest.raises(ValueError, match="unknown ModelConfig keys"):
        ModelConfig.from_dict({"d_model": 32, "depth": 3})
    assert ModelConfig.from_dict(TINY.to_dict()) == TINY


def test_step_features_values(batch):
    """Each step feature against its definition, for a few (last node, cost so far) states."""
    inst = batch
    feats = node_features(inst)
    b, n = inst.set_id.shape
    last = jnp.asarray(np.stack([np.arange(b) % n, (np.arange(b) + 3) % n], 1), jnp.int32)
    travelled = jnp.asarray(np.stack([np.zeros(b), 0.5 * np.asarray(inst.budget)], 1), jnp.float32)
    out = np.asarray(step_features(inst, feats, last, travelled))
    assert out.shape == (b, 2, n, NUM_STEP_FEATURES)
    cost, scale = np.asarray(inst.cost), np.asarray(feats.cost_scale)
    valid = np.asarray(feats.valid)
    for i in range(b):
        end = int(inst.end[i])
        for s in range(2):
            row = out[i, s][valid[i]]
            c = cost[i, int(last[i, s])][valid[i]]
            d = np.where(np.isfinite(c), np.minimum(c / scale[i], FAR), FAR)
            np.testing.assert_allclose(row[:, 0], d, rtol=1e-5)
            e = (
                np.zeros_like(d)
                if end < 0
                else np.minimum(cost[i, :, end][valid[i]] / scale[i], FAR)
            )
            np.testing.assert_allclose(row[:, 1], e, rtol=1e-5)
            left = np.clip(
                (float(inst.budget[i]) - float(travelled[i, s])) / scale[i], 0, BUDGET_CLIP
            )
            np.testing.assert_allclose(row[:, 2], left, rtol=1e-5)
            np.testing.assert_allclose(row[:, 3], np.clip(left - d - e, -1, BUDGET_CLIP), atol=1e-5)
            np.testing.assert_allclose(row[:, 5], np.asarray(feats.nodes[i, :, 2])[valid[i]])
        assert (out[i, :, ~valid[i]] == 0).all()  # padding nodes


def test_first_set_forces_the_first_move(batch):
    """Multi-start decoding: a row's first move goes into its ``first_set`` whenever that
    set has an allowed node; otherwise (blocked set, -1) the move is the free greedy one."""
    model = untrained(dataclasses.replace(TINY, budget_mask=True), 5)
    g, p = _split(model)
    b, k = batch.set_id.shape[0], batch.set_reward.shape[1]
    free = run_decode(model, batch)
    for target in range(-1, k):
        first = jnp.full((b,), target, jnp.int32)
        trace = jax.jit(
            lambda params, inst, first: decode(nnx.merge(g, params), inst, first_set=first)
        )(p, batch, first)
        nodes = np.asarray(trace.solution.nodes)
        allowed0 = np.asarray(free.allowed)[:, 0, :-1]
        for i in range(b):
            check_plan(batch[i], nodes[i])
            in_set = allowed0[i] & (np.asarray(batch.set_id[i]) == target)
            if target >= 0 and in_set.any():
                assert int(batch.set_id[i, nodes[i, 1]]) == target
            else:
                np.testing.assert_array_equal(nodes[i], np.asarray(free.solution.nodes)[i])
