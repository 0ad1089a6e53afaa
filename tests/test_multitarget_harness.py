"""Multi-target scenarios (a scenario with a world section, pmsr_nn.harness.scenario.world) through `pmsr evaluate`."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from pmsr_nn.config import load_yaml
from pmsr_nn.errors import ConfigError
from pmsr_nn.harness import evaluate
from pmsr_nn.harness.scenario.references import reference_table
from pmsr_nn.harness.run.runner import prepare
from pmsr_nn.harness.scenario.schema import load_scenario

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ["access2019_msjpda.yaml", "access2019_msjpda_pd.yaml", "access2019_msjpda_clutter.yaml",
             "access2019_msjpda_mbest.yaml"]


def _small(tmp_path: Path, **over) -> Path:
    data = load_yaml(ROOT / "evaluate" / "access2019_msjpda.yaml")
    data.update(mc_runs=3, block_runs=2, warmup_steps=2)
    data["world"]["scans"] = 6
    data["detections"]["clutter"]["per_scan"] = 5
    two = {**data["cases"][0]["formation"], "count": 2}
    data["cases"] = [{"name": "nominal", "reference_key": "0.8", "formation": two},
                     {"name": "close", "formation": {**two, "spacing_m": 500.0}}]
    data["reference"]["file"] = str(ROOT / "evaluate" / "reference" / "paper_tables.json")
    data.update(over)
    p = tmp_path / "small.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def test_small_scenario_writes_every_method_with_timing_and_loss(tmp_path):
    res = evaluate(_small(tmp_path), tmp_path / "out", progress=False)
    assert res["kind"] == "sampled" and res["mc_runs"] == 3  # truth sampled per run: no per-case PCRB
    for case in res["cases"].values():
        assert set(case["methods"]) == {"S-MSJPDA", "P-MSJPDA", "P-MSJPDA relaxation", "P-MSJPDA m=100", "true assignment"}
        for r in case["methods"].values():
            for key in ("rmse_pos_m", "rmse_vel_mps", "anees", "seconds_per_run", "loss_probability", "swap_probability"):
                assert math.isfinite(r[key]), key
            assert math.isfinite(r["rmse_pos_se_m"]) and math.isfinite(r["ospa_se_m"])  # 3 runs: errors exist
            lost = r["loss_probability"] * 3 * 2  # a fraction of the 3 runs x 2 targets
            assert lost == pytest.approx(round(lost), abs=1e-9) and 0 <= round(lost) <= 6
            assert len(r["rmse_pos_per_target_m"]) == 2
        assert len(case["curves"]["rmse_pos_m"]["S-MSJPDA"][0]) == 6
        assert case["methods"]["P-MSJPDA"]["max_duality_gap"] == 0.0  # ranked exactly (branch and bound)
        assert math.isfinite(case["methods"]["P-MSJPDA relaxation"]["max_duality_gap"])
        assert "max_duality_gap" not in case["methods"]["S-MSJPDA"]
    saved = json.loads((tmp_path / "out" / "results.json").read_text())
    assert saved["kind"] == "sampled" and all(c["pcrb"] is None for c in saved["cases"].values())
    assert saved["cases"]["nominal"]["methods"]["P-MSJPDA"]["rmse_pos_m"] == res["cases"]["nominal"]["methods"]["P-MSJPDA"]["rmse_pos_m"]
    report = (tmp_path / "out" / "report.md").read_text()
    assert "paper (MATLAB" in report and "| 2.45 |" in report  # the paper's S-MSJPDA time at Pd 0.8, labelled
    for f in ("trajectories.png", "nominal_rmse.png", "nominal_set_metrics.png"):
        assert (tmp_path / "out" / f).is_file(), f


@pytest.mark.slow  # the designed-scenario twin (test_harness) and the multi-target shard merge (test_one_scenario) stay in the default tier
def test_same_seed_same_figures_and_blocks_independent_of_mc_runs(tmp_path):
    a = evaluate(_small(tmp_path), tmp_path / "a", progress=False)
    b = evaluate(_small(tmp_path), tmp_path / "b", progress=False)
    key = lambda r: [(c, m, v["rmse_pos_m"], v["loss_probability"]) for c, case in r["cases"].items()
                     for m, v in case["methods"].items()]
    assert key(a) == key(b)
    # the first block's draws do not depend on how many runs follow it
    c = evaluate(_small(tmp_path), tmp_path / "c", mc_runs=2, progress=False)
    d = evaluate(_small(tmp_path, mc_runs=2), tmp_path / "d", progress=False)
    assert key(c) == key(d)


@pytest.mark.integration
def test_sweep_report_has_the_sweep_table(tmp_path):
    two = {"count": 2, "centre_m": [-25000.0, -20000.0], "velocity_mps": [200.0, 244.1], "spacing_m": 2000.0}
    p = _small(tmp_path, sweep="pd", cases=[{"name": "pd_0.6", "detections": {"pd": 0.6}, "reference_key": "0.6",
                                             "formation": two},
                                            {"name": "pd_0.9", "detections": {"pd": 0.9}, "reference_key": "0.9",
                                             "formation": two}])
    data = yaml.safe_load(p.read_text())
    data["methods"].insert(2, {"name": "P-MSJPDA m=3", "kind": "p_msjpda", "options": {"m_best": 3}})
    p.write_text(yaml.safe_dump(data))
    res = evaluate(p, tmp_path / "out", progress=False)
    report = (tmp_path / "out" / "report.md").read_text()
    assert "## Sweep" in report and "| 0.6 |" in report and "paper (MATLAB, 4 x 3.3 GHz): P/S time" in report
    assert (tmp_path / "out" / "sweep_pd.png").is_file()
    # every P-MSJPDA variant gets our time ratio to S-MSJPDA; paper times only for the methods the paper timed
    head = next(line for line in report.splitlines() if line.startswith("| detection probability"))
    cols = [c.strip() for c in head.strip("|").split("|")]
    assert "P-MSJPDA / S-MSJPDA time" in cols and "P-MSJPDA m=3 / S-MSJPDA time" in cols
    assert not any("paper" in c and "m=3" in c for c in cols)
    row = next(line for line in report.splitlines() if line.startswith("| 0.6 |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    r = res["cases"]["pd_0.6"]["methods"]
    ratio = r["P-MSJPDA m=3"]["seconds_per_run"] / r["S-MSJPDA"]["seconds_per_run"]
    assert cells[cols.index("P-MSJPDA m=3 / S-MSJPDA time")] == f"{ratio:.1f}"
    assert res["settings"]["methods"]["P-MSJPDA m=3"]["m_best"] == 3


@pytest.mark.parametrize("name", SCENARIOS)
def test_recorded_scenarios_load_and_name_paper_keys(name):
    sc = load_scenario(ROOT / "evaluate" / name)
    setup = prepare(sc)  # geometry and flights are valid
    if sc.reference is None:  # an ablation of ours: no paper table, so no case may name a key
        assert all(c.reference_key is None for c in sc.cases)
    else:
        node = reference_table(sc.path(sc.reference.file), sc.reference.timing)
        for c in sc.cases:
            if c.reference_key is not None:
                assert c.reference_key in node["S-MSJPDA"]
    assert sc.mc_runs == 100 and sc.world.scans == 50 and all(c.formation.count == 4 for c in sc.cases)
    # each case's sweep setting reaches the case that runs: the recorded Pd and clutter are the detections'
    for c, case in zip(sc.cases, setup.cases):
        d = sc.case_detections(c)
        assert (case.sensing.pd, case.sensing.clutter.per_scan) == (d.pd, d.clutter.per_scan)
        assert case.info["spacing_m"] == c.formation.spacing_m


def test_bad_multitarget_inputs_are_clear(tmp_path):
    p = _small(tmp_path)
    with pytest.raises(ConfigError, match="3 shards but only 2 block"):
        evaluate(p, tmp_path / "o1", shard=(1, 3), progress=False)
    with pytest.raises(ConfigError, match="checkpoint"):
        evaluate(p, tmp_path / "o2", checkpoints={"S-MSJPDA": "x.pt"}, progress=False)
    with pytest.raises(ConfigError, match="unknown key"):
        evaluate(_small(tmp_path, clutterr=3), tmp_path / "o3", progress=False)
    with pytest.raises(ConfigError, match="within 1 km of a sensor"):
        near = {"name": "near", "formation": {"count": 2, "centre_m": [-200.0, -300.0]}}
        evaluate(_small(tmp_path, cases=[near]), tmp_path / "o4", progress=False)
    with pytest.raises(ConfigError, match="a world case gives its targets"):
        evaluate(_small(tmp_path, cases=[{"name": "inline", "start_range_m": 5000.0, "start_bearing_deg": 10.0,
                                          "speed_mps": 10.0, "heading_deg": 0.0, "segments": [{"duration_s": 5.0}]}]),
                 tmp_path / "o5", progress=False)
    with pytest.raises(ConfigError, match="case 'nominal': detections: .*pd must be in"):
        evaluate(_small(tmp_path, cases=[{"name": "nominal", "formation": {"count": 2}, "detections": {"pd": 1.5}}]),
                 tmp_path / "o6", progress=False)
    with pytest.raises(ConfigError, match="a recipe or a world section, not both"):
        evaluate(_small(tmp_path, recipe="x.yaml"), tmp_path / "o7", progress=False)
    with pytest.raises(ConfigError, match="detections.components has doppler: give noise.doppler_hz"):
        evaluate(_small(tmp_path, noise={"range_m": 1000.0}), tmp_path / "o8", progress=False)
    assert not any(tmp_path.glob("o*"))  # nothing half-written


def test_a_recipe_scenario_refuses_the_targets_of_a_world(tmp_path):
    """A formation (or a case's detections override) belongs to a world section: without one, one line."""
    from pmsr_nn.harness.scenario.schema import scenario_from_dict

    data = load_yaml(ROOT / "evaluate" / "fitee2023_three_trajectories.yaml")
    data["cases"][0] = {**data["cases"][0], "detections": {"pd": 0.5}}
    with pytest.raises(ConfigError, match="are cases of a world section"):
        scenario_from_dict(data, ROOT / "evaluate")
    data["cases"][0] = {"name": "f", "formation": {"count": 2}}
    with pytest.raises(ConfigError, match="are cases of a world section"):
        scenario_from_dict(data, ROOT / "evaluate")


def test_a_retired_multitarget_file_is_refused_in_one_line(tmp_path, capsys):
    """A YAML that still says kind: multitarget: one line saying how to write it now, exit 2, nothing written."""
    from pmsr_nn.cli import main

    p = tmp_path / "old.yaml"
    p.write_text((ROOT / "tests" / "data" / "legacy" / "msjpda_subset.yaml").read_text().replace(
        "name: msjpda_subset", "kind: multitarget\nname: msjpda_subset"))
    assert main(["evaluate", str(p), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "retired" in err[0] and "world section" in err[0]
    assert not (tmp_path / "out").exists()


def test_cli_evaluate_runs_a_multitarget_scenario(tmp_path, capsys):
    from pmsr_nn.cli import main

    out = tmp_path / "cli"
    assert main(["evaluate", str(_small(tmp_path)), "--mc-runs", "2", "--out", str(out), "--methods", "S-MSJPDA"]) == 0
    printed = capsys.readouterr().out
    assert "S-MSJPDA" in printed and "loss prob." in printed and "P-MSJPDA" not in printed
    res = json.loads((out / "results.json").read_text())
    assert list(res["cases"]["nominal"]["methods"]) == ["S-MSJPDA"] and res["mc_runs"] == 2


@pytest.mark.slow
def test_done_when_command(tmp_path):
    """The issue's acceptance command on the real scenario (about 10 s)."""
    out = tmp_path / "msjpda"
    r = subprocess.run([sys.executable, "-m", "pmsr_nn.cli", "evaluate", str(ROOT / "evaluate" / "access2019_msjpda.yaml"),
                        "--mc-runs", "5", "--out", str(out)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    res = json.loads((out / "results.json").read_text())
    for r in res["cases"]["nominal"]["methods"].values():
        lost = r["loss_probability"] * 5 * len(r["rmse_pos_per_target_m"])  # a fraction of runs x targets
        assert math.isfinite(r["seconds_per_run"]) and lost == pytest.approx(round(lost), abs=1e-9)


def _worst_runs_module():
    from script_loader import load_script

    return load_script("evaluate/msjpda_worst_runs.py")


@pytest.mark.integration
def test_per_run_errors_use_the_harness_draws(tmp_path):
    mod = _worst_runs_module()
    p = _small(tmp_path)
    err = mod.per_run_errors(p, "nominal", blocks=2)
    assert set(err) == {"S-MSJPDA", "P-MSJPDA", "P-MSJPDA relaxation", "P-MSJPDA m=100", "true assignment"}
    assert all(e.shape == (3, 2) and np.isfinite(e).all() for e in err.values())  # 3 runs in blocks of 2, 2 targets
    # the same draws as `pmsr evaluate`: the mean squared error over runs gives its converged RMSE
    # when every scan from warmup_steps on is averaged with the same weight
    res = evaluate(p, tmp_path / "out", progress=False)
    per_scan = np.array(res["cases"]["nominal"]["curves"]["rmse_pos_m"]["S-MSJPDA"])  # (T, K)
    assert np.allclose((err["S-MSJPDA"] ** 2).mean(0), (per_scan[:, 2:] ** 2).mean(1), rtol=1e-9)
    with pytest.raises(ConfigError, match="no case 'nope'"):
        mod.per_run_errors(p, "nope", blocks=1)
    with pytest.raises(ConfigError, match="--blocks"):
        mod.per_run_errors(p, "nominal", blocks=9)
