"""``pmsr evaluate --workers N``: the blocks shared by worker processes, the figures one process's."""

from __future__ import annotations

import json

import pytest

from pmsr_nn.cli import main
from pmsr_nn.harness.workers import default_workers, staging_bank
from test_harness import accuracy
from test_one_scenario import two_drones


def test_two_workers_give_one_process_figures_bit_for_bit_and_leave_only_the_results(tmp_path, capsys):
    """In the default tier (issue 57): the processes' figures are one process's, bit for bit."""
    path = two_drones(tmp_path, mc_runs=4, block_runs=1)  # 4 blocks, EKF and S-MSJPDA
    assert main(["evaluate", str(path), "--out", str(tmp_path / "one"), "--workers", "1", "--quiet"]) == 0
    assert main(["evaluate", str(path), "--out", str(tmp_path / "two"), "--workers", "2", "--quiet"]) == 0
    one, two = (json.loads((tmp_path / d / "results.json").read_text()) for d in ("one", "two"))
    assert accuracy(two) == accuracy(one)
    assert not staging_bank(tmp_path / "two").exists()  # the staging bank went with the merge
    assert sorted(p.name for p in tmp_path.iterdir()) == ["one", "two", "two.yaml"]


@pytest.mark.integration
def test_a_run_stopped_part_way_continues_from_the_banked_blocks(tmp_path, capsys):
    """Blocks a stopped run filed in the staging bank are not run again: the merge takes them."""
    from pmsr_nn.harness.evaluate import execute
    from pmsr_nn.harness.run.runner import open_run

    path = two_drones(tmp_path, mc_runs=4, block_runs=1)
    bank = staging_bank(tmp_path / "out")
    execute(open_run(path, bank, target="bank", shard=(1, 2), progress=False))  # blocks 0-1, as if stopped there
    first = {p.name: p.stat().st_mtime_ns for p in bank.glob("block-*")}
    assert sorted(first) == ["block-0000", "block-0001"]
    assert main(["evaluate", str(path), "--out", str(tmp_path / "out"), "--workers", "2"]) == 0
    out = capsys.readouterr().out
    assert "workers: 2 of 4 block(s) done" in out and "workers: 4 of 4 block(s) done" in out
    assert main(["evaluate", str(path), "--out", str(tmp_path / "whole"), "--workers", "1", "--quiet"]) == 0
    got, whole = (json.loads((tmp_path / d / "results.json").read_text()) for d in ("out", "whole"))
    assert accuracy(got) == accuracy(whole) and not bank.exists()


@pytest.mark.parametrize("extra, message", [
    (["--workers", "0"], "--workers must be at least 1"),
    (["--workers", "two"], "--workers must be a positive whole number of worker processes, got 'two'"),
    (["--workers", "2", "--shard", "1/2"], "--workers runs the whole scenario on this machine: give it or --shard"),
    (["--workers", "2", "--per-block"], "give it or --per-block"),
])
def test_bad_worker_counts_and_conflicts_are_one_line_errors_and_write_nothing(tmp_path, capsys, extra, message):
    path = two_drones(tmp_path)
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["evaluate", str(path), "--out", str(tmp_path / "out"), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


@pytest.mark.integration
def test_more_workers_than_blocks_is_a_warning_and_one_per_block_runs(tmp_path, capsys):
    path = two_drones(tmp_path, mc_runs=4, block_runs=2)  # 2 blocks
    assert main(["evaluate", str(path), "--out", str(tmp_path / "out"), "--workers", "3", "--quiet"]) == 0
    assert "warning: --workers 3 is more than the 2 block(s) of runs; 2 worker(s) run" in capsys.readouterr().err
    assert (tmp_path / "out" / "results.json").is_file()


def test_the_default_is_every_core_or_the_environment(monkeypatch):
    monkeypatch.delenv("PMSR_WORKERS", raising=False)
    import os

    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    assert default_workers() == cores and default_workers("cuda") == 1
    monkeypatch.setenv("PMSR_WORKERS", "3")
    assert default_workers() == 3


def test_a_foreign_staging_bank_is_refused_in_one_line_before_any_worker_starts(tmp_path, capsys):
    from pmsr_nn.harness.evaluate import execute
    from pmsr_nn.harness.run.runner import open_run

    path = two_drones(tmp_path, mc_runs=4, block_runs=1)
    (tmp_path / "other").mkdir()
    other = two_drones(tmp_path / "other", mc_runs=2, block_runs=1)
    bank = staging_bank(tmp_path / "out")
    execute(open_run(other, bank, target="bank", progress=False))  # an earlier command's blocks, of 2 runs
    before = {str(p.relative_to(tmp_path)): p.stat().st_mtime_ns for p in tmp_path.rglob("*")}
    assert main(["evaluate", str(path), "--out", str(tmp_path / "out"), "--workers", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "where --workers stages the blocks of" in err[0] and "another scenario" in err[0], err
    assert {str(p.relative_to(tmp_path)): p.stat().st_mtime_ns for p in tmp_path.rglob("*")} == before


@pytest.mark.integration
def test_the_staging_bank_goes_only_as_far_as_it_is_the_banks_own(tmp_path, capsys):
    """A file someone put into the staging bank (and one added inside a block) stays, with a
    warning; the bank's own files and the untouched blocks go; the results are written."""
    from pmsr_nn.harness.evaluate import execute
    from pmsr_nn.harness.run.runner import open_run

    path = two_drones(tmp_path, mc_runs=4, block_runs=1)
    bank = staging_bank(tmp_path / "out")
    execute(open_run(path, bank, target="bank", shard=(1, 2), progress=False))  # blocks 0-1
    (bank / "notes.txt").write_text("mine")
    (bank / "block-0001" / "extra.txt").write_text("mine too")
    assert main(["evaluate", str(path), "--out", str(tmp_path / "out"), "--workers", "2", "--quiet"]) == 0
    assert "keeps 2 file(s) this command did not write (block-0001, ...)" in capsys.readouterr().err
    assert sorted(p.name for p in bank.iterdir()) == ["block-0001", "notes.txt"]
    assert (bank / "notes.txt").read_text() == "mine" and (bank / "block-0001" / "extra.txt").read_text() == "mine too"
    assert (tmp_path / "out" / "results.json").is_file()
