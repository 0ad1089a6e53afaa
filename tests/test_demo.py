"""`pmsr demo`: the main job end to end (a shrunken budget here; the real one is marked slow)."""

import json

import pytest

from pmsr_nn.cli import main
from pmsr_nn.harness import demo

EXPECTED = {"EKF", "UKF", "SI+KF", "MDFNN", "KalmanNet"}


def check_demo_folder(out, mc_runs):
    res = json.loads((out / "evaluation" / "results.json").read_text())
    assert res["mc_runs"] == mc_runs
    assert set(res["cases"]) == {"trajectory_1", "trajectory_2", "trajectory_3"}
    for case in res["cases"].values():
        assert set(case["methods"]) == EXPECTED
        assert case["pcrb"]["pos_m"] > 0
        for r in case["methods"].values():
            assert r["rmse_pos_m"] > case["pcrb"]["q0_pos_m"]  # nothing beats the floor
    for f in ("report.md", "trajectories.png", "trajectory_1_rmse.png"):
        assert (out / "evaluation" / f).is_file()
    for kind in ("mdfnn", "kalmannet"):
        assert (out / "train" / kind / "tracker.pt").is_file()
    shared = json.loads((out / "shared_drones" / "results.json").read_text())
    assert shared["mc_runs"] == min(mc_runs, demo.SHARED_DRONES_RUNS)
    rows = shared["cases"]["three_drones"]["methods"]
    assert set(rows) == {"EKF", "UKF", "MDFNN", "KalmanNet", "S-MSJPDA", "S-MSJPDA from detections"}
    for r in rows.values():
        assert 0 < r["ospa_m"] <= 500.0 and len(r["rmse_pos_per_target_m"]) == 3
    for f in ("report.md", "three_drones_set_metrics.png", "three_drones_rmse.png"):
        assert (out / "shared_drones" / f).is_file()


def test_demo_runs_end_to_end_and_replaces_only_its_own_folder(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(demo, "DEMO_DATA", {**demo.DEMO_DATA, "tracks": 12, "batch_size": 16})
    monkeypatch.setattr(demo, "DEMO_TRAINER", {**demo.DEMO_TRAINER, "max_epochs": 1, "train_batches_per_epoch": 2,
                                               "val_batches": 2})
    monkeypatch.setattr(demo, "DEMO_BUDGET", {})
    monkeypatch.setattr(demo, "DEMO_MODELS", {
        "mdfnn": {**demo.DEMO_MODELS["mdfnn"], "hidden": [16, 12, 16], "filter_order": 5},
        "kalmannet": {**demo.DEMO_MODELS["kalmannet"], "rnn_hidden": 4}})
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--mc-runs", "2"]) == 0
    out_err = capsys.readouterr()
    printed = out_err.out
    assert "| MDFNN |" in printed and "report" in printed and "| S-MSJPDA | detections | oracle |" in printed
    assert "| S-MSJPDA from detections | detections | detections |" in printed
    # One screen: a header, two lines per stage, two tables; no third-party banners, tips or bars.
    lines = printed.splitlines()
    assert [line[:5] for line in lines if line.startswith("[")] == [f"[{i}/5]" for i in range(1, 6)]
    assert len(lines) <= 40 and max(len(line.replace(str(out), "runs/demo")) for line in lines) <= 120
    for chatter in ("GPU available", "LOCAL_RANK", "Tip", "Epoch 0", "Sanity", "it/s]"):
        assert chatter not in out_err.out + out_err.err
    check_demo_folder(out, 2)
    assert main(["demo", "--out", str(out), "--mc-runs", "1"]) == 0  # a previous demo is replaced
    check_demo_folder(out, 1)
    other = tmp_path / "mine"
    other.mkdir()
    (other / "thesis.tex").write_text("keep")
    assert main(["demo", "--out", str(other)]) == 2
    assert "not a pmsr demo folder" in capsys.readouterr().err
    assert (other / "thesis.tex").read_text() == "keep"


@pytest.mark.slow
def test_the_real_demo(tmp_path):
    """The README's first command with its real budget (about 2.5 minutes on 2 cores)."""
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out)]) == 0
    check_demo_folder(out, 20)
    res = json.loads((out / "evaluation" / "results.json").read_text())
    for case in res["cases"].values():  # issue 17: the demo's learned rows within 3x the EKF
        ekf = case["methods"]["EKF"]["rmse_pos_m"]
        for name in ("MDFNN", "KalmanNet"):
            assert case["methods"][name]["rmse_pos_m"] < 3 * ekf, (name, case["methods"][name]["rmse_pos_m"], ekf)
    assert json.loads((out / "demo.json").read_text())["total_seconds"] < 300
