"""The spherical initiator (pmsr_nn.trackers.management.SphericalInitiator): tentative tracks from
detections of bistatic range and Doppler (or range-rate) alone, at pairs that share a receiver
(the IEEE Access 2019 study) or a transmitter, against references that do not run its code:

* noise-free detections give back the targets' positions and velocities (float64 rounding);
* its covariance is the Cramer-Rao bound of ranges and rates, from autograd of a measurement
  function written out here, and the first-order covariance of its own estimate (finite
  differences) equals that bound: it is the maximum-likelihood estimate;
* the greedy selection uses each detection once and picks what a brute-force enumeration with
  scipy's least squares picks;
* the chi-square of true combinations passes the gate as often as the gate probability says;
* geometries it can not handle are one-line refusals;
* S-MSJPDA with initiation from detections on a small Access-like study confirms one track per
  target.
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from scipy.optimize import least_squares
from scipy.stats import chi2 as chi2_dist

from pmsr_nn import SPEED_OF_LIGHT
from pmsr_nn.errors import ConfigError
from pmsr_nn.geometry import Geometry, Receiver, Transmitter
from pmsr_nn.harness.run.blocks import call_method, draw_block
from pmsr_nn.harness.run.runner import prepare
from pmsr_nn.harness.scenario.loading import load_any
from pmsr_nn.measurements import MeasurementModel
from pmsr_nn.metrics import set_scores, track_scores
from pmsr_nn.trackers.gating import gate_threshold
from pmsr_nn.trackers.spherical_initiator import MAX_SPHERICAL_PAIRS, SphericalInitiator

ROOT = Path(__file__).resolve().parents[1]
CV_POS, CV_VEL = (0, 2), (1, 3)  # the 2-D CV state (x, vx, y, vy)
F64 = torch.float64
ACCESS_TX = ((-38000.0, 12000.0, 93.1e6), (26000.0, 31000.0, 90.9e6), (14000.0, -42000.0, 99.9e6))
ACCESS_NOISE = (1000.0, 1.0)  # range (m), Doppler (Hz)


def access_model(noise=ACCESS_NOISE) -> MeasurementModel:
    """The Access study: three FM transmitters, one receiver at the origin, range and Doppler."""
    g = Geometry.all_pairs([Transmitter((x, y), f) for x, y, f in ACCESS_TX], [Receiver((0.0, 0.0))])
    return MeasurementModel(g, ("range", "doppler"), noise, CV_POS, CV_VEL, layout="pair")


def one_tx_model(noise=(30.0, 2.0)) -> MeasurementModel:
    """One transmitter at the origin, three receivers about 8 km west; range and range-rate."""
    g = Geometry.all_pairs([Transmitter((0.0, 0.0), 650e6)],
                           [Receiver((-7000.0, -3000.0)), Receiver((-8000.0, 500.0)), Receiver((-7500.0, 4000.0))])
    return MeasurementModel(g, ("range", "range_rate"), noise, CV_POS, CV_VEL, layout="pair")


def measure(model: MeasurementModel, p: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Ranges and rates ``(..., S, 2)`` written out from the conventions of
    pmsr_nn.measurements (not its code): ``R = |p - t| + |p - r|``, range-rate
    ``v . (u_t + u_r)``, Doppler ``-rate f_c / c``; differentiable (autograd)."""
    g = model.geometry
    t, r = g.pair_tx_positions(F64), g.pair_rx_positions(F64)
    dt, dr = p.unsqueeze(-2) - t, p.unsqueeze(-2) - r
    nt, nr = dt.norm(dim=-1), dr.norm(dim=-1)
    rate = (v.unsqueeze(-2) * (dt / nt.unsqueeze(-1) + dr / nr.unsqueeze(-1))).sum(-1)
    if model.components[1] == "doppler":
        rate = -rate * g.pair_carriers(F64) / SPEED_OF_LIGHT
    return torch.stack([nt + nr, rate], -1)


