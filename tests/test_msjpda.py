"""Multi-sensor JPDA: association probabilities, the trackers, the loss rule."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch
from scipy.stats import multivariate_normal

from pmsr_nn.errors import ConfigError
from pmsr_nn.filters import Gaussian, predict, sequential_update, ukf, unscented_moments
from pmsr_nn.geometry import Geometry, Receiver, Transmitter
from pmsr_nn.measurements import MeasurementModel
from pmsr_nn.metrics import track_loss
from pmsr_nn.motion import ConstantVelocity
from pmsr_nn.rng import seeded_generator
from pmsr_nn.simulation.detections import ClutterSpec, Scans, simulate_scans
from pmsr_nn.trackers.clustering import track_clusters
from pmsr_nn.trackers.gating import gaussian_log_likelihood
from pmsr_nn.trackers.jpda import (assignment_matrix, batched_single_sensor_marginals, candidate_marginals, miss_cost,
                                   single_sensor_marginals)
from pmsr_nn.trackers.msjpda import JPDASettings, msjpda, true_assignment_ukf

TX = [Transmitter((-38e3, 12e3), 93.1e6), Transmitter((26e3, 31e3), 90.9e6), Transmitter((14e3, -42e3), 99.9e6)]
MOTION = ConstantVelocity(2)


def _model(n_tx=3) -> MeasurementModel:
    return MeasurementModel(Geometry.all_pairs(TX[:n_tx], [Receiver((0.0, 0.0))]), ("range", "doppler"), (1000.0, 1.0),
                            MOTION.pos_idx, MOTION.vel_idx, layout="pair")


def _formation(B, K, T, spacing=2000.0, seed=1, q=1.0):
    x0 = torch.tensor([[-25e3 + spacing * 0.77 * t, 200.0, -20e3 - spacing * 0.63 * t, 244.1] for t in range(T)],
                      dtype=torch.float64)
    x = MOTION.sample(x0.repeat(B, 1), K, 1.0, q, seeded_generator(seed)).reshape(B, T, K, 4).transpose(1, 2)
    return x


def _prior(truth, seed=3, sd=(300.0, 10.0)):
    B, K, T, n = truth.shape
    s = torch.tensor([sd[0], sd[1]] * 2, dtype=torch.float64)
    g = seeded_generator(seed)
    return Gaussian(truth[:, 0] + torch.randn(B, T, n, generator=g, dtype=torch.float64) * s,
                    torch.diag(s ** 2).expand(B, T, n, n).clone())


# ----------------------------------------------------------------------------------- probabilities

def _enumerate_single_sensor(cost: np.ndarray) -> np.ndarray:
    """Independent exhaustive JPDA: every track takes one detection or none, detections used once."""
    T, MT = cost.shape
    M = MT - T
    alpha = np.zeros((T, M + 1))
    total = 0.0
    for choice in itertools.product(range(-1, M), repeat=T):
        used = [c for c in choice if c >= 0]
        if len(used) != len(set(used)):
            continue
        c = sum(cost[t, M + t] if i < 0 else cost[t, i] for t, i in enumerate(choice))
        if not np.isfinite(c):
            continue
        w = math.exp(-c)
        total += w
        for t, i in enumerate(choice):
            alpha[t, M if i < 0 else i] += w
    return alpha / total


@pytest.mark.parametrize("seed", range(6))
def test_single_sensor_marginals_equal_exhaustive_enumeration(seed):
    rng = np.random.default_rng(seed)
    T, M = int(rng.integers(1, 4)), int(rng.integers(0, 5))
    det = rng.normal(0.0, 2.0, (T, M))
    det[rng.random((T, M)) < 0.3] = np.inf  # outside the gate
    cost = assignment_matrix(det, miss_cost(0.8))
    expected = _enumerate_single_sensor(cost)
    np.testing.assert_allclose(single_sensor_marginals(cost, m=10_000), expected, rtol=1e-10, atol=1e-14)
    ours = single_sensor_marginals(cost, m=None)
    np.testing.assert_allclose(ours, expected, rtol=1e-10, atol=1e-14)
    assert np.all(ours[:, :M].sum(0) <= 1 + 1e-12)  # a detection goes to one track at most


def test_one_tracks_marginals_are_its_normalised_likelihoods():
    """One track (no other to compete with): the marginal of each detection and of the miss is its
    ``exp(-cost)`` over their sum, in closed form; a detection outside the gate gets 0."""
    cost = assignment_matrix(np.array([[0.3, 2.0, np.inf, -1.1]]), miss_cost(0.8))
    w = np.exp(-cost[0])  # the four detections, then the miss
    for m in (None, 10_000):  # every event, by brute force and by ranked assignment
        alpha = single_sensor_marginals(cost, m=m)[0]
        assert alpha[2] == 0.0  # the detection outside the gate is never taken
        np.testing.assert_allclose(alpha, w / w.sum(), rtol=1e-12, atol=1e-300)


def test_m_best_marginals_approach_the_exact_ones():
    rng = np.random.default_rng(11)
    cost = assignment_matrix(rng.normal(0.0, 1.0, (3, 4)), miss_cost(0.8))
    exact = _enumerate_single_sensor(cost)
    errors = [np.abs(single_sensor_marginals(cost, m) - exact).max() for m in (1, 5, 20, 1000)]
    assert errors[-1] < 1e-12 and errors[0] > errors[-1]


def _enumerate_multi(tuples, costs, n_targets):
    """Independent exhaustive (N+1)-D JPDA over candidate lists."""
    by_target = [np.flatnonzero(tuples[:, 0] == t) for t in range(n_targets)]
    beta = np.zeros(len(costs))
    total = 0.0
    for picks in itertools.product(*by_target):
        used = [(s, i) for p in picks for s, i in enumerate(tuples[p, 1:]) if i >= 0]
        if len(used) != len(set(used)):
            continue
        w = math.exp(-sum(costs[p] for p in picks))
        total += w
        beta[list(picks)] += w
    return beta / total


@pytest.mark.parametrize("seed", range(4))
def test_multi_sensor_marginals_equal_exhaustive_enumeration_when_m_covers_every_event(seed):
    rng = np.random.default_rng(seed)
    K, n_meas = 2, [2, 2]  # two targets, two sensors
    rows = []
    for t in range(K):
        opts = [[-1] + [i for i in range(n) if rng.random() < 0.7] for n in n_meas]
        rows += [(t, *c) for c in itertools.product(*opts)]
    tuples = np.array(rows)
    costs = rng.normal(0.0, 1.5, len(tuples))
    beta, gap = candidate_marginals(tuples, costs, n_meas, K, m=10_000, iterations=30)
    np.testing.assert_allclose(beta, _enumerate_multi(tuples, costs, K), rtol=1e-9, atol=1e-12)
    assert np.isfinite(gap)


def test_gaussian_log_likelihood_matches_scipy():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(3, 2, 2))
    S = torch.from_numpy(A @ A.transpose(0, 2, 1) + np.eye(2))
    nu = torch.from_numpy(rng.normal(size=(3, 5, 2)))
    d2, ll = gaussian_log_likelihood(nu, S)
    for b in range(3):
        ref = multivariate_normal(np.zeros(2), S[b].numpy()).logpdf(nu[b].numpy())
        np.testing.assert_allclose(ll[b].numpy(), ref, rtol=1e-12)
        np.testing.assert_allclose(d2[b].numpy(), np.einsum("mi,ij,mj->m", nu[b].numpy(), np.linalg.inv(S[b].numpy()),
                                                            nu[b].numpy()), rtol=1e-10)


def test_clusters_are_connected_components_of_shared_detections():
    gated = np.array([[1, 0, 0, 0], [1, 1, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 0]], dtype=bool)
    clusters = sorted(sorted(c.tolist()) for c in track_clusters(gated))
    assert clusters == [[0, 1, 2], [3]]  # track 4 gates nothing: left out


@pytest.mark.parametrize("seed", range(4))
def test_dense_clusters_equal_the_sparse_graph_components(seed, monkeypatch):
    import pmsr_nn.trackers.clustering as clustering

    rng = np.random.default_rng(seed)
    gated = rng.random((int(rng.integers(2, 20)), 30)) < 0.04
    dense = sorted(sorted(c.tolist()) for c in track_clusters(gated))
    monkeypatch.setattr(clustering, "SMALL", 0)  # every problem through scipy's connected components
    assert dense == sorted(sorted(c.tolist()) for c in track_clusters(gated))


def test_one_track_marginals_keep_the_m_cheapest_events_like_murty():
    rng = np.random.default_rng(3)
    for m in (1, 2, 3, 50):
        det = rng.normal(0.0, 2.0, (1, 6))
        det[0, 2] = np.inf  # outside the gate
        cost = assignment_matrix(det, miss_cost(0.7))
        events = sorted(np.flatnonzero(np.isfinite(cost[0])), key=lambda j: cost[0, j])[:m]
        expected = np.zeros((1, 7))
        w = np.exp(-cost[0, events] + cost[0, events].min())
        for j, v in zip(events, w / w.sum()):
            expected[0, min(j, 6)] += v
        np.testing.assert_allclose(single_sensor_marginals(cost, m), expected, rtol=1e-12)


def _blocks_of_costs(seed: int) -> np.ndarray:
    """``(B, T, M)`` detection costs N(0, 1) (so no event is negligible: with at most 5 tracks every
    event is within ~15 nats of the best), ``inf`` outside sparse random gates that chain tracks
    into clusters of 1-5, different in every run."""
    rng = np.random.default_rng(seed)
    B, T, M = 6, 5, 7
    cost = rng.normal(0.0, 1.0, (B, T, M))
    cost[rng.random((B, T, M)) > 0.3] = np.inf
    return cost


def _per_cluster(cost: np.ndarray, miss: float, m: int | None) -> np.ndarray:
    """The per-run, per-cluster path the batched one replaces (Murty, or brute force for ``None``)."""
    B, T, M = cost.shape
    alpha = np.zeros((B, T, M + 1))
    alpha[..., M] = 1.0
    for b in range(B):
        gated = np.isfinite(cost[b])
        for cl in track_clusters(gated):
            cols = np.flatnonzero(gated[cl].any(0))
            a = single_sensor_marginals(assignment_matrix(cost[b][np.ix_(cl, cols)], miss), m)
            alpha[b, cl, M] = a[:, -1]
            alpha[b][np.ix_(cl, cols)] = a[:, :-1]
    return alpha


# Probabilities are normalised sums of at most a few thousand exp(-cost) terms: their rounding
# is ~1e-13; 1e-9 is far below the smallest event probability of these draws (exp(-15) ~ 3e-7).
PROB_ATOL = 1e-9


@pytest.mark.parametrize("seed", range(4))
def test_batched_marginals_equal_brute_force_when_m_covers_every_event(seed):
    cost = _blocks_of_costs(seed)
    miss = miss_cost(0.8)
    exact = _per_cluster(cost, miss, None)  # every event of every cluster, by enumeration
    np.testing.assert_allclose(batched_single_sensor_marginals(cost, miss, 10_000), exact, atol=PROB_ATOL)
    np.testing.assert_allclose(batched_single_sensor_marginals(cost, miss, 10_000, max_events=0), exact,
                               atol=PROB_ATOL)  # every cluster through Murty


@pytest.mark.parametrize("m", [1, 3, 10])
def test_batched_m_best_marginals_equal_murty_per_cluster(m):
    """Truncated to m events the enumeration keeps Murty's m cheapest; clusters above the event
    limit (here every cluster of more than 16 events) go through Murty in the same call."""
    for seed in range(4):
        cost = _blocks_of_costs(seed)
        expected = _per_cluster(cost, miss_cost(0.8), m)
        for limit in (4096, 16):
            got = batched_single_sensor_marginals(cost, miss_cost(0.8), m, max_events=limit)
            np.testing.assert_allclose(got, expected, atol=PROB_ATOL)


def test_batched_marginals_do_not_mix_runs():
    """Every run solved in one call gives what it gives alone, whatever the other runs hold."""
    cost = _blocks_of_costs(7)
    together = batched_single_sensor_marginals(cost, miss_cost(0.8), 5)
    for b in range(cost.shape[0]):
        alone = batched_single_sensor_marginals(cost[b:b + 1], miss_cost(0.8), 5)
        np.testing.assert_allclose(together[b:b + 1], alone, atol=PROB_ATOL)


def test_pda_collapse_equals_the_mixture_of_kalman_updates():
    """The shared-gain collapse of S-MSJPDA is the moment match of the per-detection posteriors."""
    from pmsr_nn.filters.gaussian import kalman_update, safe_cholesky
    from pmsr_nn.trackers.mixture import collapse as _collapse, expand_moments as _expand, pda_collapse as _pda_collapse

    model = _model(1)
    truth = _formation(B=2, K=2, T=3)
    g = _prior(truth)
    mom = unscented_moments(g, model, model.R())
    rng = np.random.default_rng(0)
    z = mom.z[:, :1] + torch.from_numpy(rng.normal(0.0, 1.0, (2, 6, 2)) * np.array([1500.0, 2.0]))  # (B, M, d)
    z[1, 4:] = math.nan  # padding
    gate = torch.from_numpy(rng.random((2, 3, 6)) < 0.6) & ~torch.isnan(z[:, None, :, 0])
    w = torch.from_numpy(rng.random((2, 3, 7))) * torch.cat([gate, torch.ones(2, 3, 1, dtype=torch.bool)], -1)
    w = w / w.sum(-1, keepdim=True)
    post, _, _ = kalman_update(Gaussian(g.x.unsqueeze(-2), g.P.unsqueeze(-3)), z.unsqueeze(1), _expand(mom), model)
    ref = _collapse(w, torch.cat([post.x, g.x.unsqueeze(-2)], -2), torch.cat([post.P, g.P.unsqueeze(-3)], -3))
    L = safe_cholesky(mom.S)
    nu = model.residual(z.unsqueeze(1), mom.z.unsqueeze(2))
    e = torch.linalg.solve_triangular(L, nu.nan_to_num().transpose(-1, -2), upper=False).transpose(-1, -2)
    got = _pda_collapse(g, mom, L, e, gate, w)
    # the reference subtracts positions of ~30 km: its rounding is ~1e-11 m, ~1e-8 m^2 in P
    torch.testing.assert_close(got.x, ref.x, rtol=0, atol=1e-6)
    torch.testing.assert_close(got.P, ref.P, rtol=1e-9, atol=1e-4)


# ----------------------------------------------------------------------------------- trackers

@pytest.mark.parametrize("architecture", ["sequential", "parallel"])
def test_one_target_one_sensor_no_clutter_pd_one_is_the_ukf(architecture):
    model = _model(1)
    truth = _formation(B=3, K=12, T=1)
    scans = simulate_scans(truth, model, 1.0, ClutterSpec(per_scan=0), seeded_generator(4))
    prior = _prior(truth)
    settings = JPDASettings(pd=1.0, clutter_density=1e-9, gate_probability=1 - 1e-12)
    R = model.R()
    res = msjpda(scans, prior, MOTION, 1.0, 1.0, model, R, settings, architecture)
    z = scans.target_measurements(1)[:, :, 0].reshape(3, 12, 2)
    ref = ukf(Gaussian(prior.x[:, 0], prior.P[:, 0]), z, MOTION, 1.0, 1.0, model, R)
    torch.testing.assert_close(res.x[:, :, 0], ref.x, rtol=1e-9, atol=1e-7)
    torch.testing.assert_close(res.P[:, :, 0], ref.P, rtol=1e-9, atol=1e-7)


def test_sequential_and_parallel_agree_with_one_sensor():
    """With one sensor the (N+1)-D problem is the 2-D one: same events, same update."""
    model = _model(1)
    truth = _formation(B=2, K=8, T=3)
    scans = simulate_scans(truth, model, 0.8, ClutterSpec(per_scan=20), seeded_generator(6))
    prior = _prior(truth)
    s = JPDASettings(pd=0.8, clutter_density=20 / ClutterSpec().volume, m_best=50)
    a = msjpda(scans, prior, MOTION, 1.0, 1.0, model, model.R(), s, "sequential")
    b = msjpda(scans, prior, MOTION, 1.0, 1.0, model, model.R(), s, "parallel")
    torch.testing.assert_close(a.x, b.x, rtol=1e-8, atol=1e-6)


def test_empty_all_clutter_and_crossing_scans_stay_finite():
    model = _model()
    # two targets whose paths cross at scan 10
    x0 = torch.tensor([[-27e3, 250.0, -20e3, 250.0], [-22e3, -250.0, -20e3, 250.0]], dtype=torch.float64)
    truth = MOTION.sample(x0.repeat(2, 1), 20, 1.0, 0.0, seeded_generator(0)).reshape(2, 2, 20, 4).transpose(1, 2)
    prior = _prior(truth)
    s = JPDASettings(pd=0.8, clutter_density=50 / ClutterSpec().volume)
    for pd, clutter in ((0.0, 0), (0.0, 50), (0.9, 50)):  # empty scans, all clutter, crossing with clutter
        scans = simulate_scans(truth, model, pd, ClutterSpec(per_scan=clutter), seeded_generator(8))
        for arch in ("sequential", "parallel"):
            res = msjpda(scans, prior, MOTION, 1.0, 1.0, model, model.R(), s, arch)
            assert torch.isfinite(res.x).all() and torch.isfinite(res.P).all()
            assert (torch.linalg.eigvalsh(res.P) > 0).all()
            if pd == 0.0 and clutter == 0:  # nothing detected: the dummy is always the likeliest
                assert res.dummy_most_probable.all()


def test_true_assignment_reference_uses_exactly_the_targets_detections():
    model = _model()
    truth = _formation(B=2, K=10, T=2)
    scans = simulate_scans(truth, model, 0.7, ClutterSpec(per_scan=30), seeded_generator(9))
    prior = _prior(truth)
    res = true_assignment_ukf(scans, prior, MOTION, 1.0, 1.0, model, model.R())
    for t in range(2):
        z = scans.target_measurements(2)[:, :, t].reshape(2, 10, 6)
        ref = ukf(Gaussian(prior.x[:, t], prior.P[:, t]), z, MOTION, 1.0, 1.0, model, model.R())
        torch.testing.assert_close(res.x[:, :, t], ref.x)


def _sequential_ukf(prior: Gaussian, z: torch.Tensor, model: MeasurementModel) -> torch.Tensor:
    """Reference: UKF with the sequential per-sensor update of pmsr_nn.filters (no association)."""
    F, Q = MOTION.F(1.0), MOTION.Q(1.0, 1.0)
    g, out = prior, []
    for k in range(z.shape[1]):
        if k:
            g = predict(g, F, Q)
        g, _ = sequential_update(g, z[:, k], model, model.R(), unscented_moments)
        out.append(g.x)
    return torch.stack(out, 1)


def test_well_separated_targets_track_like_the_reference():
    """No clutter, Pd 1, targets 40 km apart (no detection in a foreign gate): every association is
    certain, so P-MSJPDA is the joint UKF and S-MSJPDA the sequential UKF of each target."""
    model = _model()
    truth = _formation(B=2, K=10, T=2, spacing=40e3)
    scans = simulate_scans(truth, model, 1.0, ClutterSpec(per_scan=0), seeded_generator(2))
    prior = _prior(truth)
    s = JPDASettings(pd=1.0, clutter_density=1e-9, gate_probability=1 - 1e-12)  # no true detection gated out
    ref = true_assignment_ukf(scans, prior, MOTION, 1.0, 1.0, model, model.R())
    par = msjpda(scans, prior, MOTION, 1.0, 1.0, model, model.R(), s, "parallel")
    torch.testing.assert_close(par.x, ref.x, rtol=1e-9, atol=1e-7)
    seq = msjpda(scans, prior, MOTION, 1.0, 1.0, model, model.R(), s, "sequential")
    for t in range(2):
        z = scans.target_measurements(2)[:, :, t].reshape(2, 10, 6)
        expected = _sequential_ukf(Gaussian(prior.x[:, t], prior.P[:, t]), z, model)
        torch.testing.assert_close(seq.x[:, :, t], expected, rtol=1e-9, atol=1e-7)


@pytest.mark.parametrize("architecture", ["sequential", "parallel"])
def test_runs_of_one_block_track_as_each_alone(architecture):
    """Runs with different detections (targets 1.5 km apart, 30 clutter points: clusters of
    several tracks) in one call give the estimates each gives alone: batching never mixes runs."""
    model = _model()
    truth = _formation(B=3, K=8, T=3, spacing=1500.0)
    scans = simulate_scans(truth, model, 0.8, ClutterSpec(per_scan=30), seeded_generator(11))
    prior = _prior(truth)
    s = JPDASettings(pd=0.8, clutter_density=30 / ClutterSpec().volume)
    block = msjpda(scans, prior, MOTION, 1.0, 1.0, model, model.R(), s, architecture)
    for b in range(3):
        one = Scans(scans.z[b:b + 1], scans.valid[b:b + 1], scans.origin[b:b + 1])
        alone = msjpda(one, Gaussian(prior.x[b:b + 1], prior.P[b:b + 1]), MOTION, 1.0, 1.0, model, model.R(), s,
                       architecture)
        # the same algebra on a different batch size: rounding only (~1e-11 m at 30 km)
        torch.testing.assert_close(block.x[b:b + 1], alone.x, rtol=1e-9, atol=1e-6)
        torch.testing.assert_close(block.P[b:b + 1], alone.P, rtol=1e-9, atol=1e-6)
        assert torch.equal(block.dummy_most_probable[b:b + 1], alone.dummy_most_probable)


def test_bad_tracker_inputs():
    model = _model()
    truth = _formation(B=1, K=3, T=2)
    scans = simulate_scans(truth, model, 0.9, ClutterSpec(per_scan=2), seeded_generator(0))
    prior = _prior(truth)
    s = JPDASettings(pd=0.9, clutter_density=1e-7)
    with pytest.raises(ConfigError, match="prior must be"):
        msjpda(scans, Gaussian(prior.x[0], prior.P[0]), MOTION, 1.0, 1.0, model, model.R(), s, "sequential")
    bad = Scans(scans.z.clone(), scans.valid, scans.origin)
    bad.z[0, 1, 0, 0, 0] = float("nan")
    with pytest.raises(ConfigError, match="NaN"):
        msjpda(bad, prior, MOTION, 1.0, 1.0, model, model.R(), s, "parallel")
    with pytest.raises(ConfigError, match="sensors"):
        msjpda(scans, prior, MOTION, 1.0, 1.0, _model(2), _model(2).R(), s, "parallel")
    with pytest.raises(ConfigError, match="architecture"):
        msjpda(scans, prior, MOTION, 1.0, 1.0, model, model.R(), s, "both")
    with pytest.raises(ConfigError, match="clutter_density"):
        JPDASettings(pd=0.9, clutter_density=0.0)


def test_loss_rule():
    dummy = torch.zeros(1, 10, 3, dtype=torch.bool)
    dummy[0, 2:5, 0] = True  # 3 in a row: kept
    dummy[0, 3:7, 1] = True  # 4 in a row: lost at scan 6
    gate = torch.zeros(1, 10, 3)
    gate[0, 8, 2] = 6000.0  # gate too large at scan 8
    lost = track_loss(dummy, gate, successive=4, gate_limit=5000.0)
    assert lost.tolist() == [[-1, 6, 8]]
