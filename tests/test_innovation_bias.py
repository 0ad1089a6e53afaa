"""The innovation bias test (pmsr_nn.trackers.innovation_bias) and the trackers that use it: the
statistic is chi-square for white unit innovations and has the non-central mean a constant offset
gives (closed forms); the track table keeps, grows and clears the means with its slots; S-MSJPDA
deletes a track whose detections carry a bias it cannot absorb and, on unbiased detections, no
more than the test's false-alarm bound allows; refusals (action ``learn`` left with the hybrid
tracker under issue 56)."""

from __future__ import annotations

import math

import pytest
import torch
from scipy.stats import binom, chi2

from pmsr_nn.errors import ConfigError
from pmsr_nn.geometry import Geometry, Receiver, Transmitter
from pmsr_nn.measurements import MeasurementModel
from pmsr_nn.motion import ConstantAcceleration
from pmsr_nn.rng import seeded_generator
from pmsr_nn.simulation.detections import ClutterSpec, simulate_scans
from pmsr_nn.trackers.innovation_bias import BiasTest
from pmsr_nn.trackers.management import CONFIRMED, Confirmer, Deleter, FixInitiator, Management, TrackTable
from pmsr_nn.trackers.msjpda import JPDASettings
from pmsr_nn.trackers.msjpda_managed import managed_msjpda

NOISE = (30.0, 2.0, math.radians(3.0))
S_X = torch.tensor([100.0, 5.0, 0.1] * 2, dtype=torch.float64)
MOTION = ConstantAcceleration(spatial_dim=2)


def model() -> MeasurementModel:
    """One transmitter, three receivers: bistatic range, range-rate and azimuth per pair."""
    geometry = Geometry.all_pairs([Transmitter((0.0, 0.0), 650e6)],
                                  [Receiver((-7000.0, -3000.0)), Receiver((-8000.0, 500.0)), Receiver((-7500.0, 4000.0))])
    return MeasurementModel(geometry, ("range", "range_rate", "azimuth"), NOISE, (0, 3), (1, 4), layout="pair")

DOF = 9  # 3 pairs x (range, range-rate, azimuth)


def folded(test: BiasTest, e: torch.Tensor) -> torch.Tensor:
    """The means after folding ``e (k, R, S, d)`` in, scan by scan and pair by pair."""
    k, R, S, d = e.shape
    mean = torch.zeros(R, 1, S, d, dtype=torch.float64)
    on = torch.ones(R, 1, dtype=torch.bool)
    for i in range(k):
        for j in range(S):
            mean = test.update(mean, j, e[i, :, j].unsqueeze(1), on)
    return mean


@pytest.mark.parametrize("k", [3, 40])
def test_the_statistic_of_white_unit_innovations_is_chi_square_at_every_age(k):
    R, test = 20_000, BiasTest(window=20.0, probability=0.99)
    e = torch.randn(k, R, 3, 3, generator=seeded_generator(11, k), dtype=torch.float64)
    q = test.statistic(folded(test, e), torch.full((R, 1), k))[:, 0]
    assert abs(float(q.mean()) - DOF) < 5 * math.sqrt(2 * DOF / R)  # chi2(9): mean 9, variance 18
    share = float((q > test.threshold(DOF)).double().mean())
    assert abs(share - 0.01) < 5 * math.sqrt(0.01 * 0.99 / R)
    assert test.threshold(DOF) == pytest.approx(chi2.ppf(0.99, DOF), rel=1e-12)


def test_a_constant_offset_gives_the_non_central_mean():
    """``e = b + white``: the weighted mean is ``b (1 - (1 - a)^k)`` plus noise of variance ``v_k``,
    so ``E q = dof + |b|^2 (1 - (1 - a)^k)^2 / v_k``."""
    R, k, test = 20_000, 15, BiasTest(window=10.0)
    b = torch.zeros(3, 3, dtype=torch.float64)
    b[0, 0], b[2, 2] = 0.8, -0.5
    e = b + torch.randn(k, R, 3, 3, generator=seeded_generator(12), dtype=torch.float64)
    q = test.statistic(folded(test, e), torch.full((R, 1), k))[:, 0]
    a = test.weight
    v = a / (2 - a) * (1 - (1 - a) ** (2 * k))
    lam = float((b * b).sum()) * (1 - (1 - a) ** k) ** 2 / v
    assert abs(float(q.mean()) - (DOF + lam)) < 5 * math.sqrt(2 * (DOF + 2 * lam) / R)  # non-central chi2 variance


def test_inactive_tracks_keep_their_means_and_no_update_scores_zero():
    test = BiasTest()
    mean = torch.zeros(1, 2, 3, 3, dtype=torch.float64)
    e = torch.ones(1, 2, 3, dtype=torch.float64)
    mean = test.update(mean, 1, e, torch.tensor([[True, False]]))
    assert torch.allclose(mean[0, 0, 1], torch.full((3,), test.weight, dtype=torch.float64))
    assert not mean[0, 1].any() and not mean[0, 0, [0, 2]].any()
    assert test.statistic(mean, torch.tensor([[0, 0]])).tolist() == [[0.0, 0.0]]


