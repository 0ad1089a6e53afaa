"""The pmsr command: every bad input is a one-line error, a non-zero exit, and nothing written."""

import json
import math
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from pmsr_nn.cli import main
from pmsr_nn.simulation.recipe import SplitSpec

ROOT = Path(__file__).resolve().parents[1]
RECIPE = ROOT / "datasets" / "fitee2023_ca.yaml"


def small_recipe_dict(**changes):
    d = yaml.safe_load(RECIPE.read_text())
    d["tracks"] = 24
    d["window"] = 10
    d["motion"]["steps"] = 60
    for dotted, value in changes.items():
        node = d
        *path, last = dotted.split(".")
        for k in path:
            node = node[k]
        node[last] = value
    return d


def run(tmp_path, capsys, recipe: dict, *extra, out="out"):
    path = tmp_path / "recipe.yaml"
    path.write_text(yaml.safe_dump(recipe))
    rc = main(["simulate", str(path), "--out", str(tmp_path / out), "--quiet", *extra])
    err = capsys.readouterr().err.strip()
    return rc, err


def test_simulate_writes_a_dataset(tmp_path, capsys):
    rc, err = run(tmp_path, capsys, small_recipe_dict())
    assert rc == 0 and err == ""
    assert (tmp_path / "out" / "manifest.json").is_file()


@pytest.mark.parametrize("change,message", [
    ({"trackz": 5}, "unknown key 'trackz' (did you mean 'tracks'?)"),
    ({"noise.range_mm": [1, 2]}, "unknown key 'range_mm'"),
    ({"noise.range_m": [-5.0, 30.0]}, "noise.range_m: must be positive"),
    ({"noise.azimuth_deg": [0.0, 0.0]}, "noise.azimuth_deg: must be positive"),
    ({"window": 61}, "window of 61 samples is longer than the track (60 samples)"),
    ({"geometry.receivers": [{"position_m": [0.0, 0.0]}]}, "receiver 0 is placed on transmitter 0"),
    ({"motion.q_psd": "four"}, "recipe.motion.q_psd: expected a number, got 'four'"),
    ({"tracks": "many"}, "recipe.tracks: expected an integer"),
    ({"variant": "loose"}, "must be one of ['envelope', 'literal']"),
    ({"splits": {"train": 0.9, "val": 0.2, "test": 0.05}}, "sum to 1"),
])
def test_bad_recipes(tmp_path, capsys, change, message):
    recipe = small_recipe_dict()
    for k, v in change.items():
        node = recipe
        *path, last = k.split(".")
        for p in path:
            node = node[p]
        node[last] = v
    rc, err = run(tmp_path, capsys, recipe)
    assert rc == 2
    assert err.startswith("pmsr: error: ") and len(err.splitlines()) == 1
    assert message in err
    assert not (tmp_path / "out").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["recipe.yaml"]


def test_output_path_that_is_not_ours(tmp_path, capsys):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "thesis.tex").write_text("precious")
    rc, err = run(tmp_path, capsys, small_recipe_dict(), "--overwrite")
    assert rc == 2 and "exists and is not a pmsr_nn dataset" in err
    assert (tmp_path / "out" / "thesis.tex").read_text() == "precious"
    (tmp_path / "file").write_text("x")
    rc, err = run(tmp_path, capsys, small_recipe_dict(), out="file")
    assert rc == 2 and "not a pmsr_nn dataset" in err


