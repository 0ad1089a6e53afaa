"""Batched bootstrap particle filter: systematic resampling, exact step-0 update, agreement with the
Kalman filter (linear-Gaussian) and the UKF (mildly nonlinear bistatic), missing data, bad input.

How the statistical tolerances are derived. The Monte Carlo (MC) error of a particle filter (PF) is
not ``P / ESS``: every resampling adds noise that later steps carry along (in the linear scenario
below the variance of the PF mean is several times ``P / ESS`` after a few steps and keeps
growing), and at finite ``Np`` its estimates carry an O(1/Np) bias of unknown constant. So no test
here assumes a variance or neglects a bias:

* against the Kalman filter the tests use identities that hold *exactly for every Np*: the PF's
  unnormalised estimates are unbiased (``E[Z_hat f_hat] = p(z) E_post[f]`` for unbiased resampling
  such as systematic, adaptive or not). Each identity is a mean over independent runs of a
  quantity whose expectation is 0; the tolerance is a t-test with the empirical standard error;
* against the UKF (approximate itself), the scenario is filtered twice with independent generators
  and the product of the two replicates' errors estimates the UKF's squared error (see there).

Every statistical assertion has a family-wise false-alarm rate ALPHA (Bonferroni within it).
"""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from scipy.stats import binom, multivariate_normal, norm

from pmsr_nn.errors import ConfigError
from pmsr_nn.filters import FilterError, Gaussian, kalman_filter, ukf
from pmsr_nn.filters.particle import particle_filter, systematic_resample
from pmsr_nn.measurements import LinearMeasurementModel
from pmsr_nn.motion import ConstantAcceleration
from pmsr_nn.rng import seeded_generator, standard_normal
from pmsr_nn.simulation.recipe import TrackRecipe
from pmsr_nn.simulation.tracks import build_models

DT = 1.0
ALPHA = 1e-3  # family-wise false-alarm rate of every statistical assertion in this file


def _diag(P):
    return torch.diagonal(P, dim1=-2, dim2=-1)


# --------------------------------------------------------------------------- resampling

def test_systematic_resample_counts_floor_or_ceil_and_unbiased():
    Np, draws = 50, 20000
    g = torch.Generator().manual_seed(3)
    w = -torch.log(torch.rand(Np, generator=g))  # Dirichlet(1) weights
    w[[4, 17]] = 0.0  # zero weights must never be drawn
    w = w / w.sum()
    idx = systematic_resample(w.expand(draws, Np).contiguous(), seeded_generator(1))  # one draw per row
    counts = torch.zeros(draws, Np, dtype=torch.long).scatter_add_(1, idx, torch.ones_like(idx))
    expected = Np * w
    # Exact property of systematic resampling: particle i gets floor(Np w_i) or ceil(Np w_i)
    # copies (the 1e-9 slack only absorbs round-off of the cumulative sum).
    lo, hi = torch.floor(expected - 1e-9), torch.ceil(expected + 1e-9)
    assert bool(((counts >= lo) & (counts <= hi)).all())
    assert bool((counts[:, [4, 17]] == 0).all())
    # Unbiased: extra = count - floor is Bernoulli(frac(Np w_i)) per draw, the draws are
    # independent, so its sum over draws is exactly Binomial(draws, frac); accept the central
    # 1 - ALPHA / Np interval of each (Bonferroni over the Np particles).
    extra = (counts - torch.floor(expected).long()).sum(0).numpy()
    frac = (expected - torch.floor(expected)).numpy()
    a = ALPHA / Np
    lo_k, hi_k = binom.ppf(a / 2, draws, frac), binom.isf(a / 2, draws, frac)
    assert np.all((extra >= lo_k) & (extra <= hi_k)), (extra, draws * frac)


def test_systematic_resample_bad_weights():
    with pytest.raises(ConfigError, match="non-negative"):
        systematic_resample(torch.tensor([[0.5, -0.1, 0.6]]))
    with pytest.raises(ConfigError, match="row 1 are all zero"):
        systematic_resample(torch.tensor([[1.0, 0.0], [0.0, 0.0]]))
    with pytest.raises(ConfigError, match=r"\(B, Np\)"):
        systematic_resample(torch.ones(4))


# --------------------------------------------------------------------------- linear-Gaussian

