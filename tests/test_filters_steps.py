"""The predict / update interface trackers reuse: per-sensor sequential updates and per-hypothesis
broadcasting."""

from dataclasses import replace

import pytest
import torch

from pmsr_nn.errors import ConfigError
from pmsr_nn.filters import Gaussian, kalman_update, linearised_moments, sequential_update
from pmsr_nn.filters.gaussian import MeasurementMoments
from pmsr_nn.geometry import Geometry, Receiver, Transmitter
from pmsr_nn.measurements import MeasurementModel
from pmsr_nn.simulation.recipe import TrackRecipe
from pmsr_nn.simulation.tracks import build_models


def _state(B=4, seed=0):
    g = torch.Generator().manual_seed(seed)
    x = torch.tensor([4000.0, 10.0, 0.1, 3000.0, -5.0, 0.0]) + torch.randn(B, 6, generator=g) * torch.tensor([300.0, 5, 0.1] * 2)
    P = torch.diag(torch.tensor([80.0, 4.0, 0.2] * 2) ** 2).expand(B, 6, 6).clone()
    return Gaussian(x, P), g


@pytest.mark.parametrize("layout", ["component", "pair"])
def test_rows_for_pairs_select_the_sub_model(layout):
    _, model = build_models(TrackRecipe())
    model = replace(model, layout=layout)
    prior, _ = _state()
    for pairs in ([0], [2], [2, 0], [1, 2]):
        sub = model.for_pairs(pairs)
        torch.testing.assert_close(model.h(prior.x)[..., model.rows_for_pairs(pairs)], sub.h(prior.x), rtol=0, atol=0)
        assert sub.dim_z == 3 * len(pairs)
    with pytest.raises(ConfigError, match="pair indices"):
        model.for_pairs([3])


def _frozen_linearisation(x_lin):
    """Moments of the model linearised once at ``x_lin`` (not at the current mean): a linear model,
    for which sequential and joint updates must agree exactly."""
    def moments(g, model, R):
        H = model.jacobian(x_lin)
        z = model.h(x_lin) + ((g.x - x_lin).unsqueeze(-2) @ H.transpose(-1, -2)).squeeze(-2)
        C = g.P @ H.transpose(-1, -2)
        return MeasurementMoments(z, H @ C + R, C)
    return moments


def test_sequential_equals_joint_for_a_linear_model():
    _, model = build_models(TrackRecipe())
    prior, g = _state()
    R = model.R(torch.tensor([[20.0, 2.0, 0.01]] * 4))
    z = model.sample(prior.x + torch.randn(4, 6, generator=g) * 30, torch.tensor([[20.0, 2.0, 0.01]] * 4), g)
    z[1, [0, 4]] = float("nan")  # missing entries are skipped in both
    moments = _frozen_linearisation(prior.x)
    joint, _, nis_joint = kalman_update(prior, z, moments(prior, model, R), model)
    seq, nis_seq = sequential_update(prior, z, model, R, moments, order=[2, 0, 1])
    torch.testing.assert_close(seq.x, joint.x, rtol=1e-10, atol=1e-8)
    torch.testing.assert_close(seq.P, joint.P, rtol=1e-8, atol=1e-8)
    assert bool(torch.isfinite(nis_seq).all())
    # The EKF re-linearises after each sensor, so its sequential update is a different estimator.
    ekf_seq, _ = sequential_update(prior, z, model, R, linearised_moments)
    assert not torch.allclose(ekf_seq.x, joint.x, rtol=0, atol=1e-6)


def test_sequential_update_rejects_correlated_sensors():
    _, model = build_models(TrackRecipe())
    prior, _ = _state()
    R = model.R().clone()
    R[0, 1] = R[1, 0] = 1.0  # range noise of pairs 1 and 2 correlated
    with pytest.raises(ConfigError, match="block-diagonal"):
        sequential_update(prior, model.h(prior.x), model, R, linearised_moments)


def test_one_track_many_measurement_hypotheses_broadcast():
    """x (B, 1, n) against z (B, M, m) gives the M single-measurement posteriors."""
    geometry = Geometry.all_pairs([Transmitter((0.0, 0.0), 600e6)], [Receiver((5000.0, -6000.0))])
    model = MeasurementModel(geometry, ("range", "doppler"), (15.0, 2.0), (0, 3), (1, 4), layout="pair")
    prior, g = _state(B=3)
    R = model.R()
    z = model.sample(prior.x.unsqueeze(1) + torch.randn(3, 5, 6, generator=g) * 50, None, g)  # (3, 5, 2)
    track = Gaussian(prior.x.unsqueeze(1), prior.P.unsqueeze(1))
    post, nu, nis = kalman_update(track, z, linearised_moments(track, model, R), model)
    assert post.x.shape == (3, 5, 6) and post.P.shape == (3, 5, 6, 6) and nis.shape == (3, 5)
    for j in range(5):
        one, nu_j, nis_j = kalman_update(prior, z[:, j], linearised_moments(prior, model, R), model)
        torch.testing.assert_close(post.x[:, j], one.x, rtol=1e-12, atol=1e-9)
        torch.testing.assert_close(post.P[:, j], one.P, rtol=1e-12, atol=1e-9)
        torch.testing.assert_close(nis[:, j], nis_j)
