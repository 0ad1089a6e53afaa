"""Smoke test of the baselines-vs-bounds study script on a tiny problem (the real run is recorded
in evaluate/RESULTS.md)."""

import importlib.util
import json
from pathlib import Path

import pytest
from figure_check import assert_drawn_png

SCRIPT = Path(__file__).resolve().parents[1] / "evaluate" / "baselines_vs_bounds.py"


@pytest.mark.figures
def test_study_runs_end_to_end_and_writes_results(tmp_path, capsys):
    spec = importlib.util.spec_from_file_location("baselines_vs_bounds", SCRIPT)
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    assert study.main(["--tracks", "6", "--steps", "15", "--burn-in", "3", "--particles", "64",
                       "--variants", "envelope", "--out", str(tmp_path)]) == 0
    res = json.loads((tmp_path / "results.json").read_text())["results"][0]
    methods = [r["method"] for r in res["rows"]]
    assert {"EKF", "UKF", "EKF + RTS", "UKF + URTS", "SI+KF", "SI+GN+KF"} <= set(methods)
    assert sum("PCRB" in m for m in methods) == 4
    assert all(r["position_rmse_m"] > 0 for r in res["rows"])
    by = {r["method"]: r for r in res["rows"]}
    # Smoothing bounds sit below filtering bounds; the per-trajectory form above the averaged one.
    assert by["PCRB per-trajectory (smoothing)"]["position_rmse_m"] < by["PCRB per-trajectory (filtering)"]["position_rmse_m"]
    assert by["PCRB information-averaged (filtering)"]["position_rmse_m"] <= by["PCRB per-trajectory (filtering)"]["position_rmse_m"]
    assert_drawn_png(tmp_path / "rmse.png")
    assert "MSE/own bound" in capsys.readouterr().out
