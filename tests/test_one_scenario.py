"""One scenario, every method: targets with births and deaths seen as streams and as detections,
single- and multi-target methods through one interface, set metrics, shards for every scenario."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from pmsr_nn.cli import main
from pmsr_nn.errors import ConfigError
from pmsr_nn.filters import Gaussian, ekf
from pmsr_nn.harness import evaluate, merge
from pmsr_nn.harness.run.blocks import call_method, draw_block, stream_block
from pmsr_nn.harness.run.runner import prepare
from pmsr_nn.harness.scenario.schema import load_scenario, scenario_from_dict
from pmsr_nn.methods import REGISTRY, MethodKind, register
from pmsr_nn.trackers.base import Estimates

ROOT = Path(__file__).resolve().parents[1]
FLIGHT = {"start_range_m": 4000.0, "start_bearing_deg": 130.0, "speed_mps": 10.0, "heading_deg": 20.0,
          "segments": [{"duration_s": 200.0}]}
OTHER = {"start_range_m": 7800.0, "start_bearing_deg": 140.0, "speed_mps": 12.0, "heading_deg": 0.0,
         "segments": [{"duration_s": 200.0}]}


def two_drones(tmp_path: Path, methods=None, **over) -> Path:
    """Two drones: one from 0 to 60 s, one from 20 s to 100 s; streams and detections."""
    d = {"name": "two", "seed": 5, "mc_runs": 4, "block_runs": 2, "warmup_steps": 10, "random_streams": "per_product",
         "detections": {"pd": 0.9, "clutter": {"per_scan": 3, "range_m": [0.0, 25000.0], "range_rate_mps": [-40.0, 40.0]}},
         "set_metrics": {"c_m": 300.0, "p": 2.0},
         "cases": [{"name": "c", "targets": [{"name": "a", "death_s": 60.0, **FLIGHT},
                                             {"name": "b", "birth_s": 20.0, "death_s": 100.0, **OTHER}]}],
         "methods": methods or [{"name": "EKF", "kind": "ekf"}, {"name": "S-MSJPDA", "kind": "s_msjpda"}]}
    d.update(over)
    path = tmp_path / "two.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


@pytest.mark.integration
def test_births_and_deaths_give_the_cardinality_and_lives(tmp_path):
    res = evaluate(two_drones(tmp_path), tmp_path / "out", progress=False)
    case = res["cases"]["c"]
    assert case["steps"] == 100 and case["lives"] == [{"name": "a", "first_scan": 0, "end_scan": 60},
                                                      {"name": "b", "first_scan": 20, "end_scan": 100}]
    truth = np.array(case["curves"]["cardinality_truth"])
    assert truth.tolist() == [1] * 20 + [2] * 40 + [1] * 40
    for m in ("EKF", "S-MSJPDA"):
        # these trackers hold a track exactly while its target lives: no cardinality error at all
        assert case["curves"]["set"][m]["cardinality"] == truth.tolist()
        assert case["methods"][m]["cardinality_mean_abs_error"] == 0.0
        curve = np.array(case["curves"]["rmse_pos_m"][m])  # (targets, scans): NaN outside each life
        assert np.isnan(curve[0, 60:]).all() and np.isfinite(curve[0, :60]).all()
        assert np.isnan(curve[1, :20]).all() and np.isfinite(curve[1, 20:]).all()
        assert 0 < case["methods"][m]["ospa_m"] < 300.0
    # the PCRB of each drone starts at its birth from the initiation prior: drone b's bound is that
    # of its own 80 scans alone
    from pmsr_nn.bounds import pcrb

    setup = prepare(load_scenario(tmp_path / "two.yaml"))
    m, x = setup.models, setup.cases[0].truth.x
    own = pcrb(x[20:, 1][None], m.motion, m.dt, m.q, m.model, m.R, torch.diag(setup.prior_sd**2)).position_rmse()
    bound = np.array(case["curves"]["pcrb_pos_m"])
    assert np.allclose(bound[1, 20:], own.numpy(), rtol=1e-12) and np.isnan(bound[1, :20]).all()
    for f in ("report.md", "c_rmse.png", "c_set_metrics.png", "trajectories.png"):
        assert (tmp_path / "out" / f).is_file(), f


def test_a_single_target_method_through_the_interface_is_the_direct_call(tmp_path):
    path = two_drones(tmp_path)
    setup = prepare(load_scenario(path))
    case = setup.cases[0]
    truth, products = draw_block(setup, 0, 1)
    est = call_method(setup, setup.methods[0], case, products, (5, 0, 1))
    s, m = products["measurements"], setup.models
    for t, (k0, k1) in enumerate(((0, 60), (20, 100))):
        prior = Gaussian(s.prior.x[:, t], s.prior.P[:, t])
        direct = ekf(prior, s.z[:, t, k0:k1], m.motion, m.dt, m.q, m.model, m.R)
        assert torch.equal(est.x[:, k0:k1, t], direct.x) and torch.equal(est.P[:, k0:k1, t], direct.P)
        assert est.exists[:, k0:k1, t].all() and not est.exists[:, :k0, t].any() and not est.exists[:, k1:, t].any()
        # the prior is the truth at the drone's birth plus a draw: the same for both products
        assert torch.equal(products["detections"].prior.x[:, t], s.prior.x[:, t])
        assert torch.isnan(truth.x[:, :k0, t]).all() and torch.isfinite(truth.x[:, k0:k1, t]).all()


def test_one_target_case_through_the_interface_is_the_direct_call(tmp_path):
    sc = scenario_from_dict({"name": "one", "mc_runs": 2, "block_runs": 2, "warmup_steps": 10,
                             "cases": [{"name": "c", **FLIGHT}], "methods": [{"name": "UKF", "kind": "ukf"}]}, tmp_path)
    setup = prepare(sc)
    _, products = draw_block(setup, 0, 0)
    z, prior = stream_block(setup, 0, 0)
    m = setup.models
    from pmsr_nn.filters import ukf

    est = call_method(setup, setup.methods[0], setup.cases[0], products, (0, 0, 0))
    assert torch.equal(est.x[:, :, 0], ukf(prior, z, m.motion, m.dt, m.q, m.model, m.R).x)


def test_detections_have_no_target_outside_its_life(tmp_path):
    setup = prepare(load_scenario(two_drones(tmp_path)))
    truth, products = draw_block(setup, 0, 0)
    origin = products["detections"].scans.origin  # (B, K, sensors, M)
    assert not (origin[:, 60:] == 0).any() and not (origin[:, :20] == 1).any()
    assert (origin[:, :60] == 0).any() and (origin[:, 20:] == 1).any()


def test_a_new_method_kind_is_one_registration(tmp_path):
    """A tracker that reports each target's truth at birth, held: registered here, run by evaluate."""

    def hold(call):
        z, prior = call.product.z, call.product.prior  # (B, N, K, m), x (B, N, n)
        B, N, K, _ = z.shape
        x = prior.x[:, None].expand(B, K, N, prior.x.shape[-1]).clone()
        return Estimates(x, call.alive.expand(B, K, N))

    register(MethodKind("hold_prior", "measurements", hold, description="test: the prior, held"))
    try:
        res = evaluate(two_drones(tmp_path, methods=[{"name": "hold", "kind": "hold_prior"},
                                                     {"name": "EKF", "kind": "ekf"}]),
                       tmp_path / "out", progress=False)
        rows = res["cases"]["c"]["methods"]
        assert rows["hold"]["anees"] is None and rows["hold"]["rmse_pos_m"] > rows["EKF"]["rmse_pos_m"]
    finally:
        del REGISTRY["hold_prior"]


