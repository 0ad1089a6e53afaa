"""SI+KF: spherical-interpolation fixes (exactness, covariance against Monte Carlo and the CRB),
the Kalman filter on them (against a hand-made call and filterpy), missed data and bad input."""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from filterpy.kalman import KalmanFilter

from pmsr_nn.errors import ConfigError
from pmsr_nn.filters import Gaussian, kalman_filter
from pmsr_nn.filters.fix_covariance import fix_covariance
from pmsr_nn.filters.si_kf import si_kf
from pmsr_nn.filters.spherical import range_rows, spherical_interpolation
from pmsr_nn.geometry import Geometry, Receiver, Transmitter
from pmsr_nn.measurements import LinearMeasurementModel, MeasurementModel, bistatic_range
from pmsr_nn.motion import ConstantVelocity
from pmsr_nn.rng import seeded_generator
from pmsr_nn.simulation.recipe import TrackRecipe
from pmsr_nn.simulation.tracks import build_models, generate_tracks

DT, Q_PSD = 1.0, 1e-7  # the envelope variant's jerk PSD: the filter's motion model matches the truth


def default_geometry(dim=2):
    return build_models(TrackRecipe(dim=dim))[1].geometry


def two_tx_geometry():
    """2 transmitters x 4 receivers = 8 pairs for 2 + 2 unknowns (overdetermined)."""
    txs = [Transmitter((0.0, 0.0), 650e6), Transmitter((3000.0, -6000.0), 500e6)]
    rxs = [Receiver((-7000.0, -3000.0)), Receiver((-8000.0, 0.0)), Receiver((-7000.0, 4000.0)), Receiver((2000.0, -9000.0))]
    return Geometry.all_pairs(txs, rxs)


def ranges_of(p, g):
    return bistatic_range(p, g.pair_tx_positions(), g.pair_rx_positions())


def targets(n, seed, altitude=None):
    """Targets 3-8 km from the origin at bearings 30-150 deg (the recipe's sector), optional altitude."""
    gen = torch.Generator().manual_seed(seed)
    r = 3000 + 5000 * torch.rand(n, generator=gen)
    th = math.radians(30) + math.radians(120) * torch.rand(n, generator=gen)
    cols = [r * torch.sin(th), r * torch.cos(th)]
    if altitude is not None:
        cols.append(altitude[0] + (altitude[1] - altitude[0]) * torch.rand(n, generator=gen))
    return torch.stack(cols, -1)


# Noise-free tolerance: the fixes are solved in float64 in a frame scaled to the sensor spread
# (~8 km); round-off (eps 2.2e-16) amplified by the conditioning of the small normal systems
# (<~1e4 here) gives errors of order 1e-8 m. 1e-6 m leaves a wide margin and still catches any
# error in the algebra (a wrong sign or weight moves fixes by metres).
EXACT_M = 1e-6


# ----------------------------------------------------------------------------------------------
# 1. Noise-free ranges are inverted exactly
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("weighting", ["distance", "uniform"])
@pytest.mark.parametrize("refine", [0, 2])
def test_noise_free_fixes_are_exact(weighting, refine):
    p = targets(500, 0)
    for g in (default_geometry(), two_tx_geometry()):
        est = spherical_interpolation(ranges_of(p, g), g, weighting=weighting, refine_steps=refine)
        assert (est - p).abs().max() < EXACT_M
    # Batched over any leading axes: (runs, steps, pairs) -> (runs, steps, 2).
    g = default_geometry()
    est = spherical_interpolation(ranges_of(p, g).reshape(50, 10, 3), g)
    assert est.shape == (50, 10, 2) and (est - p.reshape(50, 10, 2)).abs().max() < EXACT_M


