"""CLEAR MOT identity switches (issue 55, item 4): a target keeps its track while that track stays
within the cut-off (the persistent mapping), and a switch is a target's track changing from the
last one it had, also across scans without one. The EKF with the association known shows none
where two drones cross."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from pmsr_nn.harness.run.blocks import call_method, draw_block, run_blocks
from pmsr_nn.harness.results.finalise import finalise
from pmsr_nn.harness.run.runner import prepare
from pmsr_nn.harness.scenario.schema import scenario_from_dict
from pmsr_nn.metrics import identity_switches, label_switches, optimal_assignment, persistent_assignment

from test_track_mapping import _crossing

ROOT = Path(__file__).resolve().parents[1]


def _per_target(tracks: list[list[int]]) -> torch.Tensor:
    """An assignment ``(1, K, M)`` from each target's track per scan (``tracks[n][k]``, -1: none)."""
    K = len(tracks[0])
    M = 1 + max(max(t) for t in tracks)
    a = torch.full((1, K, M), -1, dtype=torch.int64)
    for n, row in enumerate(tracks):
        for k, m in enumerate(row):
            if m >= 0:
                a[0, k, m] = n
    return a


@pytest.mark.parametrize("tracks, ids, labels", [
    ([[0, 0, 1, 1, 1]], [1], [1]),            # one change between consecutive scans: both count it
    ([[0, -1, 1, 1, 1]], [1], [0]),           # lost, then another track: a switch only across the gap
    ([[0, -1, -1, 0, 0]], [0], [0]),          # the same track back after a gap: no switch
    ([[0, 1, 0, -1, 1]], [3], [2]),           # 0 -> 1 -> 0, gap, -> 1: three changes from the last track
    ([[-1, -1, 2, 2, -1]], [0], [0]),         # a first track is no switch
    ([[0, 0, 0, 0, 0], [1, -1, 2, -1, 2]], [0, 1], [0, 0]),  # two targets counted apart
])
def test_identity_switches_by_hand(tracks, ids, labels):
    a = _per_target(tracks)
    tm = torch.ones(1, a.shape[1], len(tracks), dtype=torch.bool)
    assert identity_switches(a, tm).tolist() == [ids]
    assert label_switches(a, tm).tolist() == [labels]


def _reference(a: torch.Tensor, tm: torch.Tensor) -> list[list[int]]:
    """The MOTChallenge count in plain Python: per run and target, remember the last track seen."""
    B, K, M = a.shape
    N = tm.shape[-1]
    out = []
    for b in range(B):
        row = []
        for n in range(N):
            last, count = None, 0
            for k in range(K):
                hit = [m for m in range(M) if int(a[b, k, m]) == n and bool(tm[b, k, n])]
                if hit:
                    if last is not None and hit[0] != last:
                        count += 1
                    last = hit[0]
            row.append(count)
        out.append(row)
    return out


