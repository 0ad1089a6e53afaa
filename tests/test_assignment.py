import itertools

import numpy as np
import pytest

from pmsr_nn.errors import ConfigError
from pmsr_nn.trackers.assignment import brute_force_events, m_best_sd, sd_assign
from pmsr_nn.trackers.assignment_2d import brute_force_assignments, murty


def random_matrix(rng, allow_infeasible=True):
    R = int(rng.integers(1, 5))
    C = int(rng.integers(R, 7))
    cost = rng.normal(size=(R, C))
    cost[rng.random((R, C)) < 0.3] = np.inf
    if allow_infeasible and rng.random() < 0.1:
        cost[rng.integers(R)] = np.inf
    return cost


def assert_feasible(cost, a):
    assert len(a.cols) == cost.shape[0]
    assert len(set(a.cols.tolist())) == len(a.cols)
    entries = cost[np.arange(cost.shape[0]), a.cols]
    assert np.isfinite(entries).all()
    assert a.cost == pytest.approx(entries.sum(), abs=1e-12)


def test_murty_matches_brute_force():
    rng = np.random.default_rng(0)
    n_infeasible = 0
    for _ in range(150):
        cost = random_matrix(rng)
        ranked = brute_force_assignments(cost)
        n_infeasible += not ranked
        for m in (1, 4, 10):
            got = murty(cost, m)
            assert [a.cost for a in got] == pytest.approx([a.cost for a in ranked[:m]], abs=1e-9)
            assert len({tuple(a.cols) for a in got}) == len(got)
            for a in got:
                assert_feasible(cost, a)
    assert n_infeasible > 0  # the all-inf rows were exercised


def test_murty_returns_all_when_m_exceeds_the_count():
    rng = np.random.default_rng(1)
    for _ in range(20):
        cost = random_matrix(rng, allow_infeasible=False)
        ranked = brute_force_assignments(cost)
        got = murty(cost, len(ranked) + 5)
        assert len(got) == len(ranked)
        assert {tuple(a.cols) for a in got} == {tuple(a.cols) for a in ranked}
    assert [a.cost for a in murty(np.array([[1.0, 2.0], [3.0, 0.5]]), 10)] == [1.5, 5.0]


def test_murty_infeasible_and_empty():
    assert murty(np.array([[np.inf, np.inf], [0.0, 1.0]]), 3) == []
    assert murty(np.array([[0.0, np.inf], [0.0, np.inf]]), 3) == []  # two rows, one usable column
    (only,) = murty(np.zeros((0, 3)), 2)
    assert only.cols.shape == (0,) and only.cost == 0.0


def random_problem(rng, K, N, additive=False):
    """Candidates = every combination of each target's gated subset (at most 2 measurements per
    sensor), the all-(-1) candidate included; every other problem is dense (1-2 measurements per
    sensor, 1-2 gated: targets contest them)."""
    dense = rng.random() < 0.5
    n_meas = [int(rng.integers(1, 3) if dense else rng.integers(0, 4)) for _ in range(N)]
    rows, costs = [], []
    for k in range(K):
        gated = [rng.choice(n, size=min(n, int(rng.integers(int(dense), 3))), replace=False) for n in n_meas]
        terms = [{int(i): rng.normal() for i in g} for g in gated]
        miss = rng.normal(0.5, 0.5, size=N)
        for combo in itertools.product(*[[-1, *g.tolist()] for g in gated]):
            rows.append([k, *combo])
            if additive:
                costs.append(sum(terms[s][i] if i >= 0 else miss[s] for s, i in enumerate(combo)))
            else:
                costs.append(rng.normal(-sum(i >= 0 for i in combo), 1.0))
    return np.array(rows, dtype=np.int64).reshape(-1, 1 + N), np.array(costs), n_meas, K


def assert_event(tuples, costs, n_meas, K, picks, cost):
    assert picks.shape == (K,)
    assert (tuples[picks, 0] == np.arange(K)).all()
    for s in range(len(n_meas)):
        used = tuples[picks, 1 + s]
        used = used[used >= 0]
        assert len(np.unique(used)) == len(used)
    assert cost == pytest.approx(costs[picks].sum(), abs=1e-9)


def test_sd_assign_bounds_the_brute_force_optimum():
    rng = np.random.default_rng(2)
    for _ in range(120):
        K, N = int(rng.integers(1, 4)), int(rng.integers(1, 4))
        problem = random_problem(rng, K, N)
        best = brute_force_events(*problem)[0][1]
        sol = sd_assign(*problem)
        assert_event(*problem, sol.picks, sol.cost)
        assert sol.lower_bound <= best + 1e-9
        assert best <= sol.cost + 1e-9
        if sol.gap <= 1e-9 or N == 1:
            assert sol.cost == pytest.approx(best, abs=1e-9)


def contested_problem(rng, K, N, n):
    """Every target gates every measurement: the relaxation often leaves a duality gap."""
    rows, costs = [], []
    for k in range(K):
        for combo in itertools.product(*[range(-1, n)] * N):
            rows.append([k, *combo])
            costs.append(rng.normal(-sum(i >= 0 for i in combo), 1.0))
    return np.array(rows), np.array(costs), [n] * N, K


