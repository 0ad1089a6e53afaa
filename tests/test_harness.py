"""The evaluation harness: scenarios, designed trajectories, same draws for every method,
reproducibility, shards, the report, and bad input."""

import json
import math
from pathlib import Path

import pytest
import torch
import yaml

from pmsr_nn.cli import main
from pmsr_nn.errors import CheckpointError, ConfigError, OutputError
from pmsr_nn.filters import ekf
from pmsr_nn.harness import evaluate, load_scenario, merge
from pmsr_nn.harness.run.blocks import stream_block as draw_block
from pmsr_nn.harness.run.runner import prepare
from pmsr_nn.harness.scenario.case_spec import FITEE2023_TRAJECTORIES, CaseSpec, SegmentSpec
from pmsr_nn.harness.scenario.schema import scenario_from_dict
from pmsr_nn.harness.scenario.trajectories import design_trajectory
from pmsr_nn.simulation.recipe import TrackRecipe

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "evaluate" / "fitee2023_three_trajectories.yaml"


def tiny(tmp_path: Path, **over) -> dict:
    """A small scenario: two 100-s cases (the MDFNN's window), 4 runs in blocks of 2, EKF, UKF, SI+KF and a released MDFNN."""
    d = {
        "name": "tiny", "seed": 3, "mc_runs": 4, "block_runs": 2, "warmup_steps": 50,
        "reference": {"file": str(ROOT / "evaluate/reference/paper_tables.json"),
                      "table": "fitee2023_mdfnn.table6_methods_rmse_pos_m"},
        "cases": [
            {"name": "trajectory_1", "start_range_m": 4000.0, "start_bearing_deg": 130.0, "speed_mps": 10.0,
             "heading_deg": 20.0, "segments": [{"duration_s": 100.0}]},
            {"name": "trajectory_3", "start_range_m": 7800.0, "start_bearing_deg": 140.0, "speed_mps": 12.0,
             "heading_deg": 0.0, "segments": [{"duration_s": 30.0}, {"duration_s": 70.0, "across_mps2": 0.02}]},
        ],
        "methods": [{"name": "EKF", "kind": "ekf"}, {"name": "UKF", "kind": "ukf"}, {"name": "SI+KF", "kind": "si_kf"},
                    {"name": "MDFNN", "kind": "learned", "checkpoint": str(ROOT / "models/released/mdfnn.pt")}],
    }
    d.update(over)
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


def accuracy(res: dict) -> dict:
    """Everything of a results dict except the timings and the environment."""
    return {c: {"methods": {m: {k: v for k, v in r.items() if k != "seconds_per_run"} for m, r in v["methods"].items()},
                "pcrb": v["pcrb"], "curves": v["curves"]} for c, v in res["cases"].items()}


# -- scenarios and trajectories ------------------------------------------------------------------

def test_shipped_scenario_loads_and_its_cases_are_the_built_in_ones():
    sc = load_scenario(SHIPPED)
    assert sc.cases == FITEE2023_TRAJECTORIES
    seeds = [f"{n} [seed {k}]" for n in ("MDFNN local", "KalmanNet", "KalmanNet, whole sequence",
                                          "KalmanNet 300-scan training, whole sequence") for k in range(3)]
    assert [m.name for m in sc.methods] == ["EKF", "UKF", "SI+KF", "PF", "DFNN", "MDFNN", "RNN", *seeds]
    assert [m.options.get("inference") for m in sc.methods if "whole" in m.name] == ["whole_sequence"] * 6
    assert sc.mc_runs == 100 and sc.noise.si() == (30.0, 2.0, math.radians(3.0))
    for m in sc.methods:
        if m.checkpoint:
            assert sc.path(m.checkpoint).is_file(), m.checkpoint