def test_noise_free_3d():
    # Sensors at several heights: full 3-D SI (1 Tx + 4 Rx for 3 + 1 unknowns).
    g3 = Geometry.all_pairs([Transmitter((0.0, 0.0, 0.0), 650e6)],
                            [Receiver((-7000.0, -3000.0, 0.0)), Receiver((-8000.0, 0.0, 500.0)),
                             Receiver((-7000.0, 4000.0, 100.0)), Receiver((2000.0, -9000.0, 1200.0))])
    p = targets(500, 1, altitude=(0.0, 3000.0))
    assert (spherical_interpolation(ranges_of(p, g3), g3) - p).abs().max() < EXACT_M
    # Ground sensors (the recipe's 3-D geometry): horizontal SI, then the altitude above ground.
    # Altitudes from 200 m: the root of h = z^2 amplifies round-off of h by 1 / (2 z).
    g = default_geometry(3)
    p = targets(500, 2, altitude=(200.0, 3000.0))
    assert (spherical_interpolation(ranges_of(p, g), g) - p).abs().max() < EXACT_M
    # The mirror target below ground gives the same ranges and the fix above ground.
    below = p * torch.tensor([1.0, 1.0, -1.0])
    assert (spherical_interpolation(ranges_of(below, g), g) - p).abs().max() < EXACT_M


def test_si_equals_joint_least_squares_and_missing_rows():
    """The projection steps of SI give the least-squares solution of the joint linear system in
    (p, D_1, D_2) (Frisch-Waugh-Lovell), also with missing rows; checked with torch.linalg.lstsq."""
    g = two_tx_geometry()
    tx, rx = g.pair_tx_positions(), g.pair_rx_positions()
    p = targets(200, 3)
    R = ranges_of(p, g) + 30.0 * torch.randn(200, 8, generator=torch.Generator().manual_seed(4))
    R[:50, 2] = float("nan")  # a missed detection
    R[50:100, 4:] = float("nan")  # transmitter 2 unseen: only transmitter 1's four pairs remain
    est = spherical_interpolation(R, g, weighting="uniform")
    onehot = torch.tensor([[1.0, 0.0]] * 4 + [[0.0, 1.0]] * 4)
    for sl in (slice(0, 50), slice(50, 100), slice(100, 200)):
        keep = ~torch.isnan(R[sl.start])
        Rk = R[sl][:, keep]
        A = torch.cat([(rx - tx)[keep].expand(len(Rk), -1, -1), -Rk.unsqueeze(-1) * onehot[keep]], -1)
        b = 0.5 * ((rx**2).sum(-1) - (tx**2).sum(-1))[keep] - 0.5 * Rk**2
        cols = (A.abs().sum(-2) > 0).all(0)  # drop the column of an unseen transmitter
        theta = torch.linalg.lstsq(A[..., cols], b.unsqueeze(-1)).solution.squeeze(-1)
        torch.testing.assert_close(est[sl], theta[:, :2], rtol=0, atol=1e-6)
    # Too few valid ranges for the unknowns -> NaN fix, others untouched.
    R2 = ranges_of(p[:3], default_geometry())
    R2[1, 0] = float("nan")  # 2 ranges for (x, y, D): underdetermined
    est = spherical_interpolation(R2, default_geometry())
    assert torch.isnan(est[1]).all() and torch.isfinite(est[[0, 2]]).all()


# ----------------------------------------------------------------------------------------------
# 2. Fix covariance against Monte Carlo and the CRB
# ----------------------------------------------------------------------------------------------
N_DRAWS = 20_000


def whitened_gap(samples, cov):
    """Empirical covariance of ``samples (n, d)`` whitened by ``cov``, minus the identity.

    If ``cov`` is the true covariance, the whitened sample covariance of n Gaussian draws has
    diagonal entries with standard deviation sqrt(2/n) and off-diagonal ones sqrt(1/n) (Wishart).
    """
    L = torch.linalg.cholesky(cov)
    w = torch.linalg.solve_triangular(L, (samples - samples.mean(0)).T, upper=False).T
    return torch.cov(w.T) - torch.eye(cov.shape[-1])


# 5 standard deviations of the Wishart spread; the first-order (linearisation) error of the
# covariance is of relative order (range noise / distance)^2 ~ 1e-7 at 1 m noise over km, invisible.
TOL = 5 * math.sqrt(2 / N_DRAWS)


