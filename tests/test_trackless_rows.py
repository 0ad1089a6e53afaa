"""A row that reports no track in a whole run (a tracker whose existence never reaches its reporting
threshold): counted per row in results.json (``runs_without_tracks``) and flagged under the report's
table and on the console; results written before the count was kept render without the flag."""

from __future__ import annotations

import copy
import math

import pytest
import torch
from test_one_scenario import two_drones

from pmsr_nn.harness import evaluate
from pmsr_nn.harness.report.flags import flag_paragraphs, warning_lines
from pmsr_nn.harness.report.multitarget_tables import multi_target_tables
from pmsr_nn.harness.results.typed import Results
from pmsr_nn.harness.run.scoring import track_mapping, track_sums
from pmsr_nn.methods import REGISTRY, MethodKind, register
from pmsr_nn.simulation.products import Truth
from pmsr_nn.trackers.base import Estimates


def counted(exists: torch.Tensor, alive: torch.Tensor) -> float:
    """``runs_without_tracks`` of tracks at the origin reported where ``exists (B, K, M)``, the
    targets (``alive (K, N)``) 100 m and more from it."""
    B, K, M = exists.shape
    N = alive.shape[1]
    truth_x = torch.arange(K * N * 2, dtype=torch.float64).reshape(1, K, N, 2).expand(B, K, N, 2) * 100.0
    truth = Truth(torch.where(alive[None, ..., None], truth_x, float("nan")), alive)
    est = Estimates(torch.zeros(B, K, M, 2, dtype=torch.float64), exists, paired=False)
    return float(track_sums(track_mapping(est, truth, [0, 1], 50.0, 2.0), exists, truth)["runs_without_tracks"])


def test_a_run_with_no_reported_track_is_counted_and_one_with_a_track_is_not():
    K, M = 5, 2
    alive = torch.ones(K, 1, dtype=torch.bool)
    exists = torch.zeros(4, K, M, dtype=torch.bool)
    exists[1, 3, 0] = True  # run 1: one track at one scan
    exists[2, :, 1] = True  # run 2: a track at every scan (a false one: the target is 100 m off or more)
    assert counted(exists, alive) == 2.0  # runs 0 and 3 reported nothing
    # no target lives in the case at all: reporting nothing is right, nothing is counted
    assert counted(torch.zeros(3, K, M, dtype=torch.bool), torch.zeros(K, 1, dtype=torch.bool)) == 0.0


def _silent(call):
    """No track, ever (a tracker that forgets its existence update)."""
    z, n = call.product.z, call.product.prior.x.shape[-1]  # (B, N, K, m), the state's dimension
    B, K = z.shape[0], z.shape[2]
    return Estimates(torch.zeros(B, K, 1, n, dtype=torch.float64), torch.zeros(B, K, 1, dtype=torch.bool), paired=False)


def _half(call):
    """One track at the origin at scan 30 in the first run of each block (of two runs), none in the other."""
    est = _silent(call)
    est.exists[0, 30, 0] = True
    return est


@pytest.fixture
def quiet_kinds():
    for name, run in (("test_silent", _silent), ("test_half", _half)):
        register(MethodKind(name, "measurements", run, description="test: reports (almost) no track"))
    yield
    for name in ("test_silent", "test_half"):
        del REGISTRY[name]


def test_rows_that_report_no_track_are_counted_and_flagged(tmp_path, quiet_kinds):
    methods = [{"name": "Silent", "kind": "test_silent"}, {"name": "Half", "kind": "test_half"},
               {"name": "EKF", "kind": "ekf"}]
    res = evaluate(two_drones(tmp_path, methods=methods), tmp_path / "out", progress=False)  # 4 runs, blocks of 2
    rows = res["cases"]["c"]["methods"]
    assert [rows[m]["runs_without_tracks"] for m in ("Silent", "Half", "EKF")] == [4, 2, 0]
    assert rows["Silent"]["gospa_missed_share"] == 1.0  # nothing reported: every living target missed
    report = (tmp_path / "out" / "report.md").read_text()
    flag = ("**No track reported:** Silent reported no track in 4 of 4 runs on c; Half reported no track in 2 of 4 "
            "runs on c: its existence update or reporting threshold may be wrong")
    assert flag in report and "EKF reported" not in report
    # under the table, before the multi-target figures
    assert report.index("## Position RMSE") < report.index(flag) < report.index("## Multi-target figures")
    assert [line for line in warning_lines(res, "") if "no track" in line] == [
        "Silent reported no track in 4 of 4 runs on c: its existence update or reporting threshold may be wrong",
        "Half reported no track in 2 of 4 runs on c: its existence update or reporting threshold may be wrong"]

    old = copy.deepcopy(res)  # as written before the count was kept
    for row in old["cases"]["c"]["methods"].values():
        row.pop("runs_without_tracks", None)
    assert Results.of(old).cases["c"].methods["Silent"].tracks.runs_without_tracks is None
    assert not any("No track reported" in line for line in flag_paragraphs(old))
    assert not any("no track" in line for line in warning_lines(old))
    table = multi_target_tables(Results.of(old), None, "paper")
    assert any(line.startswith("| Silent |") for line in table)
    assert math.isclose(Results.of(old).cases["c"].methods["Silent"].sets.gospa_missed_share, 1.0)