def test_designed_trajectories_follow_their_kinematics():
    recipe = TrackRecipe()
    dt = recipe.motion.dt_s
    t = torch.arange(1000, dtype=torch.float64) * dt
    steady, accel, turn = (design_trajectory(c, recipe, 60.0) for c in FITEE2023_TRAJECTORIES)
    # steady flight: straight line at constant velocity (closed form)
    v = steady[0, [1, 4]]
    assert torch.allclose(steady[:, [0, 3]], steady[0, [0, 3]] + t[:, None] * v, atol=1e-6)
    # sustained acceleration along a straight path: s = v0 t + a t^2 / 2
    s = torch.linalg.vector_norm(accel[:, [0, 3]] - accel[0, [0, 3]], dim=-1)
    assert torch.allclose(s, 5.0 * t + 0.5 * 0.015 * t**2, atol=1e-6)
    # the turn: constant speed; heading change = integral of across / v (60-s linear ramp, then held)
    speed = torch.linalg.vector_norm(turn[:, [1, 4]], dim=-1)
    assert torch.allclose(speed, torch.full_like(speed, 12.0), atol=1e-9)
    heading = torch.atan2(turn[-1, 1], turn[-1, 4])
    expected = 0.02 / 12.0 * (700.0 - 1.0 - 30.0)  # the ramp loses half its length; the last sample is at 999 s
    assert float(heading) == pytest.approx(expected, abs=2e-3)
    # the stored acceleration is the true one: it matches a central difference of the velocity
    dv = (turn[2:, [1, 4]] - turn[:-2, [1, 4]]) / (2 * dt)
    assert torch.allclose(dv[400:], turn[1:-1][400:, [2, 5]], atol=1e-6)


def test_a_trajectory_leaving_the_envelope_is_refused(tmp_path):
    sc = load_scenario(tiny(tmp_path, cases=[{"name": "far", "start_range_m": 10500.0, "start_bearing_deg": 90.0,
                                               "speed_mps": 20.0, "heading_deg": 90.0, "segments": [{"duration_s": 200.0}]}]))
    with pytest.raises(ConfigError, match="leaves the recipe's envelope"):
        prepare(sc)


# -- the same draws for every method, and what the figures mean ----------------------------------

def test_every_method_sees_the_same_draws_and_the_rmse_is_eq31(tmp_path):
    out = tmp_path / "out"
    res = evaluate(tiny(tmp_path), out, progress=False)
    sc = load_scenario(tmp_path / "tiny.yaml")
    setup = prepare(sc)
    case = setup.cases[0]
    zs, priors = zip(*(draw_block(setup, 0, b) for b in range(sc.n_blocks)))
    z = torch.cat(zs)
    x0, P0 = torch.cat([p.x for p in priors]), torch.cat([p.P for p in priors])
    from pmsr_nn.filters import Gaussian

    m = setup.models
    x = ekf(Gaussian(x0, P0), z, m.motion, m.dt, m.q, m.model, m.R).x
    err2 = ((x - case.truth.x[:, 0])[..., [0, 3]] ** 2).sum(-1)  # (runs, K)
    curve = err2.mean(0).sqrt()
    r = res["cases"]["trajectory_1"]["methods"]["EKF"]
    w = sc.warmup_steps
    assert r["rmse_pos_m"] == pytest.approx(float(curve[w:].mean()), rel=1e-12)
    assert r["rmse_pos_pooled_m"] == pytest.approx(float(err2[:, w:].mean().sqrt()), rel=1e-12)
    # the measurements are the truth plus noise of the scenario's deviations
    resid = m.model.residual(z, m.model.h(case.truth.x[:, 0]))
    std = resid.reshape(-1, resid.shape[-1]).std(0)
    assert torch.allclose(std, m.model.std_vector(m.noise_std), rtol=0.15)  # 600 samples: 99.9 % within ~10 %
    for f in ("results.json", "report.md", "trajectories.png", "trajectory_1_rmse.png", "trajectory_3_rmse.png"):
        assert (out / f).is_file(), f
    assert set(res["cases"]["trajectory_1"]["methods"]) == {"EKF", "UKF", "SI+KF", "MDFNN"}
    assert {"pmsr_nn", "torch", "device", "threads"} <= set(res["environment"])
    report = (out / "report.md").read_text()
    assert "7.47" in report and "paper" in report  # the paper's EKF number for trajectory_1, labelled
    assert res["cases"]["trajectory_1"]["methods"]["MDFNN"]["causal"] is True


@pytest.mark.integration
def test_same_seed_same_figures_and_shards_merge_to_the_unsharded_run(tmp_path):
    path = tiny(tmp_path)
    a = evaluate(path, tmp_path / "a", progress=False)
    b = evaluate(path, tmp_path / "b", progress=False)
    assert accuracy(a) == accuracy(b)
    evaluate(path, tmp_path / "s1", shard=(1, 2), progress=False)
    evaluate(path, tmp_path / "s2", shard=(2, 2), progress=False)
    assert not (tmp_path / "s1" / "results.json").exists()
    merged = merge([tmp_path / "s2", tmp_path / "s1"], tmp_path / "m")
    assert accuracy(merged) == accuracy(a)  # bit for bit: the same per-block sums reduced in the same order
    assert json.loads((tmp_path / "m" / "results.json").read_text())["mc_runs"] == 4
    c = evaluate(tiny(tmp_path, seed=4), tmp_path / "c", progress=False)
    assert accuracy(c) != accuracy(a)