def test_missing_and_malformed_recipe_files(tmp_path, capsys):
    assert main(["simulate", str(tmp_path / "none.yaml"), "--out", str(tmp_path / "o")]) == 2
    assert "config file not found" in capsys.readouterr().err
    bad = tmp_path / "bad.yaml"
    bad.write_text("tracks: [1, 2\n")
    assert main(["simulate", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "not valid YAML" in capsys.readouterr().err


def test_non_numeric_command_line_value(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["simulate", str(RECIPE), "--out", str(tmp_path / "o"), "--tracks", "abc"])
    assert exc.value.code == 2
    assert "expected a positive integer, got 'abc'" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def manifest(path: Path) -> dict:
    return json.loads((path / "manifest.json").read_text())


def test_too_few_tracks_for_the_splits_give_a_dataset_without_splits(tmp_path, capsys):
    """The issue's ``pmsr simulate datasets/fitee2023_ca.yaml --tracks 4``: every track a test track, and a
    summary line that says so (and why) instead of an error."""
    assert main(["simulate", str(RECIPE), "--out", str(tmp_path / "x4"), "--tracks", "4"]) == 0
    out, err = capsys.readouterr()
    assert err == "" and manifest(tmp_path / "x4")["splits"] == {"train": 0, "val": 0, "test": 4}
    line = next(ln for ln in out.splitlines() if ln.startswith("splits"))
    assert line == ("splits    none: all 4 tracks are test tracks, for tracking, not training; 4 tracks are too few "
                    "for the recipe's train/val/test split 0.85/0.1/0.05, which needs at least 11")
    assert main(["info", str(tmp_path / "x4"), "--verify"]) == 0
    assert "splits    none: all 4 tracks are test tracks, for tracking, not training\n" in capsys.readouterr().out


def test_splits_where_the_tracks_fill_them(tmp_path, capsys):
    need = SplitSpec(0.85, 0.10, 0.05).min_tracks()  # the fractions of small_recipe_dict
    assert need == 11  # test round(10 * 0.05) = 0
    for tracks, want in ((need, {"train": 9, "val": 1, "test": 1}), (need - 1, {"train": 0, "val": 0, "test": 10})):
        rc, err = run(tmp_path, capsys, small_recipe_dict(), "--tracks", str(tracks), out=f"n{tracks}")
        assert rc == 0 and err == "" and manifest(tmp_path / f"n{tracks}")["splits"] == want
    rc, err = run(tmp_path, capsys, small_recipe_dict(tracks=3), out="yaml3")  # the recipe's own count, too
    assert rc == 0 and manifest(tmp_path / "yaml3")["splits"] == {"train": 0, "val": 0, "test": 3}
    rc, err = run(tmp_path, capsys, small_recipe_dict(), "--no-splits", out="asked")
    m = manifest(tmp_path / "asked")
    assert rc == 0 and m["splits"] == {"train": 0, "val": 0, "test": 24}
    assert m["recipe"]["splits"] == {"train": 0.0, "val": 0.0, "test": 1.0} and m["normalisation"]["fitted_on"] == "all"
    # where the tracks fill it the recipe keeps its own split; the tracks are the same either way
    rc, err = run(tmp_path, capsys, small_recipe_dict(), out="split")
    assert manifest(tmp_path / "split")["recipe"]["splits"] == {"train": 0.85, "val": 0.10, "test": 0.05}
    assert manifest(tmp_path / "split")["checksums_sha256"]["states"] == m["checksums_sha256"]["states"]


def test_a_dataset_without_splits_written_by_the_recipe_itself(tmp_path, capsys):
    rc, err = run(tmp_path, capsys, small_recipe_dict(splits={"train": 0, "val": 0, "test": 1}))
    assert rc == 0 and manifest(tmp_path / "out")["splits"] == {"train": 0, "val": 0, "test": 24}
    rc, err = run(tmp_path, capsys, small_recipe_dict(splits={"train": 0, "val": 0.5, "test": 0.5}), out="o2")
    assert rc == 2 and "the training split cannot be empty" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "o2").exists()


def test_info_renders_a_manifest_with_only_a_test_split(tmp_path, capsys):
    run(tmp_path, capsys, small_recipe_dict(), "--tracks", "3")
    m = manifest(tmp_path / "out")
    m["splits"], m["windows"] = {"test": 3}, {"test": 3 * m["windows_per_track"]}
    (tmp_path / "out" / "manifest.json").write_text(json.dumps(m))
    assert main(["info", str(tmp_path / "out")]) == 0
    assert "splits    none: all 3 tracks are test tracks" in capsys.readouterr().out


def test_paper_scale_split_counts():
    assert SplitSpec().counts(70) == (59, 7, 4)


def test_info_and_verify(tmp_path, capsys):
    run(tmp_path, capsys, small_recipe_dict())
    assert main(["info", str(tmp_path / "out"), "--verify"]) == 0
    out = capsys.readouterr().out
    assert "envelope" in out and "checksums: all arrays match" in out
    assert main(["info", str(tmp_path)]) == 2


@pytest.mark.integration
def test_console_script_help_and_error_without_traceback(tmp_path):
    exe = Path(sys.executable).with_name("pmsr")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "pmsr_nn.cli"]
    helped = subprocess.run([*cmd, "simulate", "--help"], capture_output=True, text=True)
    assert helped.returncode == 0
    for option in ("--out", "--tracks", "--seed", "--variant", "--overwrite"):
        assert option in helped.stdout
    bad = tmp_path / "r.yaml"
    bad.write_text("trackz: 3\n")
    failed = subprocess.run([*cmd, "simulate", str(bad), "--out", str(tmp_path / "o")], capture_output=True, text=True)
    assert failed.returncode == 2
    assert "Traceback" not in failed.stderr and failed.stderr.strip().count("\n") == 0


