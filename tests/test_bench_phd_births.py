"""benchmarks/bench_phd_births.py keeps a record (``--json``) of what it prints (issue 60)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.integration
def test_bench_phd_births_records_what_it_prints(tmp_path):
    """The --json record of benchmarks/bench_phd_births.py (a tiny scene): every call, and ratios that
    are the calls' own minimum CPU seconds at 30 over those at 10."""
    out = tmp_path / "births.json"
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks/bench_phd_births.py"), "--scans", "4", "--runs", "1",
                           "--targets", "1", "--json", str(out)], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rec = json.loads(out.read_text())
    assert len(rec["calls"]) == 4 and rec["info"]["command"].startswith("python ")
    for births in ("adaptive", "every_detection"):
        cpu = {c: min(x["cpu_s_per_run"] for x in rec["calls"] if x["births"] == births and x["clutter"] == c)
               for c in (10, 30)}
        assert rec["summary"][births]["ratio_30_over_10"] == pytest.approx(cpu[30] / cpu[10], rel=1e-12)
        assert f"{births}: min cpu per run {cpu[10]:.2f} s (10) {cpu[30]:.2f} s (30)" in proc.stdout