@pytest.mark.integration
def test_shards_of_a_multi_target_scenario_merge_to_the_whole(tmp_path):
    path = two_drones(tmp_path, mc_runs=6)
    whole = evaluate(path, tmp_path / "whole", progress=False)
    for i in (1, 2):
        evaluate(path, tmp_path / f"s{i}", shard=(i, 2), progress=False)
    merged = merge([tmp_path / "s2", tmp_path / "s1"], tmp_path / "merged")
    strip = lambda r: {m: {k: v for k, v in row.items() if k != "seconds_per_run"}
                       for m, row in r["cases"]["c"]["methods"].items()}
    assert strip(merged) == strip(whole)
    assert merged["cases"]["c"]["curves"]["set"] == whole["cases"]["c"]["curves"]["set"]
    # overlapping shards (the same blocks from two runs) are refused, nothing written
    evaluate(path, tmp_path / "again1", shard=(1, 2), progress=False)
    with pytest.raises(ConfigError, match="each needed exactly once"):
        merge([tmp_path / "s1", tmp_path / "again1", tmp_path / "s2"], tmp_path / "bad")
    assert not (tmp_path / "bad").exists()


@pytest.mark.parametrize("change, message", [
    ({"methods": [{"name": "X", "kind": "jpda9000"}]}, "unknown method kind 'jpda9000'"),
    ({"detections": None, "random_streams": "per_block"}, "reads detections, which this scenario does not make"),
    ({"random_streams": "per_block"}, "set random_streams: per_product"),
    ({"cases": [{"name": "c", "targets": [{"name": "a", "birth_s": 50.0, "death_s": 40.0, **FLIGHT}]}]},
     "death before birth"),
    ({"cases": [{"name": "c", "targets": [{"name": "a", **{**FLIGHT, "start_range_m": 60000.0}}]}]}, "envelope"),
    ({"cases": [{"name": "c", "targets": [{"name": "a", "death_s": 5.0, **FLIGHT}]}]}, "warmup_steps 10"),
])
def test_bad_scenarios_are_one_line_errors_and_write_nothing(tmp_path, capsys, change, message):
    path = two_drones(tmp_path, **change)
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["evaluate", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pmsr: error:") and message in err and "\n" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_the_report_shows_every_method_and_the_set_metrics(tmp_path):
    evaluate(two_drones(tmp_path, mc_runs=2), tmp_path / "out", progress=False)
    report = (tmp_path / "out" / "report.md").read_text()
    for text in ("| EKF | measurements (association known) |", "| S-MSJPDA | detections (oracle births) |", "OSPA (m)", "GOSPA (m)", "Random streams: per_product"):
        assert text in report, text
    res = json.loads((tmp_path / "out" / "results.json").read_text())
    assert res["settings"]["methods"]["S-MSJPDA"]["reads"] == "detections"
    row = res["cases"]["c"]["methods"]["S-MSJPDA"]
    shares = sum(row[f"gospa_{p}_share"] for p in ("localisation", "missed", "false"))
    assert shares == pytest.approx(1.0)
    # every row in one table: its cells are the results' figures
    table = report.split("Every row in one table (2 runs;", 1)[1].split("\n\n", 2)[1].splitlines()
    line = next(r for r in table if r.startswith("| S-MSJPDA |")).split(" | ")
    assert line[2] == f"{row['gospa_m']:.1f} ± {row['gospa_se_m']:.1f}"
    assert line[3] == f"{row['gospa_median_run_m']:.1f}" and line[5] == f"{row['ospa_m']:.1f} ± {row['ospa_se_m']:.1f}"
    assert line[7] == f"{row['confirmed_tracks_per_target']:.2f}"
    assert len(table) == 2 + len(res["cases"]["c"]["methods"])
    # each run's GOSPA: the quartiles, the 90 % point and the worst of the two runs
    spread = report.split("Each run's GOSPA (m) over the 2 runs", 1)[1].split("\n\n", 2)[1].splitlines()
    cells = next(r for r in spread if r.startswith("| S-MSJPDA |")).strip(" |").split(" | ")[1:]
    assert cells == [f"{v:.1f}" for v in row["gospa_run_quantiles_m"]] and len(cells) == 5
    assert row["gospa_run_quantiles_m"][1] == pytest.approx(row["gospa_median_run_m"], rel=1e-12)
