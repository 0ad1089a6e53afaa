"""Consistency of the batched EKF / UKF when their model matches the truth (seeded, chi-square intervals)."""

from dataclasses import replace

import pytest
import torch
from scipy.stats import chi2

from pmsr_nn.bounds import pcrb
from pmsr_nn.filters import Gaussian, ekf, ukf
from pmsr_nn.rng import seeded_generator
from pmsr_nn.simulation.recipe import TrackRecipe
from pmsr_nn.simulation.tracks import build_models

RUNS, STEPS, DT, Q_PSD = 1000, 40, 1.0, 1e-2


def matched_scenario():
    """1,000 truths drawn from the filter's own prior and CA model; range 20 m, rate 2 m/s, azimuth 1 deg."""
    motion, model = build_models(TrackRecipe())
    model = replace(model, noise_std=(20.0, 2.0, 0.0174533))
    g = seeded_generator(42)
    mean = torch.tensor([5000.0, 5.0, 0.0, 1000.0, -3.0, 0.0])
    P0 = torch.diag(torch.tensor([100.0, 5.0, 0.1, 100.0, 5.0, 0.1]) ** 2)
    x0 = mean + torch.randn(RUNS, 6, generator=g, dtype=torch.float64) @ torch.linalg.cholesky(P0).T
    truth = motion.sample(x0, STEPS, DT, Q_PSD, g)
    z = model.sample(truth, None, g)
    prior = Gaussian(mean.expand(RUNS, 6).clone(), P0.expand(RUNS, 6, 6).clone())
    return motion, model, truth, z, prior


@pytest.mark.parametrize("method", [ekf, ukf])
def test_nees_inside_its_99_percent_interval(method):
    motion, model, truth, z, prior = matched_scenario()
    res = method(prior, z, motion, DT, Q_PSD, model, model.R())
    err = (res.x - truth).unsqueeze(-1)
    nees = (err.transpose(-1, -2) @ torch.linalg.solve(res.P, err)).squeeze(-1).squeeze(-1).mean(0)  # (STEPS,)
    # The run-average of RUNS chi-square(6) variables is chi-square(6 RUNS) / RUNS.
    lo, hi = chi2.ppf([0.005, 0.995], 6 * RUNS) / RUNS
    inside = ((nees > lo) & (nees < hi)).double().mean().item()
    # A consistent filter is inside at 99 % of the steps; allow the binomial spread of 40 steps
    # (P[more than 3 of 40 outside | p = 0.01] < 1e-3) and nothing more.
    assert inside >= 1 - 3 / STEPS, f"NEES inside the 99% interval at {inside:.0%} of steps: {nees.tolist()}"
    nis = res.nis.mean(0)
    lo_z, hi_z = chi2.ppf([0.005, 0.995], 9 * RUNS) / RUNS
    assert ((nis > lo_z) & (nis < hi_z)).double().mean().item() >= 1 - 3 / STEPS


def test_ukf_rmse_within_a_few_percent_of_the_pcrb_after_convergence():
    """Matched, mildly nonlinear scenario: the UKF is nearly efficient once converged."""
    motion, model, truth, z, prior = matched_scenario()
    res = ukf(prior, z, motion, DT, Q_PSD, model, model.R())
    pos = list(motion.pos_idx)
    after = slice(STEPS // 2, None)
    per_run = ((res.x - truth)[:, after][..., pos] ** 2).sum(-1).mean(1)  # (RUNS,) time-averaged squared error
    mse, se = per_run.mean().item(), per_run.std().item() / RUNS**0.5
    for form in ("information_averaged", "per_trajectory"):
        bound = pcrb(truth, motion, DT, Q_PSD, model, model.R(), prior.P[0], form=form)
        b = torch.diagonal(bound.filtering[after], dim1=-2, dim2=-1)[..., pos].sum(-1).mean().item()
        # No estimator beats the bound (up to 3 standard errors of the Monte Carlo MSE) ...
        assert mse > b - 3 * se, (form, mse, b)
        # ... and the UKF's RMSE is within 5 % of it (the same statistical allowance).
        assert mse - 3 * se < 1.05**2 * b, (form, mse**0.5, b**0.5)
