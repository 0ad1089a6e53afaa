"""The figures a method kind declares (``MethodKind.metrics``, :mod:`pmsr_nn.methods.kind_metrics`):
a kind that declares a metric gets its row fields, one that declares none gets none even where
its extras carry a metric's keys (the harness reads no extras), and blocks merged give the
figures of one block holding every run."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_one_scenario import two_drones

from pmsr_nn.harness import evaluate
from pmsr_nn.harness.run import scoring
from pmsr_nn.harness.run.block_sums import BlockSums
from pmsr_nn.methods import REGISTRY, MethodKind, register
from pmsr_nn.methods.kind_metrics import (PER_RUN_SUMS, BlockContext, DualityGap, Labelling, Metric, RowContext,
                                          TBDFrames, TrackLoss)
from pmsr_nn.simulation.products import Truth
from pmsr_nn.trackers.base import Estimates


class Held(Metric):
    """Reported (run, scan, track) entries: ``held`` summed per block; the row's ``held_per_run``."""

    keys = ("held",)

    def update(self, est, truth, ctx):
        return {"held": np.asarray(float(est.exists.sum()))}

    def compute(self, s, ctx):
        return {"held_per_run": float(s["held"] / ctx.runs)}, {}


def _hold(call):
    """Every living target's track at the origin; extras as a P-MSJPDA's and a PHD's would carry
    them (the duality gap: the block's index + 0.5)."""
    z = call.product.z  # (B, N, K, m)
    B, N, K = z.shape[:3]
    x = torch.zeros(B, K, N, call.product.prior.x.shape[-1], dtype=torch.float64)
    extras = {"max_duality_gap": call.seed[-1] + 0.5, "labels": torch.ones(B, dtype=torch.int64),
              "unlabelled": True}
    return Estimates(x, call.alive.expand(B, K, N).clone(), extras=extras)


@pytest.fixture
def kinds():
    register(MethodKind("test_measured", "measurements", _hold, metrics=(Held(), DualityGap()),
                        description="test: declares two metrics"))
    register(MethodKind("test_plain", "measurements", _hold, description="test: declares none"))
    yield
    for name in ("test_measured", "test_plain"):
        del REGISTRY[name]


def test_a_kind_gets_the_fields_of_the_metrics_it_declares_and_one_without_gets_none(tmp_path, kinds):
    methods = [{"name": "Measured", "kind": "test_measured"}, {"name": "Plain", "kind": "test_plain"}]
    res = evaluate(two_drones(tmp_path, methods=methods), tmp_path / "out", progress=False)  # 4 runs, blocks of 2
    case = res["cases"]["c"]
    measured, plain = case["methods"]["Measured"], case["methods"]["Plain"]
    # a track exactly where a target lives: the truth's cardinality summed over the scans
    assert measured["held_per_run"] == float(sum(case["curves"]["cardinality_truth"]))
    assert measured["max_duality_gap"] == 1.5  # blocks 0 and 1: the largest, not their sum (2.0)
    # extras the harness does not read: no labels, no "unlabelled" row, trajectories scored
    for row in (measured, plain):
        assert "labels_per_run" not in row and "labelled" not in row and row["tgospa_m"] is not None
    assert not {"held_per_run", "max_duality_gap", "loss_probability"} & set(plain)
    same = {k: v for k, v in plain.items() if k not in ("kind", "seconds_per_run")}
    assert same == {k: measured[k] for k in same}  # the harness's own figures: the same for both


def _loss_block(B: int, offset: int):
    """Flags of ``B`` runs (runs ``offset..``) of 2 tracks over 6 scans: run r's track 0 has the
    dummy most probable at scans r..r+3 (lost by the 4-in-a-row rule iff r <= 2), its track 1 a
    gate of (r + 1) km at every scan (lost beyond 2.5 km: iff r >= 2)."""
    K, N = 6, 2
    r = torch.arange(offset, offset + B)
    k = torch.arange(K)
    dummy = torch.zeros(B, K, N, dtype=torch.bool)
    dummy[..., 0] = (k[None] >= r[:, None]) & (k[None] < r[:, None] + 4)
    gate = torch.zeros(B, K, N, dtype=torch.float64)
    gate[..., 1] = (r[:, None] + 1.0) * 1000.0
    x = torch.zeros(B, K, N, 2, dtype=torch.float64)
    est = Estimates(x, torch.ones(B, K, N, dtype=torch.bool),
                    extras={"dummy_most_probable": dummy, "gate_range_sd_m": gate, "labels": r + 1,
                            "game_rounds": torch.full((K,), float(offset))})
    truth = Truth(x.clone(), torch.ones(K, N, dtype=torch.bool))
    return est, truth


class _Loss:
    successive_scans, gate_range_sd_m = 4, 2500.0


