"""Linear and unscented RTS smoothers against filterpy on identical inputs (float64)."""


import numpy as np
import pytest
import torch
from filterpy.kalman import KalmanFilter, MerweScaledSigmaPoints, UnscentedKalmanFilter

from pmsr_nn.errors import ConfigError
from pmsr_nn.filters import Gaussian, SigmaPoints, kalman_filter, rts_smoother, ukf, unscented_rts_smoother
from pmsr_nn.measurements import LinearMeasurementModel
from pmsr_nn.motion import ConstantAcceleration
from pmsr_nn.rng import seeded_generator

DT, Q_PSD = 1.0, 1e-2


def _linear_case(B=3, K=30):
    motion = ConstantAcceleration()
    model = LinearMeasurementModel.position(6, motion.pos_idx, 15.0)
    g = seeded_generator(3)
    truth = motion.sample(torch.randn(B, 6, generator=g) * 100, K, DT, Q_PSD, g)
    prior = Gaussian(torch.zeros(B, 6), torch.diag(torch.tensor([200.0, 10, 1] * 2) ** 2).expand(B, 6, 6).clone())
    return motion, model, model.sample(truth, g), prior


def test_rts_matches_filterpy_kalman_smoother():
    motion, model, z, prior = _linear_case()
    filt = kalman_filter(prior, z, motion, DT, Q_PSD, model, model.R())
    ours = rts_smoother(filt.x, filt.P, motion, DT, Q_PSD)
    kf = KalmanFilter(dim_x=6, dim_z=2)
    F, Q = motion.F(DT).numpy(), motion.Q(DT, Q_PSD).numpy()
    for b in range(z.shape[0]):
        # filterpy's batch_filter predicts before the first update; our prior is at step 0, so the
        # reference starts from the prior "predicted backwards" by giving it F = I on the first step.
        kf.x, kf.P, kf.F, kf.Q, kf.H, kf.R = prior.x[b].numpy().copy(), prior.P[b].numpy().copy(), F, Q, model.H.numpy(), model.R().numpy()
        Fs = [np.eye(6)] + [F] * (z.shape[1] - 1)
        Qs = [np.zeros((6, 6))] + [Q] * (z.shape[1] - 1)
        mu, cov, _, _ = kf.batch_filter(z[b].numpy(), Fs=Fs, Qs=Qs)
        np.testing.assert_allclose(filt.x[b].numpy(), mu, rtol=1e-10, atol=1e-8)
        xs, Ps, _, _ = kf.rts_smoother(mu, cov, Fs=[F] * z.shape[1], Qs=[Q] * z.shape[1])
        np.testing.assert_allclose(ours.x[b].numpy(), xs, rtol=1e-10, atol=1e-8)
        np.testing.assert_allclose(ours.P[b].numpy(), Ps, rtol=1e-8, atol=1e-10 * np.abs(Ps).max())


@pytest.fixture(scope="module")
def bistatic(make_tracks):
    motion, model, batch = make_tracks(steps=25, n=3, seed=5)
    sd = torch.tensor([50.0, 3.0, 0.5] * 2)
    P0 = torch.diag(sd**2).expand(3, 6, 6).clone()
    x0 = batch.states[:, 0] + torch.randn(3, 6, generator=seeded_generator(6)) * sd
    return motion, model, batch.measurements, model.R(batch.noise_std), Gaussian(x0, P0)


def test_unscented_rts_matches_filterpy(bistatic):
    motion, model, z, R, prior = bistatic
    sigma = SigmaPoints(alpha=0.5, beta=2.0, kappa=0.0)
    filt = ukf(prior, z, motion, DT, Q_PSD, model, R, sigma)
    F, Q = motion.F(DT), motion.Q(DT, Q_PSD)
    ours = unscented_rts_smoother(filt.x, filt.P, lambda s: s @ F.T, Q, sigma)
    for b in range(z.shape[0]):
        # filterpy 2.0.0's rts_smoother ignores its Qs argument and uses self.Q: Q is constant here.
        f = UnscentedKalmanFilter(dim_x=6, dim_z=9, dt=DT, fx=lambda x, dt: F.numpy() @ x, hx=None,
                                  points=MerweScaledSigmaPoints(6, alpha=0.5, beta=2.0, kappa=0.0))
        f.Q = Q.numpy()
        xs, Ps, _ = f.rts_smoother(filt.x[b].numpy(), filt.P[b].numpy())
        np.testing.assert_allclose(ours.x[b].numpy(), xs, rtol=1e-10, atol=1e-8)
        np.testing.assert_allclose(ours.P[b].numpy(), Ps, rtol=1e-8, atol=1e-10 * np.abs(Ps).max())
    # With a linear transition the unscented smoother is the linear one.
    lin = rts_smoother(filt.x, filt.P, motion, DT, Q_PSD)
    torch.testing.assert_close(ours.x, lin.x, rtol=1e-10, atol=1e-8)
    torch.testing.assert_close(ours.P, lin.P, rtol=1e-8, atol=1e-8)


def test_smoother_reduces_error_and_covariance(bistatic):
    motion, model, z, R, prior = bistatic
    filt = ukf(prior, z, motion, DT, Q_PSD, model, R)
    sm = rts_smoother(filt.x, filt.P, motion, DT, Q_PSD)
    # Smoothing never increases the covariance: P - P_s is positive semi-definite at every step.
    eig = torch.linalg.eigvalsh(filt.P - sm.P)
    assert bool((eig > -1e-9 * filt.P.abs().amax((-1, -2), keepdim=True)[..., 0]).all())
    # The last step has no future: smoothed = filtered.
    torch.testing.assert_close(sm.x[:, -1], filt.x[:, -1])


def test_smoother_rejects_bad_shapes():
    with pytest.raises(ConfigError, match="smoother needs"):
        rts_smoother(torch.zeros(2, 5, 6), torch.zeros(2, 5, 6), ConstantAcceleration(), DT, Q_PSD)