def _position_scenario(B, K, q, seed, r_sd=10.0):
    """CA truths drawn from the filter's own prior and model; position fixes with sd ``r_sd`` (m)."""
    motion = ConstantAcceleration()
    model = LinearMeasurementModel.position(6, motion.pos_idx, r_sd)
    g = seeded_generator(seed)
    mean = torch.tensor([1000.0, 5.0, 0.0, 1000.0, -3.0, 0.0])
    P0 = torch.diag(torch.tensor([10.0, 2.0, 0.5, 10.0, 2.0, 0.5]) ** 2)
    x0 = mean + torch.randn(B, 6, generator=g) @ torch.linalg.cholesky(P0).T
    truth = motion.sample(x0, K, DT, q, g)
    z = model.sample(truth, g)
    return motion, model, z, Gaussian(mean.expand(B, 6).clone(), P0.expand(B, 6, 6).clone())


def test_step0_update_equals_direct_importance_sampling():
    """White box: step 0 is importance sampling from the prior. With the draw order of the filter
    (prior draws first, from the generator), recompute it with scipy for a full (non-diagonal) R
    and a partly missing scan: mean, covariance, ESS and log-likelihood must match to round-off."""
    B, Np = 3, 500
    motion, _, z, prior = _position_scenario(B, 1, 1.0, seed=5)
    H = torch.zeros(3, 6)
    H[0, 0] = H[1, 3] = H[2, 0] = 1.0
    H[2, 3] = 1.0  # third row measures x + y
    model = LinearMeasurementModel(H, (1.0, 1.0, 1.0))
    R = torch.tensor([[100.0, 30.0, 20.0], [30.0, 64.0, -10.0], [20.0, -10.0, 150.0]])
    z = torch.cat([z, z[..., :1] + z[..., 1:]], -1)
    z[1, 0, 1] = float("nan")  # run 1 misses its y fix
    res = particle_filter(prior, z, motion, DT, 1.0, model, R, n_particles=Np, generator=seeded_generator(9))
    X = prior.x[:, None] + standard_normal((B, Np, 6), seeded_generator(9)) @ torch.linalg.cholesky(prior.P).transpose(-1, -2)
    for b in range(B):
        keep = ~torch.isnan(z[b, 0])
        ll = multivariate_normal(mean=np.zeros(int(keep.sum())), cov=R[keep][:, keep].numpy()).logpdf(
            (z[b, 0, keep] - X[b] @ H[keep].T).numpy())
        w = np.exp(ll - ll.max())
        w /= w.sum()
        xb = X[b].numpy()
        mean = w @ xb
        np.testing.assert_allclose(res.x[b, 0].numpy(), mean, rtol=1e-10, atol=1e-9)
        np.testing.assert_allclose(res.P[b, 0].numpy(), (xb - mean).T @ ((xb - mean) * w[:, None]), rtol=1e-8, atol=1e-9)
        np.testing.assert_allclose(res.ess[b, 0].item(), 1 / (w @ w), rtol=1e-10)
        log_mean_lik = ll.max() + np.log(np.exp(ll - ll.max()).mean())
        np.testing.assert_allclose(res.log_likelihood[b, 0].item(), log_mean_lik, rtol=1e-12, atol=1e-10)


@pytest.fixture(scope="module")
def linear_runs():
    """200 runs x 6 steps of CA motion (jerk PSD 1 m^2/s^5) with position fixes of 10 m, truths
    drawn from the filters' own prior; the prior is about as wide as one fix (mean ESS stays near
    40 % of the particles). KF, and two PF replicates with 2000 particles."""
    torch.set_default_dtype(torch.float64)
    B, K, q, Np = 200, 6, 1.0, 2000
    motion, model, z, prior = _position_scenario(B, K, q, seed=7)
    R = model.R()
    kf = kalman_filter(prior, z, motion, DT, q, model, R)
    # Exact incremental log-likelihoods of the KF: log N(nu; 0, S), S = H P_pred H^T + R.
    F, Q, H = motion.F(DT), motion.Q(DT, q), model.H
    P_pred = torch.cat([prior.P.unsqueeze(1), F @ kf.P[:, :-1] @ F.T + Q], 1)
    S = H @ P_pred @ H.T + R
    ll_kf = -0.5 * (kf.nis + torch.logdet(S) + z.shape[-1] * math.log(2 * math.pi))
    pf = [particle_filter(prior, z, motion, DT, q, model, R, n_particles=Np, generator=seeded_generator(100, r))
          for r in range(2)]
    return motion, model, z, prior, q, R, kf, ll_kf, pf


