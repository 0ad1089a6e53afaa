"""The pmsr command: every bad input is a one-line error, a non-zero exit, and nothing written."""

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


def test_too_few_tracks_for_the_splits(tmp_path, capsys):
    rc, err = run(tmp_path, capsys, small_recipe_dict(), "--tracks", "3")
    assert rc == 2 and "leave the val split empty" in err


def test_paper_scale_split_counts():
    assert SplitSpec().counts(70) == (59, 7, 4)


def test_info_and_verify(tmp_path, capsys):
    run(tmp_path, capsys, small_recipe_dict())
    assert main(["info", str(tmp_path / "out"), "--verify"]) == 0
    out = capsys.readouterr().out
    assert "envelope" in out and "checksums: all arrays match" in out
    assert main(["info", str(tmp_path)]) == 2


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


