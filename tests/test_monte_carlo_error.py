"""The Monte Carlo standard errors the runner writes beside its RMSE and OSPA cells
(``rmse_pos_se_m``, ``ospa_se_m``): checked against repeated experiments, not against their own
formula."""

from __future__ import annotations

import numpy as np
import pytest

from pmsr_nn.harness.results.finalise import _median_root, _rmse_se, _se


def test_the_rmse_standard_error_is_the_spread_of_repeated_experiments():
    """2000 experiments of B = 50 runs, each run's mean squared error a scaled chi-square with 6
    degrees of freedom (sigma = 10 m, 2 targets x 3 axes): the delta-method standard error of one
    experiment's RMSE matches the standard deviation of the RMSE over the experiments. That
    deviation is itself estimated from 2000 values (relative error 1/sqrt(2 x 1999) = 1.6 %) and
    the delta method is first order (its bias at B = 50 is under 1 %): a 6 % tolerance is ~3 of
    those errors."""
    rng = np.random.default_rng(3)
    B, experiments, sigma = 50, 2000, 10.0
    mse = sigma**2 * rng.chisquare(6, size=(experiments, B, 2)) / 6  # (experiments, B, N) per run and target
    rmse = np.sqrt(mse.mean(axis=(1, 2)))  # (experiments,)
    predicted = np.array([_rmse_se(m, r) for m, r in zip(mse, rmse)])
    assert predicted.mean() == pytest.approx(rmse.std(ddof=1), rel=0.06)


def test_the_standard_errors_need_two_runs_and_skip_runs_without_a_value():
    assert _se(np.array([3.0])) is None and _rmse_se(np.array([[4.0]]), 2.0) is None
    v = np.array([1.0, 2.0, np.nan, 4.0])  # a run with no matched track carries no value
    assert _se(v) == pytest.approx(np.std([1.0, 2.0, 4.0], ddof=1) / np.sqrt(3), rel=1e-12)
    # the RMSE form: rmse * se(MSE) / (2 mean MSE), by hand for per-run MSEs 1, 4 (one target)
    assert _rmse_se(np.array([[1.0], [4.0]]), 5**0.5 / 2**0.5) == pytest.approx(
        (2.5**0.5) * (np.std([1.0, 4.0], ddof=1) / 2**0.5) / (2 * 2.5), rel=1e-12)


def test_the_median_runs_gospa_is_the_root_of_the_median_run_and_ignores_one_lost_run():
    """Each run's GOSPA^p mean; p = 2: runs of 40, 50, 60 m and one at 300 m (tracks lost)."""
    per_run = np.array([40.0, 50.0, 60.0, 300.0, np.nan]) ** 2  # the NaN: a run without a value
    assert _median_root(per_run, 2.0) == pytest.approx(55.0)  # the median of the runs' GOSPA: (50 + 60) / 2
    assert _median_root(per_run[:3], 2.0) == pytest.approx(50.0)
    assert _median_root(np.array([np.nan]), 2.0) is None and _median_root(None, 2.0) is None
