"""Tests for the episode metrics (optimal visit length, PPL, revisits, bootstrap)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from bfsop_jax import metrics
from bfsop_jax.metrics import (
    EXACT_FORCE_MAX,
    EXACT_MAX,
    bootstrap_ci,
    optimal_visit_length,
    paired_bootstrap_ci,
    ppl,
    revisit_fraction,
)


def _brute_force(d: np.ndarray) -> float:
    f = d.shape[0] - 1
    if f == 0:
        return 0.0
    best = np.inf
    for perm in itertools.permutations(range(1, f + 1)):
        path = (0, *perm)
        best = min(best, sum(d[path[k], path[k + 1]] for k in range(f)))
    return float(best)


def _euclidean(rng: np.random.Generator, f: int) -> np.ndarray:
    pts = rng.uniform(0.0, 20.0, size=(f + 1, 2))
    return np.linalg.norm(pts[:, None, :] - pts[None, :, :], axis=-1)


# ----------------------------------------------------------------------- optimal visit length


@pytest.mark.parametrize("f", range(8))
@pytest.mark.parametrize("symmetric", [True, False])
def test_held_karp_matches_brute_force(f: int, symmetric: bool) -> None:
    rng = np.random.default_rng(100 + f + 50 * symmetric)
    for _ in range(3):
        d = rng.uniform(0.5, 10.0, size=(f + 1, f + 1))
        if symmetric:
            d = (d + d.T) / 2
        np.fill_diagonal(d, 0.0)
        got = optimal_visit_length(d, exact=True)
        assert got == pytest.approx(_brute_force(d), rel=1e-12, abs=1e-12)
        assert optimal_visit_length(d) == got  # automatic mode is exact here


@pytest.mark.parametrize("f", [8, 12, 16, EXACT_MAX])
def test_heuristic_finds_the_optimum(f: int) -> None:
    """The iterated local search lands on Held-Karp's optimum on these seeded matrices,
    uniform and clustered (points around a few room centres, as targets in a house are);
    it is never below it. Its miss rate by size: ``python -m benchmarks.bench_metrics``."""
    rng = np.random.default_rng(f)
    rooms = rng.uniform(0.0, 20.0, size=(4, 2))
    clustered = rooms[rng.integers(0, 4, f + 1)] + rng.normal(0.0, 1.0, size=(f + 1, 2))
    for d in (_euclidean(rng, f), np.linalg.norm(clustered[:, None] - clustered[None], axis=-1)):
        ex = optimal_visit_length(d, exact=True)
        assert optimal_visit_length(d, exact=False) == pytest.approx(ex, rel=1e-12)


def test_heuristic_asymmetric_never_below_exact() -> None:
    rng = np.random.default_rng(7)
    for f in (5, 9, 14):
        d = rng.uniform(1.0, 10.0, size=(f + 1, f + 1))
        assert optimal_visit_length(d, exact=False) >= optimal_visit_length(d, exact=True) - 1e-9


def test_heuristic_is_deterministic() -> None:
    d = _euclidean(np.random.default_rng(21), 30)
    assert optimal_visit_length(d) == optimal_visit_length(d)


@pytest.mark.parametrize("symmetric", [True, False])
def test_best_moves_match_every_move_applied(symmetric: bool) -> None:
    """The vectorised deltas of the best 2-opt and or-opt moves equal the best change in
    path length over every move applied one by one (asymmetric costs included)."""
    rng = np.random.default_rng(4 + symmetric)
    n = 9
    w = rng.uniform(0.5, 10.0, size=(n, n))
    if symmetric:
        w = (w + w.T) / 2
    path = np.concatenate([[0], 1 + rng.permutation(n - 1)])
    base = metrics._path_cost(w, path)
    two = [
        metrics._path_cost(w, np.concatenate((path[:i], path[i : j + 1][::-1], path[j + 1 :])))
        for i in range(1, n) for j in range(i + 1, n)
    ]  # fmt: skip
    delta, (i, j) = metrics._best_two_opt(path, w, *metrics._prefix_costs(path, w))
    assert delta == pytest.approx(min(two) - base, abs=1e-9)
    moved = np.concatenate((path[:i], path[i : j + 1][::-1], path[j + 1 :]))
    assert metrics._path_cost(w, moved) == pytest.approx(base + delta, abs=1e-9)

    ors = []
    for s in (1, 2, 3):
        for i in range(1, n - s + 1):
            for t in [*range(0, i - 1), *range(i + s, n)]:
                for rev in (False, True) if s > 1 else (False,):
                    out = metrics._apply_or_opt(path, (i, s, t, rev))
                    assert sorted(out) == list(range(n)) and out[0] == 0
                    ors.append(metrics._path_cost(w, out))
    delta, move = metrics._best_or_opt(path, w, *metrics._prefix_costs(path, w))
    assert delta == pytest.approx(min(ors) - base, abs=1e-9)
    assert metrics._path_cost(w, metrics._apply_or_opt(path, move)) == pytest.approx(
        base + delta, abs=1e-9
    )


def test_automatic_is_exact_up_to_exact_max() -> None:
    """Automatic mode runs Held-Karp up to ``EXACT_MAX`` targets (its time by size:
    ``python -m benchmarks.bench_metrics``)."""
    rng = np.random.default_rng(3)
    for _ in range(3):
        d = _euclidean(rng, EXACT_MAX)
        exact = optimal_visit_length(d, exact=True)
        assert optimal_visit_length(d) == exact
        assert optimal_visit_length(d, exact=False) >= exact - 1e-9


def test_automatic_uses_heuristic_above_exact_max() -> None:
    f = EXACT_MAX + 1
    d = _euclidean(np.random.default_rng(11), f)
    auto = optimal_visit_length(d)
    assert np.isfinite(auto)
    assert auto == optimal_visit_length(d, exact=False)
    assert auto >= d[0, 1:].max() - 1e-9


def test_exact_forced_too_large_raises() -> None:
    d = _euclidean(np.random.default_rng(0), EXACT_FORCE_MAX + 1)
    with pytest.raises(ValueError, match="at most"):
        optimal_visit_length(d, exact=True)


@pytest.mark.parametrize("exact", [True, False])
def test_points_on_a_line(exact: bool) -> None:
    x = np.array([0.0, 3.0, -1.0, 5.0, 2.0])  # start at 0: go left to -1, then right to 5
    d = np.abs(x[:, None] - x[None, :])
    assert optimal_visit_length(d, exact=exact) == pytest.approx(7.0)
    x = np.array([0.0, 4.0, 1.0, 3.0, 2.0])
    d = np.abs(x[:, None] - x[None, :])
    assert optimal_visit_length(d, exact=exact) == pytest.approx(4.0)
    x = np.arange(20.0)[::-1] - 0.0  # start at 19, targets 18..0 (heuristic regime)
    d = np.abs(x[:, None] - x[None, :])
    assert optimal_visit_length(d) == pytest.approx(19.0)


def test_trivial_sizes() -> None:
    assert optimal_visit_length(np.zeros((1, 1))) == 0.0
    assert optimal_visit_length(np.array([[0.0, 2.5], [9.0, 0.0]])) == 2.5
    assert optimal_visit_length(np.array([[0.0, 2.5], [9.0, 0.0]]), exact=False) == 2.5


@pytest.mark.parametrize("exact", [True, False])
def test_inf_entries(exact: bool) -> None:
    d = np.array(
        [
            [0.0, 1.0, np.inf],
            [1.0, 0.0, 2.0],
            [np.inf, 2.0, 0.0],
        ]
    )
    assert optimal_visit_length(d, exact=exact) == pytest.approx(3.0)
    d[1, 2] = d[2, 1] = np.inf  # node 2 unreachable
    assert optimal_visit_length(d, exact=exact) == np.inf


def test_heuristic_avoids_inf_edges_when_possible() -> None:
    d = _euclidean(np.random.default_rng(5), 10)
    d[0, 1:] = np.inf
    d[0, 3] = 1.0  # only one way out of the start
    d[[2, 5], 7] = np.inf
    ex = optimal_visit_length(d, exact=True)
    heur = optimal_visit_length(d, exact=False)
    assert np.isfinite(ex) and np.isfinite(heur)
    assert ex - 1e-9 <= heur <= 1.3 * ex


@pytest.mark.parametrize(
    "bad",
    [
        np.zeros((2, 3)),
        np.zeros(3),
        np.zeros((0, 0)),
        np.array([[0.0, np.nan], [1.0, 0.0]]),
        np.array([[0.0, -1.0], [1.0, 0.0]]),
        np.array([[0.0, -np.inf], [1.0, 0.0]]),
    ],
)
def test_bad_dist_raises(bad: np.ndarray) -> None:
    with pytest.raises(ValueError):
        optimal_visit_length(bad)


# ----------------------------------------------------------------------------------------- PPL


def test_ppl_hand_cases() -> None:
    assert ppl(0, 3, 10.0, 5.0) == 0.0
    assert ppl(0, 0, 0.0, 0.0) == 0.0
    assert ppl(3, 3, 5.0, 5.0) == 1.0
    assert ppl(3, 3, 4.0, 5.0) == 1.0  # capped at 1
    assert ppl(2, 4, 10.0, 5.0) == pytest.approx(0.25)  # L = 2 l_opt -> P / 2
    assert ppl(2, 2, 0.0, 0.0) == 1.0  # verified at the start without moving
    assert isinstance(ppl(1, 2, 3.0, 3.0), float)


def test_ppl_elementwise() -> None:
    found = np.array([0, 1, 2, 2])
    total = np.array([2, 2, 2, 2])
    length = np.array([5.0, 4.0, 8.0, 0.0])
    lopt = np.array([4.0, 4.0, 4.0, 0.0])
    out = ppl(found, total, length, lopt)
    assert isinstance(out, np.ndarray)
    np.testing.assert_allclose(out, [0.0, 0.5, 0.5, 1.0])
    np.testing.assert_allclose(ppl(found, 2, length, lopt), out)


@pytest.mark.parametrize(
    "args",
    [
        (3, 2, 1.0, 1.0),
        (-1, 2, 1.0, 1.0),
        (1, 2, -1.0, 1.0),
        (1, 2, 1.0, -1.0),
        (1, 2, np.nan, 1.0),
        (np.array([1, 2]), np.array([2, 2, 2]), 1.0, 1.0),
    ],
)
def test_ppl_bad_input_raises(args: tuple) -> None:
    with pytest.raises(ValueError):
        ppl(*args)


# ----------------------------------------------------------------------------------- revisits


def test_revisit_back_and_forth() -> None:
    start = np.array([4, 4])
    cells = np.array([[4, 5], [4, 6], [4, 7], [4, 6], [4, 5], [4, 4]])
    lengths = np.full(6, 0.25)
    assert revisit_fraction(start, cells, lengths) == pytest.approx(0.5)


def test_revisit_straight_and_empty() -> None:
    start = np.array([0, 0])
    cells = np.array([[1, 0], [2, 0], [3, 0], [3, 1]])
    assert revisit_fraction(start, cells, np.array([1.0, 1.0, 2.0, 0.5])) == 0.0
    assert revisit_fraction(start, np.zeros((0, 2), int), np.zeros(0)) == 0.0


def test_revisit_weighted_by_length() -> None:
    start = np.array([0, 0])
    cells = np.array([[0, 1], [0, 0], [0, 1], [0, 2]])
    lengths = np.array([1.0, 2.0, 3.0, 4.0])  # steps 2 and 3 are revisits
    assert revisit_fraction(start, cells, lengths) == pytest.approx(0.5)


def test_revisit_bad_shapes_raise() -> None:
    with pytest.raises(ValueError):
        revisit_fraction(np.array([0, 0]), np.zeros((3, 2), int), np.zeros(2))
    with pytest.raises(ValueError):
        revisit_fraction(np.array([0, 0]), np.zeros((3, 3), int), np.zeros(3))
    with pytest.raises(ValueError):
        revisit_fraction(np.array([0, 0]), np.zeros((1, 2), int), np.array([-1.0]))


# ---------------------------------------------------------------------------------- bootstrap


def test_bootstrap_contains_mean_and_deterministic() -> None:
    v = np.random.default_rng(0).normal(2.0, 1.0, size=60)
    lo, hi = bootstrap_ci(v)
    assert lo < v.mean() < hi
    assert bootstrap_ci(v) == (lo, hi)
    assert bootstrap_ci(v, seed=1) != (lo, hi)


def test_bootstrap_shrinks_with_more_data() -> None:
    rng = np.random.default_rng(1)
    small = rng.normal(0.0, 1.0, size=25)
    large = rng.normal(0.0, 1.0, size=400)
    w_small = np.subtract(*bootstrap_ci(small)[::-1])
    w_large = np.subtract(*bootstrap_ci(large)[::-1])
    assert w_large < w_small


def test_bootstrap_edge_cases() -> None:
    assert bootstrap_ci([3.5]) == (3.5, 3.5)
    with pytest.raises(ValueError):
        bootstrap_ci([])
    with pytest.raises(ValueError):
        bootstrap_ci([1.0, 2.0], level=1.5)


def test_paired_bootstrap() -> None:
    rng = np.random.default_rng(2)
    a = rng.normal(size=50)
    assert paired_bootstrap_ci(a, a) == (0.0, 0.0, 0.0)
    np.testing.assert_allclose(paired_bootstrap_ci(a - 0.1, a), -0.1, rtol=1e-12)
    base = np.arange(50.0)
    assert paired_bootstrap_ci(base + 0.5, base) == (0.5, 0.5, 0.5)
    c = a + rng.normal(0.3, 0.5, size=50)
    m, lo, hi = paired_bootstrap_ci(c, a)
    assert m == pytest.approx(np.mean(c - a))
    assert lo < m < hi
    assert paired_bootstrap_ci(c, a) == (m, lo, hi)
    with pytest.raises(ValueError):
        paired_bootstrap_ci(a, a[:-1])


def test_bootstrap_over_groups_resamples_whole_groups() -> None:
    """With one label per value the group bootstrap is the plain one; when values within a
    group are alike, resampling groups gives the (wider) interval of a few group means, and
    it matches a plain bootstrap of those means when groups are of equal size."""
    rng = np.random.default_rng(3)
    v = rng.normal(size=40)
    np.testing.assert_allclose(bootstrap_ci(v, groups=np.arange(40)), bootstrap_ci(v))
    means = rng.normal(0.0, 1.0, size=6)
    clustered = np.repeat(means, 25) + rng.normal(0.0, 0.01, size=150)
    houses = np.repeat(np.arange(100, 106), 25)
    lo, hi = bootstrap_ci(clustered, groups=houses)
    plo, phi = bootstrap_ci(clustered)
    assert hi - lo > 3 * (phi - plo)  # 150 near-copies of 6 values are 6 values
    glo, ghi = bootstrap_ci(clustered.reshape(6, 25).mean(axis=1))
    assert (lo, hi) == pytest.approx((glo, ghi), abs=1e-9)
    assert bootstrap_ci(clustered, groups=houses) == (lo, hi)  # seeded
    order = rng.permutation(150)  # labels, not positions, define the groups
    assert bootstrap_ci(clustered[order], groups=houses[order]) == pytest.approx((lo, hi))
    d, dlo, dhi = paired_bootstrap_ci(clustered + 0.2, clustered, groups=houses)
    assert (d, dlo, dhi) == pytest.approx((0.2, 0.2, 0.2))
    with pytest.raises(ValueError, match="one label per value"):
        bootstrap_ci(v, groups=np.arange(39))
    with pytest.raises(ValueError, match="at least two distinct labels"):
        paired_bootstrap_ci(v, v + rng.normal(size=40), groups=np.zeros(40))


def test_metrics_benchmark_rows() -> None:
    """``benchmarks.bench_metrics`` times both solvers where Held-Karp is allowed, the
    heuristic alone above, and never finds the heuristic below the optimum."""
    from benchmarks.bench_metrics import main

    rows = main(["--sizes", f"3,{EXACT_FORCE_MAX + 1}", "--matrices", "2"])
    assert [r["F"] for r in rows] == [3, EXACT_FORCE_MAX + 1]
    assert rows[0]["gap_pct_max"] >= rows[0]["gap_pct_mean"] >= -1e-9
    assert rows[0]["misses"] == 0
    assert "exact_ms_median" not in rows[1] and rows[1]["heuristic_ms_median"] > 0


def test_metrics_benchmark_on_house_matrices() -> None:
    """With ``--preset``, the heuristic is compared with Held-Karp on the evaluation's own
    matrices (a house's targets, from an episode's start)."""
    from benchmarks.bench_metrics import main

    rows = main(["--sizes", "3", "--matrices", "1", "--preset", "demo", "--houses", "1"])
    house = [r for r in rows if r.get("preset") == "demo"]
    assert [r["F"] for r in house] == [3] and house[0]["pairs"] >= 1
    assert house[0]["misses"] == 0 and house[0]["gap_pct_max"] >= -1e-9


def test_paired_ratio_ci_is_the_ratio_of_means_with_a_seeded_interval():
    rng = np.random.default_rng(3)
    b = rng.uniform(0.1, 0.3, 60)
    a = 1.5 * b  # a constant ratio: every resample gives it exactly
    ratio, lo, hi = metrics.paired_ratio_ci(a, b)
    assert ratio == pytest.approx(1.5) and lo == pytest.approx(1.5) and hi == pytest.approx(1.5)
    a = b * rng.uniform(1.0, 2.0, 60)
    ratio, lo, hi = metrics.paired_ratio_ci(a, b, groups=np.repeat(np.arange(6), 10))
    assert ratio == pytest.approx(a.mean() / b.mean())
    assert 1.0 <= lo < ratio < hi <= 2.0
    assert metrics.paired_ratio_ci(a, b, seed=1) == metrics.paired_ratio_ci(a, b, seed=1)
    with pytest.raises(ValueError, match="positive mean of b"):
        metrics.paired_ratio_ci(a, np.zeros(60))