@pytest.mark.parametrize("case", ["default", "two_tx"])
def test_fix_covariance_matches_monte_carlo(case):
    g = default_geometry() if case == "default" else two_tx_geometry()
    p0 = torch.tensor([5000.0, 3000.0])
    gen = torch.Generator().manual_seed(5)
    R = ranges_of(p0, g) + torch.randn(N_DRAWS, g.n_pairs, generator=gen)  # 1 m range noise
    for weighting in ("distance", "uniform"):
        fixes = spherical_interpolation(R, g, weighting=weighting)
        cov = fix_covariance(p0, g, 1.0, weighting=weighting)
        assert whitened_gap(fixes, cov).abs().max() < TOL
        # Unbiased to first order: the whitened mean is N(0, I / n).
        mean = torch.linalg.solve_triangular(torch.linalg.cholesky(cov), (fixes.mean(0) - p0)[:, None], upper=False)
        assert mean.abs().max() < 5 / math.sqrt(N_DRAWS)
    # Two Gauss-Newton steps give the maximum-likelihood fix: covariance = CRB (J^T R^-1 J)^-1.
    crb = fix_covariance(p0, g, 1.0, method="crb")
    J = (p0 - g.pair_tx_positions()) / (p0 - g.pair_tx_positions()).norm(dim=-1, keepdim=True) + \
        (p0 - g.pair_rx_positions()) / (p0 - g.pair_rx_positions()).norm(dim=-1, keepdim=True)
    torch.testing.assert_close(crb, torch.linalg.inv(J.T @ J), rtol=1e-10, atol=0)
    assert whitened_gap(spherical_interpolation(R, g, refine_steps=2), crb).abs().max() < TOL
    # SI itself is NOT efficient: it fits a nuisance direction (the dropped constraint
    # D = |p - t|) besides the position. Even the exactly determined 1 Tx / 3 Rx case in 2-D is far
    # from the CRB (3 ranges for 2 coordinates: SI solves the 3x3 linear system exactly, ML does
    # least squares). Variance ratio measured: ~45 (default), ~30 (2 Tx).
    si = fix_covariance(p0, g, 1.0)
    assert torch.trace(si) > 10 * torch.trace(crb)


def test_ground_3d_si_is_maximum_likelihood_when_exactly_determined():
    """Ground sensors, 1 Tx / 3 Rx, 3-D: 3 ranges for 3 coordinates, so the SI fix is the exact
    intersection (the ML fix) and its covariance is the CRB; both match Monte Carlo."""
    g = default_geometry(3)
    p0 = torch.tensor([5000.0, 3000.0, 1500.0])
    si, crb = fix_covariance(p0, g, 1.0), fix_covariance(p0, g, 1.0, method="crb")
    torch.testing.assert_close(si, crb, rtol=1e-6, atol=0)
    # The covariance is nearly singular (altitude and east error correlated at -0.997; smallest
    # eigenvalue 0.09 m^2 per m^2 of range variance) and the altitude is the root of a noisy
    # square, so the second-order error seen along the thin direction grows like the noise
    # (~7 whitened sd per metre of range noise): use 3 cm, where it is ~0.2 sd.
    sd = 0.03
    R = ranges_of(p0, g) + sd * torch.randn(N_DRAWS, 3, generator=torch.Generator().manual_seed(6))
    assert whitened_gap(spherical_interpolation(R, g), si * sd**2).abs().max() < TOL
    # On the ground the altitude is not observable to first order: the covariance is NaN.
    assert torch.isnan(fix_covariance(torch.tensor([5000.0, 3000.0, 0.0]), g, 1.0)).all()


def test_fix_covariance_shapes_and_missing_pairs():
    g = two_tx_geometry()
    p = targets(12, 7).reshape(3, 4, 2)
    std = torch.tensor([10.0, 20.0, 30.0])[:, None]  # per run, broadcast over steps
    cov = fix_covariance(p, g, std)
    assert cov.shape == (3, 4, 2, 2)
    torch.testing.assert_close(cov[1], fix_covariance(p[1], g, 20.0))
    torch.testing.assert_close(cov[2], fix_covariance(p[2], g, 10.0) * 9.0)  # scales with the variance
    valid = torch.ones(3, 4, 8, dtype=torch.bool)
    valid[0, 0, 0] = False
    fewer = fix_covariance(p, g, std, valid=valid)
    assert torch.linalg.eigvalsh(fewer[0, 0] - cov[0, 0]).min() > -1e-9  # less data, more variance
    torch.testing.assert_close(fewer[1:], cov[1:])
    assert torch.isnan(fix_covariance(torch.full((2,), float("nan")), g, 1.0)).all()


