"""The BP associator (pmsr_nn/trackers/bp_associator.py) on the one tracker loop: against the PDA
update of S-MSJPDA's associator where no detection is shared, exact enumeration where two tracks
share one, and the shared track management."""

from __future__ import annotations

import math

import torch
from scipy.stats import chi2

from pmsr_nn.filters import Gaussian, unscented_moments
from pmsr_nn.filters.gaussian import kalman_update
from pmsr_nn.rng import seeded_generator
from pmsr_nn.simulation.detections import ClutterSpec, simulate_scans
from pmsr_nn.trackers.bp_associator import BPAssociator
from pmsr_nn.trackers.gating import gaussian_log_likelihood
from pmsr_nn.trackers.jpda_associators import SequentialJPDA
from pmsr_nn.trackers.loop import run_tracker
from pmsr_nn.trackers.management import Confirmer, Deleter, Management
from pmsr_nn.trackers.mixture import collapse
from pmsr_nn.trackers.msjpda import JPDASettings
from pmsr_nn.trackers.own_tracks import OwnTracks
from pmsr_nn.trackers.spherical_initiator import SphericalInitiator
from test_msjpda import MOTION, _formation, _model, _prior

CLUTTER = ClutterSpec(per_scan=200, range_m=(0.0, 60e3), doppler_hz=(-250.0, 250.0))
DENSITY = 200 / (60e3 * 500.0)


def test_one_track_per_run_is_the_pda_update_and_ipda_existence():
    """One track per run, dense clutter, three pairs, no births: no other track competes for a
    detection, so BP's weights given existence are the PDA weights and the update is S-MSJPDA's
    with ``association: pda``, pair by pair; the existence is the IPDA update of each pair in
    turn (Musicki et al.: ``delta = Pd (1 - ratio)``, ``r' = (1 - delta) r / (1 - delta r)``) with
    that pair's likelihood ratio."""
    model = _model()
    truth = _formation(B=20, K=1, T=1)
    scans = simulate_scans(truth, model, 0.8, CLUTTER, seeded_generator(5))
    prior = _prior(truth, sd=(600.0, 20.0))
    r0 = torch.linspace(0.05, 0.95, 20, dtype=torch.float64).unsqueeze(-1)
    pd = 0.8 * 0.999
    bp = BPAssociator(model, model.R(), pd, DENSITY, existence=lambda: r0)
    step = bp.associate(prior, scans.z[:, 0], scans.valid[:, 0], None)
    pda = SequentialJPDA(model, model.R(), JPDASettings(pd, DENSITY), association="pda")
    ref = pda.associate(prior, scans.z[:, 0], scans.valid[:, 0], None)
    assert (ref.ratio > 0).sum() >= 30 and (ref.ratio == 0).any(), "detections in most gates, some gates empty"
    torch.testing.assert_close(step.posterior.x, ref.posterior.x, rtol=1e-12, atol=1e-8)
    torch.testing.assert_close(step.posterior.P, ref.posterior.P, rtol=1e-10, atol=1e-8)
    torch.testing.assert_close(step.ratio, ref.ratio, rtol=1e-12, atol=0)
    r = r0
    for j in range(3):
        delta = pd * (1 - ref.ratio[..., j])
        r = (1 - delta) * r / (1 - delta * r)
    torch.testing.assert_close(step.existence, r, rtol=1e-12, atol=0)
    assert (step.new_existence == 0).all()


