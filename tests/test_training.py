"""Training runs, checkpoints, inference and the CLI commands train / track / select / export."""

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
import yaml

from pmsr_nn.cli import main
from pmsr_nn.errors import CheckpointError, ConfigError
from pmsr_nn.nets.checkpoint import read_checkpoint, save_tracker
from pmsr_nn.nets.inference import Tracker
from pmsr_nn.nets.train_config import apply_overrides, load_train_config

TINY = {
    "name": "tiny",
    "seed": 0,
    "data": {"tracks": 12, "steps": 120, "window": 40, "batch_size": 32, "eval_window_stride": 4},
    "model": {"kind": "mdfnn", "hidden": [32, 24, 32], "filter_order": 5},
    "optim": {"lr": 3.0e-3},
    "trainer": {"max_epochs": 2, "checkpoint_every_n_steps": 2, "accelerator": "cpu", "progress": False},
}


def write_config(path: Path, cache: Path, **sections) -> Path:
    cfg = json.loads(json.dumps(TINY))
    cfg["data"]["cache_dir"] = str(cache)
    for k, v in sections.items():
        cfg[k].update(v)
    path.write_text(yaml.safe_dump(cfg))
    return path


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """One tiny training run shared by the tests that only read it."""
    root = tmp_path_factory.mktemp("run")
    cfg = write_config(root / "tiny.yaml", root / "data")
    assert main(["train", str(cfg), "--out", str(root / "run")]) == 0
    return root


def dataset_of(root: Path) -> Path:
    return next((root / "data").iterdir())


def test_a_run_folder_holds_everything_it_promises(run):
    out = run / "run"
    for name in ("config.yaml", "metrics.json", "tracker.pt", "checkpoints/best.ckpt", "checkpoints/last.ckpt"):
        assert (out / name).is_file(), name
    assert any((out / "tb").glob("events.out.tfevents.*"))
    m = json.loads((out / "metrics.json").read_text())
    assert m["epochs"] == 2 and m["global_step"] >= 2 and m["global_step"] % 2 == 0 and math.isfinite(m["val"]["pos_rmse_m"])  # same batches per epoch
    assert m["history"] and m["context_samples"] == {"behind": 8, "ahead": 0}
    stored = yaml.safe_load((out / "config.yaml").read_text())
    assert stored["trainer"]["max_epochs"] == 2 and stored["optim"]["schedule"] == "cosine"  # defaults spelled out


def test_every_checkpoint_of_a_run_serves_inference_and_they_agree(run):
    out = run / "run"
    z = torch.from_numpy(__import__("h5py").File(dataset_of(run) / "tracks.h5")["measurements"][:2]).double()
    best = Tracker.load(out / "checkpoints" / "best.ckpt").track(z)
    slim = Tracker.load(out / "tracker.pt").track(z)
    torch.testing.assert_close(best, slim, rtol=0, atol=0)
    assert best.shape == (2, 120, 6) and best.dtype == torch.float64


def test_spliced_tracking_equals_one_pass_over_the_whole_sequence(run):
    tracker = Tracker.load(run / "run" / "tracker.pt")
    g = torch.Generator().manual_seed(0)
    z = torch.from_numpy(__import__("h5py").File(dataset_of(run) / "tracks.h5")["measurements"][:3]).double()
    z = z + torch.randn(z.shape, generator=g, dtype=torch.float64)
    with torch.no_grad():
        full = tracker.state_scaler.denormalise(tracker.net(tracker.measurement_scaler.normalise(z).float()).double())
    for stride in (None, 1, 13):
        torch.testing.assert_close(tracker.track(z, stride=stride), full, rtol=0, atol=0)


