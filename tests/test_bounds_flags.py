""""Below the bound" only beyond the Monte Carlo error: a method is flagged when the one-sided
97.5 % Student-t bound of its per-run mean squared error over the bound's mean square is under 1."""

from __future__ import annotations

import numpy as np

from pmsr_nn.harness.report.flags import flag_paragraphs as _flags
from pmsr_nn.harness.results.finalise import _under


def _case(per_run_mse: list[float], bound_m: float = 10.0, K: int = 4):
    mse = np.array(per_run_mse)[:, None]  # (R, 1): one target
    curve = np.full((K, 1), bound_m)
    return mse, curve, np.ones((K, 1), dtype=bool)


def test_a_ratio_under_one_within_its_error_is_not_below():
    # mean ratio 0.95 with a standard error of 0.07: 0.95 + t(0.975, 3) se = 0.95 + 3.18 x 0.07 > 1
    ratio, se, below = _under(*_case([85.0, 105.0, 80.0, 110.0]))
    assert ratio == np.mean([0.85, 1.05, 0.80, 1.10]) and not below
    assert se == np.std([0.85, 1.05, 0.80, 1.10], ddof=1) / 2


def test_a_ratio_under_one_beyond_its_t_bound_is_below():
    ratio, se, below = _under(*_case([80.0, 82.0, 81.0, 79.0]))
    assert abs(ratio - 0.805) < 1e-12 and ratio + 3.1824 * se < 1 and below


def test_two_runs_need_the_t_bound_not_two_standard_errors():
    # 0.90 and 0.92: two standard errors (0.01 each) would call it below; t(0.975, 1) = 12.7 does not
    ratio, se, below = _under(*_case([90.0, 92.0]))
    assert abs(se - 0.01) < 1e-12 and ratio + 2 * se < 1 and not below


def test_one_run_is_never_below_and_the_rule_is_about_squares():
    assert _under(*_case([1.0]))[1:] == (float("inf"), False)
    # RMSE 9.4 m against a 10 m bound: MSE ratio 0.884 (squares, not 0.94)
    ratio, _, _ = _under(*_case([9.4**2] * 3))
    assert abs(ratio - 0.8836) < 1e-12


def test_the_report_states_the_ratio_and_its_error():
    row = {"below_bound": True, "below_q0_bound": False, "anees": 0.9, "mse_over_bound": 0.805,
           "mse_over_bound_se": 0.0066}
    res = {"settings": {}, "cases": {"c": {"methods": {"EKF": row}}}}
    text = " ".join(_flags(res))
    assert "EKF on c (MSE / bound^2 0.805 +- 0.007)" in text
    assert "one-sided 97.5 % Student-t bound" in text
    assert "no method is below it beyond its Monte Carlo error" in text