def test_identity_switches_equal_a_plain_reference_on_random_mappings():
    """Random tracks around slowly moving targets, appearing and vanishing, through the persistent
    mapping; the count is never below the label switches (consecutive scans only) and above them
    in some run (a change across a gap happens)."""
    g = torch.Generator().manual_seed(3)
    B, K, M, N = 40, 12, 4, 3
    truth = (torch.rand(B, 1, N, 2, generator=g) * 300.0 + torch.arange(K)[None, :, None, None] * 20.0).double()
    pick = torch.randint(0, N, (B, K, M), generator=g)
    est = truth.gather(2, pick[..., None].expand(B, K, M, 2)) + torch.randn(B, K, M, 2, generator=g, dtype=torch.float64) * 40.0
    em = torch.rand(B, K, M, generator=g) < 0.6
    tm = torch.rand(B, K, N, generator=g) < 0.9
    mapped = persistent_assignment(est, em, truth, tm, 100.0, 2.0)
    ids = identity_switches(mapped, tm)
    assert ids.tolist() == _reference(mapped, tm)
    labels = label_switches(mapped, tm)
    assert bool((ids >= labels).all()) and bool((ids > labels).any())
    # leading dims: a (2, B/2) batch gives the same counts
    assert torch.equal(identity_switches(mapped.view(2, B // 2, K, M), tm.view(2, B // 2, K, N)).view(B, N), ids)


def test_the_crossing_cases_of_the_persistent_mapping():
    """Tracks that follow their own targets through a crossing: no switch (the per-scan assignment
    would count two per target); tracks that exchange targets: one each."""
    est, em, truth, tm = _crossing(swap_after=False)
    assert identity_switches(persistent_assignment(est, em, truth, tm, 500.0, 2.0), tm).tolist() == [[0, 0]]
    assert identity_switches(optimal_assignment(est, em, truth, tm, 500.0, 2.0), tm).tolist() == [[2, 2]]
    est, em, truth, tm = _crossing(swap_after=True)
    assert identity_switches(persistent_assignment(est, em, truth, tm, 100.0, 2.0), tm).tolist() == [[1, 1]]


def _crossing_drones(tmp_path) -> dict:
    """one_sky's crossing pair (6 km out at bearings 70 and 110 deg, headings 150 and 30 deg,
    15 m/s: they meet at one point 158 s after birth) for 220 s, through one_sky's six pairs."""
    cross = {"start_range_m": 6000.0, "speed_mps": 15.0, "birth_s": 0.0, "death_s": 220.0,
             "segments": [{"duration_s": 220.0}]}
    return {"name": "crossing_ekf", "recipe": str(ROOT / "datasets" / "one_sky_fm.yaml"), "seed": 5, "mc_runs": 4,
            "block_runs": 4, "warmup_steps": 20, "noise": {"range_m": 30.0, "range_rate_mps": 2.0, "azimuth_deg": 3.0},
            "set_metrics": {"c_m": 500.0, "p": 2.0},
            "methods": [{"name": "EKF", "kind": "ekf"}],
            "cases": [{"name": "cross", "targets": [
                {"name": "cross_1", "start_bearing_deg": 70.0, "heading_deg": 150.0, **cross},
                {"name": "cross_2", "start_bearing_deg": 110.0, "heading_deg": 30.0, **cross}]}]}


def test_the_ekf_with_the_association_known_shows_no_switch_where_two_drones_cross(tmp_path):
    """Through the runner: 0 identity and label switches per run for the EKF, whose slot i is
    target i's track, though the drones pass through one point; on the same estimates the
    per-scan OSPA assignment trades the two tracks near the crossing (so the check can fail)."""
    setup = prepare(scenario_from_dict(_crossing_drones(tmp_path), tmp_path))
    row = finalise(setup, run_blocks(setup, range(1), progress=False))["cross"]["methods"]["EKF"]
    assert row["id_switches_per_run"] == 0.0 and row["label_switches_per_run"] == 0.0
    assert row["id_switches_per_target"] == [0.0, 0.0]
    case = setup.cases[0]
    truth, products = draw_block(setup, 0, 0)
    est = call_method(setup, setup.methods[0], case, products, (setup.scenario.seed, 0, 0))
    pos = list(setup.models.motion.pos_idx)
    tm = truth.alive.expand(truth.x.shape[:3])
    per_scan = optimal_assignment(est.x[..., pos], est.exists, truth.x[..., pos], tm, 500.0, 2.0)
    assert int(identity_switches(per_scan, tm).sum()) > 0


def test_the_report_shows_identity_switches_and_old_records_their_label_switches():
    """A recorded results.json (before identity switches were kept) renders its label switches;
    the same rows holding identity switches render those, under their own header."""
    import copy
    import json

    from pmsr_nn.harness.report.multitarget_tables import multi_target_tables

    old = json.loads((ROOT / "evaluate" / "results" / "dense_crossing" / "results.json").read_text())
    text = "\n".join(multi_target_tables(old, None, "paper"))
    assert "label switches / run" in text and "ID switches" not in text
    new = copy.deepcopy(old)
    for row in new["cases"]["dense_crossing"]["methods"].values():
        if row.get("label_switches_per_run") is not None:
            row["id_switches_per_run"] = 12.345
    text = "\n".join(multi_target_tables(new, None, "paper"))
    assert "ID switches / run (CLEAR MOT)" in text and "label switches / run" not in text and "| 12.35 |" in text
