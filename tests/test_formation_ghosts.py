"""``evaluate/formation_ghosts.py``: its per-run GOSPA re-draws the runs of ``pmsr evaluate`` and
gives the report's GOSPA, median run's GOSPA and spread over runs; its nearest-track distances find a track held
beside its target."""

from __future__ import annotations

import numpy as np
import pytest

from pmsr_nn.harness import evaluate
from pmsr_nn.harness.results.result_rows import RUN_QUANTILES
from script_loader import ROOT, load_script
from test_one_scenario import two_drones


@pytest.mark.integration
def test_the_per_run_gospa_is_the_reports(tmp_path):
    # tracks confirmed at once, reported from existence 0.05 and kept 5 scans without a detection, in
    # 30 clutter points a scan: false tracks in every run, so the split of their charge is put to the test
    options = {"initiation": "detections", "confirm_m": 1, "confirm_n": 1, "report_existence": 0.05, "delete_misses": 5}
    clutter = {"per_scan": 30, "range_m": [0.0, 25000.0], "range_rate_mps": [-40.0, 40.0]}
    path = two_drones(tmp_path, methods=[{"name": "S", "kind": "s_msjpda", "options": options}], mc_runs=4, block_runs=2,
                      detections={"pd": 0.9, "clutter": clutter})
    row = evaluate(path, tmp_path / "out", progress=False)["cases"]["c"]["methods"]["S"]
    r = load_script("evaluate/formation_ghosts.py").run_figures(path, None, None, 2)["S"]
    assert r["gospa_m"].shape == (4,) and r["nearest_m"].shape == (4, 2)
    assert np.sqrt(np.mean(r["gospa_m"] ** 2)) == pytest.approx(row["gospa_m"], rel=1e-9)
    assert np.median(r["gospa_m"]) == pytest.approx(row["gospa_median_run_m"], rel=1e-9)
    # the spread over runs: the quartiles, the 90 % point and the worst of the re-drawn runs
    assert row["gospa_run_quantiles_m"] == pytest.approx(np.quantile(r["gospa_m"], RUN_QUANTILES), rel=1e-9)
    assert row["gospa_run_quantiles_m"][-1] == pytest.approx(r["gospa_m"].max(), rel=1e-9)
    assert np.all(r["nearest_m"] < 100.0)  # two drones far apart: each has a track on it
    # a list of blocks re-draws those blocks: block 1 alone is runs 2 and 3 of the whole
    second = load_script("evaluate/formation_ghosts.py").run_figures(path, None, None, [1])["S"]
    assert second["gospa_m"] == pytest.approx(r["gospa_m"][2:], rel=1e-12)
    assert r["false_shares"].shape == (4, 3) and np.all(r["false_shares"].sum(1) <= 1 + 1e-12)
    # the three classes add up to the report's false share: each run's shares of its GOSPA^p (p = 2),
    # weighted by that GOSPA^p, over the runs' summed GOSPA^p (the report pools the runs and scans)
    w = r["gospa_m"] ** 2
    assert np.sum(r["false_shares"].sum(1) * w) / np.sum(w) == pytest.approx(row["gospa_false_share"], rel=1e-9)
    assert np.all(r["false_shares"].sum(1) > 0)  # (the false tracks are there)
    assert r["beside_m"].shape == (4,)
    # (tracks reported from existence 0.05 and kept 5 scans without a detection: a false one lives
    # at least one scan, and none outlives the 90 scored scans: 100 steps, the first 10 the warm-up)
    assert r["longest_false"].shape == (4,) and np.all((r["longest_false"] >= 1) & (r["longest_false"] <= 90))


