"""Trajectory GOSPA in the results and the report (issue 55, item 4): its per-run sums on
hand-worked cases, a row through the runner against the closed form of its assignment, and
results recorded before it still rendering."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from pmsr_nn.harness.run import scoring
from pmsr_nn.harness.run.blocks import call_method, draw_block, run_blocks
from pmsr_nn.harness.results.finalise import finalise
from pmsr_nn.harness.run.runner import prepare
from pmsr_nn.harness.scenario.schema import scenario_from_dict
from pmsr_nn.simulation.products import Truth
from pmsr_nn.trackers.base import Estimates

from test_identity_switches import _crossing_drones

ROOT = Path(__file__).resolve().parents[1]


def _states(xy: np.ndarray) -> torch.Tensor:
    """``(..., 2)`` positions as CV states ``[x, vx, y, vy]`` (velocities 0)."""
    x = torch.zeros(*xy.shape[:-1], 4, dtype=torch.float64)
    x[..., 0], x[..., 2] = torch.as_tensor(xy[..., 0]), torch.as_tensor(xy[..., 1])
    return x


def test_trajectory_sums_by_hand():
    """Two targets 100 m apart on parallel lines, 6 scans, set scans 1..5 (5 scans), c = 10 m,
    p = 2, so gamma = c = 10 m. Run 0: two tracks exactly on the targets that exchange them from
    scan 3 on: two switches cost 2 gamma^2 = 200 m^2, less than keeping the tracks (two missed
    targets and two false tracks at 3 scans: 12 c^2/2 = 600 m^2), so d^2 = 200 m^2, 40 m^2 per set
    scan. Run 1: the tracks stay on their targets: 0. Both LP solutions are integral."""
    k = np.arange(6, dtype=float)
    A = np.stack([k * 10.0, np.zeros(6)], -1)
    B = np.stack([k * 10.0, np.full(6, 100.0)], -1)
    truth_xy = np.stack([A, B], 1)  # (K, N, 2)
    swapped = truth_xy.copy()
    swapped[3:] = swapped[3:, ::-1]
    est = Estimates(_states(np.stack([swapped, truth_xy])), torch.ones(2, 6, 2, dtype=torch.bool), paired=False)
    truth = Truth(_states(np.stack([truth_xy, truth_xy])), torch.ones(6, 2, dtype=torch.bool))
    scans = torch.arange(6) >= 1
    out = scoring.trajectory_sums(est, truth, [0, 2], 10.0, 2.0, scans)
    np.testing.assert_allclose(out["tgospa_run"], [40.0, 0.0], rtol=1e-9, atol=1e-9)
    assert float(out["tgospa_switching"]) == pytest.approx(40.0, rel=1e-9)
    assert float(out["tgospa_loc"] + out["tgospa_missed"] + out["tgospa_false"]) == pytest.approx(0.0, abs=1e-9)
    assert float(out["tgospa_switches"]) == 2.0 and float(out["tgospa_integral"]) == 2.0
    # over scans 3..5 only, the swapped tracks are on the targets throughout: nothing to pay
    out = scoring.trajectory_sums(est, truth, [0, 2], 10.0, 2.0, torch.arange(6) >= 3)
    np.testing.assert_allclose(out["tgospa_run"], [0.0, 0.0], atol=1e-9)


def test_a_lost_track_replaced_by_another_pays_one_switch_by_hand():
    """One target, 4 set scans, c = 10 m, p = 2: track 0 exactly on it at scans 0-1, track 1
    exactly on it at 2-3 (a track lost and another started). Following both is one switch from
    one track to another, gamma^2 = 100 m^2; keeping either track instead pays a missed target
    and a false track at the 2 scans it is gone, 2 (c^2/2 + c^2/2) = 200 m^2. So d^2 = 100 m^2,
    25 m^2 per scan."""
    xy = np.stack([np.arange(4.0) * 10.0, np.zeros(4)], -1)[:, None]  # (K, 1, 2)
    est_xy = np.concatenate([xy, xy], 1)  # (K, 2, 2): both tracks on the target where they exist
    exists = torch.tensor([[True, False], [True, False], [False, True], [False, True]])[None]
    est = Estimates(_states(est_xy[None]), exists, paired=False)
    truth = Truth(_states(xy[None]), torch.ones(4, 1, dtype=torch.bool))
    out = scoring.trajectory_sums(est, truth, [0, 2], 10.0, 2.0, torch.ones(4, dtype=torch.bool))
    np.testing.assert_allclose(out["tgospa_run"], [25.0], rtol=1e-9)
    assert float(out["tgospa_switches"]) == 1.0


def test_the_ekf_row_holds_the_trajectory_gospa_of_its_own_assignment(tmp_path):
    """Through the runner on one_sky's crossing pair: the EKF's slot i is target i's track and
    stays within the cut-off, so the optimal trajectory assignment is slot i to target i (any
    other costs a switch, c^2 = 250,000 m^2, against localisation of a few hundred m^2): the row's
    value is the closed form, the root of the mean over runs and set scans of sum_i d_ii^2, with
    no switch, every run integral, at least the GOSPA (which may trade the tracks at a scan)."""
    sc = scenario_from_dict(_crossing_drones(tmp_path), tmp_path)
    setup = prepare(sc)
    row = finalise(setup, run_blocks(setup, range(1), progress=False))["cross"]["methods"]["EKF"]
    truth, products = draw_block(setup, 0, 0)
    est = call_method(setup, setup.methods[0], setup.cases[0], products, (sc.seed, 0, 0))
    pos = list(setup.models.motion.pos_idx)
    scans = torch.arange(truth.x.shape[1]) >= sc.warmup_steps
    d2 = ((est.x[..., pos] - truth.x[..., pos]) ** 2).sum(-1)[:, scans]  # (B, K', N), every target alive
    assert bool((d2.sqrt() < 500.0).all())
    closed = float(d2.sum(-1).mean()) ** 0.5
    assert row["tgospa_m"] == pytest.approx(closed, rel=1e-9)
    assert row["tgospa_switches_per_run"] == 0.0 and row["tgospa_integral_runs"] == 4
    assert row["tgospa_switching_share"] == 0.0 and row["tgospa_localisation_share"] == pytest.approx(1.0)
    assert row["tgospa_gamma_m"] == 500.0 and row["tgospa_m"] >= row["gospa_m"] - 1e-9


def test_rows_holding_it_get_its_table_and_rows_recorded_before_it_none():
    """dense_crossing's recorded rows (no trajectory GOSPA: no table; the whole report of that
    file renders, test_track_figure) and the same rows holding the figures (their table)."""
    from pmsr_nn.harness.report.multitarget_tables import multi_target_tables

    old = json.loads((ROOT / "evaluate" / "results" / "dense_crossing" / "results.json").read_text())
    assert "Trajectory GOSPA" not in "\n".join(multi_target_tables(old, None, "paper"))
    new = copy.deepcopy(old)
    for row in new["cases"]["dense_crossing"]["methods"].values():
        if row.get("ospa_m") is not None and row.get("labelled", True):
            row.update({"tgospa_m": 123.45, "tgospa_se_m": 6.78, "tgospa_gamma_m": 500.0, "tgospa_localisation_share": 0.5,
                        "tgospa_missed_share": 0.25, "tgospa_false_share": 0.15, "tgospa_switching_share": 0.1,
                        "tgospa_switches_per_run": 1.5, "tgospa_integral_runs": 9})
    report = "\n".join(multi_target_tables(new, None, "paper"))
    assert "switching cost gamma = 500 m" in report
    assert "| 123.5 ± 6.8 | 50 / 25 / 15 / 10 | 1.50 | 9 of 10 |" in report


def test_a_quantity_some_blocks_lack_is_left_out_not_summed_over_part_of_the_runs():
    """Blocks of a bank recorded before a quantity was kept, merged with newer ones: the figure
    built on it is absent from the row, the others as before."""
    from pmsr_nn.harness.results.finalise import complete

    sums = {"pos": np.ones((3, 5, 2)), "run_mse": np.ones((6, 2)), "tgospa_loc": np.ones(2), "tgospa_run": np.ones(4),
            "id_switches": np.ones((3, 2))}
    assert sorted(complete(sums)) == ["id_switches", "pos", "run_mse"]


def test_a_track_without_a_finite_position_counts_as_absent():
    """A diverged track (NaN at two of its scans) is scored as absent there, not refused: one
    target with its track exactly on it but NaN at 2 of 5 scans, c = 10 m, p = 2. The pair is kept
    through the gap (a target assigned to an absent track pays c^2/2, as a missed one, and
    nothing switches), so d^2 = 2 c^2/2 = 100 m^2, 20 m^2 per scan."""
    xy = np.stack([np.arange(5.0) * 10.0, np.zeros(5)], -1)[:, None]
    est_xy = xy.copy()
    est_xy[1:3] = np.nan
    est = Estimates(_states(est_xy[None]), torch.ones(1, 5, 1, dtype=torch.bool), paired=False)
    truth = Truth(_states(xy[None]), torch.ones(5, 1, dtype=torch.bool))
    out = scoring.trajectory_sums(est, truth, [0, 2], 10.0, 2.0, torch.ones(5, dtype=torch.bool))
    np.testing.assert_allclose(out["tgospa_run"], [20.0], rtol=1e-9)
    assert float(out["tgospa_switches"]) == 0.0
