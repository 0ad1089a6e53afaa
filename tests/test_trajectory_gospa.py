"""Trajectory GOSPA against brute-force enumeration of assignment sequences, per-scan GOSPA
(gamma = 0), hand-worked cases and its LP relaxation."""

import itertools
import math

import numpy as np
import pytest
import torch

from pmsr_nn.metrics.sets import gospa
from pmsr_nn.metrics.trajectory_gospa import trajectory_gospa

NAN = float("nan")


def _brute_force(est, exists, truth, alive, c, p, gamma):
    """Least cost over every sequence of assignments of one run (numpy arrays ``(K, M, D)``,
    ``(K, M)``, ``(K, N, D)``, ``(K, N)``), written from the paper's definition: target ``i``
    assigned to track ``j`` (0: nothing) costs ``min(d, c)^p`` where both exist, ``c^p/2`` where one
    does, 0 where neither; an existing track assigned to no target ``c^p/2``; a change of a
    target's track ``gamma^p`` (``gamma^p/2`` to or from nothing)."""
    K, N = alive.shape
    M = exists.shape[1]
    options = [a for a in itertools.product(range(M + 1), repeat=N) if len([j for j in a if j]) == len({j for j in a if j})]
    scan = np.zeros((K, len(options)))
    for k in range(K):
        for o, a in enumerate(options):
            cost = 0.0
            for i, j in enumerate(a):
                x, y = bool(alive[k, i]), j > 0 and bool(exists[k, j - 1])
                if x and y:
                    cost += min(float(np.linalg.norm(truth[k, i] - est[k, j - 1])), c) ** p
                elif x or y:
                    cost += c**p / 2
            cost += c**p / 2 * sum(1 for j in range(M) if exists[k, j] and (j + 1) not in a)
            scan[k, o] = cost
    switch = np.array([[sum(0.0 if u == v else (1.0 if u and v else 0.5) for u, v in zip(a, b)) for b in options] for a in options])
    total = np.zeros((1,) * K)  # every sequence at once: axis k is scan k's assignment
    for k in range(K):
        shape = [1] * K
        shape[k] = len(options)
        total = total + scan[k].reshape(shape)
        if k:
            shape[k - 1] = len(options)
            total = total + gamma**p * switch.reshape(shape)
    return float(total.min())


def _random_case(rng, K, N, M, c):
    truth = rng.uniform(0, 2 * c, (1, K, N, 2))
    est = truth[:, :, rng.integers(0, N, M)] + rng.normal(0, 0.6 * c, (1, K, M, 2))  # near and far pairs
    alive, exists = rng.random((1, K, N)) < 0.75, rng.random((1, K, M)) < 0.75
    est[~exists] = NAN
    truth[~alive] = NAN
    return torch.tensor(est), torch.tensor(exists), torch.tensor(truth), torch.tensor(alive)


CASES = [(K, M, p, g) for K, M in ((3, 2), (4, 2), (3, 3), (4, 3)) for p, g in ((2.0, 0.0), (2.0, 4.0), (1.0, 10.0), (2.0, 15.0))]


@pytest.mark.parametrize("K,M,p,gamma", CASES)
def test_integer_value_is_the_least_cost_over_every_assignment_sequence(K, M, p, gamma):
    rng = np.random.default_rng(1000 * K + 10 * M + int(gamma))
    c = 10.0
    for _ in range(3):
        est, exists, truth, alive = _random_case(rng, K, 2, M, c)
        r = trajectory_gospa(est, exists, truth, alive, c, p, gamma)
        want = _brute_force(est[0].numpy(), exists[0].numpy(), truth[0].numpy(), alive[0].numpy(), c, p, gamma)
        assert float(r.total[0]) ** p == pytest.approx(want, rel=1e-9, abs=1e-9)
        lp = trajectory_gospa(est, exists, truth, alive, c, p, gamma, integer=False)
        assert float(lp.total[0]) ** p <= want * (1 + 1e-7) + 1e-7  # a relaxation: never above the integer optimum
        assert bool(r.integral[0])