def test_track_cli_writes_one_estimate_per_input_row(run, tmp_path):
    csv_in, csv_out = tmp_path / "z.csv", tmp_path / "est.csv"
    assert main(["export", str(dataset_of(run)), "--out", str(csv_in), "--tracks", "2"]) == 0
    assert main(["track", "--checkpoint", str(run / "run" / "tracker.pt"), "--input", str(csv_in), "--out", str(csv_out)]) == 0
    rows_in = csv_in.read_text().splitlines()
    rows_out = csv_out.read_text().splitlines()
    assert len(rows_out) == len(rows_in) == 1 + 2 * 120
    assert rows_out[0] == "track,k,x,vx,ax,y,vy,ay"
    assert main(["track", "--checkpoint", str(run / "run" / "tracker.pt"), "--input", str(dataset_of(run)),
                 "--split", "test", "--out", str(tmp_path / "est.h5")]) == 0


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """``pmsr simulate datasets/fitee2023_ca.yaml --tracks 4``, shortened to the tiny run's 120 steps: a
    dataset without splits (every track a test track), for tracking only."""
    root = tmp_path_factory.mktemp("small")
    recipe = yaml.safe_load((Path(__file__).resolve().parents[1] / "datasets" / "fitee2023_ca.yaml").read_text())
    recipe["motion"]["steps"], recipe["window"] = 120, 40
    (root / "r.yaml").write_text(yaml.safe_dump(recipe))
    assert main(["simulate", str(root / "r.yaml"), "--out", str(root / "small"), "--tracks", "4", "--seed", "5",
                 "--quiet"]) == 0
    return root / "small"


def test_track_reads_a_dataset_folder_its_tracks_h5_and_its_csv_alike(run, small, tmp_path):
    ck = str(run / "run" / "tracker.pt")
    assert main(["export", str(small), "--out", str(tmp_path / "z.csv")]) == 0
    estimates = {}
    for name, given, split in (("dir", small, []), ("h5", small / "tracks.h5", []), ("csv", tmp_path / "z.csv", []),
                               ("h5-test", small / "tracks.h5", ["--split", "test"])):
        out = tmp_path / f"{name}.csv"
        assert main(["track", "--checkpoint", ck, "--input", str(given), "--out", str(out), *split]) == 0, name
        estimates[name] = out.read_text()
    assert len(estimates["dir"].splitlines()) == 1 + 4 * 120
    assert estimates["dir"] == estimates["h5"] == estimates["csv"] == estimates["h5-test"]