def test_false_tracks_are_classed_outlived_beside_or_far():
    """Target 0 lives scans 0-1, target 1 all three; track 0 holds target 0 and stays after it
    dies (outlived at scan 2), track 1 holds target 1, track 2 appears beside target 1 at scan 1
    (a duplicate) and 2 km from everything at scan 2 (far). Each class is charged c^p/2 at its
    scans, and the classes add up to GOSPA's own false charge."""
    import torch

    from pmsr_nn.metrics.sets import gospa

    c, p = 100.0, 2.0
    tx = torch.tensor([[0.0, 0.0], [1000.0, 0.0]]).expand(1, 3, 2, 2)
    alive = torch.tensor([[[True, True], [True, True], [False, True]]])
    ex = torch.tensor([[[1.0, 0.0], [1001.0, 0.0], [0.0, 0.0]], [[1.0, 0.0], [1001.0, 0.0], [1030.0, 0.0]],
                       [[1.0, 0.0], [1001.0, 0.0], [3000.0, 0.0]]])[None]
    exists = torch.tensor([[[True, True, False], [True, True, True], [True, True, True]]])
    script = load_script("evaluate/formation_ghosts.py")
    parts, beside, false = script.false_kinds(ex, exists, tx, alive, c, p)
    parts, beside = parts[0], beside[0]
    # charged as false: track 0 at scan 2, track 2 at scans 1 and 2, the longest two scans in a row
    assert false[0].tolist() == [[False, False, False], [False, False, True], [True, False, True]]
    assert script.longest_stretch(false).tolist() == [2]
    assert script.longest_stretch(torch.zeros(2, 4, 0, dtype=torch.bool)).tolist() == [0, 0]
    half = c**p / 2
    assert parts.tolist() == [[0.0, 0.0, 0.0], [0.0, half, 0.0], [half, 0.0, half]]
    assert parts.sum(-1).tolist() == gospa(ex, exists, tx, alive, c, p).false[0].tolist()
    assert beside[1, 2].item() == 30.0 and int(beside.isfinite().sum()) == 1  # the duplicate, 30 m from target 1


@pytest.mark.integration
def test_seed_and_options_re_draw_and_re_run_as_the_scenario_with_them_would(tmp_path, capsys):
    """``--seed`` and ``--options`` give the report's GOSPA of the scenario with that seed and the
    chosen rows' options changed (``pmsr evaluate`` on an edited copy), and differ from the
    scenario's own; a bad option is one line and exit 2."""
    import subprocess
    import sys

    import yaml

    clutter = {"per_scan": 30, "range_m": [0.0, 25000.0], "range_rate_mps": [-40.0, 40.0]}
    methods = [{"name": "S", "kind": "s_msjpda", "options": {"initiation": "detections"}},
               {"name": "O", "kind": "s_msjpda"}]
    path = two_drones(tmp_path, methods=methods, mc_runs=2, block_runs=2, detections={"pd": 0.9, "clutter": clutter})
    changed = {"confirm_m": 1, "confirm_n": 1, "report_existence": 0.05, "delete_misses": 5}
    edited = yaml.safe_load(path.read_text())
    edited.update(seed=11, methods=[{**methods[0], "options": {**methods[0]["options"], **changed}}])
    copy = tmp_path / "edited.yaml"
    copy.write_text(yaml.safe_dump(edited))
    row = evaluate(copy, tmp_path / "out", progress=False)["cases"]["c"]["methods"]["S"]
    script = load_script("evaluate/formation_ghosts.py")
    r = script.run_figures(path, "S", None, 1, seed=11, options=changed)
    assert list(r) == ["S"]
    assert np.sqrt(np.mean(r["S"]["gospa_m"] ** 2)) == pytest.approx(row["gospa_m"], rel=1e-9)
    own = script.run_figures(path, "S", None, 1)["S"]["gospa_m"]
    assert not np.allclose(own, r["S"]["gospa_m"], rtol=1e-3)
    bad = subprocess.run([sys.executable, str(ROOT / "evaluate/formation_ghosts.py"), str(path), "--methods", "S",
                          "--options", "{delete_misses: -1}"], capture_output=True, text=True)
    assert bad.returncode == 2 and bad.stdout == ""
    lines = bad.stderr.strip().splitlines()
    assert len(lines) == 1 and "delete_misses" in lines[0], bad.stderr
