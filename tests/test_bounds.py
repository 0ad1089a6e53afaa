"""PCRB: exact in the linear-Gaussian case, equal to the brute-force inverse of the trajectory's
information matrix, and the per-trajectory form never below the information-averaged one."""


import pytest
import torch

from pmsr_nn.bounds import information_bound, measurement_information, pcrb
from pmsr_nn.errors import ConfigError
from pmsr_nn.filters import Gaussian, kalman_filter, rts_smoother
from pmsr_nn.measurements import LinearMeasurementModel
from pmsr_nn.motion import ConstantAcceleration
from pmsr_nn.rng import seeded_generator

DT, Q_PSD = 1.0, 0.05
P0 = torch.diag(torch.tensor([100.0, 5.0, 0.3] * 2, dtype=torch.float64) ** 2)


@pytest.fixture(scope="module")
def tracks(make_tracks):
    motion, model, batch = make_tracks(steps=12, n=40, seed=9)
    return motion, model, batch.states, model.R(batch.noise_std)


@pytest.mark.parametrize("form", ["information_averaged", "per_trajectory"])
def test_linear_gaussian_bound_is_the_kalman_covariance(form):
    motion = ConstantAcceleration()
    model = LinearMeasurementModel.position(6, motion.pos_idx, 12.0)
    g = seeded_generator(1)
    truth = motion.sample(torch.randn(5, 6, generator=g) * 100, 20, DT, Q_PSD, g)
    z = model.sample(truth, g)
    filt = kalman_filter(Gaussian(torch.zeros(5, 6), P0.expand(5, 6, 6)), z, motion, DT, Q_PSD, model, model.R())
    smooth = rts_smoother(filt.x, filt.P, motion, DT, Q_PSD)
    bound = pcrb(truth, motion, DT, Q_PSD, model, model.R(), P0, form=form)
    # The KF covariance does not depend on the data: every run has the same one, equal to the bound.
    torch.testing.assert_close(bound.filtering, filt.P[0], rtol=1e-9, atol=1e-9)
    torch.testing.assert_close(bound.smoothing, smooth.P[0], rtol=1e-9, atol=1e-9)


def _trajectory_information(info: torch.Tensor, F: torch.Tensor, Q: torch.Tensor) -> torch.Tensor:
    """Full information matrix ``(K n, K n)`` of one trajectory: prior, transitions, measurements."""
    K, n = info.shape[0], info.shape[-1]
    Qi = torch.linalg.inv(Q)
    J = torch.zeros(K * n, K * n)
    J[:n, :n] = torch.linalg.inv(P0)
    for k in range(K):
        blk = slice(k * n, (k + 1) * n)
        J[blk, blk] += info[k]
        if k > 0:
            prev = slice((k - 1) * n, k * n)
            J[prev, prev] += F.T @ Qi @ F
            J[prev, blk] -= F.T @ Qi
            J[blk, prev] -= Qi @ F
            J[blk, blk] += Qi
    return J


def test_bounds_equal_brute_force_inverse_of_trajectory_information(tracks):
    motion, model, truth, R = tracks
    truth, R = truth[:1], R[:1]
    bound = pcrb(truth, motion, DT, Q_PSD, model, R, P0, form="per_trajectory")
    info = measurement_information(truth, model, R)[0]
    F, Q = motion.F(DT), motion.Q(DT, Q_PSD)
    n, K = 6, truth.shape[1]
    cov = torch.linalg.inv(_trajectory_information(info, F, Q))
    for k in range(K):
        blk = slice(k * n, (k + 1) * n)
        torch.testing.assert_close(bound.smoothing[k], cov[blk, blk], rtol=1e-6, atol=1e-9)
        # The filtering bound at k is the smoothing bound of the trajectory cut after step k.
        cut = torch.linalg.inv(_trajectory_information(info[: k + 1], F, Q))
        torch.testing.assert_close(bound.filtering[k], cut[-n:, -n:], rtol=1e-6, atol=1e-9)


def test_per_trajectory_bound_is_never_below_the_averaged_one(tracks):
    motion, model, truth, R = tracks
    avg = pcrb(truth, motion, DT, Q_PSD, model, R, P0, form="information_averaged")
    per = pcrb(truth, motion, DT, Q_PSD, model, R, P0, form="per_trajectory", chunk_tracks=7)
    for which in ("filtering", "smoothing"):
        gap = torch.linalg.eigvalsh(getattr(per, which) - getattr(avg, which))
        scale = torch.linalg.eigvalsh(getattr(per, which)).amax(-1, keepdim=True)
        assert bool((gap > -1e-9 * scale).all()), which
    assert bool((per.position_rmse("smoothing") <= per.position_rmse() + 1e-9).all())
    # Per-track bounds average (in MSE) to the reported one.
    torch.testing.assert_close((per.per_track_position**2).mean(0), per.position_rmse() ** 2)
    # Missed detections remove information: a lower detection probability gives a higher bound.
    low = pcrb(truth, motion, DT, Q_PSD, model, R, P0, form="per_trajectory", detection_probability=0.5)
    assert bool((low.position_rmse() > per.position_rmse()).all())