def _t_test(y, n_tests):
    """``y (B, ...)`` independent over runs with expectation 0: |t| per remaining index, and the
    two-sided Bonferroni limit (B = 200 or more: the t statistic is normal to within 1e-2)."""
    t = y.mean(0) / (y.std(0) / math.sqrt(y.shape[0]))
    return t.abs(), norm.isf(ALPHA / (2 * n_tests))


def test_linear_gaussian_pf_matches_kalman_filter(linear_runs):
    """With ``W_k = exp(sum_{j<=k} (ll_pf_j - ll_kf_j)) = Z_hat_k / p(z_0:k)`` (the KF's
    likelihood is exact), unbiasedness of the unnormalised PF estimates gives, for every Np:
    ``E[W_k] = 1``, ``E[W_k (x_pf - x_kf)] = 0`` and ``E[W_k (M_k - P_kf)] = 0`` with
    ``M = P_pf + (x_pf - x_kf)(x_pf - x_kf)^T`` (the PF's second moment about the exact mean).
    The two replicates are averaged per run; the runs are independent."""
    motion, model, z, prior, q, R, kf, ll_kf, reps = linear_runs
    B, K, n = kf.x.shape
    sd = _diag(kf.P).sqrt()
    norm_ = sd.unsqueeze(-1) * sd.unsqueeze(-2)
    iu = torch.triu_indices(n, n)
    W = torch.stack([torch.exp((r.log_likelihood - ll_kf).cumsum(1)) for r in reps])  # (2, B, K)
    err = torch.stack([(r.x - kf.x) / sd for r in reps])  # (2, B, K, n)
    M = torch.stack([(r.P + (r.x - kf.x).unsqueeze(-1) * (r.x - kf.x).unsqueeze(-2) - kf.P) / norm_ for r in reps])
    checks = {
        "likelihood E[W] = 1": (W - 1).mean(0),
        "mean E[W (x_pf - x_kf)] = 0": (W.unsqueeze(-1) * err).mean(0),
        "covariance E[W (M - P_kf)] = 0": (W[..., None, None] * M).mean(0)[..., iu[0], iu[1]],
    }
    for name, y in checks.items():
        t, limit = _t_test(y, y[0].numel())
        assert float(t.max()) < limit, f"{name}: |t| per step/entry {t}, limit {limit:.2f}"
    # The identities hold for any Np, even 2, so they do not show the PF is accurate. That is a
    # requirement (a specification, not a statistical tolerance): with 2000 particles the PF mean
    # is within 0.25 posterior sd, RMS over runs, at every step and component, and its variances
    # within 25 % (about 0.15 and 0.15 at the last step here).
    rms = err.pow(2).mean((0, 1)).sqrt()
    assert float(rms.max()) < 0.25, f"RMS |x_pf - x_kf| / sd per step/component {rms}"
    rel = torch.stack([_diag(r.P) / sd**2 - 1 for r in reps]).pow(2).mean((0, 1)).sqrt()
    assert float(rel.max()) < 0.25, f"RMS relative variance error per step/component {rel}"


def test_ess_and_resampling_flags(linear_runs):
    motion, model, z, prior, q, R, kf, _, (ra, _) = linear_runs
    Np = 2000
    assert bool(((ra.ess >= 1 - 1e-9) & (ra.ess <= Np * (1 + 1e-12))).all())
    torch.testing.assert_close(ra.resampled, ra.ess < 0.5 * Np)
    never = particle_filter(Gaussian(prior.x[:4], prior.P[:4]), z[:4], motion, DT, q, model, R,
                            n_particles=200, generator=seeded_generator(1), resample_threshold=0.0)
    always = particle_filter(Gaussian(prior.x[:4], prior.P[:4]), z[:4], motion, DT, q, model, R,
                             n_particles=200, generator=seeded_generator(1), resample_threshold=1.0)
    assert not bool(never.resampled.any()) and bool(always.resampled.all())


# --------------------------------------------------------------------------- bistatic vs UKF