def detections(model, states: torch.Tensor) -> torch.Tensor:
    """Noise-free detections ``(1, S, M, 2)`` of ``M`` states ``(M, 4)``, one per target per pair."""
    return measure(model, states[:, list(CV_POS)], states[:, list(CV_VEL)]).transpose(0, 1).unsqueeze(0)


def fisher(model, state: torch.Tensor) -> torch.Tensor:
    """``J^T R^-1 J`` ``(4, 4)`` in (x, y, vx, vy) by autograd of :func:`measure`."""
    sd = torch.tensor(model.noise_std, dtype=F64).expand(model.n_pairs, 2).reshape(-1)
    theta = torch.cat([state[list(CV_POS)], state[list(CV_VEL)]])
    J = torch.autograd.functional.jacobian(lambda th: measure(model, th[:2], th[2:]).reshape(-1), theta)
    return J.T @ torch.diag(sd**-2) @ J


FORMATION = torch.tensor([[-25000.0, 200.0, -20000.0, 244.1], [-23000.0, 200.0, -21000.0, 244.1],
                          [-10000.0, -150.0, 5000.0, 40.0], [-40000.0, 0.0, -30000.0, 300.0]], dtype=F64)
NEAR_FITEE = torch.tensor([[3000.0, 5.0, 6000.0, -2.0], [-1000.0, 0.0, 9000.0, 3.0],
                           [6000.0, -20.0, -4000.0, 10.0]], dtype=F64)


# -- (i) noise-free detections ---------------------------------------------------------------------

@pytest.mark.parametrize("make, truth", [(access_model, FORMATION), (one_tx_model, NEAR_FITEE)],
                         ids=["one receiver, three transmitters", "one transmitter, three receivers"])
def test_noise_free_detections_give_the_targets_back(make, truth):
    m = make()
    T = truth.shape[0]
    z = detections(m, truth)
    # the detection lists in different orders per pair: a combination is found by its content
    perm = [torch.arange(T), torch.arange(T).roll(1), torch.arange(T).flip(0)]
    z = torch.stack([z[0, s, perm[s]] for s in range(3)]).unsqueeze(0)
    ini = SphericalInitiator(velocity_sd_mps=1e9)  # no prior pull: the estimate itself
    other = torch.ones(4, dtype=F64)
    g, real = ini.initiate(z, torch.ones(1, 3, T, dtype=torch.bool), m, 4, other)
    assert real.tolist() == [[True] * T]
    combos = ini.select(z, torch.ones(1, 3, T, dtype=torch.bool), m, 4)[0][0]
    # each track: one target's own detection at every pair (list entry j of pair s is target perm[s][j])
    owners = torch.stack([perm[s][combos[:, s]] for s in range(3)], -1)
    assert bool((owners == owners[:, :1]).all()) and sorted(owners[:, 0].tolist()) == list(range(T))
    est = g.x[0, torch.argsort(owners[:, 0])]
    # exact data: the fixes are exact up to float64 rounding, ~1e-16 of the 1e4-1e5 m and
    # 1e2 m/s scales amplified by the geometry (position deviations per unit range deviation
    # are O(1) here); 1e-6 m and 1e-8 m/s leave four orders of margin
    assert (est[:, list(CV_POS)] - truth[:, list(CV_POS)]).abs().max() < 1e-6
    assert (est[:, list(CV_VEL)] - truth[:, list(CV_VEL)]).abs().max() < 1e-8


# -- (ii) covariance ---------------------------------------------------------------------------------

