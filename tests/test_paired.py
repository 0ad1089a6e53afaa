"""Paired differences between rows of a case (GOSPA, OSPA) and their standard errors."""

import numpy as np
import pytest

from pmsr_nn.harness.results.paired import BEYOND, comparison_lines, paired_difference, set_comparisons, verdict


def test_linear_difference_is_the_mean_difference_with_the_paired_error():
    rng = np.random.default_rng(0)
    scene = rng.gamma(2.0, 50.0, size=40)  # run-to-run difficulty both rows share
    a, b = scene + rng.normal(3.0, 1.0, 40), scene + rng.normal(0.0, 1.0, 40)
    d = paired_difference(a, b)
    assert d["difference"] == pytest.approx(float((a - b).mean()), rel=1e-12)
    assert d["se"] == pytest.approx(float((a - b).std(ddof=1) / np.sqrt(40)), rel=1e-12)
    unpaired = np.hypot(a.std(ddof=1), b.std(ddof=1)) / np.sqrt(40)
    assert d["se"] < unpaired / 10  # the shared scene cancels: that is why the rows are compared paired
    assert verdict(d["difference"], d["se"]) == "behind"


def test_root_difference_error_matches_a_monte_carlo_of_the_estimator():
    """GOSPA^p per run -> difference of the p-th roots of the means: the delta-method error is the
    spread of that difference over many independent sets of runs (to the Monte Carlo error of a
    standard deviation from 4000 sets, ~1.1 %, and the delta method's bias at 50 runs)."""
    rng = np.random.default_rng(1)
    runs, p = 50, 2.0

    def draw(size):
        scene = rng.gamma(4.0, 400.0, size=size)
        return scene * rng.uniform(1.1, 1.3, size=size), scene * rng.uniform(0.9, 1.1, size=size)

    diffs = []
    for _ in range(4000):
        a, b = draw(runs)
        diffs.append(np.sqrt(a.mean()) - np.sqrt(b.mean()))
    a, b = draw(200_000)  # the delta-method error of 50 runs, from the population means and covariance
    ma, mb = a.mean(), b.mean()
    d = a / (2 * np.sqrt(ma)) - b / (2 * np.sqrt(mb))
    predicted = d.std() / np.sqrt(runs)
    assert float(np.std(diffs, ddof=1)) == pytest.approx(predicted, rel=0.05)
    one = paired_difference(*draw(runs), p=p)  # one set's estimate: within the estimate's own spread
    assert one["se"] == pytest.approx(predicted, rel=0.4)


def test_verdict_needs_more_than_the_stated_number_of_errors():
    assert verdict(-BEYOND * 1.01, 1.0) == "ahead"
    assert verdict(BEYOND * 1.01, 1.0) == "behind"
    assert verdict(BEYOND * 0.99, 1.0) == "tie" and verdict(-BEYOND, 1.0) == "tie"
    assert verdict(-100.0, None) == "tie"  # one run: no error, no claim


def test_rows_are_compared_with_the_lowest_gospa_of_their_group_and_the_table_says_so():
    runs = {"A": {"gospa_run": np.array([400.0, 900.0, 100.0]), "ospa_run": np.array([10.0, 20.0, 5.0])},
            "B": {"gospa_run": np.array([100.0, 400.0, 25.0]), "ospa_run": np.array([11.0, 21.0, 6.0])},
            "C": {"gospa_run": np.array([1.0, 4.0, 9.0]), "ospa_run": np.array([1.0, 2.0, 3.0])},
            "D": {"gospa_run": np.array([4.0, 4.0, 16.0]), "ospa_run": np.array([2.0, 2.0, 4.0])},
            "EKF": {}}  # a row without set figures stays out
    rows = {"A": {"gospa_m": float(np.sqrt(1400 / 3)), "initiation": "detections"},
            "B": {"gospa_m": float(np.sqrt(175.0)), "initiation": "detections"},
            "C": {"gospa_m": float(np.sqrt(14 / 3)), "initiation": "association known"},  # lowest of all: not A's reference
            "D": {"gospa_m": float(np.sqrt(8.0)), "initiation": "oracle"},
            "EKF": {"gospa_m": None, "initiation": "association known"}}
    own, handed = set_comparisons(rows, runs, p=2.0)
    assert own["reference"] == "B" and list(own["rows"]) == ["A"] and own["runs"] == 3
    assert handed["reference"] == "C" and list(handed["rows"]) == ["D"]
    g = own["rows"]["A"]["gospa_m"]
    assert g["difference"] == pytest.approx(np.sqrt(1400 / 3) - np.sqrt(175.0), rel=1e-12)
    o = own["rows"]["A"]["ospa_m"]
    assert o["difference"] == pytest.approx(-1.0, rel=1e-12) and o["se"] == pytest.approx(0.0, abs=1e-12)
    assert o["verdict"] == "ahead"  # lower OSPA in every run by the same metre
    lines = comparison_lines([own, handed])
    assert any("Rows that start their own tracks: GOSPA and OSPA minus those of B (the lowest GOSPA among them), "
               "paired over the same 3 runs" in line for line in lines)
    assert sum(line.startswith("| A | +") for line in lines) == 1 and sum(line.startswith("| D | +") for line in lines) == 1
    assert set_comparisons({"A": rows["A"], "C": rows["C"]}, runs, 2.0) == [] and comparison_lines([]) == []
