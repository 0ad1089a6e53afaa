"""``evaluate/paired_banks.py``: two rows compared run by run from the per-run GOSPA^p a block bank
keeps, against the merged report and against the runs re-drawn by ``formation_ghosts.py``."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pmsr_nn.errors import ConfigError
from pmsr_nn.harness import merge
from pmsr_nn.harness.evaluate import execute
from pmsr_nn.harness.run.block_bank import bank_blocks
from pmsr_nn.harness.run.runner import open_run
from script_loader import load_script
from test_block_bank import _score_every_scan
from test_one_scenario import two_drones

ROWS = [{"name": "oracle", "kind": "s_msjpda"}, {"name": "own", "kind": "s_msjpda", "options": {"initiation": "detections"}}]


@pytest.mark.integration
def test_the_paired_figures_are_the_reports_and_the_re_drawn_runs(tmp_path):
    path = two_drones(tmp_path, methods=ROWS, mc_runs=4, block_runs=2)
    execute(open_run(path, tmp_path / "bank", target="bank", progress=False))
    report = merge([tmp_path / "bank"], tmp_path / "merged")["cases"]["c"]["methods"]
    script = load_script("evaluate/paired_banks.py")
    own, p = script.run_powers(tmp_path / "bank", None, "own")
    oracle, _ = script.run_powers(tmp_path / "bank", None, "oracle")
    assert sorted(own) == [0, 1, 2, 3] and p == 2.0
    r = script.compare(oracle, own, p)
    # each row's GOSPA is the merged report's
    assert r["gospa_a_m"] == pytest.approx(report["oracle"]["gospa_m"], rel=1e-9)
    assert r["gospa_b_m"] == pytest.approx(report["own"]["gospa_m"], rel=1e-9)
    # each run's GOSPA is the one formation_ghosts.py gets by drawing the runs again
    again = load_script("evaluate/formation_ghosts.py").run_figures(path, None, None, 2)
    d = again["own"]["gospa_m"] - again["oracle"]["gospa_m"]
    assert r["paired_b_minus_a_m"] == pytest.approx(d.mean(), rel=1e-9, abs=1e-12)
    assert r["paired_se_m"] == pytest.approx(d.std(ddof=1) / 2.0, rel=1e-9, abs=1e-12)
    assert r["better"] + r["worse"] + r["same"] == 4
    # a row against itself: no difference, ratio 1 with no spread
    same = script.compare(own, own, p)
    assert same["largest_relative_difference"] == 0.0 and same["ratio_a_over_b"] == 1.0 and same["ratio_se"] == 0.0
    # a bank whose bank.json was deleted reads its scenario from its blocks: the same runs
    (tmp_path / "bank" / "bank.json").unlink()
    assert script.run_powers(tmp_path / "bank", None, "own") == (own, p)


def test_the_ratios_error_is_the_delta_methods():
    """Two rows whose runs' GOSPA^2 are (1, 4) x 100 and (1, 1) x 25: ratio sqrt(250 / 25); the
    delta method with the runs' variances (A: 45000, B: 0) over n = 2 gives its error."""
    script = load_script("evaluate/paired_banks.py")
    r = script.compare({0: 100.0, 1: 400.0}, {0: 25.0, 1: 25.0}, 2.0)
    ratio = math.sqrt(250.0 / 25.0)
    assert r["ratio_a_over_b"] == pytest.approx(ratio, rel=1e-12)
    assert r["ratio_se"] == pytest.approx(ratio / 2 / 250.0 * math.sqrt(45000.0 / 2), rel=1e-12)
    assert r["paired_b_minus_a_m"] == pytest.approx(np.mean([5.0 - 10.0, 5.0 - 20.0]), rel=1e-12)
    assert r["run_ratios"].tolist() == pytest.approx([2.0, 4.0], rel=1e-12)


def test_too_few_shared_runs_or_a_foreign_folder_are_refused(tmp_path):
    script = load_script("evaluate/paired_banks.py")
    with pytest.raises(ConfigError, match="share 1 run"):
        script.compare({0: 1.0, 1: 2.0}, {1: 2.0, 2: 3.0}, 2.0)
    with pytest.raises(ConfigError, match="not a block bank"):
        script.run_powers(tmp_path, None, "own")


def test_blocks_scored_over_every_scan_are_read_as_the_merge_reads_them(tmp_path):
    """A bank made before issue 55's fix of the set scans: each run's GOSPA^p is re-derived from its
    block's per-scan sums, so the pairs are the fresh run's, like the merged record's figures."""
    path = two_drones(tmp_path, methods=ROWS, mc_runs=2, block_runs=1)
    execute(open_run(path, tmp_path / "bank", target="bank", progress=False))
    script = load_script("evaluate/paired_banks.py")
    fresh, _ = script.run_powers(tmp_path / "bank", None, "own")
    rewritten = [pair for folder in bank_blocks(tmp_path / "bank") for pair in _score_every_scan(folder)]
    assert max(abs(old[0] / kept[0] - 1) for kept, old in rewritten) > 1e-3  # the blocks now disagree
    assert script.run_powers(tmp_path / "bank", None, "own")[0] == pytest.approx(fresh, rel=1e-12)