def test_the_covariance_is_the_cramer_rao_bound_with_the_velocity_prior():
    m = access_model()
    truth = FORMATION[:1]
    z = detections(m, truth)
    sd_v = 50.0
    other = torch.tensor([7.0, 8.0, 9.0, 10.0], dtype=F64)  # every entry is fixed here: unused
    g, real = SphericalInitiator(velocity_sd_mps=sd_v).initiate(z, torch.ones(1, 3, 1, dtype=torch.bool), m, 4, other)
    assert real.tolist() == [[True]]
    info = fisher(m, truth[0])
    prior = torch.diag(torch.tensor([0.0, 0.0, sd_v**-2, sd_v**-2], dtype=F64))
    P_ref = torch.linalg.inv(info + prior)
    idx = list(CV_POS) + list(CV_VEL)
    P = g.P[0, 0][idx][:, idx]
    # compared scaled by the deviations (entries span 1e-1 to 1e5): the analytic and the autograd
    # Jacobians agree to rounding, the 4x4 inverse loses a few digits (condition ~1e6)
    scale = P_ref.diagonal().sqrt()
    assert ((P - P_ref) / scale[:, None] / scale[None, :]).abs().max() < 1e-8
    # the mean: the exact estimate (the truth) pulled by the prior N(0, sd_v^2) on velocity
    mean_ref = P_ref @ info @ torch.cat([truth[0, list(CV_POS)], truth[0, list(CV_VEL)]])
    assert torch.allclose(g.x[0, 0, idx], mean_ref, rtol=1e-9, atol=1e-6)
    assert bool((mean_ref[2:].abs() < truth[0, list(CV_VEL)].abs()).all())  # the prior did pull


def test_the_estimate_is_efficient_its_first_order_covariance_is_the_bound():
    """Finite differences of the estimate by each range and Doppler: ``A R A^T`` is the
    covariance of the estimator to first order; the ML estimator's equals the bound."""
    m = access_model()
    truth = FORMATION[0]
    z = detections(m, truth[None])
    ini = SphericalInitiator()
    unused = torch.ones(1, 3, 1, dtype=torch.bool)
    steps = (1.0, 1e-3)  # m, Hz: the estimate is smooth on these scales, rounding far below
    A = torch.zeros(4, 6, dtype=F64)
    for s in range(3):
        for c in range(2):
            zp, zm = z.clone(), z.clone()
            zp[0, s, 0, c] += steps[c]
            zm[0, s, 0, c] -= steps[c]
            A[:, 2 * s + c] = (ini.select(zp, unused, m, 4)[2][0, 0] - ini.select(zm, unused, m, 4)[2][0, 0]) / (2 * steps[c])
    R = torch.diag(torch.tensor(ACCESS_NOISE, dtype=F64).repeat(3) ** 2)
    cov = A @ R @ A.T
    crb = torch.linalg.inv(fisher(m, truth))
    scale = crb.diagonal().sqrt()
    # central differences: error ~ step^2 times third derivatives, ~1e-6 relative here
    assert ((cov - crb) / scale[:, None] / scale[None, :]).abs().max() < 1e-4


# -- (iii) selection --------------------------------------------------------------------------------

def noisy(model, truth: torch.Tensor, B: int, gen: torch.Generator) -> torch.Tensor:
    """Detections ``(B, S, T, 2)`` of the targets ``truth (T, 4)`` with the model's noise."""
    z = detections(model, truth).expand(B, -1, -1, -1)
    return z + torch.randn(z.shape, generator=gen, dtype=F64) * torch.tensor(model.noise_std, dtype=F64)


def test_with_clutter_every_detection_starts_at_most_one_track():
    m = access_model()
    gen = torch.Generator().manual_seed(11)
    B, M = 3, 25
    z = torch.stack([torch.rand(B, 3, M, generator=gen, dtype=F64) * 150000.0,
                     (torch.rand(B, 3, M, generator=gen, dtype=F64) - 0.5) * 500.0], -1)
    z[:, :, :2] = noisy(m, FORMATION[:2], B, gen)
    unused = torch.ones(B, 3, M, dtype=torch.bool)
    unused[0, 1, 5] = False  # gated by a track: takes part in no combination
    z[1, 2, 20:] = math.nan  # a shorter list (padding)
    unused[1, 2, 20:] = False
    combos, chi2, _, _ = SphericalInitiator().select(z, unused, m, 4)
    real = (combos >= 0).all(-1)
    assert bool(real.sum(1).min() >= 5), real.sum(1)  # enough tracks that a repeat could occur
    assert bool(((combos >= 0).any(-1) == real).all())  # every pair in every track (min_pairs = all)
    for b in range(B):
        for s in range(3):
            used = combos[b, real[b], s].tolist()
            assert len(used) == len(set(used)) and all(unused[b, s, i] for i in used)
    # taken in order of the chi-square within each run (the greedy order)
    assert all(bool((chi2[b, real[b]].diff() >= 0).all()) for b in range(B))
    assert bool((chi2[real] <= gate_threshold(0.999, 2)).all())


