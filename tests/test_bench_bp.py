"""benchmarks/bench_bp.py: BP's time per run against S-MSJPDA's in one process (issue 55's speed
target), its record and its refusals."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from test_track_management import scenario

ROOT = Path(__file__).resolve().parents[1]
ROWS = [{"name": "S-MSJPDA", "kind": "s_msjpda", "options": {"initiation": "detections"}}, {"name": "BP", "kind": "bp"}]


def _bench(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "benchmarks/bench_bp.py"), *args], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=300)


@pytest.mark.integration
def test_the_record_holds_each_runs_times_and_their_ratios(tmp_path):
    """Two runs of a small scene: per run and clock, the ratio is BP's seconds over S-MSJPDA's, its
    mean and standard error are those of the two ratios, and the ratio of sums the summed times'."""
    path = scenario(tmp_path, pd=0.9, clutter=3, methods=ROWS, block_runs=1)
    out = tmp_path / "bp.json"
    proc = _bench("--scenario", str(path), "--runs", "2", "--json", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    rec = json.loads(out.read_text())
    assert rec["runs"] == 2 and rec["reference"] == "S-MSJPDA" and rec["info"]["command"].startswith("python ")
    for clock in ("wall", "cpu"):
        r = rec["rows"][clock]
        a, b = r["seconds_per_run"]["S-MSJPDA"], r["seconds_per_run"]["BP"]
        ratios = [y / x for x, y in zip(a, b)]
        assert len(a) == len(b) == 2 and r["ratio_per_run"] == pytest.approx(ratios, rel=1e-12)
        assert r["ratio_mean"] == pytest.approx(sum(ratios) / 2, rel=1e-12)
        assert r["ratio_se"] == pytest.approx(abs(ratios[0] - ratios[1]) / 2, rel=1e-9)  # sd / sqrt(2) of two
        assert r["ratio_of_sums"] == pytest.approx(sum(b) / sum(a), rel=1e-12)
        assert f"{clock}: BP / S-MSJPDA per run {r['ratio_mean']:.3f}" in proc.stdout


@pytest.mark.parametrize("over, runs, message", [
    ({}, "3", "--runs must be in [1, 2]"),
    ({"block_runs": 2}, "1", "must run one run per block"),
    ({"methods": [ROWS[1]]}, "1", "has no row ['S-MSJPDA']"),
])
def test_what_it_cannot_time_is_refused_in_one_line_and_writes_nothing(tmp_path, capsys, over, runs, message):
    """In-process (the record's test above runs it as its own process, as its times need)."""
    spec = importlib.util.spec_from_file_location("bench_bp", ROOT / "benchmarks/bench_bp.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    path = scenario(tmp_path, **{"methods": ROWS, "block_runs": 1, **over})
    out = tmp_path / "bp.json"
    with pytest.raises(SystemExit) as exit_:
        bench.main(["--scenario", str(path), "--runs", runs, "--json", str(out)])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and message in err.strip().splitlines()[-1], err[-2000:]
    assert not out.exists()