def test_bad_inputs(tracks):
    motion, model, truth, R = tracks
    with pytest.raises(ConfigError, match="form must be"):
        pcrb(truth, motion, DT, Q_PSD, model, R, P0, form="average")
    with pytest.raises(ConfigError, match="truth must be"):
        pcrb(truth[..., :4], motion, DT, Q_PSD, model, R, P0)
    bad = truth.clone()
    bad[3, 5, 0] = float("nan")
    with pytest.raises(ConfigError, match="run 3 at step 5 is not finite"):
        pcrb(bad, motion, DT, Q_PSD, model, R, P0)
    on = truth.clone()
    on[2, 4, list(motion.pos_idx)] = torch.tensor(model.geometry.receivers[1].position_m)
    with pytest.raises(ConfigError, match="run 2 at step 4 is within"):
        pcrb(on, motion, DT, Q_PSD, model, R, P0)
    with pytest.raises(ConfigError, match="P0 is not positive definite"):
        pcrb(truth, motion, DT, Q_PSD, model, R, -P0)
    with pytest.raises(ConfigError, match="one q for all runs"):
        pcrb(truth, motion, DT, torch.full((40,), Q_PSD), model, R, P0, form="information_averaged")


def test_finite_memory_bound_reduces_to_the_filtering_bound_and_to_single_scans(tracks):
    from pmsr_nn.bounds import finite_memory_pcrb

    motion, model, truth, R = tracks
    full = pcrb(truth, motion, DT, Q_PSD, model, R, P0, smoothing=False)
    whole = finite_memory_pcrb(truth, motion, DT, Q_PSD, model, R, P0, memory=truth.shape[1])
    torch.testing.assert_close(whole.filtering, full.filtering, rtol=1e-12, atol=1e-12)
    # One scan: the prior on that scan's state plus its own information, nothing carried over.
    one = finite_memory_pcrb(truth, motion, DT, Q_PSD, model, R, P0, memory=1)
    single = torch.linalg.inv(torch.linalg.inv(P0) + measurement_information(truth, model, R)).mean(0)
    torch.testing.assert_close(one.filtering, single, rtol=1e-9, atol=1e-9)


def test_finite_memory_window_equals_a_filtering_pass_over_that_window(tracks):
    from pmsr_nn.bounds import finite_memory_pcrb

    motion, model, truth, R = tracks
    L, k = 4, 9
    window = pcrb(truth[:, k - L + 1 : k + 1], motion, DT, Q_PSD, model, R, P0, smoothing=False)
    bound = finite_memory_pcrb(truth, motion, DT, Q_PSD, model, R, P0, memory=L, chunk_windows=7)
    torch.testing.assert_close(bound.filtering[k], window.filtering[-1], rtol=1e-10, atol=1e-10)
    # less memory, less information: every step's position bound is at least the full filter's
    full = pcrb(truth, motion, DT, Q_PSD, model, R, P0, smoothing=False)
    assert bool((bound.position_rmse() >= full.position_rmse() * (1 - 1e-12)).all())


def test_information_bound_is_the_pcrb_of_the_same_information(tracks):
    """The bound from information formed elsewhere (a map's, :mod:`pmsr_nn.tbd.bound`) is
    :func:`pcrb`'s per-trajectory bound when handed the detections' own information."""
    motion, model, truth, R = tracks
    ref = pcrb(truth, motion, DT, Q_PSD, model, R, P0)
    ours = information_bound(measurement_information(truth, model, R), motion, DT, Q_PSD, P0)
    torch.testing.assert_close(ours.filtering, ref.filtering, rtol=1e-12, atol=0.0)
    torch.testing.assert_close(ours.smoothing, ref.smoothing, rtol=1e-12, atol=0.0)
    torch.testing.assert_close(ours.per_track_position, ref.per_track_position, rtol=1e-12, atol=0.0)
    with pytest.raises(ConfigError, match=r"info must be \(B, K, 6, 6\)"):
        information_bound(measurement_information(truth, model, R)[0], motion, DT, Q_PSD, P0)
