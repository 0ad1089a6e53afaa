"""``pmsr evaluate --per-block``: a recording banked block by block, continued after an
interruption, merged to the unsharded run's figures bit for bit."""

import json
import os
import shutil

import numpy as np
import pytest

from pmsr_nn.cli import main
from pmsr_nn.errors import ConfigError, OutputError
from pmsr_nn.harness import evaluate, merge
from pmsr_nn.harness.evaluate import execute
from pmsr_nn.harness.run.block_bank import bank_blocks, block_folder
from pmsr_nn.harness.run.runner import open_run
from test_harness import ROOT, accuracy, tiny
from test_one_scenario import two_drones


def bank(path, out, shard=(1, 1)):
    return execute(open_run(path, out, target="bank", shard=shard, progress=False))


def snapshot(folder):
    """Every file under ``folder`` with its size and modification time."""
    return {str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in folder.rglob("*") if p.is_file()}


@pytest.mark.integration
def test_a_bank_filled_in_two_sittings_merges_to_the_unsharded_run(tmp_path):
    path = tiny(tmp_path, block_runs=1)  # 4 blocks of one run
    whole = evaluate(path, tmp_path / "whole", progress=False)
    first = bank(path, tmp_path / "bank", shard=(1, 2))
    assert first["blocks"] == [0, 1] and first["skipped"] == []
    assert [p.name for p in bank_blocks(tmp_path / "bank")] == ["block-0000", "block-0001"]
    with pytest.raises(ConfigError, match="lack blocks 2-3 and repeat none"):
        merge([tmp_path / "bank"], tmp_path / "early")
    assert not (tmp_path / "early").exists()
    before = snapshot(tmp_path / "bank")
    again = bank(path, tmp_path / "bank", shard=(1, 2))  # the same command again: nothing to do
    assert again["blocks"] == [] and again["skipped"] == [0, 1]
    assert snapshot(tmp_path / "bank") == before
    rest = bank(path, tmp_path / "bank")  # the whole run now: only the blocks the bank lacks
    assert rest["blocks"] == [2, 3] and rest["skipped"] == [0, 1]
    merged = merge([tmp_path / "bank"], tmp_path / "merged")
    assert accuracy(merged) == accuracy(whole)  # the same per-block sums, reduced in the same order
    assert merged["environment"]["shard_commits"] == [str(json.loads(
        (block_folder(tmp_path / "bank", 0) / "shard.json").read_text())["environment"]["commit"])]
    # a block folder is what --shard (b+1)/n_blocks writes: bank blocks and shards mix
    evaluate(path, tmp_path / "s2of2", shard=(2, 2), progress=False)
    mixed = merge([block_folder(tmp_path / "bank", 0), block_folder(tmp_path / "bank", 1), tmp_path / "s2of2"],
                  tmp_path / "mixed")
    assert accuracy(mixed) == accuracy(whole)


def test_an_interrupted_block_is_run_again_and_nothing_else(tmp_path):
    path = tiny(tmp_path, block_runs=1, mc_runs=2)
    bank(path, tmp_path / "bank")
    kept = snapshot(block_folder(tmp_path / "bank", 0))
    with np.load(block_folder(tmp_path / "bank", 1) / "blocks.npz") as f:
        old = {k: f[k] for k in f.files}
    # a killed run leaves a hidden temporary and no block folder
    gone = block_folder(tmp_path / "bank", 1)
    gone.rename(tmp_path / "bank" / ".block-0001.partial-999999999")
    assert [p.name for p in bank_blocks(tmp_path / "bank")] == ["block-0000"]
    res = bank(path, tmp_path / "bank")
    assert res["blocks"] == [1] and res["skipped"] == [0]
    assert snapshot(block_folder(tmp_path / "bank", 0)) == kept
    assert not (tmp_path / "bank" / ".block-0001.partial-999999999").exists()  # its process is gone: ours to remove
    with np.load(gone / "blocks.npz") as f:
        assert {k: f[k] for k in f.files}.keys() == old.keys()
        for k in (k for k in old if not k.startswith("seconds/")):  # timings aside
            assert np.array_equal(f[k], old[k], equal_nan=True), k  # the same draws: the same sums


