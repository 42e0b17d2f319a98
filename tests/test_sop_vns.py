"""VNS teacher: feasibility properties, exact move evaluation, determinism, optimality rate."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from bfsop_jax.sop import SOPInstance, solve_exact, solve_greedy, solve_vns
from bfsop_jax.sop import vns as V
from bfsop_jax.sop.io import random_instance
from bfsop_jax.sop.vns import DEMO_LABELLING, REFERENCE, VNSConfig
from tests.test_sop_exact import SETTINGS, assert_valid_plan, small_instances

QUICK = dict(max_iters=40, max_no_improve=20)


@SETTINGS
@given(small_instances(max_sets=6))
def test_vns_plans_are_feasible_and_not_worse_than_greedy(inst):
    sol, greedy = solve_vns(inst, seed=3, return_greedy=True, **QUICK)
    assert_valid_plan(inst, sol)
    assert_valid_plan(inst, greedy)
    assert float(sol.reward) >= float(greedy.reward) - 1e-6
    if abs(float(sol.reward) - float(greedy.reward)) <= 1e-6:
        assert float(sol.cost) <= float(greedy.cost) + 1e-5
    np.testing.assert_array_equal(solve_greedy(inst).nodes, greedy.nodes)


def _order_cost(view: V.SetView, order: list[int]) -> float:
    rest = [s for s in range(view.num_sets) if s not in order]
    perm = np.array(order + rest)[None]
    return float(V._tables(view, perm, np.array([len(order)])).length[0])


@pytest.mark.parametrize("seed", range(6))
def test_every_move_cost_is_exact(seed):
    """Batched move costs equal a fresh layered DP on the moved set order."""
    rng = np.random.default_rng(seed)
    inst = random_instance(seed, num_sets=7, viewpoints=3, closed=seed % 2 == 1, budget_scale=1.5)
    view = V.set_view(inst)
    width = 3
    perm = np.stack([rng.permutation(view.num_sets) for _ in range(width)])
    m = rng.integers(0, view.num_sets + 1, size=width)
    tables = V._tables(view, perm, m)
    kinds = set()
    for which in (1, 2):
        for mv in V._neighbourhood(view, perm, m, tables, which, reversals=True):
            for w, a, b in zip(*np.nonzero(mv.valid), strict=True):
                new_perm, new_m = V._apply(perm[w], int(m[w]), mv.kind, int(a), int(b))
                assert sorted(new_perm) == list(range(view.num_sets))
                want = _order_cost(view, list(new_perm[:new_m]))
                kinds.add(mv.kind)
                if mv.kind == "reverse":  # scored with the current nodes: an upper bound
                    assert mv.cost[w, a, b] >= want - 1e-9, (a, b)
                else:
                    assert mv.cost[w, a, b] == pytest.approx(want, rel=1e-9), (mv.kind, a, b)
    assert kinds == {"insert", "relocate", "replace", "swap", "reverse"}


def test_same_seed_same_plan():
    inst = random_instance(11)
    a = solve_vns(inst, seed=5, max_iters=200, max_no_improve=100)
    b = solve_vns(inst, seed=5, max_iters=200, max_no_improve=100)
    np.testing.assert_array_equal(a.nodes, b.nodes)
    assert a.cost == b.cost


def test_matches_exact_on_most_small_instances():
    """Navigation-like instances with 8 sets x 3 viewpoints, default settings."""
    hits = 0
    trials = 12
    for seed in range(trials):
        inst = random_instance(100 + seed, num_sets=8, viewpoints=3, closed=seed % 3 == 0)
        sol = solve_vns(inst, seed=seed)
        best = solve_exact(inst, reference=sol)
        assert_valid_plan(inst, sol)
        assert float(sol.reward) <= float(best.reward) + 1e-6
        hits += abs(float(sol.reward) - float(best.reward)) <= 1e-6
    assert hits >= 11, hits


def test_nothing_reachable_gives_start_only_plan():
    cost = np.full((4, 4), np.inf)
    np.fill_diagonal(cost, 0.0)
    inst = SOPInstance.create(cost, [0, 1, 1, 2], [0.0, 1.0, 1.0], 0, -1, 100.0)
    assert solve_vns(inst).node_list() == [0]
    closed = inst.replace(end=np.int32(0))
    assert solve_vns(closed).node_list() == [0, 0]


def test_masked_instance_gives_empty_plan():
    inst = random_instance(0, num_sets=3, masked_sets=3)
    sol = solve_vns(inst)
    assert sol.node_list() == [0] and float(sol.reward) == 0 and float(sol.cost) == 0


def test_no_single_set_fits_but_a_pair_does():
    """A cost matrix without the triangle inequality: each set alone overshoots the
    budget (11 and 20), the two together fit (3). Greedy insertion never starts a tour,
    so the search stagnates with nothing visited, and the ruin-and-recreate step, which
    has nothing to remove, keeps the empty plan (it used to fail on an empty batch). The
    exact solver, which does not build tours one set at a time, finds the pair."""
    cost = np.array([[0.0, 1.0, 10.0], [10.0, 0.0, 1.0], [1.0, 10.0, 0.0]])
    inst = SOPInstance.create(cost, [0, 1, 2], [0.0, 1.0, 2.0], 0, 0, 5.0)
    sol = solve_vns(inst)
    assert_valid_plan(inst, sol)
    assert sol.node_list() == [0, 0] and float(sol.reward) == 0.0
    view = V.set_view(inst)
    perm = np.arange(view.num_sets)
    p, m, reward, length = V._recreate(view, perm, 0, np.random.default_rng(0), slack=0.3)
    assert m == 0 and reward == 0.0 and length == 0.0 and list(p) == list(perm)
    exact = solve_exact(inst)
    assert exact.node_list() == [0, 1, 2, 0] and float(exact.reward) == 3.0


def test_zero_budget():
    inst = random_instance(2, budget_scale=0.0)
    assert solve_vns(inst).node_list() == [0]


def test_path_to_a_goal_node():
    xs = np.array([0.0, 1.0, 2.0, 5.0, 3.0])  # node 3 is the goal, alone in set 3
    cost = np.abs(xs[:, None] - xs[None])
    inst = SOPInstance.create(cost, [0, 1, 2, 3, 4], [0.0, 1.0, 1.0, 0.0, 1.0], 0, 3, 5.0)
    sol = solve_vns(inst)
    assert_valid_plan(inst, sol)
    assert sol.node_list() == [0, 1, 2, 4, 3] and float(sol.cost) == 5.0


@SETTINGS
@given(small_instances(max_sets=6), st.sampled_from([0.0, 0.3]))
def test_fill_keeps_the_selection_respects_bans_and_fits(inst, slack):
    """The fill keeps what was visited, never inserts a banned set and ends within the
    budget. Without slack it stops only when no unbanned set fits by a plain insertion.
    With slack a set whose overshooting insertion could not be repaired is banned for
    the rest of that fill, even if a later insertion or reordering would make room for it
    (possible when the costs break the triangle inequality, or after a repair reorders
    the tour), so that last property is not promised there."""
    view = V.set_view(inst)
    if view.num_sets == 0:
        return
    rng = np.random.default_rng(0)
    width = 4
    perm = np.stack([rng.permutation(view.num_sets) for _ in range(width)])
    m = np.zeros(width, int)
    m = V._fit(view, perm, m)  # feasible prefixes
    banned = rng.random((width, view.num_sets)) < 0.3
    before = V._visited_mask(view, perm, m)
    banned &= ~before
    out, om = V._fill(view, perm, m, banned, rng, slack=slack)
    after = V._visited_mask(view, out, om)
    assert (after >= before).all()
    assert not (after & banned).any()
    assert (V._score(view, out, om)[1] <= view.budget + 1e-9).all()
    if slack:
        return
    # nothing left that fits by a plain insertion
    t = V._tables(view, out, om)
    into, out_of = V._gap_tables(view, t)
    cost = V._lowest(into + out_of)
    gaps = np.arange(cost.shape[1])[None, :, None] <= om[:, None, None]
    free = (~after & ~banned)[:, None, :]
    assert not ((cost <= view.budget) & gaps & free).any()


def test_recreate_makes_a_two_out_one_in_move():
    """Two cheap neighbours (reward 1 each) block a far set worth 3: only removing both
    and refilling reaches it; single moves lower the reward or overshoot the budget."""
    xs = np.array([0.0, 1.0, 1.05, -2.0])
    cost = np.abs(xs[:, None] - xs[None])
    inst = SOPInstance.create(cost, [0, 1, 2, 3], [0.0, 1.0, 1.0, 3.0], 0, 0, 4.5)
    view = V.set_view(inst)
    perm, m = np.array([0, 1, 2]), 2  # visits the two neighbours: reward 2, cost 2.1
    rng = np.random.default_rng(0)
    for which in (1, 2):
        p, pm = V._local_search(view, perm[None], np.array([m]), which, rng, reversals=True)
        assert float(V._score(view, p, pm)[0][0]) == 2.0  # a local optimum
    p, pm, reward, length = V._recreate(view, perm, m, rng, slack=0.3)
    assert reward == 3.0 and length == 4.0 and list(p[:pm]) == [2]


def test_recreate_recovers_a_benchmark_optimum(shared):
    """20kroD100 T20 p2: the optimum swaps two visited sets for one (2180 against 2120)."""
    from bfsop_jax.sop import read_sop

    inst = read_sop(shared("sop", "instances", "20kroD100_RND_T20_p2.sop"))
    assert float(solve_vns(inst, seed=0, recreate=False).reward) < 2180
    assert float(solve_vns(inst, seed=0).reward) == 2180


def test_config_defaults_are_the_reference_configuration():
    assert VNSConfig() == REFERENCE
    assert REFERENCE.max_iters == 2000 and REFERENCE.max_no_improve == 1000
    assert REFERENCE.time_limit is None and REFERENCE.width is None
    assert (REFERENCE.trades, REFERENCE.reversals, REFERENCE.recreate) == (False, True, True)
    assert REFERENCE.squeeze == 0.3 and REFERENCE.squeeze_tries == 3
    assert DEMO_LABELLING == VNSConfig(max_iters=500, max_no_improve=250)
    assert VNSConfig.labelling(50, 25, trades=True) == VNSConfig(50, 25, trades=True)


@pytest.mark.parametrize(
    "field, value",
    [
        ("max_iters", -1),
        ("max_iters", 1.5),
        ("max_no_improve", True),
        ("squeeze_tries", -2),
        ("width", 0),
        ("time_limit", -1.0),
        ("squeeze", -0.1),
        ("squeeze", float("nan")),
        ("trades", 1),
        ("recreate", None),
    ],
)
def test_config_rejects_invalid_fields(field, value):
    with pytest.raises(ValueError, match=rf"VNSConfig\.{field} "):
        VNSConfig(**{field: value})


def test_config_is_hashable_picklable_and_round_trips():
    cfg = VNSConfig(max_iters=np.int64(300), width=8, time_limit=2, squeeze=0)
    assert type(cfg.max_iters) is int and cfg.time_limit == 2.0 and cfg.squeeze == 0.0
    assert hash(cfg) == hash(VNSConfig(max_iters=300, width=8, time_limit=2.0, squeeze=0.0))
    assert pickle.loads(pickle.dumps(cfg)) == cfg
    assert VNSConfig.from_dict(cfg.to_dict()) == cfg
    assert cfg.to_dict() == dataclasses.asdict(cfg)
    with pytest.raises(ValueError, match="unknown VNSConfig field"):
        VNSConfig.from_dict({"max_iter": 3})
    assert cfg.replace(trades=True) == dataclasses.replace(cfg, trades=True)


def test_config_and_old_keywords_agree():
    inst = random_instance(4, num_sets=10)
    kw = dict(max_iters=120, max_no_improve=60, reversals=False)
    old = solve_vns(inst, seed=2, **kw)
    new = solve_vns(inst, seed=2, config=VNSConfig(**kw))
    as_dict = solve_vns(inst, 2, VNSConfig(**kw).to_dict())
    # loose keywords override the config's fields
    mixed = solve_vns(inst, seed=2, config=VNSConfig(max_iters=7, reversals=False), **QUICK | kw)
    for sol in (new, as_dict, mixed):
        np.testing.assert_array_equal(sol.nodes, old.nodes)
        assert sol.cost == old.cost
    with pytest.raises(TypeError, match="max_iter"):
        solve_vns(inst, max_iter=3)


def test_a_batch_of_instances_is_a_one_line_error():
    inst = random_instance(0, num_sets=3)
    batch = inst.replace(cost=np.stack([np.asarray(inst.cost)] * 2))
    with pytest.raises(ValueError, match=r"one instance \(cost \[N, N\]\).*solve_vns_batch"):
        solve_vns(batch)