def test_merge_refuses_incomplete_or_mixed_shards(tmp_path):
    path = tiny(tmp_path)
    evaluate(path, tmp_path / "s1", shard=(1, 2), progress=False)
    with pytest.raises(ConfigError, match="each needed exactly once"):
        merge([tmp_path / "s1"], tmp_path / "m")
    evaluate(tiny(tmp_path, seed=9), tmp_path / "t2", shard=(2, 2), progress=False)
    with pytest.raises(ConfigError, match="another scenario"):
        merge([tmp_path / "s1", tmp_path / "t2"], tmp_path / "m")
    (tmp_path / "plain").mkdir()
    with pytest.raises(ConfigError, match="not a shard folder"):
        merge([tmp_path / "plain"], tmp_path / "m")
    assert not (tmp_path / "m").exists()



def test_every_entry_path_hands_one_run_to_execute(tmp_path, monkeypatch):
    """evaluate, a shard, ``--per-block`` and merge each build a Run (output checked, scenario
    prepared) and hand it to the one function that writes; nothing is written before it."""
    import importlib

    entry = importlib.import_module("pmsr_nn.harness.evaluate")  # the module (the package's name is the function)
    path = tiny(tmp_path, mc_runs=2, block_runs=1)
    evaluate(path, tmp_path / "s1", shard=(1, 2), progress=False)
    evaluate(path, tmp_path / "s2", shard=(2, 2), progress=False)
    seen = []
    monkeypatch.setattr(entry, "execute", lambda run: seen.append(run) or {})
    evaluate(path, tmp_path / "whole", progress=False)
    evaluate(path, tmp_path / "shard", shard=(2, 2), progress=False)
    assert main(["evaluate", str(path), "--out", str(tmp_path / "bank"), "--per-block", "--quiet"]) == 0
    merge([tmp_path / "s2", tmp_path / "s1"], tmp_path / "merged")
    assert [(r.target, list(r.blocks), r.out.name) for r in seen] == [
        ("results", [0, 1], "whole"), ("shard", [1], "shard"), ("bank", [0, 1], "bank"), ("results", [], "merged")]
    assert [r.sums is None for r in seen] == [True, True, True, False]
    assert seen[-1].sums.blocks == [0, 1] and seen[-1].merged["shard_commits"]  # the shards' sums, in block order
    assert all(r.setup.scenario.mc_runs == 2 for r in seen)
    assert not any((tmp_path / name).exists() for name in ("whole", "shard", "bank", "merged"))

# -- bad input: one line, exit 2, nothing written -----------------------------------------------