@pytest.fixture(scope="module")
def bistatic_runs():
    """1T-3R range / range-rate / azimuth (20 m, 2 m/s, 1 deg), targets ~5 km from the
    transmitter and ~12 km from the receivers, 200 runs x 8 steps drawn from the filters' own
    prior and CA model (jerk PSD 0.1 m^2/s^5). The prior sds (3 / 12 m, 0.6 / 2.5 m/s,
    0.2 m/s^2 in x / y) are about the UKF's posterior sds in this geometry, i.e. about what one
    scan resolves, so step 0 keeps ~40 % of the weight instead of collapsing it. UKF, and two PF
    replicates with 4000 particles."""
    torch.set_default_dtype(torch.float64)
    B, K, q, Np = 200, 8, 0.1, 4000
    motion, model = build_models(TrackRecipe())
    model = replace(model, noise_std=(20.0, 2.0, math.radians(1.0)))
    g = seeded_generator(42)
    mean = torch.tensor([5000.0, 5.0, 0.0, 1000.0, -3.0, 0.0])
    P0 = torch.diag(torch.tensor([3.0, 0.6, 0.2, 12.0, 2.5, 0.2]) ** 2)
    x0 = mean + torch.randn(B, 6, generator=g) @ torch.linalg.cholesky(P0).T
    z = model.sample(motion.sample(x0, K, DT, q, g), None, g)
    prior = Gaussian(mean.expand(B, 6).clone(), P0.expand(B, 6, 6).clone())
    R = model.R()
    u = ukf(prior, z, motion, DT, q, model, R)
    pf = [particle_filter(prior, z, motion, DT, q, model, R, n_particles=Np, generator=seeded_generator(200, r))
          for r in range(2)]
    return motion, model, z, prior, q, R, u, pf


def test_bistatic_pf_agrees_with_ukf(bistatic_runs):
    """H0: the UKF's mean is within DELTA = 0.1 posterior sd of the exact one (RMS over runs) and
    its variances within 10 %; the PF, run twice, measures both, and the test fails only when the
    data contradict H0 at level ALPHA.

    Why a correct UKF should be well inside DELTA here: its moments are exact to second order, and
    the neglected curvature, in units of the measurement sd, is ~ curvature x predicted spread^2 /
    sd: range 20^2 m^2 / (2 x 5 km) / 20 m ~ 2e-3; range-rate 20 m x 2.5 m/s / 5 km / 2 m/s
    ~ 5e-3; azimuth (20 m / 12 km)^2 / 0.017 rad ~ 2e-4. So the UKF error is ~1e-2 sd, and DELTA
    leaves an order of magnitude for what this estimate misses. A PF bias of DELTA or more (a bug
    in the propagation, the likelihood or the resampling) fails the test.

    Replicates a, c: with A, C their errors against the UKF (in UKF sds) and u the UKF's error,
    ``E[A C] = u^2`` (up to the PF's O(1/Np^2) squared bias), since A and C are independent given
    the data. Runs are independent and steps are not: average over steps per run first."""
    motion, model, z, prior, q, R, u, (ra, rc) = bistatic_runs
    DELTA = 0.1
    sd = _diag(u.P).sqrt()
    A, C = (ra.x - u.x) / sd, (rc.x - u.x) / sd
    z_one_sided = norm.isf(ALPHA / 12)  # 6 components x (mean, variance)
    T = (A * C).mean(1)  # (B, n)
    lower = T.mean(0) - z_one_sided * T.std(0) / math.sqrt(T.shape[0])
    assert bool((lower < DELTA**2).all()), f"UKF mean error^2 (sd^2) is above {DELTA**2} with confidence: {lower.tolist()}"
    # Variance: the PF second moment about the UKF mean estimates P_true + u^2 (exactly, up to the
    # PF's O(1/Np) bias); over P_ukf that is 1 + (relative variance error) + (u / sd)^2.
    M = ((_diag(ra.P) + (ra.x - u.x) ** 2 + _diag(rc.P) + (rc.x - u.x) ** 2) / 2 / sd**2 - 1).mean(1)  # (B, n)
    half = z_one_sided * M.std(0) / math.sqrt(M.shape[0])
    lo, hi = M.mean(0) - half, M.mean(0) + half
    assert bool(((hi > -DELTA) & (lo < DELTA + DELTA**2)).all()), f"relative variance error CI {lo.tolist()} .. {hi.tolist()}"
    # The PF itself must be accurate (else the above has no power). Requirement, as in the linear
    # case: the replicate spread, an estimate of the PF's own MC error var(A) = 2 E[((A - C) / 2)^2],
    # stays below 0.25 posterior sd RMS over runs at every step and component (about 0.17 here).
    mc_rms = (((A - C) / 2) ** 2 * 2).mean(0).sqrt()
    assert float(mc_rms.max()) < 0.25, f"PF Monte Carlo RMS error (UKF sds) per step/component {mc_rms}"


