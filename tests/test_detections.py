"""Detections with missed targets and clutter (pmsr_nn.simulation.detections)."""

from __future__ import annotations

import math

import pytest
import torch
from scipy.stats import binom, chi2

from pmsr_nn.errors import ConfigError
from pmsr_nn.geometry import Geometry, Receiver, Transmitter
from pmsr_nn.measurements import MeasurementModel
from pmsr_nn.motion import ConstantVelocity
from pmsr_nn.rng import seeded_generator
from pmsr_nn.simulation.detections import CLUTTER, PADDING, ClutterSpec, simulate_scans


def _model(n_tx: int = 3) -> MeasurementModel:
    tx = [Transmitter((-38e3, 12e3), 93.1e6), Transmitter((26e3, 31e3), 90.9e6), Transmitter((14e3, -42e3), 99.9e6)]
    motion = ConstantVelocity(2)
    return MeasurementModel(Geometry.all_pairs(tx[:n_tx], [Receiver((0.0, 0.0))]), ("range", "doppler"),
                            (1000.0, 1.0), motion.pos_idx, motion.vel_idx, layout="pair")


def _truth(B=20, K=15, T=3) -> torch.Tensor:
    x0 = torch.tensor([[-25e3 + 2e3 * t, 200.0, -20e3, 244.0] for t in range(T)], dtype=torch.float64)
    return ConstantVelocity(2).sample(x0.repeat(B, 1), K, 1.0, 1.0, seeded_generator(1)).reshape(B, T, K, 4).transpose(1, 2)


def test_counts_origins_and_noise_are_as_specified():
    model, truth = _model(), _truth()
    B, K, T, _ = truth.shape
    pd = 0.8
    clutter = ClutterSpec(per_scan=7, range_m=(0.0, 150e3), doppler_hz=(-250.0, 250.0))
    scans = simulate_scans(truth, model, pd, clutter, seeded_generator(2))
    N = model.n_pairs
    assert ((scans.origin == CLUTTER).sum(-1) == 7).all()  # a fixed count is exact
    assert (scans.valid == (scans.origin != PADDING)).all()
    assert torch.isnan(scans.z[~scans.valid]).all() and not torch.isnan(scans.z[scans.valid]).any()
    # valid detections first in every list
    assert (scans.valid.int().diff(dim=-1) <= 0).all()
    # detections per target: Binomial(B K N, pd), 99.9 % two-sided interval per target
    n = B * K * N
    lo, hi = binom.ppf([0.0005, 0.9995], n, pd)
    for t in range(T):
        assert lo <= int((scans.origin == t).sum()) <= hi
    # clutter inside the box
    cz = scans.z[scans.origin == CLUTTER]
    assert (cz[:, 0] >= 0).all() and (cz[:, 0] <= 150e3).all() and (cz[:, 1].abs() <= 250).all()
    # target detections: noise / deviation is standard normal -> sum of squares within a 99.9 % chi-square interval
    clean = model.h(truth).reshape(B, K, T, N, 2)
    own = scans.target_measurements(T)
    e = ((own - clean) / torch.tensor([1000.0, 1.0], dtype=torch.float64))
    e = e[~torch.isnan(e[..., 0])]
    dof = e.numel()
    assert chi2.ppf(0.0005, dof) <= float((e ** 2).sum()) <= chi2.ppf(0.9995, dof)


def test_poisson_clutter_mean_and_reproducibility():
    model, truth = _model(1), _truth(B=40, K=10, T=1)
    clutter = ClutterSpec(per_scan=3.0, model="poisson")
    a = simulate_scans(truth, model, 0.9, clutter, seeded_generator(5))
    b = simulate_scans(truth, model, 0.9, clutter, seeded_generator(5))
    assert torch.equal(a.origin, b.origin) and torch.equal(torch.nan_to_num(a.z), torch.nan_to_num(b.z))
    total = int((a.origin == CLUTTER).sum())
    lam = 3.0 * 40 * 10
    # Poisson total: 99.9 % interval from the normal approximation (lam = 1200)
    assert abs(total - lam) <= 3.3 * math.sqrt(lam)


def test_no_targets_detected_and_no_clutter_gives_empty_lists():
    scans = simulate_scans(_truth(B=2, K=3), _model(), 0.0, ClutterSpec(per_scan=0), seeded_generator(0))
    assert scans.z.shape[3] == 0 and not scans.valid.any()
    assert torch.isnan(scans.target_measurements(3)).all()


def test_bad_inputs():
    truth = _truth(B=2, K=3)
    with pytest.raises(ConfigError, match="pd"):
        simulate_scans(truth, _model(), 1.5, ClutterSpec(), seeded_generator(0))
    with pytest.raises(ConfigError, match="truth must be"):
        simulate_scans(truth[0], _model(), 0.5, ClutterSpec(), seeded_generator(0))
    with pytest.raises(ConfigError, match="whole number"):
        ClutterSpec(per_scan=2.5)
    with pytest.raises(ConfigError, match="lower end"):
        ClutterSpec(range_m=(5.0, 1.0))
    motion = ConstantVelocity(2)
    rr = MeasurementModel(_model().geometry, ("doppler", "range"), (1.0, 1.0), motion.pos_idx, motion.vel_idx, layout="pair")
    with pytest.raises(ConfigError, match="starting with 'range'"):
        simulate_scans(truth, rr, 0.5, ClutterSpec(), seeded_generator(0))
