"""Exact subset DP: brute-force parity on tiny instances and the benchmark's proven optima.

Also home of the small-instance strategy and brute-force reference the other SOP tests use.
"""

from __future__ import annotations

import csv
import itertools

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bfsop_jax.sop import SOPInstance, evaluate, read_sop, solve_exact, solve_greedy

SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@st.composite
def small_instances(draw, max_sets: int = 5, max_size: int = 3) -> SOPInstance:
    """Random small SOP: open or closed, optional padding, asymmetric or unreachable edges."""
    k = draw(st.integers(1, max_sets))
    sizes = draw(st.lists(st.integers(1, max_size), min_size=k, max_size=k))
    pad = draw(st.integers(0, 2))
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    n = 1 + sum(sizes) + pad
    coords = rng.uniform(0, 10, size=(n, 2))
    cost = np.linalg.norm(coords[:, None] - coords[None], axis=-1)
    if draw(st.booleans()):  # asymmetric, not metric
        cost = cost * rng.uniform(0.7, 1.5, size=cost.shape)
    if draw(st.booleans()):  # some unreachable pairs
        cost[rng.random(cost.shape) < 0.15] = np.inf
    np.fill_diagonal(cost, 0.0)
    set_id = np.concatenate([[0]] + [[s + 1] * size for s, size in enumerate(sizes)] + [[-1] * pad])
    cost[set_id == -1, :] = np.inf
    cost[:, set_id == -1] = np.inf
    reward = np.concatenate([[0.0], rng.integers(1, 6, size=k).astype(float)])
    if draw(st.booleans()):
        reward[1:] = rng.uniform(0.1, 1.0, size=k)
    finite = cost[np.isfinite(cost)]
    budget = draw(st.floats(0.0, 1.5)) * finite.sum() / max(1, n - 1)
    closed = draw(st.booleans())
    return SOPInstance.create(cost, set_id, reward, 0, 0 if closed else -1, budget, coords)


def brute_force(inst: SOPInstance) -> tuple[float, float]:
    """(best reward, least cost among best) by enumerating every order of every subset."""
    cost = inst.cost.astype(np.float64)
    start, end = int(inst.start), int(inst.end)
    sets = [s for s in range(inst.num_sets) if inst.set_reward[s] > 0]
    members = {s: np.flatnonzero(inst.set_id == s) for s in sets}
    best = (0.0, float(cost[start, end]) if end >= 0 else 0.0)
    for size in range(1, len(sets) + 1):
        for order in itertools.permutations(sets, size):
            table = cost[start, members[order[0]]]
            for a, b in itertools.pairwise(order):
                table = (table[:, None] + cost[np.ix_(members[a], members[b])]).min(axis=0)
            total = (table + cost[members[order[-1]], end]).min() if end >= 0 else table.min()
            if total > inst.budget:
                continue
            reward = sum(float(inst.set_reward[s]) for s in order)
            if reward > best[0] + 1e-9 or (abs(reward - best[0]) <= 1e-9 and total < best[1]):
                best = (reward, float(total))
    return best


def assert_valid_plan(inst: SOPInstance, sol) -> None:
    """Start first, end last (if any), one node per set, within budget, honest figures."""
    nodes = np.asarray(sol.nodes)
    reward, cost, ok = evaluate(inst, nodes)
    assert ok, (nodes, cost, float(inst.budget))
    assert nodes[0] == int(inst.start)
    if int(inst.end) >= 0:
        assert nodes[nodes >= 0][-1] == int(inst.end)
    assert abs(float(sol.reward) - reward) <= 1e-4 * max(1.0, reward)
    assert abs(float(sol.cost) - cost) <= 1e-4 * max(1.0, cost)


@SETTINGS
@given(small_instances())
def test_exact_matches_brute_force(inst):
    sol = solve_exact(inst)
    assert_valid_plan(inst, sol)
    reward, cost = brute_force(inst)
    assert float(sol.reward) == pytest.approx(reward, rel=1e-6, abs=1e-6)
    assert float(sol.cost) == pytest.approx(cost, rel=1e-5, abs=1e-5)


def test_known_answer():
    # start at 0; set 1 = {1, 2} on the left, set 2 = {3} far right: only set 1 fits
    xs = np.array([0.0, -1.0, 2.0, 10.0])
    inst = SOPInstance.create(
        np.abs(xs[:, None] - xs[None]), [0, 1, 1, 2], [0.0, 1.0, 5.0], 0, 0, 5.0
    )
    sol = solve_exact(inst)
    assert sol.node_list() == [0, 1, 0] and float(sol.cost) == 2.0
    sol = solve_exact(inst.replace(budget=np.float32(20.0)))
    assert float(sol.reward) == 6.0 and float(sol.cost) == 20.0


def test_refuses_too_many_sets():
    k = 4
    inst = SOPInstance.create(
        np.ones((k + 1, k + 1)), np.arange(k + 1), [0.0] + [1.0] * k, 0, -1, 9
    )
    with pytest.raises(ValueError, match="at most 3 rewarding sets"):
        solve_exact(inst, max_sets=3)


def test_rejects_infeasible_reference():
    from bfsop_jax.sop import Solution

    inst = SOPInstance.create(np.ones((3, 3)), [0, 1, 2], [0.0, 1.0, 1.0], 0, -1, 1.0)
    bad = Solution(nodes=np.array([0, 1, 2]), reward=np.float32(2), cost=np.float32(2))
    with pytest.raises(ValueError, match="reference"):
        solve_exact(inst, reference=bad)


# A representative subset of the proven optima: every 11- to 16-set base graph at every
# budget level and both profit types, plus tight-budget 20-22 set instances.
EXACT_SUBSET = ("11berlin52", "11eil51", "14st70", "16eil76", "16pr76")
EXACT_LARGE = ("20rat99_RND_T20", "21eil101_RND_T20", "22pr107_RND_T20", "20kroB100_RND_T20")


def test_benchmark_optima_subset(shared):
    rows = list(csv.DictReader(shared("sop", "exact_optima_set2.csv").open()))
    chosen = [
        r for r in rows if r["file"].startswith(EXACT_SUBSET) or r["file"].startswith(EXACT_LARGE)
    ]
    assert len(chosen) >= 50
    for row in chosen:
        inst = read_sop(shared("sop", "instances", row["file"]))
        sol = solve_exact(inst, reference=solve_greedy(inst), min_cost=False)
        assert_valid_plan(inst, sol)
        assert float(sol.reward) == float(row["optimal_reward"]), row["file"]