# --------------------------------------------------------------------------- missing data

def test_all_missing_scan_is_prediction_only(bistatic_runs):
    motion, model, z, prior, q, R, _, _ = bistatic_runs
    B, Np = 6, 500
    z = z[:B].clone()
    z[:, 4] = float("nan")
    res = particle_filter(Gaussian(prior.x[:B], prior.P[:B]), z, motion, DT, q, model, R, n_particles=Np,
                          generator=seeded_generator(3), resample_threshold=0.3)
    assert bool(torch.isfinite(res.x).all() and torch.isfinite(res.P).all())
    # Weights unchanged by step 4: same ESS as after step 3 (or uniform if step 3 resampled),
    # log-likelihood exactly 0, no resampling.
    expect = torch.where(res.resampled[:, 3], torch.tensor(float(Np)), res.ess[:, 3])
    torch.testing.assert_close(res.ess[:, 4], expect, rtol=1e-12, atol=0)
    assert bool((res.log_likelihood[:, 4] == 0).all()) and not bool(res.resampled[:, 4].any())


def test_missing_rows_equal_the_restricted_model(bistatic_runs):
    """NaN rows are marginalised out: with the azimuths missing at every scan, and the same
    generator, the result equals filtering with a range / range-rate model. A general (non-diagonal)
    R uses the sub-block of the present rows: same check with a linear model."""
    motion, model, z, prior, q, R, _, _ = bistatic_runs
    B, Np = 5, 400
    p = Gaussian(prior.x[:B], prior.P[:B])
    z_nan = z[:B].clone()
    z_nan[..., 6:] = float("nan")
    got = particle_filter(p, z_nan, motion, DT, q, model, R, n_particles=Np, generator=seeded_generator(8))
    sub = replace(model, components=("range", "range_rate"), noise_std=model.noise_std[:2])
    ref = particle_filter(p, z[:B, :, :6], motion, DT, q, sub, R[:6, :6], n_particles=Np, generator=seeded_generator(8))
    for name in ("x", "P", "ess", "log_likelihood", "resampled"):
        torch.testing.assert_close(getattr(got, name), getattr(ref, name), rtol=1e-9, atol=1e-9, msg=name)

    motion_l, _, zl, pl = _position_scenario(B, 6, 0.1, seed=2)
    H = torch.zeros(3, 6)
    H[0, 0] = H[1, 3] = H[2, 0] = H[2, 3] = 1.0
    lin = LinearMeasurementModel(H, (1.0, 1.0, 1.0))
    Rf = torch.tensor([[100.0, 30.0, 20.0], [30.0, 64.0, -10.0], [20.0, -10.0, 150.0]])
    zl3 = torch.cat([zl, zl[..., :1] + zl[..., 1:]], -1)
    zl3[..., 1] = float("nan")  # drop the y row everywhere
    got = particle_filter(pl, zl3, motion_l, DT, 0.1, lin, Rf, n_particles=Np, generator=seeded_generator(4))
    keep = [0, 2]
    ref = particle_filter(pl, zl3[..., keep], motion_l, DT, 0.1, LinearMeasurementModel(H[keep], (1.0, 1.0)),
                          Rf[keep][:, keep], n_particles=Np, generator=seeded_generator(4))
    for name in ("x", "P", "ess", "log_likelihood"):
        torch.testing.assert_close(getattr(got, name), getattr(ref, name), rtol=1e-9, atol=1e-9, msg=name)


# --------------------------------------------------------------------------- plumbing

