"""The coalescence test (pmsr_nn.trackers.coalescence) against hand-worked cases: tracks on one
target merge after exactly ``scans`` agreeing scans and the older id survives; tracks 300 m apart
never merge; a pair that agrees one scan short of the window and parts does not merge; the
chi-square gate is the closed form ``-2 ln(1 - p)`` for two degrees of freedom."""

from __future__ import annotations

import math

import pytest
import torch

from pmsr_nn.errors import ConfigError
from pmsr_nn.trackers.coalescence import Coalescence, CoalescenceTest, merged_existence

POS, VEL = [0, 2], [1, 3]  # state (x, vx, y, vy)


def tracks(*rows):
    """``x (B, C, 4)`` from per-run lists of (x, vx, y, vy); covariances diag(100, 4, 100, 4) m^2,
    (m/s)^2: the sum of two is diag(200, 8, 200, 8)."""
    x = torch.tensor(rows, dtype=torch.float64)
    P = torch.diag(torch.tensor([100.0, 4.0, 100.0, 4.0], dtype=torch.float64)).expand(*x.shape[:2], 4, 4)
    return x, P


def run(test, scans, confirmed, ids):
    """Feed ``scans`` (a list of (x, P)) to ``test``; the scan index of each run's first merge
    (None: never) and the last ``merged``."""
    first = [None] * confirmed.shape[0]
    merged = None
    for k, (x, P) in enumerate(scans):
        merged = test.step(x, P, confirmed, ids)
        for b in range(len(first)):
            if first[b] is None and bool(merged[b].any()):
                first[b] = k
    return first, merged


def test_two_tracks_on_one_target_merge_after_exactly_merge_scans_and_the_older_id_survives():
    # run 0: 5 m apart in x, same velocity: d2 = 25 / 200 = 0.125 (4 dof gate at 0.99: 13.28); run 1: 300 m apart
    x, P = tracks([[0.0, 10.0, 0.0, 0.0], [5.0, 10.0, 0.0, 0.0]], [[0.0, 10.0, 0.0, 0.0], [300.0, 10.0, 0.0, 0.0]])
    confirmed = torch.ones(2, 2, dtype=torch.bool)
    ids = torch.tensor([[7, 3], [7, 3]])  # slot 1 holds the older track in both runs
    for window in (1, 3, 5):
        test = CoalescenceTest(Coalescence(window), 2, POS + VEL)
        first, merged = run(test, [(x, P)] * 20, confirmed, ids)
        assert first == [window - 1, None]
        # at the scan of the merge: slot 0 (id 7) merges into slot 1 (id 3), which survives
    test = CoalescenceTest(Coalescence(3), 2, POS + VEL)
    run(test, [(x, P)] * 2, confirmed, ids)
    merged = test.step(x, P, confirmed, ids)
    assert merged[0].tolist() == [[False, False], [True, False]] and not bool(merged[1].any())
    assert merged.any(1).tolist() == [[True, False], [False, False]]


def test_a_pair_that_agrees_one_scan_short_and_parts_never_merges():
    near, _ = tracks([[0.0, 10.0, 0.0, 0.0], [5.0, 10.0, 0.0, 0.0]])
    far, P = tracks([[0.0, 10.0, 0.0, 0.0], [300.0, 10.0, 0.0, 0.0]])
    confirmed = torch.ones(1, 2, dtype=torch.bool)
    ids = torch.tensor([[0, 1]])
    window = 4
    cycle = [(near, P)] * (window - 1) + [(far, P)]
    test = CoalescenceTest(Coalescence(window), 1, POS + VEL)
    first, _ = run(test, cycle * 5, confirmed, ids)
    assert first == [None]
    # after parting, a full window again: merges at its last scan
    first, _ = run(test, [(near, P)] * window, confirmed, ids)
    assert first == [window - 1]


def test_a_tentative_scan_breaks_the_count():
    x, P = tracks([[0.0, 10.0, 0.0, 0.0], [5.0, 10.0, 0.0, 0.0]])
    ids = torch.tensor([[0, 1]])
    test = CoalescenceTest(Coalescence(3), 1, POS)
    both, one = torch.ones(1, 2, dtype=torch.bool), torch.tensor([[True, False]])
    for conf in (both, both, one, both, both):
        assert not bool(test.step(x, P, conf, ids).any())
    assert bool(test.step(x, P, both, ids).any())


def test_velocities_that_differ_keep_crossing_tracks_apart():
    # the same position, headings 26 m/s apart (one_sky's crossing pair): d2 = 26^2 / 8 = 84.5 > 13.28
    x, P = tracks([[0.0, 13.0, 0.0, 7.5], [0.0, -13.0, 0.0, 7.5]])
    test = CoalescenceTest(Coalescence(1), 1, POS + VEL)
    assert not bool(test.step(x, P, torch.ones(1, 2, dtype=torch.bool), torch.tensor([[0, 1]])).any())
    # on position alone they agree
    test = CoalescenceTest(Coalescence(1), 1, POS)
    assert bool(test.step(x, P, torch.ones(1, 2, dtype=torch.bool), torch.tensor([[0, 1]])).any())


