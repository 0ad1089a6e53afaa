"""``pmsr evaluate --batch-runs N``: several blocks' runs in one call of a batchable kind, each
block's draws its own, the figures those of block-by-block calls to float rounding."""

from __future__ import annotations

import json
import math

import pytest
import torch

from pmsr_nn.cli import main
from pmsr_nn.harness.evaluate import evaluate
from pmsr_nn.harness.run import batches
from pmsr_nn.harness.run.batches import batch_groups, blocks_per_call, split_estimates
from pmsr_nn.methods import registry
from pmsr_nn.simulation.detections import PADDING, PooledScans, Scans
from pmsr_nn.trackers.base import Estimates
from test_harness import accuracy
from test_one_scenario import two_drones

METHODS = [{"name": "EKF", "kind": "ekf"}, {"name": "PF", "kind": "particle_filter", "options": {"particles": 200}},
           {"name": "S-MSJPDA", "kind": "s_msjpda", "options": {"initiation": "detections"}},
           {"name": "BP", "kind": "bp"}]

ROUNDING = 1e-9
"""Relative agreement of a joined call's figures with block-by-block ones: float64 rounding
(1.1e-16) grouped differently by a batched matrix product, grown through 100 scans of filter
recursions; a changed association, track start or deletion moves a figure by
orders of magnitude more."""


