"""The exact m-best events of the (S+1)-D assignment (branch and bound) against brute force."""

import numpy as np
import pytest

import pmsr_nn.trackers.jpda as jpda
from pmsr_nn.errors import ConfigError
from pmsr_nn.trackers.assignment import brute_force_events, m_best_sd
from pmsr_nn.trackers.assignment_bnb import m_best_bnb

from test_assignment import assert_event, contested_problem, random_problem


def assert_ranked_like_brute_force(problem, m):
    """Costs equal brute force's m cheapest, and so are the events (continuous random costs:
    no ties), each a feasible event."""
    ranked = brute_force_events(*problem)
    got = m_best_bnb(*problem, m=m)
    assert got is not None
    assert len(got) == min(m, len(ranked))
    assert [e.cost for e in got] == pytest.approx([c for _, c in ranked[:m]], abs=1e-9)
    assert {tuple(e.picks) for e in got} == {tuple(p) for p, _ in ranked[:m]}
    for e in got:
        assert_event(*problem, e.picks, e.cost)
        assert e.gap == 0.0
    return got


@pytest.mark.parametrize("m", [1, 7, 60])
def test_m_best_bnb_equals_brute_force(m):
    rng = np.random.default_rng(11)
    for _ in range(60):
        K, N = int(rng.integers(1, 5)), int(rng.integers(1, 4))
        assert_ranked_like_brute_force(random_problem(rng, K, N), m)


def test_m_best_bnb_on_contested_problems_where_the_relaxation_leaves_a_gap():
    """Every target gates every measurement. The relaxation misses cheaper events on some of
    these problems (counted, so the case is exercised); the branch and bound never does."""
    rng = np.random.default_rng(5)
    missed = 0
    for _ in range(30):
        problem = contested_problem(rng, 3, int(rng.integers(2, 4)), 2)
        got = assert_ranked_like_brute_force(problem, 20)
        relaxed = m_best_sd(*problem, m=20)
        missed += any(r.cost > g.cost + 1e-9 for r, g in zip(relaxed, got))
    assert missed > 0


def test_window_widening_and_every_event_when_m_exceeds_the_count():
    rng = np.random.default_rng(3)
    problem = contested_problem(rng, 3, 2, 2)
    n_events = len(brute_force_events(*problem))
    costs = problem[1] * 50.0  # events spread over hundreds of nats: the first window holds few
    spread = (problem[0], costs, problem[2], problem[3])
    assert len(assert_ranked_like_brute_force(spread, n_events + 10)) == n_events


def test_state_budget_returns_none_and_marginals_fall_back_on_the_relaxation(monkeypatch):
    rng = np.random.default_rng(4)
    problem = contested_problem(rng, 3, 3, 2)
    assert m_best_bnb(*problem, m=10, max_states=2) is None
    exact, gap = jpda.candidate_marginals(*problem, 10, 20)
    assert gap == 0.0 and exact.sum() == pytest.approx(3.0)  # each target's candidates sum to 1
    monkeypatch.setattr(jpda, "m_best_bnb", lambda *a, **k: None)  # the budget exceeded
    fallback, _ = jpda.candidate_marginals(*problem, 10, 20)
    relaxation, _ = jpda.candidate_marginals(*problem, 10, 20, search="relaxation")
    np.testing.assert_array_equal(fallback, relaxation)


def test_no_target_and_bad_input():
    (only,) = m_best_bnb(np.zeros((0, 3), dtype=np.int64), np.zeros(0), [2, 1], 0, m=5)
    assert only.picks.shape == (0,) and only.cost == 0.0
    tuples, costs, n_meas, K = contested_problem(np.random.default_rng(0), 2, 2, 1)
    with pytest.raises(ConfigError, match="max_states"):
        m_best_bnb(tuples, costs, n_meas, K, m=3, max_states=0)
    with pytest.raises(ConfigError, match="m must be"):
        m_best_bnb(tuples, costs, n_meas, K, m=0)
    with pytest.raises(ConfigError, match="missed"):
        m_best_bnb(tuples[1:], costs[1:], n_meas, K, m=3)  # target 0 lost its all-(-1) candidate
    with pytest.raises(ValueError, match="search must be one of"):
        jpda.candidate_marginals(tuples, costs, n_meas, K, 3, 20, search="murty")
