"""JAX bounded 2-opt and budget gate: never longer, same sets, exact node choice, batching."""

from __future__ import annotations

import chex
import jax
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from bfsop_jax.sop import (
    Solution,
    SOPInstance,
    budget_gate,
    evaluate,
    insertion_fill,
    plan_length,
    refine_route,
    two_opt,
)
from bfsop_jax.sop import vns as V
from bfsop_jax.sop.io import random_instance
from bfsop_jax.sop.two_opt import plan_route

SETS, VIEWS = 6, 3  # fixed shapes: one compilation for all examples


def _random_plan(inst: SOPInstance, rng: np.random.Generator) -> Solution:
    """Random order of a random subset of sets, random node in each; padded."""
    sets = [s for s in range(inst.num_sets) if inst.set_reward[s] > 0]
    chosen = rng.permutation(sets)[: rng.integers(0, len(sets) + 1)]
    nodes = [int(inst.start)]
    nodes += [int(rng.choice(np.flatnonzero(inst.set_id == s))) for s in chosen]
    if int(inst.end) >= 0:
        nodes.append(int(inst.end))
    reward, cost, _ = evaluate(inst, nodes)
    length = plan_length(inst.num_sets)
    padded = np.full(length, -1, np.int32)
    padded[: len(nodes)] = nodes
    return Solution(nodes=padded, reward=np.float32(reward), cost=np.float32(cost))


def _visited_sets(inst: SOPInstance, nodes) -> list[int]:
    nodes = [int(v) for v in np.asarray(nodes) if v >= 0]
    inner = nodes[1:-1] if int(inst.end) >= 0 else nodes[1:]
    return sorted(int(inst.set_id[v]) for v in inner)


def _order_cost(inst: SOPInstance, nodes) -> float:
    """NumPy layered DP: best node choice for the plan's set order."""
    view = V.set_view(inst.replace(budget=np.float32(np.inf)))
    compact = {int(s): k for k, s in enumerate(view.set_ids)}
    order = [compact[int(inst.set_id[v])] for v in _inner(inst, nodes)]
    rest = [s for s in range(view.num_sets) if s not in order]
    perm = np.array(order + rest)[None]
    return float(V._tables(view, perm, np.array([len(order)])).length[0])


def _inner(inst, nodes):
    nodes = [int(v) for v in np.asarray(nodes) if v >= 0]
    return nodes[1:-1] if int(inst.end) >= 0 else nodes[1:]


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000), st.booleans(), st.integers(0, 2), st.floats(0.2, 2.0))
def test_two_opt_never_longer_and_keeps_the_sets(seed, closed, masked, scale):
    inst = random_instance(seed, SETS, VIEWS, closed=closed, masked_sets=masked, budget_scale=scale)
    plan = _random_plan(inst, np.random.default_rng(seed))
    out = two_opt(inst, plan)
    reward, cost, _ = evaluate(inst, out.nodes)
    assert out.nodes.shape == plan.nodes.shape
    assert int(out.nodes[0]) == int(inst.start)
    assert _visited_sets(inst, out.nodes) == _visited_sets(inst, plan.nodes)
    assert cost <= float(plan.cost) + 1e-4
    assert abs(float(out.cost) - cost) <= 1e-4 * max(1.0, cost)
    assert abs(float(out.reward) - reward) <= 1e-5 and abs(reward - float(plan.reward)) <= 1e-5
    # the node choice is optimal for the returned set order
    assert cost <= _order_cost(inst, out.nodes) + 1e-4
    gated = budget_gate(inst, out)
    reward_g, cost_g, ok = evaluate(inst, gated.nodes)
    assert ok and cost_g <= float(inst.budget) + 1e-4
    kept = _inner(inst, gated.nodes)
    assert kept == _inner(inst, out.nodes)[: len(kept)]  # a prefix of the plan
    assert abs(float(gated.reward) - reward_g) <= 1e-5


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000), st.booleans(), st.integers(0, 2), st.integers(0, 3),
       st.integers(0, 2))  # fmt: skip
def test_refine_route_never_longer_and_keeps_the_sets(seed, closed, masked, reversals, sweeps):
    """The insertion decoder's cheap route improvement: same layout and sets, a cost that
    never rises, nothing at all when asked for no step; after a sweep no visited node has
    a cheaper node of its set between its neighbours."""
    inst = random_instance(seed, SETS, VIEWS, closed=closed, masked_sets=masked)
    plan = _random_plan(inst, np.random.default_rng(seed))
    route, m = plan_route(inst, plan.nodes)
    out = np.asarray(jax.jit(refine_route, static_argnums=(3, 4))(inst, route, m, reversals,
                                                                   sweeps))  # fmt: skip
    route = np.asarray(route)
    n = inst.num_nodes
    assert out[0] == route[0] and (out[int(m) + 1 :] == route[int(m) + 1 :]).all()
    sets = lambda r: sorted(inst.set_id[r[1 : int(m) + 1]].tolist())  # noqa: E731
    assert sets(out) == sets(route)
    ext = np.full((n + 1, n + 1), np.inf)
    ext[:n, :n] = inst.cost
    ext[:, n] = 0.0
    cost = lambda r: float(ext[r[:-1], r[1:]].sum())  # noqa: E731
    assert cost(out) <= cost(route) + 1e-4
    if reversals == sweeps == 0:
        np.testing.assert_array_equal(out, route)
    if sweeps:  # the even positions moved last: none of them can do better
        for p in range(2, int(m) + 1, 2):
            same = np.flatnonzero(inst.set_id == inst.set_id[out[p]])
            detour = ext[out[p - 1], same] + ext[same, out[p + 1]]
            assert ext[out[p - 1], out[p]] + ext[out[p], out[p + 1]] <= detour.min() + 1e-4