def brute_force_chi2(model, z: np.ndarray, starts: list[np.ndarray]) -> float:
    """The joint least-squares chi-square of one combination ``z (S, 2)`` by scipy, the best of
    several starts."""
    sd = np.asarray(model.noise_std)

    def resid(th):
        t = torch.from_numpy(th)
        return ((measure(model, t[:2], t[2:]).numpy() - z) / sd).ravel()

    return min(2 * least_squares(resid, x0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15).cost for x0 in starts)


@pytest.mark.integration
def test_the_greedy_selection_is_the_brute_force_one():
    """2 runs, 3 pairs, 3 detections each: three targets 1.5 km apart (1 km range deviation), so
    that mixed combinations pass the gate too and the greedy order decides. Every one of the 27
    combinations per run is fitted by scipy's least squares; the gated ones taken by increasing
    chi-square, skipping those that share a detection with one taken, are the initiator's."""
    m = access_model()
    truth = torch.tensor([[-25000.0, 200.0, -20000.0, 244.1], [-23800.0, 200.0, -20900.0, 244.1],
                          [-26200.0, 200.0, -19100.0, 244.1]], dtype=F64)
    gen = torch.Generator().manual_seed(5)
    z = noisy(m, truth, 2, gen)
    ini = SphericalInitiator(gate_probability=0.999)
    gamma = gate_threshold(0.999, 2)
    combos, chi2, _, _ = ini.select(z, torch.ones(2, 3, 3, dtype=torch.bool), m, 4)
    starts = [np.concatenate([t[list(CV_POS)].numpy() + off, [0.0, 0.0]]) for t in truth
              for off in (np.zeros(2), np.array([3000.0, -3000.0]))]
    n_passing = 0
    for b in range(2):
        scored = []
        for c in itertools.product(range(3), repeat=3):
            x2 = brute_force_chi2(m, z[b, [0, 1, 2], list(c)].numpy(), starts)
            # a combination at the gate's edge could go either way by rounding: none may be
            assert abs(x2 - gamma) > 1e-3
            if x2 <= gamma:
                scored.append((x2, c))
        n_passing += len(scored)
        chosen, used = [], set()
        for x2, c in sorted(scored):
            if not any((s, c[s]) in used for s in range(3)):
                chosen.append((x2, c))
                used |= {(s, c[s]) for s in range(3)}
        mine = [tuple(r) for r in combos[b].tolist() if r[0] >= 0]
        assert mine == [c for _, c in chosen]
        np.testing.assert_allclose(chi2[b, :len(mine)].numpy(), [x2 for x2, _ in chosen], rtol=1e-6, atol=1e-9)
    assert n_passing > len([r for r in combos.reshape(-1, 3).tolist() if r[0] >= 0])  # the greedy dropped some


# -- (iv) the gate ------------------------------------------------------------------------------------

@pytest.mark.parametrize("probability", [0.9, 0.99])
@pytest.mark.parametrize("make, truth", [(access_model, FORMATION[0]), (one_tx_model, NEAR_FITEE[0])],
                         ids=["access", "one transmitter"])
def test_true_combinations_pass_the_gate_with_its_probability(make, truth, probability):
    """2000 noisy draws of one target's detections: the chi-square of ranges and rates (2 dof
    at 3 pairs) is chi2(2) to first order, so the fraction that starts a track is binomial
    around the gate probability; within 4 standard deviations of it."""
    m = make()
    n = 2000
    z = noisy(m, truth[None], n, torch.Generator().manual_seed(21))
    _, real = SphericalInitiator(gate_probability=probability).initiate(
        z, torch.ones(n, 3, 1, dtype=torch.bool), m, 4, torch.ones(4, dtype=F64))
    frac = float(real.to(F64).mean())
    assert abs(frac - probability) <= 4 * math.sqrt(probability * (1 - probability) / n), frac


# -- (v) refusals -------------------------------------------------------------------------------------