def test_reproducible_and_chunking_only_splits_runs(bistatic_runs):
    motion, model, z, prior, q, R, _, _ = bistatic_runs
    p, zz = Gaussian(prior.x[:5], prior.P[:5]), z[:5]
    run = lambda gen, **kw: particle_filter(p, zz, motion, DT, q, model, R, n_particles=300, generator=gen, **kw)
    a, b = run(seeded_generator(1)), run(seeded_generator(1))
    torch.testing.assert_close(a.x, b.x, rtol=0, atol=0)
    chunked = run(seeded_generator(1), chunk_runs=2)
    first = particle_filter(Gaussian(p.x[:2], p.P[:2]), zz[:2], motion, DT, q, model, R, n_particles=300,
                            generator=seeded_generator(1))
    torch.testing.assert_close(chunked.x[:2], first.x, rtol=0, atol=0)  # chunk 0 drew first, alone
    assert bool(torch.isfinite(chunked.x).all())
    # Per-run q and per-run-and-step R give the same as their shared values (same draws).
    B, K = zz.shape[:2]
    per_run = particle_filter(p, zz, motion, DT, torch.full((B,), q), model, R.expand(B, K, 9, 9), n_particles=300,
                              generator=seeded_generator(1))
    torch.testing.assert_close(per_run.x, a.x, rtol=1e-9, atol=1e-9)


def test_bad_inputs(bistatic_runs):
    motion, model, z, prior, q, R, _, _ = bistatic_runs
    p, zz = Gaussian(prior.x[:4], prior.P[:4]), z[:4]
    run = lambda **kw: particle_filter(**{"prior": p, "z": zz, "motion": motion, "dt": DT, "q": q, "model": model,
                                          "R": R, "n_particles": 100, "generator": seeded_generator(0), **kw})
    with pytest.raises(ConfigError, match="measurements must be"):
        run(z=zz[..., :8])
    with pytest.raises(ConfigError, match="R must be"):
        run(R=R[:8, :8])
    with pytest.raises(ConfigError, match="prior must be"):
        run(prior=Gaussian(p.x, prior.P[:3]))
    z_inf = zz.clone()
    z_inf[1, 3, 4] = float("inf")
    with pytest.raises(ConfigError, match="run 1 at step 3 is infinite"):
        run(z=z_inf)
    with pytest.raises(ConfigError, match="R is not positive definite"):
        run(R=-R)
    with pytest.raises(ConfigError, match="n_particles"):
        run(n_particles=1)
    with pytest.raises(ConfigError, match="resample_threshold"):
        run(resample_threshold=1.5)
    with pytest.raises(ConfigError, match="chunk_runs"):
        run(chunk_runs=0)
    with pytest.raises(ConfigError, match="per-run q"):
        run(q=torch.full((3,), q))
    # A wild range (1000 km off): every particle's kernel underflows -> FilterError naming run and step.
    z_wild = zz.clone()
    z_wild[2, 6, 0] += 1e6
    with pytest.raises(FilterError, match="run 2 underflow at step 6"):
        run(z=z_wild)
    flagged = run(z=z_wild, on_lost="flag")  # or flag it and go on, finite
    expect = torch.zeros_like(flagged.lost)
    expect[2, 6] = True
    assert torch.equal(flagged.lost, expect) and bool(torch.isfinite(flagged.x).all())
    assert not bool(run().lost.any())
    with pytest.raises(ConfigError, match="on_lost"):
        run(on_lost="ignore")
    z_huge = zz.clone()
    z_huge[3, 2, 0] = 1e300  # its squared residual overflows: never silently NaN
    with pytest.raises(FilterError, match="run 3 became non-finite at step 2"):
        run(z=z_huge, on_lost="flag")


def test_roughening_acts_only_on_resampled_runs_and_counters_collapse():
    motion, model, z, prior = _position_scenario(B=50, K=30, q=1e-9, seed=4)
    run = lambda **kw: particle_filter(prior, z, motion, DT, 1e-9, model, model.R(), n_particles=300,  # noqa: E731
                                       generator=seeded_generator(1), **kw)
    never = run(resample_threshold=0.0, roughening=0.2)
    torch.testing.assert_close(never.x, run(resample_threshold=0.0).x, rtol=0, atol=0)
    # With (almost) no process noise, resampled copies of a particle never separate: the bootstrap
    # filter's spread collapses far below the exact (Kalman) posterior's; roughening re-spreads it.
    kf = kalman_filter(prior, z, motion, DT, 1e-9, model, model.R())
    spread = lambda res: (_diag(res.P[:, -1]) / _diag(kf.P[:, -1])).mean().item()  # noqa: E731
    plain, rough = spread(run()), spread(run(roughening=0.2))
    assert plain < 0.5 and rough > plain, (plain, rough)
    with pytest.raises(ConfigError, match="roughening"):
        run(roughening=-1.0)
