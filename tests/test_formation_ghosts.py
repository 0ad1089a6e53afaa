"""``evaluate/formation_ghosts.py``: its per-run GOSPA re-draws the runs of ``pmsr evaluate`` and
gives the report's GOSPA, median run's GOSPA and spread over runs; its nearest-track distances find a track held
beside its target."""

from __future__ import annotations

import numpy as np
import pytest

from pmsr_nn.harness import evaluate
from pmsr_nn.harness.result_rows import RUN_QUANTILES
from script_loader import load_script
from test_one_scenario import two_drones


def test_the_per_run_gospa_is_the_reports(tmp_path):
    path = two_drones(tmp_path, methods=[{"name": "S", "kind": "s_msjpda", "options": {"initiation": "detections"}}],
                      mc_runs=4, block_runs=2)
    row = evaluate(path, tmp_path / "out", progress=False)["cases"]["c"]["methods"]["S"]
    r = load_script("evaluate/formation_ghosts.py").run_figures(path, None, None, 2)["S"]
    assert r["gospa_m"].shape == (4,) and r["nearest_m"].shape == (4, 2)
    assert np.sqrt(np.mean(r["gospa_m"] ** 2)) == pytest.approx(row["gospa_m"], rel=1e-9)
    assert np.median(r["gospa_m"]) == pytest.approx(row["gospa_median_run_m"], rel=1e-9)
    # the spread over runs: the quartiles, the 90 % point and the worst of the re-drawn runs
    assert row["gospa_run_quantiles_m"] == pytest.approx(np.quantile(r["gospa_m"], RUN_QUANTILES), rel=1e-9)
    assert row["gospa_run_quantiles_m"][-1] == pytest.approx(r["gospa_m"].max(), rel=1e-9)
    assert np.all(r["nearest_m"] < 100.0)  # two drones far apart in light clutter: every track on its drone