def test_track_force_past_the_checks_warns_how_many_estimates_are_not_finite(tmp_path, capsys, make_tracks):
    import csv

    from pmsr_nn.data.sequences import write_csv_measurements
    from pmsr_nn.nets.inference import Tracker

    ckpt = ROOT / "models" / "released" / "mdfnn.pt"
    tracker = Tracker.load(ckpt)
    _, _, batch = make_tracks(120, 1, 5)
    z = batch.measurements.double().clone()
    z[0, 60:, :3] = 1e300  # every bistatic range far beyond the training span from row 61 on
    csv_in = tmp_path / "z.csv"
    write_csv_measurements(csv_in, z, tracker.measurement_columns)
    argv = ["track", "--checkpoint", str(ckpt), "--input", str(csv_in)]
    assert main([*argv, "--out", str(tmp_path / "refused.csv")]) == 2  # the plausibility check
    assert "--force" in capsys.readouterr().err and not (tmp_path / "refused.csv").exists()
    assert main([*argv, "--out", str(tmp_path / "est.csv"), "--force"]) == 0
    err = capsys.readouterr().err.strip()
    with open(tmp_path / "est.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    cols = [c for c in rows[0] if c not in ("track", "time_s", "row")]
    bad = [i for i, r in enumerate(rows) if not all(math.isfinite(float(r[c])) for c in cols)]
    assert len(rows) == 120 and bad, "the forced values should break the estimates"
    assert err == (f"warning   {len(bad)} of 120 estimates are not finite (NaN or inf), first at track "
                   f"{rows[bad[0]]['track']!r} row {bad[0] + 1}: the input is outside what the network can track")


COMMANDS = ["simulate", "info", "train", "select", "track", "export", "export-onnx", "evaluate", "front-end", "methods",
            "merge", "compare", "demo"]


def test_every_command_is_listed_in_order_and_has_its_help(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    assert re.findall(r"^    (\S+)", capsys.readouterr().out, re.M) == COMMANDS
    for name in COMMANDS:
        with pytest.raises(SystemExit) as exc:
            main([name, "--help"])
        assert exc.value.code == 0 and capsys.readouterr().out.startswith(f"usage: pmsr {name} [-h] [--debug]")


def test_a_recipe_without_sensors_is_refused_naming_the_file(tmp_path, capsys):
    recipe = small_recipe_dict()
    recipe["geometry"] = {"receivers": []}
    rc, err = run(tmp_path, capsys, recipe)
    assert rc == 2 and err == (f"pmsr: error: {tmp_path / 'recipe.yaml'}: recipe: need at least one transmitter "
                               "and one receiver")


def test_the_train_help_names_every_kind_train_trains(capsys):
    """``pmsr --help`` once said "DFNN / MDFNN / RNN"; every model kind of the training config and
    the tracker on detections (the kind ``pmsr train`` hands to its own trainer) must be named, and
    the set tracker and the hybrid (removed under issue 56) no longer."""
    from typing import get_args, get_type_hints

    from pmsr_nn.nets.config import ModelConfig

    with pytest.raises(SystemExit):
        main(["--help"])
    line = " ".join(re.search(r"^    train +(.*?)\n    select", capsys.readouterr().out, re.M | re.S)[1].split())
    kinds = get_args(get_type_hints(ModelConfig)["kind"])
    assert set(kinds) == {"mdfnn", "dfnn", "rnn", "kalmannet"}
    assert all(k in line.lower() for k in kinds) and "nebp" in line
    assert "set_tracker" not in line and "jpda_gain" not in line


SET_TRACKER_META = {"format": "pmsr_nn.set_tracker", "format_version": 1, "pmsr_nn_version": "0.1.0",
                    "model": {"window": 6, "d_model": 16}, "components": ["range", "range_rate", "azimuth"],
                    "noise_std": [30.0, 2.0, 0.05], "pos_idx": [0, 1, 2], "vel_idx": [3, 4, 5], "dt_s": 1.0,
                    "dim_x": 9, "training": {"seed": 0}}
"""The ``pmsr`` block of a checkpoint of the end-to-end set tracker (``set_metadata`` at 4699b3d,
geometry left out), removed from the package under issue 56."""


def test_a_checkpoint_of_the_removed_set_tracker_is_refused_in_one_line_by_every_reader(tmp_path, capsys):
    """A set-tracker checkpoint given to the package (kind learned, ``pmsr track``, ``pmsr export-onnx``,
    kind nebp) is refused in one line naming what it was and the commit that has its
    code, not read as a foreign file or a crash, and nothing is written."""
    import torch

    from pmsr_nn.errors import CheckpointError
    from pmsr_nn.nets.checkpoint import read_checkpoint
    from pmsr_nn.nets.nebp import load_nebp_checkpoint

    ck = tmp_path / "tracker.pt"
    torch.save({"pmsr": SET_TRACKER_META, "state_dict": {"encoder.weight": torch.zeros(2, 2)}}, ck)
    why = f"{ck} is a checkpoint of the end-to-end set tracker, removed from the package under issue 56"
    for read in (read_checkpoint, load_nebp_checkpoint):  # kind learned, pmsr track / export-onnx; nebp
        with pytest.raises(CheckpointError, match="removed from the package under issue 56") as exc:
            read(ck)
        assert str(exc.value).startswith(why) and "4699b3d" in str(exc.value) and "\n" not in str(exc.value)
    z = tmp_path / "z.csv"
    z.write_text("time_s,r1\n0,1\n")
    for argv in (["track", "--checkpoint", str(ck), "--input", str(z), "--out", str(tmp_path / "est.csv")],
                 ["export-onnx", "--checkpoint", str(ck), "--out", str(tmp_path / "t.onnx")]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"pmsr: error: {why}") and err.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tracker.pt", "z.csv"]


def test_a_set_tracker_training_config_is_refused_in_one_line(tmp_path, capsys):
    """``kind: set_tracker`` (train/set_tracker.yaml at 4699b3d) names what left the package and
    where it is, and writes nothing."""
    config = tmp_path / "set_tracker.yaml"
    config.write_text(yaml.safe_dump({"kind": "set_tracker", "name": "set_tracker", "seed": 0,
                                      "recipe": str(RECIPE), "model": {"d_model": 128}}))
    assert main(["train", str(config), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert err == (f"pmsr: error: {config}: kind set_tracker is the end-to-end set tracker, removed from the package "
                   "under issue 56 (evaluate/RESULTS.md; its code is at commit 4699b3d); this pmsr_nn does not "
                   "train it\n")
    assert not (tmp_path / "run").exists()


HYBRID_META = {"format": "pmsr_nn.jpda_gain", "format_version": 1, "pmsr_nn_version": "0.1.0",
               "model": {"hidden": 32}, "components": ["range", "range_rate", "azimuth"],
               "noise_std": [30.0, 2.0, 0.05], "pos_idx": [0, 1, 2], "vel_idx": [3, 4, 5], "dt_s": 1.0,
               "dim_x": 9, "training": {"seed": 0}}
"""The ``pmsr`` block of a checkpoint of the hybrid tracker (S-MSJPDA with a learned gain, format
``pmsr_nn.jpda_gain`` at c270857, geometry left out), removed from the package under issue 56."""


def test_a_checkpoint_of_the_removed_hybrid_is_refused_in_one_line_by_every_reader(tmp_path, capsys):
    """A hybrid checkpoint (models/released/jpda_gain_s0.pt at c270857) given to kind learned,
    ``pmsr track``, ``pmsr export-onnx`` or kind nebp is refused in one line naming what it was and
    the commit that has its code, and nothing is written."""
    import torch

    from pmsr_nn.errors import CheckpointError
    from pmsr_nn.nets.checkpoint import read_checkpoint
    from pmsr_nn.nets.nebp import load_nebp_checkpoint

    ck = tmp_path / "gain.pt"
    torch.save({"pmsr": HYBRID_META, "state_dict": {"net.0.weight": torch.zeros(2, 2)}}, ck)
    why = (f"{ck} is a checkpoint of the hybrid tracker (S-MSJPDA with a learned gain correction, kind "
           "jpda_learned_gain), removed from the package under issue 56 (evaluate/RESULTS.md; its code is at commit "
           "c270857); no command of this pmsr_nn reads it")
    for read in (read_checkpoint, load_nebp_checkpoint):
        with pytest.raises(CheckpointError) as exc:
            read(ck)
        assert str(exc.value) == why
    z = tmp_path / "z.csv"
    z.write_text("time_s,r1\n0,1\n")
    for argv in (["track", "--checkpoint", str(ck), "--input", str(z), "--out", str(tmp_path / "est.csv")],
                 ["export-onnx", "--checkpoint", str(ck), "--out", str(tmp_path / "t.onnx")]):
        assert main(argv) == 2
        assert capsys.readouterr().err == f"pmsr: error: {why}\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gain.pt", "z.csv"]


def test_a_hybrid_training_config_is_refused_in_one_line(tmp_path, capsys):
    """``kind: jpda_gain`` (train/jpda_gain.yaml at c270857) names what left the package and where
    it is, and writes nothing."""
    config = tmp_path / "jpda_gain.yaml"
    config.write_text(yaml.safe_dump({"kind": "jpda_gain", "name": "jpda_gain", "seed": 0, "recipe": str(RECIPE),
                                      "scenes": {"window": 20, "targets": [2, 2]}}))
    assert main(["train", str(config), "--out", str(tmp_path / "run")]) == 2
    assert capsys.readouterr().err == (
        f"pmsr: error: {config}: kind jpda_gain is the hybrid tracker (S-MSJPDA with a learned gain correction, kind "
        "jpda_learned_gain), removed from the package under issue 56 (evaluate/RESULTS.md; its code is at commit "
        "c270857); this pmsr_nn does not train it\n")
    assert not (tmp_path / "run").exists()


def test_a_scenario_row_of_the_removed_hybrid_kind_is_refused_in_one_line(tmp_path, capsys):
    """A method row of kind jpda_learned_gain (evaluate/one_sky_hybrid.yaml at c270857) is refused
    in one line naming the removal, and nothing is written."""
    path = tmp_path / "hybrid.yaml"
    path.write_text(TINY_SCENARIO.replace("kind: ekf}", "kind: jpda_learned_gain, checkpoint: gain.pt}", 1))
    assert main(["evaluate", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown method kind 'jpda_learned_gain'" in err
    assert "removed from the package under issue 56" in err and "c270857" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hybrid.yaml"]


TINY_SCENARIO = """\
name: tiny
seed: 3
mc_runs: 2
block_runs: 1
warmup_steps: 20
noise: {range_m: 30.0, range_rate_mps: 2.0, azimuth_deg: 3.0}
cases:
  - {name: steady, start_range_m: 4000.0, start_bearing_deg: 130.0, speed_mps: 10.0, heading_deg: 20.0,
     segments: [{duration_s: 60.0}]}
  - {name: ukf_only, methods: [UKF], start_range_m: 6000.0, start_bearing_deg: 40.0, speed_mps: 8.0, heading_deg: 200.0,
     segments: [{duration_s: 60.0}]}
methods:
  - {name: EKF, kind: ekf}
  - {name: UKF, kind: ukf}
"""


def rows(out: Path) -> dict:
    """``{case: {method: position RMSE}}`` of a results.json."""
    res = json.loads((out / "results.json").read_text())
    return {c: {m: r["rmse_pos_m"] for m, r in per["methods"].items()} for c, per in res["cases"].items()}


def test_evaluate_methods_runs_only_the_named_rows_on_the_same_draws(tmp_path, capsys):
    scenario = tmp_path / "tiny.yaml"
    scenario.write_text(TINY_SCENARIO)
    assert main(["evaluate", str(scenario), "--out", str(tmp_path / "all"), "--quiet"]) == 0
    assert main(["evaluate", str(scenario), "--out", str(tmp_path / "ukf"), "--quiet", "--methods", " UKF ,UKF"]) == 0
    everything = rows(tmp_path / "all")
    assert {c: sorted(m) for c, m in everything.items()} == {"steady": ["EKF", "UKF"], "ukf_only": ["UKF"]}
    assert rows(tmp_path / "ukf") == {c: {"UKF": m["UKF"]} for c, m in everything.items()}  # bit for bit
    assert "pcrb" in json.loads((tmp_path / "ukf" / "results.json").read_text())["cases"]["steady"]  # not a row
    assert capsys.readouterr().err == ""


def test_methods_filter_keeps_the_cases_that_run_a_named_row(tmp_path):
    from pmsr_nn.cli.evaluate import keep_methods
    from pmsr_nn.harness.scenario.loading import load_any

    (tmp_path / "tiny.yaml").write_text(TINY_SCENARIO)
    sc = load_any(tmp_path / "tiny.yaml")
    ekf = keep_methods(sc, ["EKF"])  # the case that names only UKF has nothing left to run
    assert [m.name for m in ekf.methods] == ["EKF"] and [c.name for c in ekf.cases] == ["steady"]
    assert ekf.base_dir == sc.base_dir == str(tmp_path)
    ukf = keep_methods(sc, ["UKF"])
    assert [m.name for m in ukf.methods] == ["UKF"] and [(c.name, c.methods) for c in ukf.cases] == [
        ("steady", ()), ("ukf_only", ("UKF",))]


@pytest.mark.parametrize("names,message", [
    ("EKF,PF", "pmsr: error: --methods 'PF': not a row of scenario 'tiny', whose rows are: EKF, UKF\n"),
    ("pf,Ukf", "pmsr: error: --methods 'pf', 'Ukf': not rows of scenario 'tiny', whose rows are: EKF, UKF\n"),
    (",", "pmsr: error: --methods nothing: not rows of scenario 'tiny', whose rows are: EKF, UKF\n"),
])
def test_evaluate_methods_refuses_a_name_that_is_not_a_row(tmp_path, capsys, names, message):
    scenario = tmp_path / "tiny.yaml"
    scenario.write_text(TINY_SCENARIO)
    rc = main(["evaluate", str(scenario), "--out", str(tmp_path / "sub" / "out"), "--methods", names])
    assert rc == 2 and capsys.readouterr().err == message
    assert [p.name for p in tmp_path.iterdir()] == ["tiny.yaml"]  # not even the parent folder


def test_evaluate_seed_draws_the_runs_of_that_seed(tmp_path, capsys):
    """``--seed N`` runs the scenario as if its file said ``seed: N`` (the same figures, bit for
    bit, and N recorded), draws other runs than the file's seed, and reaches ``--methods`` too."""
    scenario = tmp_path / "tiny.yaml"
    scenario.write_text(TINY_SCENARIO)
    (tmp_path / "tiny4.yaml").write_text(TINY_SCENARIO.replace("seed: 3", "seed: 4"))
    assert main(["evaluate", str(scenario), "--out", str(tmp_path / "s3"), "--quiet"]) == 0
    assert main(["evaluate", str(scenario), "--out", str(tmp_path / "s4"), "--quiet", "--seed", "4"]) == 0
    assert main(["evaluate", str(tmp_path / "tiny4.yaml"), "--out", str(tmp_path / "file4"), "--quiet"]) == 0
    assert main(["evaluate", str(scenario), "--out", str(tmp_path / "ukf4"), "--quiet", "--seed", "4",
                 "--methods", "UKF"]) == 0
    assert rows(tmp_path / "s4") == rows(tmp_path / "file4") != rows(tmp_path / "s3")
    assert rows(tmp_path / "ukf4") == {c: {"UKF": m["UKF"]} for c, m in rows(tmp_path / "s4").items()}
    assert json.loads((tmp_path / "s4" / "results.json").read_text())["seed"] == 4
    assert capsys.readouterr().err == ""
    before = sorted(p.name for p in tmp_path.iterdir())
    with pytest.raises(SystemExit) as exc:
        main(["evaluate", str(scenario), "--out", str(tmp_path / "bad"), "--seed", "-1"])
    assert exc.value.code == 2
    assert capsys.readouterr().err == "pmsr: error: argument --seed: expected a non-negative integer, got '-1' (see 'pmsr evaluate --help')\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == before