# ----------------------------------------------------------------------------------------------
# 3. SI+KF on generated tracks
# ----------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def tracks(make_tracks):
    motion, model, batch = make_tracks(steps=60, n=40, seed=3)
    return motion, model, batch


def position_rmse(est, truth, after=10):
    return ((est - truth)[:, after:] ** 2).sum(-1).mean().sqrt().item()


def test_si_kf_on_tracks(tracks):
    torch.set_default_dtype(torch.float64)
    motion, model, batch = tracks
    pos = list(motion.pos_idx)
    truth = batch.states[..., pos]
    res = si_kf(batch.measurements, model, motion, DT, Q_PSD, batch.noise_std)
    assert torch.isfinite(res.x).all() and torch.isfinite(res.P).all() and res.n_rejected == 0
    fixes = spherical_interpolation(batch.measurements[..., range_rows(model)], model.geometry)
    raw, filt = position_rmse(fixes, truth), position_rmse(res.x[..., pos], truth)
    # Measured: raw ~370 m, filtered ~130 m (60 steps); require a clear gain.
    assert filt < 0.5 * raw, (raw, filt)
    # The per-step R is the fixes' true covariance: the NIS (chi-square, 2 dof) averages 2. 40 runs
    # x 50 steps of independent chi-square(2) have a mean with sd 2/sqrt(2000) = 0.045; +-0.3 is
    # ~6 sd and still fails if R were off by 15 %.
    assert abs(res.nis[:, 10:].mean().item() - 2.0) < 0.3
    # Refined (ML) fixes with the CRB as R: better still.
    ref = si_kf(batch.measurements, model, motion, DT, Q_PSD, batch.noise_std, refine_steps=2)
    assert position_rmse(ref.x[..., pos], truth) < 0.5 * filt
    assert abs(ref.nis[:, 10:].mean().item() - 2.0) < 0.3


def test_si_kf_missed_data_and_initialisation(tracks):
    motion, model, batch = tracks
    z = batch.measurements[:6].clone()
    ns = batch.noise_std[:6]
    rows = range_rows(model)
    z[0, 20] = float("nan")  # every row missing
    z[1, 25, rows[1]] = float("nan")  # one range missing: 2 ranges cannot fix (x, y, D)
    z[2, :5] = float("nan")  # no fix before step 5
    z[3] = float("nan")  # no fix at all
    res = si_kf(z, model, motion, DT, Q_PSD, ns)
    assert torch.isfinite(res.x).all() and torch.isfinite(res.P).all()
    F, Q = motion.F(DT), motion.Q(DT, Q_PSD)
    for b, k in ((0, 20), (1, 25)):  # prediction only
        assert torch.isnan(res.fixes[b, k]).all()
        torch.testing.assert_close(res.x[b, k], F @ res.x[b, k - 1])
        torch.testing.assert_close(res.P[b, k], F @ res.P[b, k - 1] @ F.T + Q)
    # Initialisation from the first valid fix, which is then not used a second time.
    assert res.init_step.tolist() == [0, 0, 5, -1, 0, 0]
    fix = spherical_interpolation(z[2, 5, rows], model.geometry)
    pos = list(motion.pos_idx)
    torch.testing.assert_close(res.x[2, 5, pos], fix)  # zero initial velocity: x_5 = fix
    R5 = fix_covariance(fix, model.geometry, ns[2, 0])
    P5 = res.P[2, 5][pos][:, pos]
    # P at step 5 = fix covariance + the process noise of 5 predictions (tiny at q = 1e-7).
    torch.testing.assert_close(P5, R5, rtol=1e-6, atol=1e-6)
    assert torch.isnan(res.fixes[2, 5]).all() and torch.isfinite(res.fixes[2, 6]).all()
    vel = list(motion.vel_idx)
    assert torch.allclose(res.prior.P[0][vel][:, vel], 50.0**2 * torch.eye(2))
    # The run without fixes never moves from its (uninformative) start at the sensors' centre.
    assert torch.allclose(res.x[3, :, pos], res.x[3, :1, pos].expand(60, 2))