def _row(metrics, bs: BlockSums, runs: int, targets: int) -> dict:
    """A row's fields from the stacked sums of ``bs``, as finalise computes them."""
    blocks = bs.sums["c"]["m"]
    s = {q: a if scoring.per_run(q) else a.sum(0) for q, a in blocks.items()}
    ctx = RowContext(runs, len(bs.blocks), targets, None, None, blocks)
    row = {}
    for m in metrics:
        row.update(m.compute(s, ctx)[0])
    return row


def test_blocks_merged_give_the_figures_of_one_block():
    metrics = (TrackLoss(), Labelling())
    ctx = BlockContext([0, 1], [0, 1], _Loss())
    whole, parts = BlockSums([0]), BlockSums([0, 1])
    est, truth = _loss_block(5, 0)
    whole.add("c", "m", {q: v for m in metrics for q, v in m.update(est, truth, ctx).items()}, 0.0)
    for offset, B in ((0, 2), (2, 3)):
        est, truth = _loss_block(B, offset)
        parts.add("c", "m", {q: v for m in metrics for q, v in m.update(est, truth, ctx).items()}, 0.0)
    one, merged = _row(metrics, whole.stacked(), 5, 2), _row(metrics, parts.stacked(), 5, 2)
    # runs 0-4: track 0 lost in runs 0, 1, 2, track 1 in runs 2, 3, 4: 6 of 10 tracks
    assert one["loss_probability"] == merged["loss_probability"] == 0.6
    assert one["labels_per_run"] == merged["labels_per_run"] == 3.0  # (1 + 2 + 3 + 4 + 5) / 5
    # game rounds: a count per block, averaged over the blocks (0 in block 0, 2 in block 1)
    assert one["game_rounds_mean"] == 0.0 and merged["game_rounds_mean"] == 1.0
    # no loss rule in the scenario: no loss sums
    assert TrackLoss().update(est, truth, BlockContext([0, 1], [0, 1], None)) == {}


def test_a_metrics_per_run_sums_are_concatenated_over_blocks_not_stacked():
    assert "tbd_run_pos_err" in PER_RUN_SUMS and scoring.per_run("tbd_run_pos_err")

    class Mine(Metric):
        per_run = ("test_mine_per_run",)

    assert scoring.per_run("test_mine_per_run") and not scoring.per_run("held")
    bs = BlockSums([0, 1])
    for b in range(2):
        bs.add("c", "m", {"test_mine_per_run": np.full((2, 3), float(b)), "held": np.full(3, 1.0)}, 0.0)
    out = bs.stacked().sums["c"]["m"]
    assert out["test_mine_per_run"].shape == (4, 3) and out["test_mine_per_run"][:, 0].tolist() == [0, 0, 1, 1]
    assert out["held"].shape == (2, 3)


def test_the_frames_of_a_track_before_detect_row_against_hand_counts():
    """Two runs, three frames, one target alive in frames 1-2, at (0, 0) with velocity (1, 0):
    run 0 detects at every frame 3 m off (velocity 1 m/s off), run 1 only in frame 2, 4 m off."""
    B, K = 2, 3
    alive = torch.tensor([[False], [True], [True]])
    t = torch.zeros(B, K, 1, 4, dtype=torch.float64)
    t[..., 2] = 1.0  # columns: x, y, vx, vy
    truth = Truth(torch.where(alive[None, ..., None], t, float("nan")), alive)
    best = torch.zeros(B, K, 4, dtype=torch.float64)
    best[0, :, 0], best[0, :, 2] = 3.0, 2.0
    best[1, :, 1], best[1, :, 2] = 4.0, 1.0
    det = torch.tensor([[True, True, True], [False, False, True]])
    extras = {"tbd_detected": det, "tbd_best_x": best, "tbd_best_r": torch.full((B, K), 0.5, dtype=torch.float64),
              "tbd_snr_db": torch.zeros(B, K, 2, dtype=torch.float64), "tbd_particles": torch.full((B, K), 10)}
    est = Estimates(torch.zeros(B, K, 1, 4, dtype=torch.float64), det[..., None], extras=extras, paired=False)
    s = TBDFrames(lambda spec, maps: {}).update(est, truth, BlockContext([0, 1], [2, 3]))
    assert s["tbd_detected"].tolist() == [1.0, 1.0, 2.0]
    assert s["tbd_hits"].tolist() == [0.0, 1.0, 2.0]  # frame 0: no target lives
    assert s["tbd_pos"].tolist() == [0.0, 9.0, 25.0] and s["tbd_vel"].tolist() == [0.0, 1.0, 1.0]
    np.testing.assert_array_equal(s["tbd_run_pos_err"], [[np.nan, 3.0, 3.0], [np.nan, np.nan, 4.0]])


def test_a_metric_placed_nowhere_in_a_row_is_refused():
    with pytest.raises(ValueError, match="after must be one of"):
        class Lost(Metric):
            after = "the end"