def test_the_track_table_grows_clears_and_deletes_with_the_bias_test():
    test = BiasTest(window=5.0, probability=0.99, burn_in=4)
    n = 6
    table = TrackTable.empty(1, n, torch.zeros(n, dtype=torch.float64), capacity=2)
    table.status = torch.tensor([[CONFIRMED, CONFIRMED]])
    table.age = torch.tensor([[3, 10]])  # the first track is in its burn-in
    e = torch.tensor([[[3.0, 0.0, 0.0], [3.0, 0.0, 0.0]]], dtype=torch.float64)
    table.update_bias(test, 0, 3, e)
    assert not table.bias_mean[0, 0].any() and table.bias_mean[0, 1, 0, 0] == pytest.approx(3.0 * test.weight)
    table.age = torch.tensor([[10, 10]])
    table.bias_mean.zero_()
    for _ in range(10):
        for j in range(3):
            table.update_bias(test, j, 3, torch.tensor([[[3.0, 0.0, 0.0], [0.1, -0.1, 0.0]]], dtype=torch.float64))
    assert table.biased(test).tolist() == [[True, False]]
    table._grow(4)
    assert table.bias_mean.shape == (1, 4, 3, 3) and not table.bias_mean[:, 2:].any()
    table.manage(Confirmer(), Deleter(), [0, 3], test)
    assert table.status[0, :2].tolist() == [0, CONFIRMED]  # the biased track is gone, its mean cleared
    assert not table.bias_mean[0, 0].any() and table.bias_mean[0, 1].any()
    table.add(table.g, torch.tensor([[True, False, False, False]]))
    assert not table.bias_mean[0, 0].any()


def one_target(B: int, K: int) -> torch.Tensor:
    x0 = torch.tensor([3000.0, 8.0, 0.0, 6000.0, -5.0, 0.0], dtype=torch.float64)
    F = MOTION.F(1.0, torch.float64)
    return torch.stack([x0 @ torch.linalg.matrix_power(F, k).T for k in range(K)])[None, :, None].expand(B, K, 1, 6)


def track_count(range_bias_m: float, bias: BiasTest | None, B: int = 40, K: int = 60):
    """Per run, how many tracks S-MSJPDA confirmed for one target seen at every scan by 3 pairs
    (no clutter), with ``range_bias_m`` added to pair 0's ranges."""
    m = model()
    scans = simulate_scans(one_target(B, K), m, 1.0, ClutterSpec(per_scan=0), seeded_generator(5))
    scans.z[:, :, 0, :, 0] += range_bias_m
    mg = Management(FixInitiator(20.0, 2, 0.999), Confirmer(2, 3), Deleter(2), S_X, bias=bias)
    rep = managed_msjpda(scans, MOTION, 1.0, 0.01, m, m.R(), JPDASettings(0.99, 1e-9), "sequential", mg)
    return rep.exists.any(1).sum(-1)


@pytest.mark.integration
def test_s_msjpda_keeps_a_consistent_track_and_deletes_one_its_detections_pull_aside():
    test = BiasTest(window=20.0, probability=0.999, burn_in=10)
    # unbiased: a run loses its track to the test with probability at most 60 x 0.001 (union bound
    # over its scans); more runs than Bin(40, 0.06)'s 1e-4 upper quantile would contradict it
    restarted = int((track_count(0.0, test) > track_count(0.0, None)).sum())
    assert restarted <= binom.ppf(1 - 1e-4, 40, 60 * 0.001)
    # pair 0's ranges 120 m (4 deviations) long: the track sits between what the pairs say, its
    # innovations keep a mean, and the test deletes it (a new track starts and is deleted again)
    plain, tested = track_count(120.0, None), track_count(120.0, test)
    assert int((plain > 1).sum()) <= 2 and int((tested > plain).sum()) >= 30


def test_refusals():
    m = model()
    scans = simulate_scans(one_target(1, 5), m, 1.0, ClutterSpec(per_scan=0), seeded_generator(5))
    s = JPDASettings(0.99, 1e-9)
    mg = lambda action: Management(FixInitiator(), Confirmer(), Deleter(), S_X, bias=BiasTest(action=action))
    with pytest.raises(ConfigError, match="sequential MSJPDA only"):
        managed_msjpda(scans, MOTION, 1.0, 0.01, m, m.R(), s, "parallel", mg("delete"))
    for bad, match in ((dict(window=0.5), "window"), (dict(probability=1.0), "probability"),
                       (dict(action="keep"), "must be delete"), (dict(action="learn"), "left with the hybrid tracker"),
                       (dict(burn_in=-1), "burn-in")):
        with pytest.raises(ConfigError, match=match):
            BiasTest(**bad)
