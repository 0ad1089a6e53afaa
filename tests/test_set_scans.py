"""The scans the set figures average over (issue 55, item 4): every scan from ``warmup_steps`` on,
in every scenario, with or without an ``rd_maps`` section. Before, a scenario with maps averaged
them over every scan (the warm-up included) while its report said "after the warm-up"."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pmsr_nn.harness.run.blocks import run_blocks
from pmsr_nn.harness.results.finalise import finalise
from pmsr_nn.harness.scenario.prepared import set_scans_after
from pmsr_nn.harness.run.runner import prepare
from pmsr_nn.harness.scenario.schema import scenario_from_dict

from test_tbd_kinds import tiny


def _two_targets(warmup: int, maps: bool) -> dict:
    """tiny()'s maps and modified ICMB, two targets: frames 1-4 and 3-5 of 7."""
    d = tiny(warmup_steps=warmup)
    d["cases"][0]["targets"][0]["segments"] = [{"duration_s": 4.0}]
    late = {**d["cases"][0]["targets"][0], "name": "late", "birth_s": 3.0, "start_m": [5200.0, 2900.0],
            "segments": [{"duration_s": 3.0}]}
    d["cases"][0]["targets"].append(late)
    d["cases"][0]["end_s"] = 7.0
    if not maps:
        del d["rd_maps"]
        d["methods"] = [{"name": "EKF", "kind": "ekf"}]
    return d


@pytest.mark.parametrize("maps", [True, False])
def test_set_scans_are_the_scans_from_the_warm_up_on_with_maps_or_without(tmp_path, maps):
    """Two targets living at frames 1-4 and 3-5 of 7, warm-up 2: the set figures average over
    frames 2..6 (counted from the case's first frame; the later target inside its own warm-up at
    3 and 4 counts, so its start-up is scored, and so does frame 6 where none lives), never over
    frames 0-1. The old code gave a case with maps every frame and one without the frames where
    some target had lived more than 2 scans (3..5)."""
    setup = prepare(scenario_from_dict(_two_targets(2, maps), tmp_path))
    case = setup.cases[0]
    assert case.alive[:, 0].tolist() == [False, True, True, True, True, False, False]
    assert case.alive[:, 1].tolist() == [False, False, False, True, True, True, False]
    assert case.set_scan_mask.tolist() == [False, False, True, True, True, True, True]
    assert torch.equal(set_scans_after(7, 0), torch.ones(7, dtype=torch.bool))


def test_a_scenario_with_maps_averages_its_gospa_over_the_scans_after_the_warm_up(tmp_path):
    """Through the runner: the row's ospa_m and gospa_m are the means of their per-frame curves
    over frames >= warmup_steps (GOSPA: the p-th root of the mean of the curve's p-th power), not
    over every frame; the track-before-detect table's OSPA stays the seed's mean over every frame."""
    d = _two_targets(2, True)
    setup = prepare(scenario_from_dict(d, tmp_path))
    res = finalise(setup, run_blocks(setup, range(setup.scenario.n_blocks), progress=False))["c"]
    row, curves = res["methods"]["m"], res["curves"]["set"]["m"]
    p = d["set_metrics"]["p"]
    ospa, gospa = np.asarray(curves["ospa_m"]), np.asarray(curves["gospa_m"])
    assert row["ospa_m"] == pytest.approx(ospa[2:].mean(), rel=1e-12)
    assert row["gospa_m"] == pytest.approx(np.mean(gospa[2:] ** p) ** (1 / p), rel=1e-12)
    assert row["tbd"]["ospa_mean_m"] == pytest.approx(ospa.mean(), rel=1e-12)
    # the curves differ between the warm-up and after it, so the old average (every frame) is another number
    assert abs(ospa.mean() - ospa[2:].mean()) > 1.0