def test_intra_set_exchange_alone_is_the_exact_dp():
    for seed in range(4):
        inst = random_instance(seed, SETS, VIEWS, closed=seed % 2 == 0, budget_scale=3.0)
        plan = _random_plan(inst, np.random.default_rng(seed + 50))
        out = two_opt(inst, plan, max_iters=0)
        order = [int(inst.set_id[v]) for v in _inner(inst, out.nodes)]
        assert order == [int(inst.set_id[v]) for v in _inner(inst, plan.nodes)]
        np.testing.assert_allclose(float(out.cost), _order_cost(inst, plan.nodes), rtol=1e-5)


def test_uncrosses_a_line():
    xs = np.arange(6.0)  # start at 0, one node per set on a line
    cost = np.abs(xs[:, None] - xs[None])
    inst = SOPInstance.create(cost, np.arange(6), [0.0] + [1.0] * 5, 0, -1, 100.0)
    plan = Solution(
        nodes=np.array([0, 4, 3, 2, 1, 5, -1], np.int32), reward=np.float32(5), cost=np.float32(12)
    )
    out = two_opt(inst, plan)
    np.testing.assert_array_equal(out.nodes, [0, 1, 2, 3, 4, 5, -1])
    assert float(out.cost) == 5.0


def test_budget_gate_drops_from_the_end():
    xs = np.arange(6.0)
    cost = np.abs(xs[:, None] - xs[None])
    inst = SOPInstance.create(cost, np.arange(6), [0.0] + [1.0] * 5, 0, 0, 6.5)
    plan = Solution(
        nodes=np.array([0, 1, 2, 3, 4, 5, 0], np.int32), reward=np.float32(5), cost=np.float32(10)
    )
    out = budget_gate(inst, plan)
    np.testing.assert_array_equal(out.nodes, [0, 1, 2, 3, 0, -1, -1])
    assert float(out.cost) == 6.0 and float(out.reward) == 3.0


def test_batch_matches_single_and_compiles_once():
    insts = [random_instance(s, SETS, VIEWS, closed=s % 2 == 0, budget_scale=0.8) for s in range(4)]
    plans = [_random_plan(i, np.random.default_rng(s)) for s, i in enumerate(insts)]
    batch_inst = jax.tree_util.tree_map(lambda *x: np.stack(x), *insts)
    batch_plan = jax.tree_util.tree_map(lambda *x: np.stack(x), *plans)
    out = two_opt(batch_inst, batch_plan)
    for b in range(4):
        single = two_opt(insts[b], plans[b])
        np.testing.assert_array_equal(out.nodes[b], single.nodes)
        np.testing.assert_allclose(out.cost[b], single.cost, rtol=1e-6)

    @jax.jit
    @chex.assert_max_traces(n=1)
    def plan_and_gate(inst, plan):
        return budget_gate(inst, two_opt(inst, plan))

    for _ in range(3):
        jax.block_until_ready(plan_and_gate(batch_inst, batch_plan))


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    closed=st.booleans(),
    masked=st.integers(0, 2),
    scale=st.floats(0.1, 0.8),
)
def test_insertion_fill_only_adds_sets_within_budget(seed, closed, masked, scale):
    inst = random_instance(seed, num_sets=SETS, viewpoints=VIEWS, closed=closed,
                           budget_scale=scale, masked_sets=masked)  # fmt: skip
    gated = budget_gate(inst, _random_plan(inst, np.random.default_rng(seed)))
    filled = insertion_fill(inst, gated)
    reward, cost, feasible = evaluate(inst, np.asarray(filled.nodes))
    assert feasible
    assert cost <= float(inst.budget) + 1e-3
    assert reward >= float(gated.reward) - 1e-5
    assert abs(float(filled.reward) - reward) <= 1e-5
    before = set(_visited_sets(inst, gated.nodes))
    after = set(_visited_sets(inst, filled.nodes))
    assert before <= after
    # nothing left out fits: every remaining rewarding set is too expensive to insert
    nodes = [int(v) for v in np.asarray(filled.nodes) if v >= 0]
    inner_end = len(nodes) - 1 if int(inst.end) >= 0 else len(nodes)
    for s in range(inst.num_sets):
        if s in after or inst.set_reward[s] <= 0 or s == inst.set_id[inst.start]:
            continue
        for v in np.flatnonzero(inst.set_id == s):
            for p in range(1, inner_end + 1):
                trial = nodes[:p] + [int(v)] + nodes[p:]
                assert evaluate(inst, trial)[1] > float(inst.budget) - 1e-3


def test_insertion_fill_batch_matches_single():
    insts = [random_instance(s, num_sets=SETS, viewpoints=VIEWS, closed=s % 2 == 1)
             for s in range(4)]  # fmt: skip
    plans = [budget_gate(i, _random_plan(i, np.random.default_rng(s))) for s, i in enumerate(insts)]
    stack = jax.tree_util.tree_map(lambda *x: np.stack(x), *insts)
    batch = insertion_fill(stack, jax.tree_util.tree_map(lambda *x: np.stack(x), *plans))
    for i, (inst, plan) in enumerate(zip(insts, plans, strict=True)):
        one = insertion_fill(inst, plan)
        np.testing.assert_array_equal(np.asarray(batch.nodes[i]), np.asarray(one.nodes))
