"""Batched IMM filter: exact reductions to the EKF / UKF, filterpy's IMMEstimator on a linear case,
mode detection on a manoeuvring track, missing measurements and bad input."""


import numpy as np
import pytest
import torch

from conftest import perturbed_prior
from filterpy.kalman import IMMEstimator, KalmanFilter

from pmsr_nn.errors import ConfigError
from pmsr_nn.filters import FilterError, Gaussian, IMMMode, ekf, imm, markov_transition, ukf, unscented_moments
from pmsr_nn.measurements import LinearMeasurementModel
from pmsr_nn.motion import ConstantAcceleration, ConstantVelocity

DT = 1.0
ASYM = torch.tensor([[0.97, 0.03], [0.10, 0.90]], dtype=torch.float64)  # asymmetric: catches a transposed T


def _assert_rel(got, ref, rel):
    """``|got - ref| <= rel * scale`` with the scale the largest magnitude of that component over
    runs and steps (a relative check that does not blow up at entries that happen to be near 0)."""
    scale = ref.abs().flatten(0, 1).amax(0).clamp_min(1e-300)
    err = ((got - ref).abs() / scale).max()
    assert err <= rel, f"max scaled error {float(err):.3g} > {rel}"


@pytest.fixture(scope="module")
def scenario(make_tracks):
    """Three bistatic CA tracks (9 measurements per step), a perturbed prior and some missing data."""
    motion, model, batch = make_tracks(steps=40, n=3, seed=5)
    R = model.R(batch.noise_std)
    z = batch.measurements.clone()
    z[1, 6] = float("nan")  # a whole scan missing
    z[2, 9, :3] = float("nan")  # the ranges of one scan missing
    return motion, model, z, R, perturbed_prior(batch.states[:, 0])


# --------------------------------------------------------------------------- exact reductions

def test_one_mode_equals_ekf_and_ukf(scenario):
    motion, model, z, R, prior = scenario
    q = 1e-2
    ref = ekf(prior, z, motion, DT, q, model, R)
    got = imm(prior, z, [IMMMode(motion, q)], torch.ones(1, 1), DT, model, R)
    # Mixing one Gaussian with weight 1 is the identity and the predict/update are the EKF's, so
    # only the order of floating-point operations differs.
    for a, b in ((got.x, ref.x), (got.P, ref.P), (got.nu, ref.nu), (got.nis, ref.nis)):
        _assert_rel(a, b, 1e-12)
    assert torch.equal(got.mode_probs, torch.ones(3, z.shape[1], 1, dtype=torch.float64))
    ref_u = ukf(prior, z, motion, DT, q, model, R)
    got_u = imm(prior, z, [IMMMode(motion, q)], markov_transition(1, 1.0), DT, model, R, moments=unscented_moments)
    _assert_rel(got_u.x, ref_u.x, 1e-12)
    _assert_rel(got_u.P, ref_u.P, 1e-12)


def test_identical_modes_equal_ekf(scenario):
    motion, model, z, R, prior = scenario
    q = 1e-2
    ref = ekf(prior, z, motion, DT, q, model, R)
    p0 = torch.tensor([0.8, 0.2], dtype=torch.float64)
    got = imm(prior, z, [IMMMode(motion, q), IMMMode(motion, q)], ASYM, DT, model, R, mode_probs0=p0)
    # Identical modes have identical Gaussians, so mixing and combining are exact (up to round-off
    # in weights that sum to 1 and spread terms of order eps^2).
    for a, b in ((got.x, ref.x), (got.P, ref.P), (got.nu, ref.nu), (got.nis, ref.nis)):
        _assert_rel(a, b, 1e-10)
    # Equal likelihoods carry no information about the mode: the probabilities follow the Markov
    # chain alone, p_k = T^T p_{k-1}, starting from p0 at step 0. Only up to round-off: mixing
    # weights that sum to 1 +- eps leave the two modes' states ~eps * 10 km ~ 1e-12 m apart, which
    # moves their log-likelihoods apart by ~1e-12 (5e-13 measured), and p by p (1 - p) times that.
    expect = [p0]
    for _ in range(1, z.shape[1]):
        expect.append(expect[-1] @ ASYM)
    torch.testing.assert_close(got.mode_probs, torch.stack(expect).expand(3, -1, -1), rtol=0, atol=1e-11)