def test_two_tracks_sharing_one_detection_are_updated_with_the_exact_marginals():
    """One pair, two tracks of different existence near one target, its single detection in
    both gates, births behind it: the graph is a tree, so the update is the mixture collapse
    with the exact marginals. Events: nobody takes the detection (``beta_1(0) beta_2(0) xi``),
    track i takes it (``beta_i(1) beta_other(0)``); ``beta_i(0) = 1 - r_i Pd``, ``beta_i(1) = r_i
    Pd L_i``, ``xi = 1 + mu``. Track i's weight given existence is ``p(a_i = 1) / r_i'`` with
    ``r_i' = 1 - p(a_i = 0) (1 - r_i) / beta_i(0)``, and the detection's new target has
    existence ``p(free) mu / xi``."""
    full = _model()
    model = full.for_pairs([0])
    truth = _formation(B=1, K=1, T=1)
    z = model.h(truth[:, 0, 0])  # noise-free, inside both gates
    x = truth[:, 0].expand(1, 2, 4) + torch.tensor([[[150.0, 3.0, -100.0, -2.0], [-300.0, 0.0, 250.0, 4.0]]],
                                                   dtype=torch.float64)
    P = torch.diag(torch.tensor([400.0, 15.0, 400.0, 15.0], dtype=torch.float64) ** 2).expand(1, 2, 4, 4)
    g = Gaussian(x, P.clone())
    r = torch.tensor([[0.9, 0.4]], dtype=torch.float64)
    pd, mu = 0.85, 0.3
    bp = BPAssociator(model, model.R(), pd, DENSITY, existence=lambda: r, birth=mu)
    step = bp.associate(g, z[:, None, None], torch.ones(1, 1, 1, dtype=torch.bool), None)
    mom = unscented_moments(g, model, model.R())
    d2, log_lik = gaussian_log_likelihood(model.residual(z[:, None, None], mom.z.unsqueeze(2)), mom.S)
    assert (d2 < chi2.ppf(0.999, 2)).all()
    L = log_lik[0, :, 0].exp() / DENSITY
    b0, b1 = 1 - r[0] * pd, r[0] * pd * L
    Z = b0[0] * b0[1] * (1 + mu) + b1[0] * b0[1] + b0[0] * b1[1]
    p1 = torch.stack([b1[0] * b0[1], b0[0] * b1[1]]) / Z
    p0 = 1 - p1
    r1 = 1 - p0 * (1 - r[0]) / b0
    torch.testing.assert_close(step.existence[0], r1, rtol=1e-12, atol=0)
    torch.testing.assert_close(step.new_existence[0, 0, 0], b0[0] * b0[1] * (1 + mu) / Z * mu / (1 + mu),
                               rtol=1e-12, atol=0)
    w = p1 / r1
    hit, _, _ = kalman_update(g, z[:, None].expand(1, 2, 2), mom, model)
    expected = collapse(torch.stack([w, 1 - w], -1)[None], torch.stack([hit.x, g.x], 2), torch.stack([hit.P, g.P], 2))
    torch.testing.assert_close(step.posterior.x, expected.x, rtol=1e-12, atol=1e-8)
    torch.testing.assert_close(step.posterior.P, expected.P, rtol=1e-10, atol=1e-8)
    assert math.isclose(float(step.legacy[0, 0, 0]), float(p1.sum()), rel_tol=1e-12)


def test_own_tracks_on_the_loop_with_bp_start_one_confirmed_track_per_separated_target():
    """No clutter, Pd ~1, two targets 40 km apart: with BP as the associator and the existence
    read from the shared management, one track per target is started, confirmed and kept, and
    it stays consistent with its covariance."""
    model = _model()
    truth = _formation(B=2, K=12, T=2, spacing=40e3)
    scans = simulate_scans(truth, model, 1.0, ClutterSpec(per_scan=0), seeded_generator(4))
    mg = Management(SphericalInitiator(), Confirmer(2, 3), Deleter(2), torch.tensor([300.0, 10.0] * 2,
                                                                                    dtype=torch.float64), hit_pairs=2)
    pd = 1.0 - 1e-9
    tracks = OwnTracks(mg, model, 4, pd)
    bp = BPAssociator(model, model.R(), pd, 1e-9, existence=lambda: tracks.table.existence,
                      gate_probability=1 - 1e-12)
    rep = run_tracker(scans, MOTION, 1.0, 1.0, bp, tracks)
    assert rep.exists.shape[2] == 2, "one track id per target, no other"
    assert not rep.exists[:, 0].any() and rep.exists[:, 1:].all()
    err = rep.x[:, 1:, :, None][..., [0, 2]] - truth[:, 1:, None, :][..., [0, 2]]  # (B, K, tracks, N, 2)
    held = err.norm(dim=-1).argmin(-1)
    assert (held == held[:, :1]).all() and (held[:, 0, 0] != held[:, 0, 1]).all()
    e = err.gather(3, held[..., None, None].expand(*held.shape, 1, 2)).squeeze(3)
    P = rep.P[:, 1:][..., [0, 2], :][..., [0, 2]]
    nees = (e.unsqueeze(-2) @ torch.linalg.solve(P, e.unsqueeze(-1))).squeeze(-1).squeeze(-1)
    assert float(nees.max()) < chi2.ppf(0.9999, 2), nees.max()
