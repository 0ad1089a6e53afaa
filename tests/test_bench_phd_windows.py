"""benchmarks/bench_phd_windows.py: the SMC-PHD's range windows against the full product, on a
study's row (issue 57): its record says whether the two gave the same estimates, and its ratios are
its own medians'."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from test_track_management import scenario

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.integration
def test_bench_phd_windows_records_identical_estimates_and_its_own_ratios(tmp_path):
    path = scenario(tmp_path, pd=0.9, clutter=5, mc_runs=1, block_runs=1,
                    methods=[{"name": "PHD", "kind": "smc_phd",
                              "options": {"particles_per_target": 200, "particles_per_birth": 20}}])
    out = tmp_path / "windows.json"
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks/bench_phd_windows.py"), str(path), "--row", "PHD",
                           "--repeats", "1", "--json", str(out)], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rec = json.loads(out.read_text())
    assert rec["identical"] == {"row_counts": True, "default_counts": True}
    assert rec["counts"] == {"particles_per_target": 200, "particles_per_birth": 20}
    med = rec["median_s"]
    assert set(med) == {"full", "windows", "windows_default_counts", "full_default_counts"}
    assert rec["ratio_windows_to_full"] == pytest.approx(med["windows"] / med["full"], rel=1e-12)
    assert rec["ratio_windows_to_full_default_counts"] == pytest.approx(
        med["windows_default_counts"] / med["full_default_counts"], rel=1e-12)
    assert rec["ratio_to_before"] == pytest.approx(med["windows"] / med["full_default_counts"], rel=1e-12)
    assert rec["info"]["command"].startswith("python ")