def test_with_no_switching_cost_it_is_the_sum_over_scans_of_per_scan_gospa():
    rng = np.random.default_rng(7)
    c, p = 10.0, 2.0
    est, exists, truth, alive = (torch.cat(x) for x in zip(*[_random_case(rng, 6, 3, 4, c) for _ in range(3)]))
    r = trajectory_gospa(est, exists, truth, alive, c, p, 0.0)
    g = gospa(est, exists, truth, alive, c, p)  # (B, K) per scan
    torch.testing.assert_close(r.total**p, (g.total**p).sum(1), rtol=1e-10, atol=1e-9)
    for mine, theirs in ((r.localisation, g.localisation), (r.missed, g.missed), (r.false, g.false)):
        torch.testing.assert_close(mine, theirs.sum(1), rtol=1e-10, atol=1e-9)  # continuous draws: no ties
    torch.testing.assert_close(r.per_scan, (g.total**p).mean(1) ** (1 / p), rtol=1e-10, atol=1e-9)
    assert float(r.switching.abs().max()) == 0.0


def _line(x0, K, dx=1.0):
    """``(K, 2)`` positions moving along x from ``x0``."""
    return np.stack([x0 + dx * np.arange(K), np.zeros(K)], -1)


def _case(targets, tracks, alive=None, exists=None):
    truth = torch.tensor(np.stack(targets, 1)[None])
    est = torch.tensor(np.stack(tracks, 1)[None]) if tracks else torch.zeros(1, truth.shape[1], 0, 2, dtype=torch.float64)
    alive = torch.ones(truth.shape[:3], dtype=torch.bool) if alive is None else torch.tensor(alive)[None]
    exists = torch.ones(est.shape[:3], dtype=torch.bool) if exists is None else torch.tensor(exists)[None]
    return est, exists, truth, alive


C, P = 10.0, 2.0


def _both(case, gamma):
    """Integer and LP results of one hand-worked case; the LP must be integral and equal."""
    r = trajectory_gospa(*case, C, P, gamma)
    lp = trajectory_gospa(*case, C, P, gamma, integer=False)
    assert bool(lp.integral[0])
    torch.testing.assert_close(lp.total, r.total, rtol=1e-9, atol=1e-9)
    return r


def test_a_perfect_tracker_scores_zero():
    A, B = _line(0.0, 6), _line(100.0, 6)
    alive = np.ones((6, 2), bool)
    alive[:2, 1] = False  # B is born at scan 2, and so is its track
    r = _both(_case([A, B], [A, B], alive, alive.copy()), 5.0)
    assert float(r.total[0]) == 0.0 and float(r.n_switches[0]) == 0.0
    assert r.assignment[0].tolist() == [[0, -1], [0, -1], [0, 1], [0, 1], [0, 1], [0, 1]]


def test_two_tracks_that_swap_targets_halfway_score_two_switches():
    A, B = _line(0.0, 4), _line(100.0, 4)
    t0 = np.concatenate([A[:2], B[2:]])
    t1 = np.concatenate([B[:2], A[2:]])
    r = _both(_case([A, B], [t0, t1]), 5.0)
    # both targets change track once (a full switch each): 2 gamma^p = 50 < keeping them, 4 c^p
    assert float(r.total[0]) == pytest.approx(math.sqrt(50.0), rel=1e-12)
    assert float(r.switching[0]) == pytest.approx(50.0) and float(r.n_switches[0]) == 2.0
    assert float(r.localisation[0] + r.missed[0] + r.false[0]) == 0.0


def test_one_track_that_moves_from_one_target_to_the_other_halfway():
    A, B = _line(0.0, 4), _line(100.0, 4)
    case = _case([A, B], [np.concatenate([A[:2], B[2:]])])
    # gamma^p = 25 < 2 c^p: follow the track; each target is missed for 2 scans (4 c^p/2 = 200)
    # and changes from/to nothing once (two half switches: gamma^p = 25)
    r = _both(case, 5.0)
    assert float(r.total[0]) ** 2 == pytest.approx(225.0, rel=1e-12)
    assert (float(r.missed[0]), float(r.false[0]), float(r.switching[0]), float(r.n_switches[0])) == (200.0, 0.0, 25.0, 1.0)
    # gamma^p = 400 > 2 c^p: a switch costs more; A keeps the track (far from it in scans 2-3:
    # one missed target and one false track there), B is missed throughout: 6 c^p/2 + 2 c^p/2 = 400
    r = _both(case, 20.0)
    assert float(r.total[0]) ** 2 == pytest.approx(400.0, rel=1e-12)
    assert (float(r.n_missed[0]), float(r.n_false[0]), float(r.n_switches[0])) == (6.0, 2.0, 0.0)


