"""The training ablation scripts (sequence size, filter order, DFNN vs MDFNN) on a tiny budget."""

import json

import pytest

from script_loader import load_script

TINY = ["--epochs", "1", "--batches", "2", "--tracks", "12", "--mc-runs", "2", "--hidden", "16", "12", "16"]


def script(name):
    return load_script(f"evaluate/{name}.py")


@pytest.mark.slow  # trains and evaluates two networks
def test_filter_order_ablation_trains_evaluates_and_tabulates(tmp_path):
    out = tmp_path / "abl"
    assert script("ablation_filter_order").main(["--values", "5", "10", "--out", str(out), *TINY]) == 0
    res = json.loads((out / "results.json").read_text())
    assert [r["label"] for r in res["rows"]] == ["5", "10"]
    assert [r["model"]["filter_order"] for r in res["rows"]] == [5, 10]
    for r in res["rows"]:
        assert set(r["rmse_pos_m"]) == {"trajectory_1", "trajectory_2", "trajectory_3"}
        # a network trained for two steps is far from the filtering bound
        assert all(v > 2 * r["bound_pos_m"][c] for c, v in r["rmse_pos_m"].items())
    table = (out / "table.md").read_text()
    assert "| 5 |" in table and "1.45" in table  # the paper's M = 10 on trajectory 1, in its labelled column
    assert (out / "rmse.png").is_file()


def test_sequence_size_sets_the_window_and_keeps_samples_per_batch(tmp_path):
    from pmsr_nn.harness.ablation import Budget, train_config

    mod = script("ablation_sequence_size")
    s = mod.settings(["10", "700"], [16, 12, 16])
    assert [w for _, w in s.values()] == [10, 700]
    b = Budget()
    c10, c700 = (train_config("x", m, w, b, tmp_path) for m, w in s.values())
    assert c10.data.window == 10 and c10.data.batch_size * 10 == b.samples_per_batch
    assert c700.data.window == 700 and c700.data.batch_size == b.samples_per_batch // 700


@pytest.mark.parametrize("name, values", [("ablation_sequence_size", ["1"]), ("ablation_filter_order", ["x"]),
                                          ("ablation_dfnn_vs_mdfnn", ["CNN"])])
def test_bad_values_are_one_line_errors(tmp_path, capsys, name, values):
    out = tmp_path / "o"
    assert script(name).main(["--values", *values, "--out", str(out), *TINY]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and err.count("\n") == 1
    assert not out.exists()