def model_of(transmitters, receivers, components=("range", "doppler"), pairs=None, dim=2) -> MeasurementModel:
    tx = [Transmitter(tuple(p), 100e6) for p in transmitters]
    rx = [Receiver(tuple(p)) for p in receivers]
    g = Geometry.all_pairs(tx, rx) if pairs is None else Geometry(tuple(tx), tuple(rx), pairs)
    idx = (tuple(range(0, 2 * dim, 2)), tuple(range(1, 2 * dim, 2)))
    return MeasurementModel(g, components, (1000.0, 1.0, 0.1)[:len(components)], *idx, layout="pair")


@pytest.mark.parametrize("model, initiator, message", [
    (lambda: model_of([(0, 0), (9000, 0)], [(0, 9000), (-9000, 0)]), SphericalInitiator(),
     "needs pairs that share one transmitter or one receiver (spherical interpolation); the 4 pairs use 2 "
     "transmitters and 2 receivers"),
    (lambda: model_of([(0, 0, 0), (9000, 0, 0), (0, 9000, 0)], [(100, 100, 0)], dim=3), SphericalInitiator(),
     "fixes positions from (bistatic range, azimuth) in 2-D, or from bistatic range and range-rate (or Doppler)"),
    (lambda: model_of([(0, 0), (9000, 0), (0, 9000)], [(100, 100)], ("range",)), SphericalInitiator(),
     "the detections measure ['range'] in 2-D (use initiation: oracle)"),
    (lambda: model_of([(0, 0), (9000, 0)], [(100, 100)]), SphericalInitiator(), "which needs 3 to 4 pairs; the "
                                                                                "geometry has 2"),
    (lambda: model_of([(9000 * math.cos(a), 9000 * math.sin(a)) for a in range(5)], [(0, 0)]), SphericalInitiator(),
     f"(M^S per scan), which needs 3 to {MAX_SPHERICAL_PAIRS} pairs; the geometry has 5"),
    (lambda: model_of([(0, 0), (9000, 0), (-5000, 0)], [(1000, 0)]), SphericalInitiator(),
     "other sensors lie on one line through the shared one"),
    (lambda: model_of([(0, 0), (9000, 0), (0, 9000)], [(100, 100)]), SphericalInitiator(min_pairs=4),
     "min_pairs (4) is more than the 3 pairs"),
])
def test_what_it_can_not_handle_is_a_one_line_refusal(model, initiator, message):
    with pytest.raises(ConfigError) as exc:
        initiator.check(model(), "initiation from detections")
    assert message in str(exc.value) and "\n" not in str(exc.value), str(exc.value)


def test_fewer_than_three_pairs_per_combination_is_refused():
    with pytest.raises(ConfigError, match=r"needs min_pairs >= 3 \(two ranges fix a position with nothing left"):
        SphericalInitiator(min_pairs=2)


def test_one_transmitter_one_receiver_layout_both_ways_is_accepted():
    SphericalInitiator().check(access_model())
    SphericalInitiator().check(one_tx_model())
    SphericalInitiator(min_pairs=3).check(model_of([(0, 0), (9000, 0), (0, 9000), (-9000, 100)], [(100, 100)]))


def access_study(tmp_path: Path, methods, **over) -> Path:
    data = yaml.safe_load((ROOT / "evaluate" / "access2019_msjpda.yaml").read_text())
    data["reference"]["file"] = str(ROOT / "evaluate" / data["reference"]["file"])
    data.update(methods=methods, **over)
    path = tmp_path / "access.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_the_access_study_now_passes_the_checks_and_picks_the_spherical_initiator(tmp_path):
    from pmsr_nn.methods.track_management import management

    path = access_study(tmp_path, [{"name": "S", "kind": "s_msjpda", "options": {"initiation": "detections"}}],
                        mc_runs=1, block_runs=1)
    setup = prepare(load_any(path))  # would raise the refusals
    case = setup.cases[0]
    mg = management(setup.methods[0], case.sensing)
    assert isinstance(mg.initiator, SphericalInitiator) and mg.initiator.min_pairs is None