def test_sd_assign_bounds_on_contested_problems():
    rng = np.random.default_rng(5)
    n_gap = 0
    for _ in range(40):
        tuples, costs, n_meas, K = problem = contested_problem(rng, 3, int(rng.integers(2, 4)), 2)
        best = brute_force_events(*problem)[0][1]
        sol = sd_assign(*problem)
        assert_event(*problem, sol.picks, sol.cost)
        assert sol.lower_bound <= best + 1e-9 <= sol.cost + 2e-9
        # The dual at u = 0 already bounds by the per-target minima.
        trivial = sum(costs[tuples[:, 0] == k].min() for k in range(K))
        assert sol.lower_bound >= trivial - 1e-9
        n_gap += sol.gap > 1e-6
        first = m_best_sd(*problem, m=5)[0]
        assert first.lower_bound <= best + 1e-9 <= first.cost + 2e-9
    assert n_gap > 0  # problems where the relaxation is not tight were exercised


def test_sd_assign_is_exact_on_additive_costs():
    rng = np.random.default_rng(3)
    for _ in range(60):
        problem = random_problem(rng, int(rng.integers(1, 4)), int(rng.integers(2, 4)), additive=True)
        sol = sd_assign(*problem)
        assert sol.cost == pytest.approx(brute_force_events(*problem)[0][1], abs=1e-9)


def test_m_best_sd_ranks_distinct_feasible_events():
    rng = np.random.default_rng(4)
    for _ in range(60):
        K, N = int(rng.integers(1, 4)), int(rng.integers(1, 4))
        problem = random_problem(rng, K, N)
        ranked = brute_force_events(*problem)
        got = m_best_sd(*problem, m=8)
        assert len(got) == min(8, len(ranked))
        assert len({tuple(e.picks) for e in got}) == len(got)
        costs = [e.cost for e in got]
        assert costs == sorted(costs)
        for e in got:
            assert_event(*problem, e.picks, e.cost)
            assert e.lower_bound <= e.cost + 1e-9
        assert costs[0] >= ranked[0][1] - 1e-9
        if N == 1:
            assert costs == pytest.approx([c for _, c in ranked[:8]], abs=1e-9)


def test_m_best_sd_returns_every_event_of_a_small_problem():
    # Two targets contest measurement 0 of both sensors.
    tuples = np.array([[0, -1, -1], [0, 0, -1], [0, 0, 0], [1, -1, -1], [1, 0, 0], [1, -1, 0]])
    costs = np.array([0.0, -1.0, -2.5, 0.0, -2.0, -0.7])
    ranked = brute_force_events(tuples, costs, [1, 1], 2)
    got = m_best_sd(tuples, costs, [1, 1], 2, m=100)
    assert {tuple(e.picks) for e in got} == {tuple(p) for p, _ in ranked}
    assert [e.cost for e in got] == pytest.approx([c for _, c in ranked])
    assert got[0].cost == -2.5


def test_m_best_sd_enumerates_every_event():
    # With m above the count, the partition must reach every event, including those behind
    # children whose forbidden all-(-1) candidate leaves a target that must detect.
    rng = np.random.default_rng(6)
    n_checked = 0
    while n_checked < 15:
        problem = random_problem(rng, int(rng.integers(2, 4)), int(rng.integers(2, 4)))
        ranked = brute_force_events(*problem)
        if len(ranked) > 60:
            continue
        got = m_best_sd(*problem, m=len(ranked) + 3)
        assert sorted(tuple(e.picks) for e in got) == sorted(tuple(p) for p, _ in ranked)
        assert [e.cost for e in got] == pytest.approx([c for _, c in ranked], abs=1e-9)
        n_checked += 1


def test_bad_input_is_rejected():
    tuples = np.array([[0, -1, -1], [0, 0, 1], [1, -1, -1]])
    costs = np.array([0.0, -1.0, 0.0])
    with pytest.raises(ConfigError, match="shape"):
        sd_assign(tuples, costs[:2], [1, 2], 2)
    with pytest.raises(ConfigError, match="shape"):
        sd_assign(tuples, costs, [1], 2)
    with pytest.raises(ConfigError, match="finite"):
        sd_assign(tuples, np.array([0.0, np.nan, 0.0]), [1, 2], 2)
    with pytest.raises(ConfigError, match="missed"):
        sd_assign(tuples[1:], costs[1:], [1, 2], 2)
    with pytest.raises(ConfigError, match="measurement indices"):
        sd_assign(tuples, costs, [1, 1], 2)
    with pytest.raises(ConfigError, match="target indices"):
        sd_assign(tuples, costs, [1, 2], 1)
    with pytest.raises(ConfigError, match="m must be"):
        m_best_sd(tuples, costs, [1, 2], 2, m=0)
    with pytest.raises(ConfigError, match="iterations"):
        sd_assign(tuples, costs, [1, 2], 2, iterations=0)
    with pytest.raises(ConfigError, match="m must be"):
        murty(np.zeros((2, 2)), 0)
    with pytest.raises(ConfigError, match="NaN"):
        murty(np.array([[0.0, np.nan]]), 1)
    with pytest.raises(ConfigError, match="rows"):
        murty(np.zeros((3, 2)), 1)
    with pytest.raises(ConfigError, match="2-D"):
        murty(np.zeros(3), 1)
    with pytest.raises(ConfigError, match="limited"):
        brute_force_assignments(np.zeros((8, 8)))