def test_a_bank_refuses_another_scenario_and_never_replaces_what_is_not_a_block(tmp_path):
    path = tiny(tmp_path, block_runs=1, mc_runs=2)
    bank(path, tmp_path / "bank", shard=(1, 2))
    before = snapshot(tmp_path / "bank")
    (tmp_path / "other").mkdir()
    other = tiny(tmp_path / "other", block_runs=1, mc_runs=2, seed=9)
    with pytest.raises(ConfigError, match="another scenario or other settings"):
        bank(other, tmp_path / "bank")
    assert snapshot(tmp_path / "bank") == before
    junk = block_folder(tmp_path / "bank", 1)
    junk.mkdir()
    (junk / "notes.txt").write_text("mine")
    with pytest.raises(OutputError, match="block-0001 is not a complete block"):
        bank(path, tmp_path / "bank")
    assert (junk / "notes.txt").read_text() == "mine"
    plain = tmp_path / "plain"
    plain.mkdir()
    (plain / "data.csv").write_text("1,2\n")
    with pytest.raises(OutputError, match="files pmsr did not write"):
        bank(path, plain)
    assert sorted(os.listdir(plain)) == ["data.csv"]


@pytest.mark.integration
def test_a_bank_that_lost_its_bank_json_gets_it_back_from_its_blocks_or_is_refused(tmp_path, capsys):
    """Every block's shard.json names the scenario and its folder, as bank.json did: the same command
    writes bank.json again (the bytes its first command wrote) and runs what is missing; a command
    of other settings, or a bank.json that is not a bank's, is refused in one line with nothing changed."""
    path = tiny(tmp_path, block_runs=1, mc_runs=2)
    whole = evaluate(path, tmp_path / "whole", progress=False)
    bank(path, tmp_path / "bank", shard=(1, 2))
    held = (tmp_path / "bank" / "bank.json").read_bytes()
    (tmp_path / "bank" / "bank.json").unlink()
    (tmp_path / "other").mkdir()
    other = tiny(tmp_path / "other", block_runs=1, mc_runs=2, seed=9)
    before = snapshot(tmp_path / "bank")
    assert main(["evaluate", str(other), "--out", str(tmp_path / "bank"), "--per-block", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"pmsr: error: --out {tmp_path / 'bank'} has 1 block(s) of 'pmsr evaluate --per-block' but no "
                   "bank.json, and block-0000 is not a complete block of this scenario and settings, so the bank's "
                   "file cannot be rebuilt: give the scenario file and options of the bank's first command, or "
                   "another --out"]
    assert snapshot(tmp_path / "bank") == before
    (tmp_path / "bank" / "bank.json").write_text("my notes\n")  # not a bank's: never replaced
    assert main(["evaluate", str(path), "--out", str(tmp_path / "bank"), "--per-block", "--quiet"]) == 2
    assert "bank.json that is not a bank's" in capsys.readouterr().err
    assert (tmp_path / "bank" / "bank.json").read_text() == "my notes\n"
    (tmp_path / "bank" / "bank.json").unlink()
    merged = merge([tmp_path / "bank"], tmp_path / "early", runs=1)  # merge reads the blocks, not bank.json
    assert merged["mc_runs"] == 1 and not (tmp_path / "bank" / "bank.json").exists()
    taken = tmp_path / "bank" / f".bank.json.{os.getpid()}"  # the temporary's name, taken by a file not ours
    taken.write_text("my draft\n")
    assert main(["evaluate", str(path), "--out", str(tmp_path / "bank"), "--per-block", "--quiet"]) == 2
    assert "is taken" in capsys.readouterr().err and taken.read_text() == "my draft\n"
    taken.unlink()
    assert main(["evaluate", str(path), "--out", str(tmp_path / "bank"), "--per-block", "--quiet"]) == 0
    assert capsys.readouterr().out.splitlines()[0] == (f"bank {tmp_path / 'bank'}: bank.json was missing; rebuilt "
                                                      "from its 1 block(s), which name this command's scenario and "
                                                      "settings")
    assert (tmp_path / "bank" / "bank.json").read_bytes() == held
    assert [p.name for p in bank_blocks(tmp_path / "bank")] == ["block-0000", "block-0001"]
    assert accuracy(merge([tmp_path / "bank"], tmp_path / "merged")) == accuracy(whole)


def test_a_bank_with_neither_bank_json_nor_blocks_is_opened_again(tmp_path, capsys):
    """Only the marker left (it says --per-block made the folder): nothing can disagree with the command."""
    import shutil

    path = tiny(tmp_path, block_runs=1, mc_runs=1)
    bank(path, tmp_path / "bank")
    held = (tmp_path / "bank" / "bank.json").read_bytes()
    (tmp_path / "bank" / "bank.json").unlink()
    shutil.rmtree(block_folder(tmp_path / "bank", 0))
    assert main(["evaluate", str(path), "--out", str(tmp_path / "bank"), "--per-block", "--quiet"]) == 0
    assert capsys.readouterr().out.splitlines()[0] == (f"bank {tmp_path / 'bank'}: bank.json was missing; written "
                                                      "again (the bank holds no block yet)")
    assert (tmp_path / "bank" / "bank.json").read_bytes() == held and len(bank_blocks(tmp_path / "bank")) == 1


@pytest.mark.parametrize("extra, message", [
    (["--overwrite"], "--per-block continues the bank at --out and never replaces it"),
    (["--executor", "local"], "--per-block banks the blocks of one process"),
])
def test_per_block_option_conflicts_are_one_line_errors(tmp_path, capsys, extra, message):
    path = tiny(tmp_path, block_runs=1, mc_runs=2)
    before = sorted(os.listdir(tmp_path))
    assert main(["evaluate", str(path), "--out", str(tmp_path / "bank"), "--per-block", "--quiet", *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert sorted(os.listdir(tmp_path)) == before


def test_the_command_line_reports_each_block_and_merges_the_bank(tmp_path, capsys):
    path = tiny(tmp_path, block_runs=1, mc_runs=2)
    assert main(["evaluate", str(path), "--out", str(tmp_path / "bank"), "--per-block", "--shard", "2/2"]) == 0
    out = capsys.readouterr().out
    assert f"block 2/2 -> {block_folder(tmp_path / 'bank', 1)}" in out and "1 of 2 block(s)" in out
    assert main(["evaluate", str(path), "--out", str(tmp_path / "bank"), "--per-block"]) == 0
    out = capsys.readouterr().out
    assert "1 of shard 1/1's 2 block(s) already there" in out and "block 1/2 ->" in out and "block 2/2" not in out
    assert main(["merge", str(tmp_path / "bank"), "--out", str(tmp_path / "merged")]) == 0
    assert json.loads((tmp_path / "merged" / "results.json").read_text())["mc_runs"] == 2


@pytest.mark.integration
def test_a_bank_of_some_rows_is_continued_by_the_same_command(tmp_path, capsys):
    """``--methods`` with ``--per-block``: the second process (or the second sitting) of a bank that
    holds some rows continues it, as for the whole scenario, and a bank of other rows is refused."""
    path = tiny(tmp_path, block_runs=1, mc_runs=2)
    cmd = ["evaluate", str(path), "--out", str(tmp_path / "bank"), "--per-block", "--methods", "UKF"]
    assert main(cmd + ["--shard", "2/2"]) == 0
    assert main(cmd) == 0
    assert "1 of shard 1/1's 2 block(s) already there" in capsys.readouterr().out
    assert main(["merge", str(tmp_path / "bank"), "--out", str(tmp_path / "merged")]) == 0
    results = json.loads((tmp_path / "merged" / "results.json").read_text())
    assert results["mc_runs"] == 2 and all(list(c["methods"]) == ["UKF"] for c in results["cases"].values())
    before = snapshot(tmp_path / "bank")
    assert main(["evaluate", str(path), "--out", str(tmp_path / "bank"), "--per-block", "--methods", "EKF"]) == 2
    assert "another scenario" in capsys.readouterr().err
    assert snapshot(tmp_path / "bank") == before


def test_every_block_records_the_environment_the_process_started_with(tmp_path, monkeypatch):
    """Commits made while a long bank runs do not change the code it runs: each block names the
    commit the process started at."""
    import pmsr_nn.harness.run.block_bank as block_bank

    calls = []
    monkeypatch.setattr(block_bank, "environment", lambda device: calls.append(device) or {"commit": f"c{len(calls)}"})
    path = tiny(tmp_path, block_runs=1, mc_runs=2)
    bank(path, tmp_path / "bank")
    assert calls == ["cpu"]
    for b in (0, 1):
        assert json.loads((block_folder(tmp_path / "bank", b) / "shard.json").read_text())["environment"] == {"commit": "c1"}


@pytest.mark.integration
def test_a_preview_merges_the_first_runs_and_says_it_is_one(tmp_path, capsys):
    """``pmsr merge --runs K``: the first K runs of a bank still filling give the figures of the
    scenario run with K runs, bit for bit, and the results and report say they are a preview."""
    path = tiny(tmp_path, block_runs=1)  # 4 blocks of one run
    bank(path, tmp_path / "bank", shard=(1, 2))  # blocks 0, 1
    evaluate(path, tmp_path / "s4", shard=(4, 4), progress=False)  # block 3: beyond the preview, left out
    short = evaluate(path, tmp_path / "short", mc_runs=2, progress=False)
    assert main(["merge", str(tmp_path / "bank"), str(tmp_path / "s4"), "--runs", "2", "--out", str(tmp_path / "p")]) == 0
    assert "A PREVIEW: the first 2 of the scenario's 4 runs" in capsys.readouterr().out
    preview = json.loads((tmp_path / "p" / "results.json").read_text())
    assert accuracy(preview) == accuracy(short) and preview["mc_runs"] == 2
    assert preview["environment"]["preview_of_runs"] == 4
    assert "**A preview: the first 2 of the scenario's 4 runs**" in (tmp_path / "p" / "report.md").read_text()
    with pytest.raises(ConfigError, match="lack blocks 2"):  # the first 3 runs: block 2 is not there yet
        merge([tmp_path / "bank"], tmp_path / "q", runs=3)
    evaluate(path, tmp_path / "s1of2", shard=(1, 2), progress=False)  # blocks 0-1 in one shard
    with pytest.raises(ConfigError, match="holds blocks on both sides of run 1"):
        merge([tmp_path / "s1of2"], tmp_path / "q", runs=1)
    with pytest.raises(ConfigError, match=r"--runs must be in 1\.\.4"):
        merge([tmp_path / "bank"], tmp_path / "q", runs=5)
    assert not (tmp_path / "q").exists()


def test_a_block_a_live_process_holds_is_passed_over_and_a_dead_ones_claim_is_taken(tmp_path):
    path = tiny(tmp_path, block_runs=1, mc_runs=4)
    bank(path, tmp_path / "bank", shard=(1, 4))  # opens the bank with block 0
    (tmp_path / "bank" / ".block-0001.claim").write_text(f"{os.getpid()}\n")  # a live process runs block 1
    (tmp_path / "bank" / ".block-0002.claim").write_text("999999999\n")  # a process that is gone held block 2
    (tmp_path / "bank" / ".block-0003.claim").write_text("my notes\n")  # not a claim of ours: never removed
    res = bank(path, tmp_path / "bank")
    assert res["skipped"] == [0] and res["others"] == [1, 3] and res["blocks"] == [2]
    assert (tmp_path / "bank" / ".block-0003.claim").read_text() == "my notes\n"
    assert [p.name for p in bank_blocks(tmp_path / "bank")] == ["block-0000", "block-0002"]
    assert (tmp_path / "bank" / ".block-0001.claim").exists()  # not ours: left alone
    assert not (tmp_path / "bank" / ".block-0002.claim").exists()  # ours once taken over: released when done
    assert not list((tmp_path / "bank").glob(".block-*.claim-*"))


@pytest.mark.integration
def test_two_processes_fill_one_bank_and_run_every_block_once(tmp_path):
    import subprocess
    import sys

    path = tiny(tmp_path, block_runs=1, mc_runs=6)
    cmd = [sys.executable, "-m", "pmsr_nn.cli", "evaluate", str(path), "--out", str(tmp_path / "bank"), "--per-block"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)
             for _ in range(2)]
    outs = [p.communicate(timeout=600)[0] for p in procs]
    assert [p.returncode for p in procs] == [0, 0]
    ran = [line.split()[1] for out in outs for line in out.splitlines() if line.startswith("block ")]
    assert sorted(ran) == [f"{b}/6" for b in range(1, 7)]  # each block run by exactly one of the two
    assert len(bank_blocks(tmp_path / "bank")) == 6 and not list((tmp_path / "bank").glob(".block-*"))
    whole = evaluate(path, tmp_path / "whole", progress=False)
    assert accuracy(merge([tmp_path / "bank"], tmp_path / "merged")) == accuracy(whole)


@pytest.mark.integration
def test_a_shards_blocks_filed_into_a_bank_merge_as_if_the_bank_had_run_them(tmp_path):
    """Blocks of 2, 2 and 1 runs: shard 2/2 holds the last two; filed into a bank (split per block)
    beside block 0 run by the bank, they merge to the unsharded figures bit for bit."""
    from pmsr_nn.harness.run.block_bank import file_shard
    from pmsr_nn.harness.run.block_sums import BlockSums, read_shard

    path = tiny(tmp_path, block_runs=2, mc_runs=5)
    evaluate(path, tmp_path / "s2", shard=(2, 2), progress=False)
    _, bs = read_shard(tmp_path / "s2")
    back = BlockSums.concatenate(bs.split([2, 1]))
    for c, per in bs.sums.items():
        for m, qs in per.items():
            for q, a in qs.items():
                assert np.array_equal(back.sums[c][m][q], a, equal_nan=True), (c, m, q)
            assert np.array_equal(back.seconds[c][m], bs.seconds[c][m])
    assert file_shard(tmp_path / "s2", tmp_path / "bank") == [1, 2]
    assert file_shard(tmp_path / "s2", tmp_path / "bank") == []  # already there: left as they are
    meta = json.loads((block_folder(tmp_path / "bank", 2) / "shard.json").read_text())
    assert meta["shard"] == [3, 3] and meta["blocks"] == [2] and meta["environment"]["filed_from"] == str(tmp_path / "s2")
    assert bank(path, tmp_path / "bank")["blocks"] == [0]
    whole = evaluate(path, tmp_path / "whole", progress=False)
    assert accuracy(merge([tmp_path / "bank"], tmp_path / "merged")) == accuracy(whole)
    with pytest.raises(ConfigError, match="another scenario or other settings"):
        (tmp_path / "o").mkdir()
        evaluate(tiny(tmp_path / "o", block_runs=2, mc_runs=5, seed=8), tmp_path / "t2", shard=(2, 2), progress=False)
        file_shard(tmp_path / "t2", tmp_path / "bank")


def test_a_bank_beside_its_scenario_merges_and_continues_from_a_copy_at_another_path(tmp_path):
    """A bank committed with its scenario (and a checkpoint the scenario names relative to its own
    folder) records that folder relative to itself: a clone at another path continues and merges it."""
    repo = tmp_path / "repo"
    (repo / "models").mkdir(parents=True)
    shutil.copy(ROOT / "models/released/mdfnn.pt", repo / "models" / "mdfnn.pt")
    path = tiny(repo, block_runs=1, mc_runs=2, methods=[
        {"name": "EKF", "kind": "ekf"}, {"name": "MDFNN", "kind": "learned", "checkpoint": "models/mdfnn.pt"}])
    whole = evaluate(path, tmp_path / "whole", progress=False)
    bank(path, repo / "results" / "bank", shard=(1, 2))
    assert json.loads((repo / "results" / "bank" / "bank.json").read_text())["base_dir"] == "../.."
    assert json.loads((block_folder(repo / "results" / "bank", 0) / "shard.json").read_text())["base_dir"] == "../../.."
    clone = tmp_path / "elsewhere" / "clone"
    shutil.copytree(repo, clone)
    shutil.rmtree(repo)  # the first checkout is gone
    res = bank(clone / "tiny.yaml", clone / "results" / "bank")
    assert res["blocks"] == [1] and res["skipped"] == [0]
    merged = accuracy(merge([clone / "results" / "bank"], tmp_path / "merged"))
    for c in merged:  # the checkpoint is named where the clone holds it; all else as the first checkout's run
        assert merged[c]["methods"]["MDFNN"].pop("checkpoint") == str((clone / "models" / "mdfnn.pt").resolve())
        whole["cases"][c]["methods"]["MDFNN"].pop("checkpoint")
    assert merged == accuracy(whole)


def test_a_bank_that_records_its_scenario_folder_absolute_still_continues_and_merges(tmp_path):
    """Banks of earlier releases name the scenario's folder by its absolute path: read as it is."""
    path = tiny(tmp_path, block_runs=1, mc_runs=2, methods=[{"name": "EKF", "kind": "ekf"}])
    whole = evaluate(path, tmp_path / "whole", progress=False)
    bank(path, tmp_path / "bank", shard=(1, 2))
    for f in [tmp_path / "bank" / "bank.json", block_folder(tmp_path / "bank", 0) / "shard.json"]:
        meta = json.loads(f.read_text())
        f.write_text(json.dumps({**meta, "base_dir": str(tmp_path.resolve())}))
    assert bank(path, tmp_path / "bank")["skipped"] == [0]
    assert accuracy(merge([tmp_path / "bank"], tmp_path / "merged")) == accuracy(whole)


def _score_every_scan(folder):
    """Rewrite a block's per-run GOSPA and OSPA as blocks made before issue 55's fix kept them in a
    scenario with maps: averaged over every scan, not the set scans, and without the trajectory
    GOSPA (kept since). Returns each block's run figures before and after."""
    path = folder / "blocks.npz"
    arrays = {k: v for k, v in np.load(path).items() if "/tgospa_" not in k}
    changed = []
    for key in [k for k in arrays if k.endswith("/gospa_run")]:
        pre = key[:-len("gospa_run")]
        per_scan = arrays[pre + "gospa_loc"] + arrays[pre + "gospa_missed"] + arrays[pre + "gospa_false"]
        runs = len(arrays[key])
        # a block of several runs keeps the sums of its runs' per-scan values: split them evenly
        old = np.repeat(per_scan.mean(1) / runs, runs)
        changed.append((arrays[key].copy(), old))
        arrays[key] = old
        arrays[pre + "ospa_run"] = np.repeat(arrays[pre + "ospa"].mean(1) / runs, runs)
    np.savez(path, **arrays)
    return changed


def test_blocks_scored_over_every_scan_are_re_derived_on_the_set_scans_or_refused(tmp_path):
    """Blocks made before issue 55's fix averaged the per-run figures over every scan: a merge
    re-derives a one-run block's from its per-scan sums over the set scans (the figures of a fresh
    run, to float64 rounding, and the record and report say which blocks), and refuses a block of
    several runs, whose per-scan sums add its runs, writing nothing."""
    path = two_drones(tmp_path, block_runs=1)  # warm-up 10 scans; EKF on each drone's stream, S-MSJPDA
    whole = evaluate(path, tmp_path / "whole", progress=False)
    bank(path, tmp_path / "bank")
    untouched = merge([tmp_path / "bank"], tmp_path / "untouched")
    assert "per_run_rescored_blocks" not in untouched["environment"]  # today's blocks agree with the set scans
    for folder in bank_blocks(tmp_path / "bank"):
        for kept, old in _score_every_scan(folder):
            assert abs(old[0] / kept[0] - 1) > 1e-3  # the window matters here: the check has something to find
    merged = merge([tmp_path / "bank"], tmp_path / "merged")
    assert merged["environment"]["per_run_rescored_blocks"] == "0-3"
    assert merged["environment"]["shard_machines"] == [json.loads(
        (block_folder(tmp_path / "bank", 0) / "shard.json").read_text())["environment"]["machine"]]
    assert "Blocks 0-3 were scored over other scans" in (tmp_path / "merged" / "report.md").read_text()
    for c, case in whole["cases"].items():
        for m, row in case["methods"].items():
            for key in ("gospa_m", "gospa_se_m", "ospa_m", "ospa_se_m", "gospa_median_run_m", "gospa_run_quantiles_m"):
                np.testing.assert_allclose(merged["cases"][c]["methods"][m][key], row[key], rtol=1e-12,
                                           err_msg=f"{c} {m} {key}")
    (tmp_path / "two").mkdir()
    several = two_drones(tmp_path / "two")  # blocks of 2 runs
    bank(several, tmp_path / "two" / "bank")
    for folder in bank_blocks(tmp_path / "two" / "bank"):
        _score_every_scan(folder)
    with pytest.raises(ConfigError, match=r"block 0 \(c, EKF\) was scored over other scans than the "
                                          r"case's set scans \(scans 10\.\.99\) and holds 2 runs"):
        merge([tmp_path / "two" / "bank"], tmp_path / "two" / "merged")
    assert not (tmp_path / "two" / "merged").exists()