@pytest.mark.parametrize("d2, agree", [(9.0, True), (9.5, False)])
def test_the_gate_is_the_chi_square_quantile(d2, agree):
    # 2 dof: P(chi2 <= g) = 1 - exp(-g / 2), so the 0.99 gate is -2 ln 0.01 = 9.2103
    assert -2 * math.log(0.01) == pytest.approx(9.2103, abs=1e-4)
    dx = math.sqrt(d2 * 200.0)
    x, P = tracks([[0.0, 0.0, 0.0, 0.0], [dx, 0.0, 0.0, 0.0]])
    ok = Coalescence(1, 0.99).agree(x, P, torch.ones(1, 2, dtype=torch.bool), POS)
    assert ok.tolist() == [[[False, agree], [agree, False]]]


def test_three_tracks_on_one_target_leave_the_oldest():
    x, P = tracks([[0.0, 10.0, 0.0, 0.0], [5.0, 10.0, 0.0, 0.0], [2.0, 10.0, 3.0, 0.0]])
    ids = torch.tensor([[4, 9, 2]])
    merged = CoalescenceTest(Coalescence(1), 1, POS).step(x, P, torch.ones(1, 3, dtype=torch.bool), ids)
    assert merged.any(1).tolist() == [[True, True, False]]
    e = merged_existence(torch.tensor([[0.3, 0.8, 0.6]], dtype=torch.float64), merged)
    assert e[0, 2] == 0.8  # the survivor takes the largest existence merged into it (the others are freed)


def test_slots_grow_with_the_table():
    test = CoalescenceTest(Coalescence(2), 1, POS)
    x, P = tracks([[0.0, 0.0, 0.0, 0.0], [500.0, 0.0, 0.0, 0.0]])
    test.step(x, P, torch.ones(1, 2, dtype=torch.bool), torch.tensor([[0, 1]]))
    x3, P3 = tracks([[0.0, 0.0, 0.0, 0.0], [500.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]])
    conf, ids = torch.ones(1, 3, dtype=torch.bool), torch.tensor([[0, 1, 2]])
    assert not bool(test.step(x3, P3, conf, ids).any())
    assert test.step(x3, P3, conf, ids)[0, 0].tolist() == [False, False, True]


def test_a_window_of_no_scans_is_refused():
    with pytest.raises(ConfigError, match="merge_scans"):
        Coalescence(0)


def test_own_tracks_merge_a_duplicate_and_report_the_older_id():
    """Two confirmed tracks on one state (a duplicate) and one 2 km away, in OwnTracks with
    merge_scans 3: reported side by side for two scans, then only the older of the pair."""
    from pmsr_nn.filters.gaussian import Gaussian
    from pmsr_nn.geometry import Geometry, Receiver, Transmitter
    from pmsr_nn.measurements import MeasurementModel
    from pmsr_nn.trackers.management import CONFIRMED, Confirmer, Deleter, FixInitiator, Management
    from pmsr_nn.trackers.own_tracks import OwnTracks
    from pmsr_nn.trackers.roles import AssociationStep

    geo = Geometry.all_pairs([Transmitter((0.0, 0.0), 650e6)], [Receiver((-7000.0, -3000.0)), Receiver((-8000.0, 500.0))])
    m = MeasurementModel(geo, ("range", "range_rate", "azimuth"), (30.0, 2.0, math.radians(3.0)), (0, 2), (1, 3),
                         layout="pair")
    mg = Management(FixInitiator(), Confirmer(), Deleter(), torch.ones(4, dtype=torch.float64),
                    coalescence=Coalescence(3))
    own = OwnTracks(mg, m, 4, 0.85)
    own.begin(1, 5)
    x = torch.tensor([[[3000.0, 10.0, 2000.0, 0.0], [3004.0, 10.0, 2003.0, 0.0], [5000.0, 10.0, 2000.0, 0.0]]],
                     dtype=torch.float64)
    P = torch.diag(torch.tensor([400.0, 4.0, 400.0, 4.0], dtype=torch.float64)).expand(1, 3, 4, 4).clone()
    own.table.add(Gaussian(x, P), torch.ones(1, 3, dtype=torch.bool), 0.9)
    C = own.table.status.shape[1]
    own.table.status[0, :3] = CONFIRMED
    own.table.track_id[0, :3] = torch.tensor([5, 2, 7])  # slot 1 holds the older of the pair
    own.table.next_id[:] = 8
    S, M, d = 2, 1, 3
    for k in range(5):
        step = AssociationStep(own.table.g, torch.full((1, C), 2), torch.full((1, C, S), 50.0, dtype=torch.float64),
                               torch.ones(1, S, M, dtype=torch.bool))
        own.updated(k, step, torch.zeros(1, S, M, d, dtype=torch.float64), torch.zeros(1, S, M, dtype=torch.bool))
    rep = own.result()
    # ids 2, 5, 7 are report slots 2, 5, 7: the duplicate (id 5) reported at scans 0-1 only
    assert rep.exists[0, :, 2].tolist() == [True] * 5 and rep.exists[0, :, 7].tolist() == [True] * 5
    assert rep.exists[0, :, 5].tolist() == [True, True, False, False, False]
    assert own.table.active[0].tolist()[:3] == [False, True, True]
