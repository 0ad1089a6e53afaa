"""``pmsr evaluate --executor local``: the shards of a scenario run as submitit jobs (separate
processes) and merge to the figures of the unsharded run; refusals are one line, exit 2, with
nothing written."""

from __future__ import annotations

import builtins
import json

import pytest

from pmsr_nn.cli import main
from pmsr_nn.harness import evaluate
from test_harness import accuracy, tiny

pytest.importorskip("submitit")


def _ekf_ukf(tmp_path, **over):
    return tiny(tmp_path, methods=[{"name": "EKF", "kind": "ekf"}, {"name": "UKF", "kind": "ukf"}], **over)


@pytest.mark.slow  # submitit starts a Python process per shard; the merge it relies on is tested in-process in the default tier
def test_local_executor_shards_merge_to_the_unsharded_figures(tmp_path, capsys):
    path = _ekf_ukf(tmp_path)
    whole = evaluate(path, tmp_path / "whole", progress=False)
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["evaluate", str(path), "--out", str(tmp_path / "jobs"), "--executor", "local", "--shards", "2"]) == 0
    out = capsys.readouterr().out
    assert "submitted 2 shard job(s) to local" in out
    res = json.loads((tmp_path / "jobs" / "results.json").read_text())
    assert accuracy(res) == accuracy(whole)  # bit for bit: the same per-block sums in the same order
    assert res["mc_runs"] == 4
    # the staging folder of the shards and the engine's logs is gone; only the results were added
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([*before, "jobs"])


@pytest.mark.parametrize("extra, message", [
    (["--shards", "3"], "--shards must be in 1..2 (the scenario's blocks of runs), got 3"),
    (["--shards", "0"], "--shards must be in 1..2"),
    (["--shard", "1/2"], "--executor runs every shard itself: give --shards N, not --shard I/N"),
    (["--timeout-min", "0"], "--timeout-min must be a positive number of minutes"),
])
def test_bad_dispatch_options_are_one_line_and_write_nothing(tmp_path, capsys, extra, message):
    path = _ekf_ukf(tmp_path)
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["evaluate", str(path), "--out", str(tmp_path / "jobs"), "--executor", "local", *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"pmsr: error: {message}" or (err.startswith("pmsr: error: ") and message in err and "\n" not in err)
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_a_method_that_can_not_run_is_refused_before_any_job(tmp_path, capsys):
    path = tiny(tmp_path, methods=[{"name": "M", "kind": "learned", "checkpoint": str(tmp_path / "nowhere.pt")}])
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["evaluate", str(path), "--out", str(tmp_path / "jobs"), "--executor", "local"]) == 2
    err = capsys.readouterr().err.strip()
    assert "nowhere.pt" in err and "\n" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_an_executor_that_is_not_installed_is_one_line(tmp_path, capsys, monkeypatch):
    real = builtins.__import__

    def no_submitit(name, *args, **kw):
        if name == "submitit" or name.startswith("submitit."):
            raise ImportError(name)
        return real(name, *args, **kw)
    monkeypatch.setattr(builtins, "__import__", no_submitit)
    path = _ekf_ukf(tmp_path)
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["evaluate", str(path), "--out", str(tmp_path / "jobs"), "--executor", "local"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("pmsr: error: --executor needs submitit, which this installation lacks: pip install "
                   "'pmsr_nn[cluster]' (or pip install submitit)")
    assert sorted(p.name for p in tmp_path.iterdir()) == before


@pytest.mark.parametrize("installed", [True, False])
def test_slurm_off_a_cluster_is_one_line_whether_or_not_submitit_is_installed(tmp_path, capsys, monkeypatch,
                                                                              installed):
    """Off a cluster submitit raised 'Could not detect "srun"', reported as a bug in pmsr_nn."""
    real = builtins.__import__

    def no_submitit(name, *args, **kw):
        if name == "submitit" or name.startswith("submitit."):
            raise ImportError(name)
        return real(name, *args, **kw)
    if not installed:
        monkeypatch.setattr(builtins, "__import__", no_submitit)
    tools = tmp_path / "bin"
    tools.mkdir()
    monkeypatch.setenv("PATH", str(tools))  # neither srun nor sbatch
    path = _ekf_ukf(tmp_path)
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["evaluate", str(path), "--out", str(tmp_path / "jobs"), "--executor", "slurm"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("pmsr: error: --executor slurm: no SLURM cluster found (srun and sbatch not on PATH); run on this "
                   "machine with --executor local, or without --executor")
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    (tools / "srun").write_text("#!/bin/sh\nexit 1\n")  # half a cluster: the line names what is missing
    (tools / "srun").chmod(0o755)
    assert main(["evaluate", str(path), "--out", str(tmp_path / "jobs"), "--executor", "slurm"]) == 2
    assert "(sbatch not on PATH)" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == before
