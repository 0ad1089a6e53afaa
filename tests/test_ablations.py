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
    rows = [ln for ln in table.splitlines() if ln.startswith("| 5 |") or ln.startswith("| 10 |")]
    assert all(float(ln.split("|")[-2]) > 0 for ln in rows)  # the real training time, never "train s 0"
    # finished: refused without --overwrite; replaced whole with it, nothing left aside
    assert script("ablation_filter_order").main(["--values", "5", "--out", str(out), *TINY]) == 2
    assert script("ablation_filter_order").main(["--values", "5", "--out", str(out), "--overwrite", *TINY]) == 0
    assert [r["label"] for r in json.loads((out / "results.json").read_text())["rows"]] == ["5"]
    assert not (out / "runs" / "10").exists() and sorted(p.name for p in tmp_path.iterdir()) == ["abl"]


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


# -- one command-line convention for the four ablation scripts ------------------------------------
ALL = {"ablation_sequence_size": TINY, "ablation_filter_order": TINY, "ablation_dfnn_vs_mdfnn": TINY,
       "ablation_altitude": ["--tracks", "12", "--steps", "30", "--warmup", "10", "--altitudes", "0", "300",
                             "--no-progress"]}


def _tree(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() if p.is_file() else None for p in sorted(folder.rglob("*"))}


@pytest.mark.parametrize("name", sorted(ALL))
def test_out_is_required_by_every_ablation_script(tmp_path, capsys, monkeypatch, name):
    """Three of them once wrote to runs/ under the current folder by default."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        script(name).main(ALL[name])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.startswith("error:") and "--out" in err and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", sorted(ALL))
def test_every_ablation_script_has_overwrite_and_never_replaces_a_users_folder(tmp_path, capsys, name):
    user = tmp_path / "mine"
    (user / "sub").mkdir(parents=True)
    (user / "notes.txt").write_text("keep me")
    (user / "sub" / "data.csv").write_text("1,2\n")
    before = _tree(user)
    with pytest.raises(SystemExit):
        script(name).main(["--help"])
    assert "--overwrite" in capsys.readouterr().out
    assert script(name).main([*ALL[name], "--out", str(user), "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and "was not written by pmsr" in err and err.count("\n") == 1
    assert _tree(user) == before and sorted(p.name for p in tmp_path.iterdir()) == ["mine"]


@pytest.mark.parametrize("name", ["ablation_sequence_size", "ablation_filter_order", "ablation_dfnn_vs_mdfnn"])
def test_a_finished_training_ablation_is_replaced_only_with_overwrite_and_only_if_all_ours(tmp_path, capsys, name):
    from pmsr_nn.outputs import folder_contents, write_marker

    out = tmp_path / "abl"
    (out / "runs").mkdir(parents=True)
    (out / "table.md").write_text("| 5 | ... |\n")
    write_marker(out, "ablation", state="finished", contents=folder_contents(out))
    before = _tree(out)
    assert script(name).main([*TINY, "--out", str(out)]) == 2  # refused before anything is trained
    assert "pass --overwrite" in capsys.readouterr().err and _tree(out) == before
    (out / "runs" / "mine.txt").write_text("a file of the user's inside our folder")
    before = _tree(out)
    assert script(name).main([*TINY, "--out", str(out), "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert "holds files pmsr did not write (runs/mine.txt)" in err and _tree(out) == before


def test_the_epochs_help_states_the_epoch_size_by_batches_not_a_fixed_50(capsys):
    with pytest.raises(SystemExit):
        script("ablation_filter_order").main(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "epochs of 50 batches" not in text and "epochs of --batches batches each" in text


def test_the_table_shows_the_real_training_time_or_no_time_column(tmp_path):
    from pmsr_nn.harness.ablation import Budget, write_ablation

    def row(label, seconds):
        return {"label": label, "steps": 2, "fit_seconds": seconds, "rmse_pos_m": {"t1": 100.0},
                "bound_pos_m": {"t1": 10.0}}

    table = write_ablation(tmp_path / "a", "T", "M", [row("5", 0.34), row("10", 12.6)], Budget(), 2, None, "", "ref")
    lines = table.splitlines()
    assert lines[2].endswith("| train steps | train s |")
    assert lines[4] == "| 5 | 100.00 | 2 | 0.3 |" and lines[5] == "| 10 | 100.00 | 2 | 13 |"
    table = write_ablation(tmp_path / "b", "T", "M", [row("5", 0.0), row("10", None)], Budget(), 2, None, "", "ref")
    assert "train s |" not in table and table.splitlines()[4] == "| 5 | 100.00 | 2 |"