def test_unreachable_mode_stays_out(scenario):
    """With T = I and p0 = (1, 0) the second mode can never be entered (c = 0, so its mixing
    weights would be 0/0): the IMM is the first mode's EKF and the probabilities stay (1, 0)."""
    motion, model, z, R, prior = scenario
    ref = ekf(prior, z, motion, DT, 1e-2, model, R)
    got = imm(prior, z, [IMMMode(motion, 1e-2), IMMMode(motion, 1.0)], torch.eye(2), DT, model, R,
              mode_probs0=torch.tensor([1.0, 0.0]))
    _assert_rel(got.x, ref.x, 1e-12)
    _assert_rel(got.P, ref.P, 1e-12)
    assert torch.equal(got.mode_probs, torch.tensor([1.0, 0.0]).expand(3, z.shape[1], 2))


# --------------------------------------------------------------------------- filterpy

def test_matches_filterpy_imm_linear():
    motion = ConstantAcceleration()
    lin = LinearMeasurementModel.position(6, motion.pos_idx, 4.0)
    R = lin.R()
    qs = (1e-3, 0.5)
    B, K = 2, 50
    g = torch.Generator().manual_seed(2)
    x_true0 = torch.tensor([1000.0, 30.0, 0.0, -500.0, -10.0, 0.0]).expand(B, 6)
    truth = motion.sample(x_true0, K, DT, 0.05, g)
    z = lin.h(truth) + 4.0 * torch.randn(B, K, 2, generator=g, dtype=torch.float64)
    sd = torch.tensor([20.0, 5.0, 1.0] * 2, dtype=torch.float64)
    prior = Gaussian(x_true0 + sd * torch.randn(B, 6, generator=g, dtype=torch.float64), torch.diag(sd**2).expand(B, 6, 6))
    p0 = torch.tensor([[0.7, 0.3], [0.2, 0.8]], dtype=torch.float64)
    ours = imm(prior, z, [IMMMode(motion, q) for q in qs], ASYM, DT, lin, R, mode_probs0=p0)
    for b in range(B):
        filters = []
        for q in qs:
            f = KalmanFilter(dim_x=6, dim_z=2)
            f.x, f.P = prior.x[b].numpy().copy(), prior.P[b].numpy().copy()
            f.F, f.Q, f.H, f.R = motion.F(DT).numpy(), motion.Q(DT, q).numpy(), lin.H.numpy(), R.numpy()
            filters.append(f)
        # filterpy's M[i, j] is used as P(i -> j) (cbar = mu @ M) although its docstring says
        # j -> i, so it takes our row-stochastic matrix as is.
        ref = IMMEstimator(filters, p0[b].numpy(), ASYM.numpy())
        for k in range(K):
            if k > 0:
                ref.predict()
            else:
                # filterpy always predicts before updating, and its update weights the likelihoods
                # by cbar, the mode probabilities after the Markov step, which its constructor sets
                # to p0 @ M. Our step 0 is an update only with p0 as the predicted probabilities
                # (every mode starts from the prior): make filterpy's cbar p0 as well.
                ref.cbar = p0[b].numpy().copy()
            best = int(np.argmax(ref.cbar))  # our nu/nis come from the mode most probable a priori
            ref.update(z[b, k].numpy())
            np.testing.assert_allclose(ours.x[b, k].numpy(), ref.x, rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(ours.P[b, k].numpy(), ref.P, rtol=1e-7, atol=1e-9 * np.abs(ref.P).max())
            np.testing.assert_allclose(ours.mode_probs[b, k].numpy(), ref.mu, rtol=1e-9, atol=1e-12)
            fb = filters[best]
            np.testing.assert_allclose(ours.nu[b, k].numpy(), fb.y, rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(float(ours.nis[b, k]), fb.y @ np.linalg.solve(fb.S, fb.y), rtol=1e-8)
    # The comparison is not vacuous: the modes do disagree here.
    assert float(ours.mode_probs[..., 1].max() - ours.mode_probs[..., 1].min()) > 0.3


# --------------------------------------------------------------------------- mode detection

def _turning_track(B: int, noise_m: float, g: torch.Generator):
    """100 s straight east at 30 m/s, then a 30 s left turn at 3 m/s^2 lateral (turn rate 0.1 rad/s,
    so the acceleration vector rotates: jerk 0.3 m/s^3, which a quiet CA mode cannot follow), then
    20 s straight again; position fixes every second with ``noise_m`` deviation."""
    speed, acc, t_turn, t_end = 30.0, 3.0, 100.0, 130.0
    w = acc / speed
    t = torch.arange(150, dtype=torch.float64)
    tau = (t.clamp(t_turn, t_end) - t_turn)
    after = (t - t_end).clamp_min(0)
    heading = w * tau
    x = speed * t.clamp(max=t_turn) + speed / w * torch.sin(heading) + speed * torch.cos(heading) * after
    y = speed / w * (1 - torch.cos(heading)) + speed * torch.sin(heading) * after
    motion = ConstantAcceleration()
    lin = LinearMeasurementModel.position(6, motion.pos_idx, noise_m)
    pos = torch.stack([x, y], -1)
    z = pos + noise_m * torch.randn(B, len(t), 2, generator=g, dtype=torch.float64)
    sd = torch.tensor([10.0, 3.0, 0.5] * 2, dtype=torch.float64)
    x0 = torch.tensor([0.0, speed, 0.0, 0.0, 0.0, 0.0], dtype=torch.float64)
    prior = Gaussian(x0 + sd * torch.randn(B, 6, generator=g, dtype=torch.float64), torch.diag(sd**2).expand(B, 6, 6))
    return motion, lin, z, prior


def test_mode_probabilities_detect_manoeuvre():
    B = 6
    motion, lin, z, prior = _turning_track(B, 2.0, torch.Generator().manual_seed(4))
    quiet, manoeuvre = IMMMode(motion, 1e-4), IMMMode(motion, 0.1)
    T = markov_transition(2, 0.98)
    res = imm(prior, z, [quiet, manoeuvre], T, DT, lin, lin.R())
    torch.testing.assert_close(res.mode_probs.sum(-1), torch.ones(B, z.shape[1], dtype=torch.float64), rtol=0, atol=1e-14)
    p = res.mode_probs[..., 1]  # the manoeuvring mode
    straight = p[:, 20:100].mean(1)  # after the initial transient, before the turn
    turn = p[:, 100:130].mean(1)
    # Measured per run (this seed and three others): straight 0.06-0.09 (the Markov chain alone
    # moves 0.02 of the quiet mode's probability into the manoeuvring mode every step), turn
    # 0.82-0.87. The thresholds leave wide margins on both sides and fail if the modes were
    # swapped or the likelihoods ignored (then p stays 0.5).
    assert bool((straight < 0.2).all()), straight
    assert bool((turn > 0.6).all()), turn
    # Relabelling the modes relabels the probabilities (T and the default p0 are symmetric).
    swapped = imm(prior, z, [manoeuvre, quiet], T, DT, lin, lin.R())
    torch.testing.assert_close(swapped.mode_probs, res.mode_probs.flip(-1), rtol=0, atol=1e-10)
    torch.testing.assert_close(swapped.x, res.x, rtol=1e-10, atol=1e-8)


# --------------------------------------------------------------------------- missing measurements

def test_missing_scan_keeps_predicted_mode_probs():
    motion = ConstantAcceleration()
    lin = LinearMeasurementModel.position(6, motion.pos_idx, 2.0)
    B = 3
    _, _, z, prior = _turning_track(B, 2.0, torch.Generator().manual_seed(6))
    modes = [IMMMode(motion, q) for q in (1e-4, 1e-2, 1.0)]
    T = torch.tensor([[0.90, 0.07, 0.03], [0.05, 0.90, 0.05], [0.02, 0.18, 0.80]], dtype=torch.float64)
    p0 = torch.tensor([0.5, 0.3, 0.2], dtype=torch.float64)
    z = z.clone()
    z[:, 0] = float("nan")  # step 0: nothing to update with, p stays p0
    z[0, 105] = float("nan")  # mid-manoeuvre, where the modes disagree most
    z[2, 40] = float("nan")
    res = imm(prior, z, modes, T, DT, lin, lin.R(), mode_probs0=p0)
    torch.testing.assert_close(res.mode_probs[:, 0], p0.expand(B, 3), rtol=0, atol=1e-15)
    for b, k in ((0, 105), (2, 40)):
        torch.testing.assert_close(res.mode_probs[b, k], res.mode_probs[b, k - 1] @ T, rtol=0, atol=1e-14)
        assert float((res.mode_probs[b, k + 1] - res.mode_probs[b, k]).abs().max()) > 1e-3  # an update moves them
    assert bool(torch.isfinite(res.x).all())
    # Partly missing: with the y fix missing throughout, the filter is the one with an x-only
    # sensor. The missing rows' log N constant is equal across modes and must cancel.
    z_x = z.clone()
    z_x[..., 1] = float("nan")
    got = imm(prior, z_x, modes, T, DT, lin, lin.R(), mode_probs0=p0)
    lin_x = LinearMeasurementModel(lin.H[:1], lin.noise_std[:1])
    ref = imm(prior, z[..., :1], modes, T, DT, lin_x, lin_x.R(), mode_probs0=p0)
    torch.testing.assert_close(got.mode_probs, ref.mode_probs, rtol=0, atol=1e-12)
    torch.testing.assert_close(got.x, ref.x, rtol=1e-12, atol=1e-9)


# --------------------------------------------------------------------------- bad input

def test_markov_transition():
    T = markov_transition(3, 0.9)
    torch.testing.assert_close(T, torch.tensor([[0.9, 0.05, 0.05], [0.05, 0.9, 0.05], [0.05, 0.05, 0.9]]), rtol=0, atol=1e-15)
    assert torch.equal(markov_transition(1, 1.0), torch.ones(1, 1, dtype=torch.float64))
    with pytest.raises(ConfigError, match="stay must be a probability"):
        markov_transition(2, 1.1)
    with pytest.raises(ConfigError, match="with one mode stay must be 1"):
        markov_transition(1, 0.9)
    with pytest.raises(ConfigError, match="at least one mode"):
        markov_transition(0, 0.9)


def test_bad_inputs():
    motion = ConstantAcceleration()
    lin = LinearMeasurementModel.position(6, motion.pos_idx, 2.0)
    B = 4
    _, _, z, prior = _turning_track(B, 2.0, torch.Generator().manual_seed(7))
    z = z[:, :8].clone()
    modes = [IMMMode(motion, 1e-4), IMMMode(motion, 1.0)]
    T = markov_transition(2, 0.95)

    def run(**kw):
        args = dict(prior=prior, z=z, modes=modes, transition=T, dt=DT, model=lin, R=lin.R())
        args.update(kw)
        return imm(**args)

    with pytest.raises(ConfigError, match="at least one mode"):
        run(modes=[])
    with pytest.raises(ConfigError, match=r"state dimensions \[6, 4\]"):
        run(modes=[modes[0], IMMMode(ConstantVelocity(), 1.0)])
    with pytest.raises(ConfigError, match="same position and velocity"):
        run(modes=[modes[0], IMMMode(ConstantVelocity(spatial_dim=3), 1.0)])  # also 6 states
    with pytest.raises(ConfigError, match=r"transition must be \(2, 2\)"):
        run(transition=markov_transition(3, 0.9))
    with pytest.raises(ConfigError, match="non-negative"):
        run(transition=torch.tensor([[1.1, -0.1], [0.5, 0.5]]))
    with pytest.raises(ConfigError, match="rows must sum to 1"):
        run(transition=torch.tensor([[0.9, 0.05], [0.05, 0.95]]))
    with pytest.raises(ConfigError, match="rows must sum to 1"):
        run(transition=T.T * torch.tensor([[1.0], [1.0 + 1e-8]]))  # off by 1e-8 > 1e-9
    with pytest.raises(ConfigError, match=r"mode_probs0 must be \(2,\) or \(B=4, 2\)"):
        run(mode_probs0=torch.ones(3) / 3)
    with pytest.raises(ConfigError, match="mode_probs0 must have finite, non-negative"):
        run(mode_probs0=torch.tensor([1.5, -0.5]))
    with pytest.raises(ConfigError, match="mode_probs0 must sum to 1"):
        run(mode_probs0=torch.tensor([[0.5, 0.5]] * 3 + [[0.5, 0.6]]))
    with pytest.raises(ConfigError, match="measurements must be"):  # the shared input checks run too
        run(z=z[..., :1])
    assert run(mode_probs0=torch.tensor([0.3, 0.7])).mode_probs.shape == (B, 8, 2)
    z_huge = z.clone()
    z_huge[1, 3, 0] = 1e300  # its squared residual overflows: never silently NaN
    with pytest.raises(FilterError, match="run 1 became non-finite at step 3"):
        run(z=z_huge)