# -- (vi) end to end ------------------------------------------------------------------------------------

def first_row_tracks(path):
    """The first row of the two-target scenario at ``path`` on its first block: its estimates (two
    track ids in all, per run, checked) and its track scores against the truth (cut-off 1 km)."""
    setup = prepare(load_any(path))
    case = setup.cases[0]
    truth, products = draw_block(setup, 0, 0)
    est = call_method(setup, setup.methods[0], case, products, (0, 0, 0))
    assert not est.paired and est.x.shape[2] == 2  # two tracks in all, per run
    B, K, _ = est.exists.shape
    alive = case.alive.expand(B, K, 2)
    pos = list(setup.models.motion.pos_idx)
    sets = set_scores(est.x[..., pos], est.exists, truth.x[..., pos], alive, 1000.0, 2.0)
    return est, track_scores(sets.assignment, est.exists, alive)


def test_s_msjpda_from_detections_confirms_one_track_per_target(tmp_path):
    """The Access geometry and noise, two targets 10 km apart, Pd 1, no clutter, 2 runs of 8
    scans: both targets are fixed at scan 0 from their three detections and confirmed at
    scan 1 (2 of 3, hits at >= 2 pairs); nothing else."""
    path = access_study(tmp_path, [{"name": "S", "kind": "s_msjpda", "options": {"initiation": "detections"}}],
                        mc_runs=2, block_runs=2, warmup_steps=2,
                        detections={"pd": 1.0, "components": ["range", "doppler"],
                                    "clutter": {"per_scan": 0, "model": "fixed", "range_m": [0.0, 150000.0],
                                                "doppler_hz": [-250.0, 250.0]}},
                        cases=[{"name": "c", "formation": {"count": 2, "centre_m": [-25000.0, -20000.0],
                                                           "velocity_mps": [200.0, 244.1], "spacing_m": 10000.0}}])
    data = yaml.safe_load(path.read_text())
    data["world"]["scans"] = 8
    path.write_text(yaml.safe_dump(data))
    est, ts = first_row_tracks(path)
    B = est.exists.shape[0]
    assert ts.tracks_per_target.tolist() == [[1.0, 1.0]] * B and ts.false_tracks.tolist() == [0.0] * B
    assert ts.scans_to_first_track.tolist() == [[1.0, 1.0]] * B
    assert bool(est.exists[:, 1:].all()) and not bool(est.exists[:, 0].any())


def test_with_min_pairs_below_the_pairs_a_target_missed_at_one_pair_starts_a_track_too():
    """Four transmitters, one receiver; target a detected at every pair, target b missed at the
    last. Every pair (default): only a. min_pairs 3: b as well, and a from all four pairs (a
    combination with more pairs goes first), not from three of them."""
    m = model_of([(-38000, 12000), (26000, 31000), (14000, -42000), (-30000, -35000)], [(0, 0)])
    truth = FORMATION[:2]
    z = torch.full((1, 4, 2, 2), math.nan, dtype=F64)
    z[0, :, :2] = measure(m, truth[:, list(CV_POS)], truth[:, list(CV_VEL)]).transpose(0, 1)
    z[0, 3, 1] = math.nan  # b missed at pair 3
    unused = torch.isfinite(z).all(-1)
    combos = SphericalInitiator().select(z, unused, m, 4)[0]
    assert combos[0].tolist() == [[0, 0, 0, 0]]
    combos, chi2, theta, _ = SphericalInitiator(min_pairs=3).select(z, unused, m, 4)
    assert combos[0].tolist() == [[0, 0, 0, 0], [1, 1, 1, -1]]
    est = torch.cat([truth[:, list(CV_POS)], truth[:, list(CV_VEL)]], -1)
    assert (theta[0] - est).abs().max() < 1e-6 and bool((chi2 < 1e-12).all())
    # nothing to start from: no rows
    combos, chi2, theta, info = SphericalInitiator().select(z, torch.zeros_like(unused), m, 4)
    assert combos.shape == (1, 0, 4) and theta.shape == (1, 0, 4) and info.shape == (1, 0, 4, 4)