@pytest.mark.parametrize("given,extra,message", [
    ("small", ["--split", "val"], "small has no val split: all its tracks are test tracks (simulated without splits); "
                                  "use --split test or leave --split out"),
    ("small/tracks.h5", ["--split", "train"], "small has no train split"),
    ("other.h5", [], "other.h5 is not the tracks.h5 of a pmsr_nn dataset folder; give a dataset folder, its tracks.h5, "
                     "or a measurement CSV as --input"),
    ("loose/tracks.h5", [], "loose/tracks.h5 is not the tracks.h5 of a pmsr_nn dataset folder"),
    ("moved/tracks.h5", [], "another sensor geometry than the dataset"),
    ("small/tracks.h5", ["--out", "small/est.csv"], "lies inside the input"),
])
def test_track_inputs_that_are_refused(run, small, tmp_path, capsys, given, extra, message):
    import shutil

    import h5py

    with h5py.File(tmp_path / "other.h5", "w") as h5:  # an HDF5 file of someone else's
        h5.create_dataset("measurements", data=torch.zeros(2, 120, 9).numpy())
    (tmp_path / "loose").mkdir()
    shutil.copyfile(small / "tracks.h5", tmp_path / "loose" / "tracks.h5")  # a dataset's file without its folder
    shutil.copytree(small, tmp_path / "moved")  # the dataset of another geometry
    m = json.loads((tmp_path / "moved" / "manifest.json").read_text())
    m["geometry"]["receivers"][0]["position_m"][0] += 500.0
    (tmp_path / "moved" / "manifest.json").write_text(json.dumps(m))
    shutil.copytree(small, tmp_path / "small")
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    args = ["track", "--checkpoint", str(run / "run" / "tracker.pt"), "--input", str(tmp_path / given)]
    out = extra[extra.index("--out") + 1] if "--out" in extra else "est.csv"
    extra = [a for i, a in enumerate(extra) if a != "--out" and (i == 0 or extra[i - 1] != "--out")]
    assert main([*args, "--out", str(tmp_path / out), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pmsr: error: ") and len(err.splitlines()) == 1 and message in err, err
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before


def test_training_on_a_dataset_without_splits_is_refused(small, tmp_path, capsys):
    cfg = json.loads(json.dumps(TINY))
    cfg["data"] = {"path": str(small), "window": 40, "batch_size": 32}
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
    assert main(["train", str(tmp_path / "c.yaml"), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"pmsr: error: dataset {small} has no train/val split (all its 4 tracks are test tracks, for "
                   "tracking only); simulate more tracks")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.yaml"]


def _csv(tmp_path, header, rows):
    p = tmp_path / "m.csv"
    p.write_text("\n".join([",".join(header)] + [",".join(map(str, r)) for r in rows]) + "\n")
    return p


COLUMNS = [f"{c}_{i}" for c in ("range", "range_rate", "azimuth") for i in (1, 2, 3)]


@pytest.mark.parametrize("case,message", [
    ("eight_columns", "do not match the checkpoint"),
    ("nan_row", "holds NaN"),
    ("short", "shorter than the network's window"),
    ("ragged", "cells, the header has"),
    ("word", "is not a number"),
])
def test_bad_measurement_files_get_one_line_errors(run, tmp_path, capsys, case, message):
    z = torch.from_numpy(__import__("h5py").File(dataset_of(run) / "tracks.h5")["measurements"][0]).double().tolist()
    header, rows = list(COLUMNS), [list(r) for r in z]
    if case == "eight_columns":
        header, rows = header[:8], [r[:8] for r in rows]
    elif case == "nan_row":
        rows[50][3] = "nan"
    elif case == "short":
        rows = rows[:30]
    elif case == "ragged":
        rows[5] = rows[5][:7]
    elif case == "word":
        rows[7][0] = "abc"
    out = tmp_path / "est.csv"
    code = main(["track", "--checkpoint", str(run / "run" / "tracker.pt"), "--input", str(_csv(tmp_path, header, rows)),
                 "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and message in err and len(err.splitlines()) == 1
    assert not out.exists() and not list(tmp_path.glob(".*partial*"))


def test_nan_hold_tracks_through_a_missing_scan(run, tmp_path):
    z = torch.from_numpy(__import__("h5py").File(dataset_of(run) / "tracks.h5")["measurements"][0]).double().tolist()
    z[50][3] = "nan"
    out = tmp_path / "est.csv"
    assert main(["track", "--checkpoint", str(run / "run" / "tracker.pt"), "--nan", "hold",
                 "--input", str(_csv(tmp_path, COLUMNS, z)), "--out", str(out)]) == 0
    assert len(out.read_text().splitlines()) == 121


def test_truncated_foreign_and_pickled_checkpoints_are_refused(run, tmp_path):
    good = (run / "run" / "tracker.pt").read_bytes()
    (tmp_path / "cut.pt").write_bytes(good[: len(good) // 2])
    with pytest.raises(CheckpointError, match="truncated or corrupted"):
        read_checkpoint(tmp_path / "cut.pt")
    torch.save({"state_dict": {"w": torch.zeros(2)}}, tmp_path / "foreign.pt")
    with pytest.raises(CheckpointError, match="not a pmsr_nn tracker checkpoint"):
        read_checkpoint(tmp_path / "foreign.pt")
    torch.save({"pmsr": ConfigError("an arbitrary object")}, tmp_path / "evil.pt")
    with pytest.raises(CheckpointError, match="refusing to unpickle"):
        read_checkpoint(tmp_path / "evil.pt")
    with pytest.raises(CheckpointError, match="no checkpoint at"):
        read_checkpoint(tmp_path / "missing.pt")


def test_a_checkpoint_for_another_geometry_is_refused(run, tmp_path):
    meta, _, state = read_checkpoint(run / "run" / "tracker.pt")
    meta = json.loads(json.dumps(meta))
    meta["geometry"]["receivers"][0]["position_m"][0] += 500.0
    save_tracker(tmp_path / "moved.pt", meta, {f"net.{k}": v for k, v in state.items()})
    code = main(["track", "--checkpoint", str(tmp_path / "moved.pt"), "--input", str(dataset_of(run)), "--out", str(tmp_path / "e.csv")])
    assert code == 2 and not (tmp_path / "e.csv").exists()
    with pytest.raises(CheckpointError, match="another sensor geometry"):
        Tracker.load(tmp_path / "moved.pt").check_compatible(read_checkpoint(run / "run" / "tracker.pt")[0]["geometry"], COLUMNS)


def test_weights_that_do_not_fit_the_config_are_refused(run, tmp_path):
    meta, _, state = read_checkpoint(run / "run" / "tracker.pt")
    meta = json.loads(json.dumps(meta))
    meta["model"]["hidden"] = [32, 24, 33]
    save_tracker(tmp_path / "odd.pt", meta, {f"net.{k}": v for k, v in state.items()})
    with pytest.raises(CheckpointError, match="do not fit the model config"):
        Tracker.load(tmp_path / "odd.pt")


def test_config_errors_name_the_key_and_nothing_is_written(tmp_path, capsys):
    cfg = write_config(tmp_path / "c.yaml", tmp_path / "data", model={"filter_ordr": 3})
    assert main(["train", str(cfg), "--out", str(tmp_path / "r")]) == 2
    assert "did you mean 'filter_order'" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()
    cfg = write_config(tmp_path / "c.yaml", tmp_path / "data")
    assert main(["train", str(cfg), "--out", str(tmp_path / "r"), "optim.lr=-1"]) == 2
    assert "optim.lr must be positive" in capsys.readouterr().err
    assert main(["train", "--resume", "--out", str(tmp_path / "nothing")]) == 2
    assert "cannot resume" in capsys.readouterr().err
    with pytest.raises(ConfigError, match="KEY=VALUE"):
        apply_overrides({}, ["trainer.max_epochs"])


def test_an_existing_run_is_never_overwritten(run, capsys):
    assert main(["train", str(run / "tiny.yaml"), "--out", str(run / "run")]) == 2
    assert "pass --resume" in capsys.readouterr().err


def test_overrides_and_model_files_resolve(tmp_path):
    (tmp_path / "m.yaml").write_text("kind: rnn\nrnn_hidden: 16\n")
    cfg = write_config(tmp_path / "c.yaml", tmp_path / "data")
    raw = yaml.safe_load(cfg.read_text())
    raw["model"] = "m.yaml"
    cfg.write_text(yaml.safe_dump(raw))
    c = load_train_config(cfg, ["model.rnn_cell=gru", "trainer.max_epochs=7"])
    assert (c.model.kind, c.model.rnn_cell, c.model.rnn_hidden, c.trainer.max_epochs) == ("rnn", "gru", 16, 7)


def _files(folder: Path) -> dict[str, bytes]:
    return {str(f.relative_to(folder)): f.read_bytes() for f in sorted(folder.rglob("*")) if f.is_file()}


def _lose_last(run_dir: Path, how: str, elsewhere: Path) -> None:
    last = run_dir / "checkpoints" / "last.ckpt"
    if how == "deleted":
        last.unlink()
    elif how == "moved":  # tidied away, out of the run folder
        last.rename(elsewhere / "last.ckpt")
    else:  # truncated: a copy cut short
        last.write_bytes(last.read_bytes()[: last.stat().st_size // 2])


@pytest.mark.parametrize("how", ["deleted", pytest.param("moved", marks=pytest.mark.slow),
                                 pytest.param("truncated", marks=pytest.mark.slow)])
def test_resume_without_a_readable_last_checkpoint_continues_from_best(run, tmp_path, capsys, how):
    """The issue's data loss: without last.ckpt, --resume trained afresh from epoch 0 and replaced
    best.ckpt, tracker.pt and metrics.json by worse ones. Now it continues from best.ckpt, says so
    in one line, and the epochs after the best are trained again to the same validation scores."""
    out = tmp_path / "run"
    shutil.copytree(run / "run", out)
    before = json.loads((out / "metrics.json").read_text())
    best_bytes = (out / "checkpoints" / "best.ckpt").read_bytes()
    _lose_last(out, how, tmp_path)
    capsys.readouterr()
    assert main(["train", "--resume", "--out", str(out)]) == 0
    said = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("pmsr:")]
    last = out / "checkpoints" / "last.ckpt"
    why = "no checkpoint at" if how != "truncated" else "not a readable torch checkpoint"
    assert len(said) == 1 and said[0].startswith(f"pmsr: resuming from {out / 'checkpoints' / 'best.ckpt'} (")
    assert str(last) in said[0] and why in said[0]
    m = json.loads((out / "metrics.json").read_text())
    assert m["resumed_from"] == str(out / "checkpoints" / "best.ckpt")
    scores = [(r["epoch"], r["step"], r["val_pos_rmse_m"]) for r in m["history"]]
    assert scores == [(r["epoch"], r["step"], r["val_pos_rmse_m"]) for r in before["history"]]  # not from scratch
    assert m["val"]["pos_rmse_m"] == before["val"]["pos_rmse_m"]
    assert (out / "checkpoints" / "best.ckpt").read_bytes() == best_bytes


def test_a_resumed_session_never_replaces_a_better_recorded_best(run, tmp_path, capsys):
    """metrics.json decides: with a recorded best better than anything this session reaches
    (1 m), best.ckpt, tracker.pt and the recorded metrics stay, and the history is merged."""
    out = tmp_path / "run"
    shutil.copytree(run / "run", out)
    m = json.loads((out / "metrics.json").read_text())
    m["val"]["pos_rmse_m"] = 1.0
    (out / "metrics.json").write_text(json.dumps(m))
    cfg = yaml.safe_load((out / "config.yaml").read_text())
    cfg["trainer"]["max_epochs"] = 3  # one more epoch to train (the run's own config, as a user may not)
    (out / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    (out / "checkpoints" / "last.ckpt").unlink()
    kept = {k: v for k, v in _files(out).items() if k in ("tracker.pt", "checkpoints/best.ckpt")}
    assert main(["train", "--resume", "--out", str(out)]) == 0
    after = json.loads((out / "metrics.json").read_text())
    assert after["val"] == m["val"] and after["test"] == m["test"] and after["epochs"] == 3
    assert [r["epoch"] for r in after["history"]] == [0, 1, 2]  # the earlier epochs and the new one
    assert after["history"][-1]["val_pos_rmse_m"] > 1.0
    assert {k: v for k, v in _files(out).items() if k in kept} == kept
    assert (out / "checkpoints" / "last.ckpt").is_file()


@pytest.mark.parametrize("val, bar", [(308.6, 308.6), (float("nan"), None), ("x", None), (None, None)])
def test_the_bar_of_a_resumed_session_is_the_recorded_finite_best(tmp_path, val, bar):
    from pmsr_nn.nets.training import recorded_best

    if val is not None:
        (tmp_path / "metrics.json").write_text(json.dumps({"val": {"pos_rmse_m": val}, "test": {},
                                                           "best_checkpoint": "checkpoints/best.ckpt"}))
    got = recorded_best(tmp_path)
    assert (got and got["val"]["pos_rmse_m"]) == bar


@pytest.mark.parametrize("left", [("tracker.pt",), ("metrics.json",), ("checkpoints/best.ckpt",)])
def test_resume_with_no_readable_checkpoint_is_refused_and_changes_nothing(run, tmp_path, capsys, left):
    """A run that holds a result but no checkpoint to continue from: starting afresh would replace
    the result, so it is refused (one line, exit 2) and nothing in the folder changes."""
    out = tmp_path / "run"
    shutil.copytree(run / "run", out)
    for f in (out / "checkpoints").glob("*.ckpt"):
        if f"checkpoints/{f.name}" not in left:
            f.unlink()
        else:
            f.write_bytes(b"")  # an unreadable checkpoint file is a result too
    for name in ("tracker.pt", "metrics.json"):
        if name not in left:
            (out / name).unlink()
    files = _files(out)
    capsys.readouterr()
    assert main(["train", "--resume", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"pmsr: error: cannot resume {out}: no readable checkpoint")
    assert left[0].split("/")[-1] in err[0]
    assert _files(out) == files


def _one_more_epoch(out: Path) -> None:
    cfg = yaml.safe_load((out / "config.yaml").read_text())
    cfg["trainer"]["max_epochs"] += 1  # the run's own config, as a user may not: something left to train
    (out / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))


def _results(out: Path) -> dict[str, bytes]:
    """The run's files but its TensorBoard logs (a resumed session starts a new log file)."""
    return {k: v for k, v in _files(out).items() if not k.startswith("tb/")}


def test_a_full_disk_during_training_gives_one_line_and_loses_nothing(run, tmp_path, capsys, monkeypatch):
    """The disk fills while a resumed session writes its first checkpoint (half the bytes land, then
    ENOSPC): one line, exit 2, every earlier file byte-identical, no temporary left; a new run that
    hits it before its first checkpoint leaves no folder at all. (Slow tier: a real tmpfs.)"""
    import errno

    out = tmp_path / "run"
    shutil.copytree(run / "run", out)
    _one_more_epoch(out)
    write_bytes = Path.write_bytes

    def full(self, data):
        if out in self.parents or tmp_path / "new" in self.parents:
            write_bytes(self, bytes(data)[: len(data) // 2])
            raise OSError(errno.ENOSPC, "No space left on device")
        return write_bytes(self, data)

    monkeypatch.setattr(Path, "write_bytes", full)
    before = _results(out)
    capsys.readouterr()
    assert main(["train", "--resume", "--out", str(out)]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("pmsr: error")]
    assert err == [f"pmsr: error: no space left on the device: {out / 'checkpoints' / 'last.ckpt'}"]
    assert _results(out) == before
    cfg = write_config(tmp_path / "c.yaml", tmp_path / "data")
    assert main(["train", str(cfg), "--out", str(tmp_path / "new")]) == 2
    assert capsys.readouterr().err.strip().endswith(f"no space left on the device: {tmp_path / 'new' / 'checkpoints' / 'last.ckpt'}")
    assert not (tmp_path / "new").exists()


@pytest.mark.slow  # mounts a tmpfs (root only)
def test_a_full_tmpfs_during_training_gives_one_line_and_loses_nothing(run, tmp_path):
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=512k", "tmpfs", str(mnt)],
                                           capture_output=True).returncode != 0:
        pytest.skip("mounting a tmpfs needs root")
    try:
        out = mnt / "run"
        shutil.copytree(run / "run", out)
        _one_more_epoch(out)
        free = os.statvfs(mnt).f_bavail * os.statvfs(mnt).f_frsize
        (mnt / "filler").write_bytes(bytes(free - 12 * 1024))  # room for the logs, not for a checkpoint
        before = _results(out)
        p = _run_cli(["train", "--resume", "--out", str(out)])
        text, _ = p.communicate(timeout=300)
        assert p.returncode == 2, text
        errors = [ln for ln in text.splitlines() if ln.startswith("pmsr: error")]
        assert errors == [f"pmsr: error: no space left on the device: {out / 'checkpoints' / 'last.ckpt'}"], text
        assert _results(out) == before
    finally:
        subprocess.run(["umount", str(mnt)], check=True)


def _run_cli(args, **kw):
    return subprocess.Popen([sys.executable, "-m", "pmsr_nn.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, **kw)


@pytest.mark.slow  # a kill test: a real training process killed and resumed
def test_a_killed_run_resumes_from_its_last_checkpoint(tmp_path):
    cfg = write_config(tmp_path / "c.yaml", tmp_path / "data", trainer={"max_epochs": 12, "early_stopping_patience": None,
                                                                           "checkpoint_every_n_steps": 5})
    run = tmp_path / "run"
    proc = _run_cli(["train", str(cfg), "--out", str(run)])
    last = run / "checkpoints" / "last.ckpt"
    deadline = time.time() + 120
    epoch_at_kill = -1
    while time.time() < deadline and proc.poll() is None:
        if last.is_file():
            try:
                epoch_at_kill = torch.load(last, weights_only=True)["epoch"]
            except Exception:  # caught mid-write: try again
                epoch_at_kill = -1
            if epoch_at_kill >= 2:
                break
        time.sleep(0.2)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert epoch_at_kill >= 2, "the run never wrote a checkpoint past epoch 2"
    assert not (run / "metrics.json").exists()  # it really was cut short
    step_at_kill = torch.load(last, weights_only=True)["global_step"]
    done = _run_cli(["train", "--resume", "--out", str(run)])
    out, _ = done.communicate(timeout=300)
    assert done.returncode == 0, out
    m = json.loads((run / "metrics.json").read_text())
    assert m["resumed_from"].endswith("last.ckpt") and m["epochs"] == 12
    assert min(r["epoch"] for r in m["history"]) >= epoch_at_kill  # no epoch before the kill was trained again
    assert m["global_step"] > step_at_kill


@pytest.mark.slow  # two training processes side by side
def test_ddp_with_two_cpu_processes(tmp_path):
    cfg = write_config(tmp_path / "c.yaml", tmp_path / "data")
    env = {**os.environ, "PMSR_TRAIN_RUN": ""}
    p = _run_cli(["train", str(cfg), "--out", str(tmp_path / "run"), "trainer.devices=2", "trainer.strategy=ddp"], env=env)
    out, _ = p.communicate(timeout=300)
    assert p.returncode == 0, out
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["world_size"] == 2
    # each of the two processes sees half of the 10 x 81 training windows per epoch
    assert m["global_step"] == 2 * -(-(-(-10 * 81 // 2)) // 32)
    assert out.count("run       ") == 1  # only rank 0 reports


def test_select_keeps_the_member_with_the_best_fresh_track_rmse(tmp_path):
    cfg = write_config(tmp_path / "c.yaml", tmp_path / "data", trainer={"max_epochs": 1})
    assert main(["select", str(cfg), "--out", str(tmp_path / "sel"), "--members", "2", "--fresh-tracks", "3"]) == 0
    res = json.loads((tmp_path / "sel" / "selection.json").read_text())
    assert [r["fold"] for r in res["members"]] == [0, 1] and [r["seed"] for r in res["members"]] == [0, 1]
    best = min(res["members"], key=lambda r: r["fresh_pos_rmse_m"])
    assert res["best"] == best["member"]
    assert (tmp_path / "sel" / "best.pt").read_bytes() == (tmp_path / "sel" / best["run"] / "tracker.pt").read_bytes()


@pytest.mark.parametrize("name", ["smoke", "mdfnn", "dfnn", "rnn"])
def test_shipped_training_configs_load(name):
    root = Path(__file__).resolve().parents[1]
    cfg = load_train_config(root / "train" / f"{name}.yaml")
    assert cfg.name == name and cfg.model.kind == ("mdfnn" if name == "smoke" else name)
    if name != "smoke":
        assert cfg.model.hidden == (384, 225, 540) or cfg.model.kind == "rnn"
        assert cfg.data.window == 100


def test_learned_vs_bounds_study_runs_on_a_tiny_run(run, tmp_path, capsys):
    import importlib.util

    script = Path(__file__).resolve().parents[1] / "evaluate" / "learned_vs_bounds.py"
    spec = importlib.util.spec_from_file_location("learned_vs_bounds", script)
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    assert study.main(["--tracker", f"TINY={run / 'run' / 'tracker.pt'}", "--split", "val", "--out", str(tmp_path)]) == 0
    res = json.loads((tmp_path / "results.json").read_text())
    rows = {r["method"]: r for r in res["rows"]}
    assert set(rows) == {"TINY", "EKF", "UKF"} and rows["TINY"]["memory_scans"] == 9
    # less memory can only cost: the finite-memory bound sits on or above the filtering bound
    assert res["bounds"]["memory_9"]["position_m"] >= res["bounds"]["filtering"]["position_m"]
    assert not rows["TINY"]["below_bound"] and rows["TINY"]["over_memory_bound"] > 1
    assert (tmp_path / "rmse.png").stat().st_size > 0 and "finite-memory" in capsys.readouterr().out


def test_precision_auto_uses_bfloat16_only_where_it_is_native(monkeypatch):
    from pmsr_nn.nets import training

    monkeypatch.setattr(training, "native_bf16", lambda accelerator: True)
    assert training.resolve_precision("auto") == "bf16-mixed"
    monkeypatch.setattr(training, "native_bf16", lambda accelerator: False)
    assert training.resolve_precision("auto", "cpu") == "32-true"
    assert training.resolve_precision("bf16-mixed") == "bf16-mixed"  # an explicit choice is kept


def test_train_prints_one_line_per_epoch_and_no_lightning_chatter(tmp_path, capsys):
    """Our console (pmsr_nn.nets.progress): one line per epoch, the summary, none of Lightning's
    banners, tips or bars; each line's validation RMSE is the epoch's own, as TensorBoard logged it."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    cfg = write_config(tmp_path / "t.yaml", tmp_path / "data", trainer={"progress": True, "max_epochs": 3})
    assert main(["train", str(cfg), "--out", str(tmp_path / "run")]) == 0
    out = capsys.readouterr()
    lines = out.out.splitlines()
    epochs = [line for line in lines if line.startswith("epoch ")]
    assert [line.split()[1] for line in epochs] == ["1/3", "2/3", "3/3"]
    assert [line.split()[0] for line in lines[len(epochs):]] == ["run", "val", "test", "tracker"]
    for chatter in ("GPU available", "LOCAL_RANK", "Sanity Checking", "Tip", "Epoch 0", "| Name", "Validation DataLoader"):
        assert chatter not in out.out + out.err
    events = EventAccumulator(str(min((tmp_path / "run" / "tb").glob("events.out.tfevents.*")))).Reload()
    logged = [e.value for e in events.Scalars("val/pos_rmse_m")]
    printed = [float(line.split("val position RMSE ")[1].split()[0]) for line in epochs]
    history = json.loads((tmp_path / "run" / "metrics.json").read_text())["history"]
    assert [r["epoch"] for r in history] == [0, 1, 2]
    assert [round(r["val_pos_rmse_m"], 1) for r in history] == [round(v, 1) for v in logged] == printed


def test_train_verbose_restores_lightnings_console(tmp_path, capsys):
    cfg = write_config(tmp_path / "t.yaml", tmp_path / "data", trainer={"progress": True, "max_epochs": 1})
    assert main(["train", str(cfg), "--out", str(tmp_path / "run"), "--verbose"]) == 0
    out = capsys.readouterr()
    assert "Epoch 0" in out.out + out.err and not any(line.startswith("epoch ") for line in out.out.splitlines())


@pytest.mark.parametrize("hidden, message", [
    ([10] * 1_000, "model.hidden lists 1,000 layers; at most 64 are accepted"),
    ([16_384] * 3, "model.hidden: 536,870,912 weights between the hidden layers; at most 100,000,000 are accepted"),
])
def test_a_network_too_big_to_build_is_refused_before_it_is_built(tmp_path, capsys, hidden, message):
    (tmp_path / "m.yaml").write_text(yaml.safe_dump({"kind": "mdfnn", "hidden": hidden}))
    cfg = yaml.safe_load((Path(__file__).resolve().parents[1] / "train" / "smoke.yaml").read_text())
    cfg["model"] = "m.yaml"
    (tmp_path / "t.yaml").write_text(yaml.safe_dump(cfg))
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["train", str(tmp_path / "t.yaml"), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and message in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_a_training_in_process_gives_back_the_callers_threads_and_determinism(tmp_path, monkeypatch):
    """``trainer.threads`` and Lightning's ``deterministic`` are process-wide: a training called
    in-process (the demo, the tests) must hand the caller its own settings back. Left at 2 threads
    in each of two pytest workers, every later test ran several times slower."""
    before = torch.get_num_threads(), torch.are_deterministic_algorithms_enabled()
    own = 1 if before[0] != 1 else 3  # a count the training's 2 threads cannot leave behind by chance
    torch.set_num_threads(own)
    torch.use_deterministic_algorithms(False)
    asked = []
    set_threads = torch.set_num_threads
    monkeypatch.setattr(torch, "set_num_threads", lambda n: (asked.append(n), set_threads(n))[1])
    try:
        cfg = write_config(tmp_path / "t.yaml", tmp_path / "data", trainer={"threads": 2, "max_epochs": 1,
                                                                           "deterministic": True})
        assert main(["train", str(cfg), "--out", str(tmp_path / "run")]) == 0
        assert asked == [2, own]  # the config's threads for the run, then the caller's own back
        assert torch.get_num_threads() == own
        assert not torch.are_deterministic_algorithms_enabled()
    finally:
        set_threads(before[0])
        torch.use_deterministic_algorithms(before[1])


@pytest.mark.parametrize("module, entry", [("nebp_training", "train_nebp")])
def test_the_scene_trainings_give_back_the_callers_threads_even_when_they_fail(monkeypatch, module, entry):
    """NEBP's training sets ``threads`` for its own run only, and hands the caller its settings
    back also when the run raises."""
    import importlib
    from types import SimpleNamespace

    mod = importlib.import_module(f"pmsr_nn.nets.{module}")
    inside = {}

    def body(cfg, out, progress):
        inside["threads"] = torch.get_num_threads()
        torch.use_deterministic_algorithms(True)  # as Lightning's deterministic=True does
        raise ConfigError("stop here")

    monkeypatch.setattr(mod, f"_{entry}", body)
    before = torch.get_num_threads(), torch.are_deterministic_algorithms_enabled()
    own = 1 if before[0] != 1 else 3
    torch.set_num_threads(own)
    torch.use_deterministic_algorithms(False)
    try:
        with pytest.raises(ConfigError, match="stop here"):
            getattr(mod, entry)(SimpleNamespace(threads=2), "unused", False)
        assert inside["threads"] == 2
        assert torch.get_num_threads() == own
        assert not torch.are_deterministic_algorithms_enabled()
    finally:
        torch.set_num_threads(before[0])
        torch.use_deterministic_algorithms(before[1])
