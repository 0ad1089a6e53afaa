"""The persistent (CLEAR MOT) mapping of tracks to targets that track-level figures are counted on."""

from __future__ import annotations

import itertools
import math

import pytest
import torch

from pmsr_nn.metrics import label_switches, optimal_assignment, persistent_assignment, track_scores


def _crossing(swap_after: bool):
    """Two targets crossing at scan 10 of 21 (1 m apart there, 100 m further apart each scan
    after), two tracks 3 m off their own target except at the crossing scan, where each is 1.5 m
    from the other target and 3.5 m from its own. With ``swap_after`` the tracks exchange targets
    from scan 11 on (a real switch)."""
    k = torch.arange(21, dtype=torch.float64)
    x = 100.0 * (k - 10)
    truth = torch.stack([torch.stack([x, 0.5 + 50.0 * (k - 10)], -1),
                         torch.stack([x, -0.5 - 50.0 * (k - 10)], -1)], 1)  # (K, N, 2)
    est = truth.clone()
    est[:, 0, 1] += 3.0
    est[:, 1, 1] -= 3.0
    est[10, 0, 1], est[10, 1, 1] = -1.0, 1.0
    if swap_after:
        est[11:] = est[11:].flip(1)
    mask = torch.ones(21, 2, dtype=torch.bool)
    return est[None], mask[None], truth[None], mask[None]


def test_tracks_that_follow_their_own_targets_through_a_crossing_do_not_switch():
    est, em, truth, tm = _crossing(swap_after=False)
    per_scan = optimal_assignment(est, em, truth, tm, 500.0, 2.0)
    mapped = persistent_assignment(est, em, truth, tm, 500.0, 2.0)
    # the per-scan assignment swaps the tracks at the crossing scan and back: 2 switches per target
    assert label_switches(per_scan, tm).tolist() == [[2, 2]]
    assert label_switches(mapped, tm).tolist() == [[0, 0]]
    assert mapped[0, :, 0].tolist() == [0] * 21 and mapped[0, :, 1].tolist() == [1] * 21
    ts = track_scores(mapped, em, tm)
    assert ts.tracks_per_target.tolist() == [[1.0, 1.0]] and ts.switches.tolist() == [[0.0, 0.0]]


def test_tracks_that_exchange_targets_switch_once_each_when_they_leave_the_cut_off():
    """After the crossing the tracks follow the other target; each keeps its old target while it is
    within the cut-off c (100 m: the targets part by 100 m per scan, so one scan), then both are
    matched anew: one switch per target, and two tracks per target."""
    est, em, truth, tm = _crossing(swap_after=True)
    mapped = persistent_assignment(est, em, truth, tm, 100.0, 2.0)
    assert label_switches(mapped, tm).tolist() == [[1, 1]]
    assert mapped[0, 10].tolist() == [0, 1] and mapped[0, 12].tolist() == [1, 0]
    assert track_scores(mapped, em, tm).tracks_per_target.tolist() == [[2.0, 2.0]]


def _reference(est, em, truth, tm, c, p):
    """CLEAR MOT's mapping by brute force, run by run and scan by scan, in plain Python."""
    B, K, M, _ = est.shape
    N = truth.shape[2]
    out = torch.full((B, K, M), -1, dtype=torch.int64)
    for b in range(B):
        prev = [-1] * M
        for k in range(K):
            d = lambda i, j: math.dist(est[b, k, i].tolist(), truth[b, k, j].tolist())
            cur = [-1] * M
            for i in range(M):  # kept: the previous target, both present, nearer than c
                j = prev[i]
                if j >= 0 and em[b, k, i] and tm[b, k, j] and d(i, j) < c:
                    cur[i] = j
            rows = [i for i in range(M) if em[b, k, i] and cur[i] < 0]
            cols = [j for j in range(N) if tm[b, k, j] and j not in cur]
            best, pick = math.inf, None
            n = min(len(rows), len(cols))
            for rs in itertools.permutations(rows, n):  # every full matching of the rest
                for cs in itertools.combinations(cols, n):
                    cost = sum(min(d(i, j), c) ** p for i, j in zip(rs, cs))
                    if cost < best - 1e-12:
                        best, pick = cost, list(zip(rs, cs))
            for i, j in pick or []:
                if d(i, j) < c:
                    cur[i] = j
            out[b, k] = torch.tensor(cur)
            prev = cur
    return out


@pytest.mark.parametrize("M, N", [(2, 3), (3, 2), (5, 4)])
def test_the_mapping_equals_a_brute_force_reference(M, N):
    """Random tracks and targets appearing and vanishing (masks), jittered around slowly moving
    targets so that kept and fresh matches both occur; sizes on both sides of the enumeration
    limit of the per-scan solver."""
    g = torch.Generator().manual_seed(7 + M + N)
    B, K = 12, 8
    truth = (torch.rand(B, 1, N, 2, generator=g) * 300.0 + torch.arange(K)[None, :, None, None] * 20.0).double()
    pick = torch.randint(0, N, (B, 1, M), generator=g).expand(B, K, M)
    est = truth.gather(2, pick[..., None].expand(B, K, M, 2)) + torch.randn(B, K, M, 2, generator=g, dtype=torch.float64) * 40.0
    em = torch.rand(B, K, M, generator=g) < 0.8
    tm = torch.rand(B, K, N, generator=g) < 0.85
    mapped = persistent_assignment(est, em, truth, tm, 100.0, 2.0)
    assert torch.equal(mapped, _reference(est, em, truth, tm, 100.0, 2.0))
    kept = (mapped[:, 1:] >= 0) & (mapped[:, 1:] == mapped[:, :-1])
    assert bool(kept.any()) and bool((mapped >= 0).sum() > kept.sum())  # both kinds of match occur