def differences(a, b, where=""):
    """``(path, a, b)`` of every value of ``a`` and ``b`` that differs: floats beyond ``ROUNDING``
    (relative), anything else at all."""
    if isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for k in a:
            yield from differences(a[k], b[k], f"{where}/{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), where
        for i, (u, v) in enumerate(zip(a, b)):
            yield from differences(u, v, f"{where}[{i}]")
    elif isinstance(a, float) and isinstance(b, float):
        if not (math.isnan(a) and math.isnan(b)) and not math.isclose(a, b, rel_tol=ROUNDING, abs_tol=1e-12):
            yield where, a, b
    elif a != b:
        yield where, a, b


def test_joined_calls_give_the_block_by_block_figures_and_draw_nothing_else(tmp_path, monkeypatch):
    """Four one-run blocks: block by block, then in one call per batchable kind (the particle
    filter, which draws from its block's stream, still block by block: bit for bit)."""
    path = two_drones(tmp_path, methods=METHODS, mc_runs=4, block_runs=1)
    one = evaluate(path, tmp_path / "one", progress=False)
    joined = []
    monkeypatch.setattr(batches, "join", lambda parts: joined.append(len(parts)) or type(parts[0]).concat(parts))
    four = evaluate(path, tmp_path / "four", progress=False, batch_runs=4)
    assert joined == [4, 4, 4]  # EKF, S-MSJPDA and BP: one call each on the four blocks
    assert [registry()[m["kind"]].batchable for m in METHODS] == [True, False, True, True]
    assert list(differences(accuracy(one), accuracy(four))) == []
    pf = lambda res: accuracy(res)["c"]["methods"]["PF"]  # noqa: E731
    assert pf(one) == pf(four)


def test_a_bank_of_joined_blocks_merges_to_the_same_figures_bit_for_bit(tmp_path, capsys):
    """--per-block with --batch-runs claims aligned groups of blocks and files each block alone."""
    path = two_drones(tmp_path, methods=METHODS[2:], mc_runs=4, block_runs=1)
    evaluate(path, tmp_path / "whole", progress=False, batch_runs=2)
    bank = tmp_path / "bank"
    assert main(["evaluate", str(path), "--per-block", "--batch-runs", "2", "--out", str(bank), "--quiet"]) == 0
    assert sorted(p.name for p in bank.iterdir() if p.name.startswith("block-")) == [f"block-{i:04d}" for i in range(4)]
    assert main(["merge", str(bank), "--out", str(tmp_path / "merged")]) == 0
    whole, merged = (json.loads((tmp_path / d / "results.json").read_text()) for d in ("whole", "merged"))
    assert accuracy(merged) == accuracy(whole)


@pytest.mark.parametrize("extra, message", [
    (["--batch-runs", "0"], "argument --batch-runs: expected a positive integer, got '0'"),
    (["--batch-runs", "2", "--executor", "local"], "--batch-runs does not reach the jobs of --executor"),
])
def test_bad_batch_runs_are_one_line_errors_and_write_nothing(tmp_path, capsys, extra, message):
    path = two_drones(tmp_path, mc_runs=4, block_runs=1)
    try:
        code = main(["evaluate", str(path), "--out", str(tmp_path / "out"), "--quiet", *extra])
    except SystemExit as exc:  # argparse's own refusal
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["two.yaml"]


def test_groups_are_aligned_so_no_shard_or_worker_changes_them():
    assert batch_groups(range(10), 4) == [[0, 1, 2, 3], [4, 5, 6, 7], [8, 9]]
    assert batch_groups([5, 1, 2, 9], 4) == [[1, 2], [5], [9]]  # a resumed bank's leftovers: the same alignment
    assert batch_groups(range(3), 1) == [[0], [1], [2]]
    assert blocks_per_call(10, 1) == 10 and blocks_per_call(10, 4) == 2 and blocks_per_call(3, 4) == 1


def _scans(B, M, fill_first):
    z = torch.full((B, 2, 1, M, 3), math.nan, dtype=torch.float64)
    valid = torch.zeros(B, 2, 1, M, dtype=torch.bool)
    z[:, :, :, :fill_first] = 1.0
    valid[:, :, :, :fill_first] = True
    origin = torch.where(valid, torch.tensor(-1), torch.tensor(PADDING))
    return Scans(z, valid, origin)


def test_joined_detections_pad_the_shorter_lists_with_invalid_padding():
    a, b = _scans(1, 2, 2), _scans(2, 4, 3)
    j = Scans.concat([a, b])
    assert j.shape == (3, 2, 1, 4)
    assert torch.equal(j.valid[0], torch.tensor([True, True, False, False]).expand(2, 1, 4))
    assert bool(j.z[0, :, :, 2:].isnan().all()) and bool((j.origin[0, :, :, 2:] == PADDING).all())
    assert torch.equal(j.valid[1:], b.valid) and torch.equal(j.origin[1:], b.origin)
    assert torch.equal(j.z[1:].nan_to_num(-7.0), b.z.nan_to_num(-7.0))  # the longer lists as they were
    pooled = PooledScans.concat([PooledScans(a, torch.zeros(1, 2, 1, 2, dtype=torch.int64), torch.ones(1, 1, dtype=torch.bool)),
                                 PooledScans(b, torch.zeros(2, 2, 1, 4, dtype=torch.int64), torch.ones(1, 1, dtype=torch.bool))])
    assert pooled.pair.shape == (3, 2, 1, 4) and bool((pooled.pair[0, :, :, 2:] == -1).all())


def test_split_estimates_cuts_runs_slots_and_per_run_extras():
    B, K, M, n = 3, 2, 4, 2
    x = torch.arange(B * K * M * n, dtype=torch.float64).reshape(B, K, M, n)
    exists = torch.zeros(B, K, M, dtype=torch.bool)
    exists[0, :, 0] = True  # block 0 (run 0) uses slot 0 only
    exists[1, 1, 2] = True  # block 1 (runs 1, 2) uses slots up to 2
    extras = {"per_run": torch.arange(B), "per_call": 7.0, "per_scan": torch.arange(K + 5)}
    est = Estimates(x, exists, None, extras, paired=False)
    first, second = split_estimates(est, [1, 2])
    assert first.x.shape == (1, K, 1, n) and torch.equal(first.x, x[:1, :, :1])
    assert second.x.shape == (2, K, 3, n) and torch.equal(second.exists, exists[1:, :, :3])
    assert torch.equal(first.extras["per_run"], torch.tensor([0])) and torch.equal(second.extras["per_run"], torch.tensor([1, 2]))
    assert second.extras["per_call"] == 7.0 and second.extras["per_scan"].shape == (K + 5,)
    paired = split_estimates(Estimates(x, exists, None, {}, paired=True), [2, 1])
    assert [p.x.shape[2] for p in paired] == [M, M]  # slot i is target i: never cut
    with pytest.raises(ValueError, match="4 runs in the blocks, 3 in the estimates"):
        split_estimates(est, [2, 2])