def test_si_kf_layouts_dtypes_and_cv(tracks):
    motion, model, batch = tracks
    z, ns = batch.measurements[:4], batch.noise_std[:4]
    ref = si_kf(z, model, motion, DT, Q_PSD, ns)
    pair = replace(model, layout="pair")
    order = [model.labels.index(lbl) for lbl in pair.labels]
    torch.testing.assert_close(si_kf(z[..., order], pair, motion, DT, Q_PSD, ns).x, ref.x)
    f32 = si_kf(z.float(), model, motion, DT, Q_PSD, ns)
    assert f32.x.dtype == torch.float32 and torch.isfinite(f32.x).all()
    cv = ConstantVelocity()
    cv_model = MeasurementModel(model.geometry, model.components, model.noise_std, cv.pos_idx, cv.vel_idx)
    res = si_kf(z, cv_model, cv, DT, 1e-3, ns)
    assert res.x.shape == (4, 60, 4) and torch.isfinite(res.x).all()


def test_si_kf_ground_3d_uses_horizontal_fixes():
    recipe = TrackRecipe(dim=3)
    recipe = replace(recipe, window=40, motion=replace(recipe.motion, steps=40))
    motion, model = build_models(recipe)
    batch, _ = generate_tracks(recipe, 10, seeded_generator(8))
    res = si_kf(batch.measurements, model, motion, DT, [Q_PSD, Q_PSD, 0.0], batch.noise_std)
    assert torch.isfinite(res.x).all()
    assert res.altitude_dropped.all()  # every fix solved; only its horizontal part is used
    assert torch.isnan(res.fixes[..., 2]).all() and torch.isfinite(res.fixes[:, 1:, :2]).all()
    pos = list(motion.pos_idx)
    fixes = spherical_interpolation(batch.measurements[..., :3], model.geometry)
    truth = batch.states[..., pos]
    assert position_rmse(res.x[..., pos[:2]], truth[..., :2]) < 0.6 * position_rmse(fixes[..., :2], truth[..., :2])


# ----------------------------------------------------------------------------------------------
# 4. The filter on the fixes: a hand-made kalman_filter call, and filterpy
# ----------------------------------------------------------------------------------------------
def test_si_kf_equals_kalman_filter_on_fixes_and_filterpy(tracks):
    motion, model, batch = tracks
    B = 5
    z, ns = batch.measurements[:B].clone(), batch.noise_std[:B]
    z[0, 7] = float("nan")
    sd = torch.tensor([200.0, 5.0, 0.05] * 2)
    x0 = batch.states[:B, 0] + torch.randn(B, 6, generator=torch.Generator().manual_seed(9)) * sd
    prior = Gaussian(x0, torch.diag(sd**2).expand(B, 6, 6).clone())
    res = si_kf(z, model, motion, DT, Q_PSD, ns, prior=prior)
    # By hand: fixes and their covariances from the public functions, then kalman_filter.
    fixes = spherical_interpolation(z[..., range_rows(model)], model.geometry)
    R = fix_covariance(fixes, model.geometry, ns[:, :1])
    R = torch.where(torch.isnan(R), torch.eye(2), R)  # placeholder where the fix is missed
    lin = LinearMeasurementModel.position(motion.dim_x, motion.pos_idx, 1.0)
    hand = kalman_filter(prior, fixes, motion, DT, Q_PSD, lin, R)
    torch.testing.assert_close(res.x, hand.x, rtol=1e-12, atol=1e-9)
    torch.testing.assert_close(res.P, hand.P, rtol=1e-12, atol=1e-9)
    torch.testing.assert_close(res.fixes, fixes, equal_nan=True)
    # Independent: filterpy's KalmanFilter on run 0, per-step R, a missed fix skipped.
    kf = KalmanFilter(dim_x=6, dim_z=2)
    kf.x, kf.P = x0[0].numpy().copy(), prior.P[0].numpy().copy()
    kf.F, kf.Q, kf.H = motion.F(DT).numpy(), motion.Q(DT, Q_PSD).numpy(), lin.H.numpy()
    for k in range(z.shape[1]):
        if k > 0:
            kf.predict()
        if not torch.isnan(fixes[0, k]).any():
            kf.update(fixes[0, k].numpy(), R=R[0, k].numpy())
        np.testing.assert_allclose(res.x[0, k].numpy(), kf.x, rtol=1e-10, atol=1e-8)
        np.testing.assert_allclose(res.P[0, k].numpy(), kf.P, rtol=1e-8, atol=1e-8)
    # Without a prior, the result is kalman_filter from the reported prior on the reported fixes.
    auto = si_kf(z, model, motion, DT, Q_PSD, ns)
    again = kalman_filter(auto.prior, auto.fixes, motion, DT, Q_PSD, lin, auto.fix_R)
    torch.testing.assert_close(auto.x, again.x, rtol=0, atol=0)


