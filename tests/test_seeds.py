"""Seed groups and paired margins of learned trackers (pmsr_nn.harness.results.seeds)."""

import numpy as np
import pytest

from pmsr_nn.harness.results.seeds import comparisons, learned_units, paired_margin, seed_groups, summarise_seeds


def test_seed_groups_collect_only_names_of_the_seed_form():
    names = ["EKF", "KalmanNet [seed 0]", "MDFNN", "KalmanNet [seed 2]", "A [b] [seed 1]", "X [seed]"]
    assert seed_groups(names) == {"KalmanNet": ["KalmanNet [seed 0]", "KalmanNet [seed 2]"], "A [b]": ["A [b] [seed 1]"]}


def test_summary_is_mean_sample_deviation_and_extremes_over_seeds():
    rows = {f"K [seed {s}]": {"kind": "learned", "rmse_pos_m": v, "over_bound": v / 10} for s, v in enumerate([12.0, 15.0, 21.0])}
    e = summarise_seeds(rows)["K"]
    assert e["seeds"] == 3
    assert e["rmse_pos_m"] == {"mean": 16.0, "std": pytest.approx(np.sqrt(((4**2) + 1 + 25) / 2)), "min": 12.0, "max": 21.0}
    assert e["over_bound"]["mean"] == pytest.approx(1.6)
    assert "over_memory_bound" not in e  # only where every seed has one


def test_paired_margin_is_the_mean_and_standard_error_of_per_run_differences():
    classical = np.array([10.0, 12.0, 11.0, 13.0])
    seeds = [np.array([9.0, 10.0, 12.0, 11.0]), np.array([11.0, 10.0, 10.0, 11.0])]
    d = classical - np.array([10.0, 10.0, 11.0, 11.0])  # [0, 2, 0, 2]
    r = paired_margin(seeds, classical)
    assert r["margin_m"] == pytest.approx(1.0)
    assert r["se_m"] == pytest.approx(d.std(ddof=1) / 2)
    assert r["runs"] == 4


def test_comparisons_pair_every_learned_unit_with_the_best_classical_method():
    methods = {"EKF": {"kind": "ekf", "rmse_pos_m": 12.0}, "IMM": {"kind": "imm", "rmse_pos_m": 11.0},
               "N [seed 0]": {"kind": "learned", "rmse_pos_m": 10.0}, "N [seed 1]": {"kind": "learned", "rmse_pos_m": 14.0},
               "R": {"kind": "learned", "rmse_pos_m": 30.0}}
    runs = {n: np.full(3, r["rmse_pos_m"]) + np.arange(3) for n, r in methods.items()}
    assert learned_units(methods) == {"N": ["N [seed 0]", "N [seed 1]"], "R": ["R"]}
    out = {c["learned"]: c for c in comparisons(methods, runs)}
    assert out["N"]["classical"] == "IMM" and out["N"]["margin_m"] == pytest.approx(-1.0) and out["N"]["se_m"] == 0
    assert out["R"]["margin_m"] == pytest.approx(-19.0)
    assert comparisons({"N [seed 0]": methods["N [seed 0]"]}, runs) == []