@pytest.mark.parametrize("change, extra, message", [
    ({"methods": [{"name": "X", "kind": "kalman9000"}]}, [], "unknown method kind"),
    ({"methods": [{"name": "X", "kind": "ukff"}]}, [], "unknown method kind 'ukff' (did you mean ukf?)"),
    ({"methods": [{"name": "X", "kind": "modified-ICMB"}]}, [], "unknown method kind 'modified-ICMB' (did you mean "
                                                                 "modified_icmb"),
    ({"methods": [{"name": "M", "kind": "learned", "checkpoint": "nowhere.pt"}]}, [], "nowhere.pt"),
    ({"cases": [{"name": "e", "start_range_m": 5000.0, "start_bearing_deg": 90.0, "speed_mps": 1.0,
                 "heading_deg": 0.0, "segments": []}]}, [], "trajectory is empty"),
    ({}, ["--shard", "3/2"], "1 <= I <= N"),
    ({}, ["--shard", "2/3"], "only 2 block"),
    ({}, ["--checkpoint", "EKF=x.pt"], "which reads no checkpoint"),
    ({"methods": [{"name": "EKF", "kind": "ekf", "options": {"particles": 5}}]}, [], "unknown option"),
])
def test_bad_scenarios_get_one_line_errors_and_leave_nothing(tmp_path, capsys, change, extra, message):
    path = tiny(tmp_path, **change)
    out = tmp_path / "out"
    assert main(["evaluate", str(path), "--out", str(out), "--quiet", *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pmsr: error:") and message in err and "\n" not in err
    assert not out.exists()
    assert not list(tmp_path.glob("out.partial-*"))



@pytest.mark.parametrize("extra", [[], ["--shard", "1/2"], ["--per-block"]])
def test_a_bad_reference_entry_is_refused_before_any_run_by_every_entry_path(tmp_path, capsys, extra):
    path = tiny(tmp_path, methods=[{"name": "EKF", "kind": "ekf"}], mc_runs=2, block_runs=1,
                reference={"file": str(ROOT / "evaluate/reference/paper_tables.json"), "table": "no.such.table"})
    out = tmp_path / "out"
    assert main(["evaluate", str(path), "--out", str(out), "--quiet", *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pmsr: error:") and "has no entry 'no.such.table'" in err and "\n" not in err
    assert not out.exists()

def test_a_checkpoint_for_another_geometry_is_refused(tmp_path):
    recipe = yaml.safe_load((ROOT / "datasets/fitee2023_ca.yaml").read_text())
    recipe["geometry"]["receivers"][0]["bearing_deg"] = 200.0
    (tmp_path / "recipe.yaml").write_text(yaml.safe_dump(recipe))
    sc = load_scenario(tiny(tmp_path, recipe=str(tmp_path / "recipe.yaml")))
    with pytest.raises(CheckpointError, match="another sensor geometry"):
        prepare(sc)


def test_a_checkpoint_for_another_pair_count_is_refused_in_one_readable_line(tmp_path, capsys):
    """The released MDFNN reads 1 transmitter x 3 receivers; a recipe with 2 receivers gives 2 pairs.
    The line names the row and the checkpoint and says what differs, uncut (it once ended mid-word)."""
    recipe = yaml.safe_load((ROOT / "datasets/fitee2023_ca.yaml").read_text())
    recipe["geometry"]["receivers"] = recipe["geometry"]["receivers"][:2]
    (tmp_path / "recipe.yaml").write_text(yaml.safe_dump(recipe))
    path = tiny(tmp_path, recipe=str(tmp_path / "recipe.yaml"))
    assert main(["evaluate", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and not err.endswith("...") and not (tmp_path / "out").exists()
    assert err.startswith("pmsr: error: scenario 'tiny', row 'MDFNN': the checkpoint ")
    assert str(ROOT / "models/released/mdfnn.pt") in err
    assert err.endswith("expects 3 pairs (9 columns: range, range_rate, azimuth); "
                        "the scenario gives 2 pairs (6 columns: range, range_rate, azimuth)")

def test_overwrite_replaces_only_what_evaluate_wrote(tmp_path):
    user = tmp_path / "out"
    user.mkdir()
    (user / "keep.txt").write_text("mine")
    path = tiny(tmp_path, methods=[{"name": "EKF", "kind": "ekf"}], mc_runs=2)
    for overwrite in (False, True):  # a folder the user wrote is never replaced, --overwrite or not
        with pytest.raises(OutputError, match="not written by pmsr"):
            evaluate(path, user, progress=False, overwrite=overwrite)
    assert [p.name for p in user.iterdir()] == ["keep.txt"] and (user / "keep.txt").read_text() == "mine"
    ours = tmp_path / "ours"
    evaluate(path, ours, progress=False)
    with pytest.raises(OutputError, match="pass --overwrite"):
        evaluate(path, ours, progress=False)
    first = (ours / "results.json").read_text()
    evaluate(path, ours, progress=False, overwrite=True)
    assert (ours / "results.json").is_file() and (ours / ".pmsr_output.json").is_file()
    rmse = lambda text: {c: v["methods"]["EKF"]["rmse_pos_m"] for c, v in json.loads(text)["cases"].items()}
    assert rmse((ours / "results.json").read_text()) == rmse(first)  # the same draws, replaced whole
    assert sorted(p.name for p in tmp_path.iterdir() if ".partial" in p.name or ".old-" in p.name) == []


def test_overwrite_never_deletes_a_file_a_user_added_to_our_output(tmp_path, capsys):
    path = tiny(tmp_path, methods=[{"name": "EKF", "kind": "ekf"}], mc_runs=2)
    ours = tmp_path / "ours"
    evaluate(path, ours, progress=False)
    listed = json.loads((ours / ".pmsr_output.json").read_text())["contents"]
    assert listed == sorted(p.name for p in ours.iterdir() if p.name != ".pmsr_output.json")
    (ours / "notes.txt").write_text("my notes")
    (ours / "figs").mkdir()
    before = sorted((p.relative_to(tmp_path).as_posix(), p.stat().st_mtime_ns) for p in tmp_path.rglob("*"))
    assert main(["evaluate", str(path), "--out", str(ours), "--overwrite", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"pmsr: error: --out {ours} holds files pmsr did not write (figs, notes.txt); pmsr never deletes "
                   "what it did not write: move them out or choose another path")
    assert sorted((p.relative_to(tmp_path).as_posix(), p.stat().st_mtime_ns) for p in tmp_path.rglob("*")) == before
    (ours / "notes.txt").unlink()
    (ours / "figs").rmdir()
    evaluate(path, ours, progress=False, overwrite=True)  # ours alone again: replaced
    assert not (ours / "notes.txt").exists() and (ours / "results.json").is_file()


def test_checkpoint_override_swaps_a_learned_method(tmp_path):
    path = tiny(tmp_path, mc_runs=2)
    res = evaluate(load_scenario(path).with_checkpoints({"MDFNN": str(ROOT / "models/released/dfnn.pt")}),
                   tmp_path / "o", progress=False)
    assert res["cases"]["trajectory_1"]["methods"]["MDFNN"]["model"] == "dfnn"


def test_scenario_errors_name_the_key():
    with pytest.raises(ConfigError, match="did you mean 'mc_runs'"):
        scenario_from_dict({"name": "x", "mc_run": 3, "cases": [], "methods": []})
    with pytest.raises(ConfigError, match="duplicate case"):
        c = CaseSpec("a", 5000.0, 90.0, 1.0, 0.0, (SegmentSpec(200.0),))
        from pmsr_nn.harness.scenario.method_spec import MethodSpec
        from pmsr_nn.harness.scenario.schema import Scenario

        Scenario(name="x", cases=(c, c), methods=(MethodSpec("EKF", "ekf"),))


def test_learned_rows_get_their_finite_memory_bound_seed_summary_and_paired_margin(tmp_path):
    """Two 'seeds' (the released MDFNN and DFNN under one name): each row's finite-memory bound is
    the filtering PCRB of only the scans it reads, recomputed here window by window with the plain
    PCRB; the seed group's figures are the rows' mean and extremes."""
    from pmsr_nn.bounds import pcrb
    from pmsr_nn.nets.inference import Tracker

    methods = [{"name": "EKF", "kind": "ekf"}, {"name": "UKF", "kind": "ukf"},
               {"name": "NN [seed 0]", "kind": "learned", "checkpoint": str(ROOT / "models/released/mdfnn.pt")},
               {"name": "NN [seed 1]", "kind": "learned", "checkpoint": str(ROOT / "models/released/dfnn.pt")}]
    path = tiny(tmp_path, methods=methods, mc_runs=2, block_runs=1)
    res = evaluate(path, tmp_path / "o", progress=False)
    sc = load_scenario(path)
    setup = prepare(sc)
    case, w = setup.cases[1], sc.warmup_steps
    m = setup.models
    rows = res["cases"][case.name]["methods"]
    for name, ckpt, scans in (("NN [seed 0]", "mdfnn.pt", 39), ("NN [seed 1]", "dfnn.pt", 1)):
        t = Tracker.load(ROOT / "models/released" / ckpt)
        assert rows[name]["memory_scans"] == scans
        per_step = [float(pcrb(case.truth.x[None, k - scans + 1 : k + 1, 0], m.motion, m.dt, m.q, m.model, m.R,
                               t.training_spread(), smoothing=False).position_rmse()[-1])
                    for k in range(w, case.steps)]
        assert rows[name]["memory_bound_pos_m"] == pytest.approx(sum(per_step) / len(per_step), rel=1e-9)
        assert rows[name]["over_memory_bound"] == pytest.approx(rows[name]["rmse_pos_m"] / rows[name]["memory_bound_pos_m"])
    g = res["cases"][case.name]["seed_groups"]["NN"]
    a, b = rows["NN [seed 0]"]["rmse_pos_m"], rows["NN [seed 1]"]["rmse_pos_m"]
    assert g["seeds"] == 2 and g["rmse_pos_m"]["mean"] == pytest.approx((a + b) / 2)
    assert (g["rmse_pos_m"]["min"], g["rmse_pos_m"]["max"]) == (min(a, b), max(a, b))
    (comp,) = res["cases"][case.name]["comparisons"]
    best = min(("EKF", "UKF"), key=lambda n: rows[n]["rmse_pos_m"])
    assert comp["learned"] == "NN" and comp["seeds"] == 2 and comp["classical"] == best and comp["runs"] == 2
    assert comp["margin_m"] < 0  # networks ~100 m against an EKF's ~10 m
    report = (tmp_path / "o" / "report.md").read_text()
    for heading in ("finite-memory bound", "over training seeds", "best classical method"):
        assert heading in report
