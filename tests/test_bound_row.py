"""``kind: pcrb``: the information bound as a row of a scenario, filled from the case's bound,
never called, kept out of the learned trackers' comparisons, refused where there is no designed truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from pmsr_nn.cli import main
from pmsr_nn.harness import evaluate
from pmsr_nn.methods import method_kind
from pmsr_nn.methods.listing import catalogue

FLIGHT = {"start_range_m": 4000.0, "start_bearing_deg": 130.0, "speed_mps": 10.0, "heading_deg": 20.0,
          "segments": [{"duration_s": 120.0}]}
OTHER = {"start_range_m": 7800.0, "start_bearing_deg": 140.0, "speed_mps": 12.0, "heading_deg": 0.0,
         "segments": [{"duration_s": 120.0}]}
BOUNDS = [{"name": "PCRB", "kind": "pcrb"},
          {"name": "PCRB smoothing", "kind": "pcrb", "options": {"bound": "smoothing"}},
          {"name": "PCRB q=0", "kind": "pcrb", "options": {"q": "zero"}}]


def _scenario(tmp_path: Path, targets: list[dict], methods: list[dict], **over) -> Path:
    d = {"name": "bound_rows", "seed": 3, "mc_runs": 3, "block_runs": 3, "warmup_steps": 10,
         "cases": [{"name": "c", "targets": targets}], "methods": methods, **over}
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


def test_the_bound_rows_are_the_cases_bounds_and_order_as_the_maths_says(tmp_path):
    path = _scenario(tmp_path, [{"name": "a", **FLIGHT}], [{"name": "EKF", "kind": "ekf"}, *BOUNDS])
    res = evaluate(path, tmp_path / "out", progress=False)
    case = res["cases"]["c"]
    rows, p = case["methods"], case["pcrb"]
    assert res["kind"] == "designed"  # a designed flight: its case has a PCRB, and the results say so
    assert list(rows) == ["EKF", "PCRB", "PCRB smoothing", "PCRB q=0"]  # where the scenario lists them
    assert rows["PCRB"]["rmse_pos_m"] == p["pos_m"] and rows["PCRB"]["rmse_vel_mps"] == p["vel_mps"]
    assert rows["PCRB smoothing"]["rmse_pos_m"] == p["smoothing_pos_m"]
    assert rows["PCRB q=0"]["rmse_pos_m"] == p["q0_pos_m"] and rows["PCRB q=0"]["rmse_vel_mps"] is None
    # smoothing reads every scan, so its bound is below filtering's; removing process noise lowers it too
    assert rows["PCRB smoothing"]["rmse_pos_m"] < rows["PCRB"]["rmse_pos_m"]
    assert rows["PCRB q=0"]["rmse_pos_m"] < rows["PCRB"]["rmse_pos_m"]
    assert [rows[m]["causal"] for m in rows] == [True, True, False, True]
    # nothing was run for a bound: no time, and no line of the run-time table (the EKF has both)
    assert all(rows[m]["seconds_per_run"] is None for m in list(rows)[1:])
    curve = np.array(case["curves"]["rmse_pos_m"]["PCRB"])
    assert np.allclose(curve, case["curves"]["pcrb_pos_m"], equal_nan=True)
    report = (tmp_path / "out" / "report.md").read_text()
    assert "| PCRB smoothing | no (looks ahead) |" in report
    timing = report[report.index("## Run time"):]
    timed = [line.split(" | ")[0][2:] for line in timing.splitlines() if line.startswith("| ") and "---" not in line]
    assert timed[1:] == ["EKF"]  # after the header: the EKF alone


def test_a_bound_row_is_never_the_classical_reference_of_a_learned_tracker():
    from pmsr_nn.harness.results.seeds import comparisons

    methods = {"PCRB": {"kind": "pcrb", "rmse_pos_m": 1.0}, "EKF": {"kind": "ekf", "rmse_pos_m": 5.0},
               "net": {"kind": "learned", "rmse_pos_m": 4.0}}
    run = {"EKF": np.array([5.0, 6.0]), "net": np.array([4.0, 4.5])}
    (c,) = comparisons(methods, run)
    assert c["classical"] == "EKF" and c["margin_m"] == pytest.approx(1.25)


def test_bound_rows_beside_multi_target_rows(tmp_path):
    det = {"pd": 0.9, "clutter": {"per_scan": 2, "range_m": [0.0, 25000.0], "range_rate_mps": [-40.0, 40.0]}}
    path = _scenario(tmp_path, [{"name": "a", "death_s": 80.0, **FLIGHT}, {"name": "b", "birth_s": 20.0, **OTHER}],
                     [BOUNDS[0], {"name": "S-MSJPDA", "kind": "s_msjpda"}], detections=det,
                     set_metrics={"c_m": 300.0, "p": 2.0})
    res = evaluate(path, tmp_path / "out", progress=False)
    rows = res["cases"]["c"]["methods"]
    per = rows["PCRB"]["rmse_pos_per_target_m"]
    assert len(per) == 2 and per[0] != per[1] and "ospa_m" not in rows["PCRB"] and "ospa_m" in rows["S-MSJPDA"]
    report = (tmp_path / "out" / "report.md").read_text()
    line = next(x for x in report.splitlines() if x.startswith("| PCRB | filtering bound (association known) |"))
    peer = next(x for x in report.splitlines() if x.startswith("| S-MSJPDA | detections"))  # the same table's row
    assert line.count("|") == peer.count("|")


def test_the_catalogue_lists_it_and_a_multi_target_study_refuses_it(tmp_path, capsys):
    assert method_kind("pcrb").bound and "pcrb  (reads truth" in "\n".join(catalogue(["pcrb"]))
    study = {"name": "mt", "mc_runs": 1, "world": {"scans": 5, "geometry": {}}, "noise": {"doppler_hz": 1.0},
             "detections": {"components": ["range", "doppler"]}, "cases": [{"name": "c", "formation": {}}],
             "methods": [{"name": "bound", "kind": "pcrb"}]}
    path = tmp_path / "mt.yaml"
    path.write_text(yaml.safe_dump(study))
    out = tmp_path / "out"
    assert main(["evaluate", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "kind pcrb reads truth" in err[0] and not out.exists()