@pytest.mark.parametrize("padded", [False, True])
def test_a_missing_track_costs_half_the_cut_off_power_per_scan(padded):
    A = _line(0.0, 5)
    case = _case([A], [np.full((5, 2), NAN)], exists=np.zeros((5, 1), bool)) if padded else _case([A], [])
    r = _both(case, 5.0)
    assert float(r.total[0]) ** 2 == pytest.approx(5 * C**2 / 2, rel=1e-12)
    assert float(r.missed[0]) == pytest.approx(250.0) and float(r.n_missed[0]) == 5.0
    # and a false track the same
    r = _both(_case([np.full((5, 2), NAN)], [A], alive=np.zeros((5, 1), bool)), 5.0)
    assert (float(r.false[0]), float(r.n_false[0]), float(r.missed[0])) == (250.0, 5.0, 0.0)


def test_padding_and_runs_do_not_change_a_run_value():
    rng = np.random.default_rng(3)
    est, exists, truth, alive = _random_case(rng, 5, 2, 3, C)
    r = trajectory_gospa(est, exists, truth, alive, C, P, 6.0)
    pad = lambda x, m, n: (torch.cat([x, torch.full((*x.shape[:2], n, 2), NAN, dtype=x.dtype)], 2),
                           torch.cat([m, torch.zeros((*m.shape[:2], n), dtype=torch.bool)], 2))
    e2, x2 = pad(est, exists, 2)
    t2, a2 = pad(truth, alive, 1)
    other = _random_case(rng, 5, 3, 5, C)
    both = trajectory_gospa(torch.cat([e2, other[0]]), torch.cat([x2, other[1]]), torch.cat([t2, other[2]]),
                            torch.cat([a2, other[3]]), C, P, 6.0)
    torch.testing.assert_close(both.total[:1], r.total, rtol=1e-10, atol=1e-10)
    torch.testing.assert_close(both.total[1:], trajectory_gospa(*other, C, P, 6.0).total, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("change", ["c", "p", "gamma", "shape", "dtype", "nan"])
def test_bad_arguments_are_refused(change):
    est, exists, truth, alive = _case([_line(0.0, 3)], [_line(0.0, 3)])
    args = {"c": C, "p": P, "gamma": 1.0}
    if change == "c":
        args["c"] = 0.0
    elif change == "p":
        args["p"] = 0.5
    elif change == "gamma":
        args["gamma"] = -1.0
    elif change == "shape":
        exists = exists[:, :2]
    elif change == "dtype":
        alive = alive.to(torch.float64)
    else:
        est = est.clone()
        est[0, 1, 0, 0] = NAN
    with pytest.raises(ValueError):
        trajectory_gospa(est, exists, truth, alive, **args)


def test_the_lp_relaxation_can_lie_strictly_below_the_integer_value():
    """A case (found by a random search, coordinates rounded to metres) whose LP optimum is
    fractional: the LP is a lower bound, not the metric's value."""
    est = np.array([[[NAN, NAN], [9, 2], [16, 6]], [[18, 11], [15, 23], [16, 3]], [[-2, 4], [0, 5], [8, -2]]], float)
    exists = np.array([[0, 1, 1], [1, 1, 1], [1, 1, 1]], bool)
    truth = np.array([[[9, 4], [8, 9]], [[18, 11], [17, 15]], [[NAN, NAN], [2, 4]]], float)
    alive = np.array([[1, 1], [1, 1], [0, 1]], bool)
    case = tuple(torch.tensor(x)[None] for x in (est, exists, truth, alive))
    r = trajectory_gospa(*case, C, P, 6.0)
    lp = trajectory_gospa(*case, C, P, 6.0, integer=False)
    assert float(r.total[0]) ** 2 == pytest.approx(_brute_force(est, exists, truth, alive, C, P, 6.0), rel=1e-12)
    assert not bool(lp.integral[0])
    assert float(lp.total[0]) ** 2 < float(r.total[0]) ** 2 - 1.0