# ----------------------------------------------------------------------------------------------
# 5. Bad input
# ----------------------------------------------------------------------------------------------
def test_unsolvable_geometries():
    two_rx = Geometry.all_pairs([Transmitter((0.0, 0.0), 650e6)], [Receiver((-7000.0, 0.0)), Receiver((0.0, 8000.0))])
    with pytest.raises(ConfigError, match="needs at least 3 bistatic pairs"):
        spherical_interpolation(torch.tensor([1e4, 1e4]), two_rx)
    on_a_line = Geometry.all_pairs([Transmitter((0.0, 0.0), 650e6)],
                                   [Receiver((-7000.0, 0.0)), Receiver((-8000.0, 0.0)), Receiver((9000.0, 0.0))])
    with pytest.raises(ConfigError, match="lie on one line"):
        spherical_interpolation(torch.tensor([2e4, 2e4, 2e4]), on_a_line)
    # 2 transmitters x 1 receiver: 2 pairs for 2 + 2 unknowns.
    with pytest.raises(ConfigError, match="needs at least 4"):
        fix_covariance(torch.zeros(2), Geometry.all_pairs([Transmitter((0.0, 0.0), 1e8), Transmitter((5e3, 0.0), 1e8)],
                                                          [Receiver((-7000.0, 0.0))]), 1.0)


def test_bad_inputs(tracks):
    motion, model, batch = tracks
    g = model.geometry
    z, ns = batch.measurements[:2], batch.noise_std[:2]
    with pytest.raises(ConfigError, match=r"ranges must be a tensor \(\.\.\., 3\)"):
        spherical_interpolation(torch.ones(4, 2), g)
    with pytest.raises(ConfigError, match="infinite"):
        spherical_interpolation(torch.tensor([1e4, float("inf"), 1e4]), g)
    with pytest.raises(ConfigError, match="weighting"):
        spherical_interpolation(torch.ones(3) * 2e4, g, weighting="optimal")
    with pytest.raises(ConfigError, match="range_std must be finite and positive"):
        fix_covariance(torch.tensor([5e3, 3e3]), g, -1.0)
    with pytest.raises(ConfigError, match="positions must be"):
        fix_covariance(torch.ones(4, 3), g, 1.0)
    with pytest.raises(ConfigError, match="measurements must be"):
        si_kf(z[..., :8], model, motion, DT, Q_PSD, ns)
    no_range = MeasurementModel(g, ("range_rate", "azimuth"), (3.0, 0.02), motion.pos_idx, motion.vel_idx)
    with pytest.raises(ConfigError, match="'range' component"):
        si_kf(z[..., 3:], no_range, motion, DT, Q_PSD, ns[:, 1:])
    with pytest.raises(ConfigError, match="noise_std must be per run"):
        si_kf(z, model, motion, DT, Q_PSD, ns[:, :2])
    with pytest.raises(ConfigError, match="range_std must be finite and positive"):
        si_kf(z, model, motion, DT, Q_PSD, ns * torch.tensor([0.0, 1.0, 1.0]))
    with pytest.raises(ConfigError, match="motion model is 3-D"):
        si_kf(z, model, type(motion)(spatial_dim=3), DT, Q_PSD, ns)
    z_bad = z.clone()
    z_bad[1, 4, 7] = float("-inf")  # any row, not only the ranges
    with pytest.raises(ConfigError, match="run 1 at step 4 is infinite"):
        si_kf(z_bad, model, motion, DT, Q_PSD, ns)
    with pytest.raises(ConfigError, match="init_velocity_std_mps"):
        si_kf(z, model, motion, DT, Q_PSD, ns, init_velocity_std_mps=0.0)
