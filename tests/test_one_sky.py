"""The flagship scenario ``evaluate/one_sky.yaml`` is what its header says: 2 transmitters x 3
receivers, eight drones with staggered births and deaths, a pair that meets and a formation, every
tracker family on one truth (its figures are recorded in evaluate/RESULTS.md by a slow run)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pmsr_nn.harness.run.blocks import draw_block
from pmsr_nn.harness.run.runner import prepare
from pmsr_nn.harness.scenario.schema import load_scenario
from pmsr_nn.simulation.detections import CLUTTER

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def setup():
    return prepare(load_scenario(ROOT / "evaluate" / "one_sky.yaml"))


def _xy(setup, name):
    case = setup.cases[0]
    t = case.targets.index(name)
    pos = list(setup.models.motion.pos_idx)
    return case.truth.x[:, t][:, pos].numpy(), case.alive[:, t].numpy()


def test_sensors_detections_and_lives(setup):
    """The header's sensors and lives, read off a drawn block (not off the file's own keys): 6 pair
    lists and 3 pooled receiver lists, 10 clutter points in every pair list and 20 in every
    receiver list at every scan, Pd 0.85 at every pair, eight drones born and dying at staggered
    times."""
    geometry = setup.geometry
    assert len(geometry.transmitters) == 2 and len(geometry.receivers) == 3
    truth, products = draw_block(setup, 0, 0)
    det = products["detections"]
    scans, pooled = det.scans, det.pooled.scans
    B, K, S, _ = scans.shape
    assert S == 6 and pooled.shape[2] == 3
    assert bool((((scans.origin == CLUTTER) & scans.valid).sum(-1) == 10).all())
    assert bool((((pooled.origin == CLUTTER) & pooled.valid).sum(-1) == 20).all())
    # a receiver pools its two pairs' lists: the same target detections, none lost or added
    assert int((pooled.valid & (pooled.origin >= 0)).sum()) == int((scans.valid & (scans.origin >= 0)).sum())
    # Pd: each living drone detected at each pair and scan with probability 0.85 (4 binomial deviations)
    trials = int(truth.alive.sum()) * S * B
    rate = int((scans.valid & (scans.origin >= 0)).sum()) / trials
    assert abs(rate - 0.85) < 4 * (0.85 * 0.15 / trials) ** 0.5, rate
    alive = truth.alive
    assert alive.shape == (K, 8)
    births = alive.to(int).argmax(0)
    ends = K - alive.flip(0).to(int).argmax(0)
    assert len(set(births.tolist())) >= 5 and len(set(ends.tolist())) >= 4  # staggered both ways
    assert int(alive.sum(1).max()) >= 6


def test_the_crossing_pair_meets_and_the_formation_keeps_its_spacing(setup):
    a, alive_a = _xy(setup, "cross_1")
    b, alive_b = _xy(setup, "cross_2")
    both = alive_a & alive_b
    gap = np.linalg.norm(a[both] - b[both], axis=1)
    # straight flights at 15 m/s closing at 2 x 7.5 m/s across: they pass within one second's flight
    assert gap.min() < 15.0 and gap[0] > 3000 and gap[-1] > 3000
    lead, alive_l = _xy(setup, "lead")
    wing, alive_w = _xy(setup, "wing")
    both = alive_l & alive_w
    spacing = np.linalg.norm(lead[both] - wing[both], axis=1)
    assert np.all(np.abs(spacing - 300.0) < 1.0)  # start given to 0.1 m / 0.01 deg: ~1 mm of spacing error


def test_every_family_is_a_row(setup):
    kinds = {m.kind for m in setup.methods}
    assert {"ekf", "ukf", "imm", "learned", "pcrb", "s_msjpda", "p_msjpda", "pmht", "pmht_3d", "smc_phd",
            "stonesoup", "bp"} <= kinds
    detection_rows = [m for m in setup.methods if setup.kinds[m.name].reads == "detections"]
    from pmsr_nn.harness.results.finalise import initiation

    starts = {m.name: initiation(setup, m) for m in detection_rows}
    assert [n for n, s in starts.items() if s == "oracle"] == ["S-MSJPDA (oracle births)"]
    for m in setup.methods:  # the released networks were trained for these sensors
        if m.kind == "learned":
            assert setup.resources[m.name].meta["dim_z"] == 18


def companion_rows(main: str, name: str) -> list[dict]:
    """The rows after the first of ``evaluate/<name>``, having checked that it is ``evaluate/<main>``'s
    draws (every setting but the name, the description and the rows is the main scenario's: the
    draws do not depend on those) and that its first row is the main scenario's S-MSJPDA."""
    import yaml

    ours, other = (yaml.safe_load((ROOT / "evaluate" / f).read_text()) for f in (main, name))
    rest = lambda d: {k: v for k, v in d.items() if k not in ("name", "description", "methods")}  # noqa: E731
    assert rest(other) == rest(ours)
    assert other["methods"][0] == next(m for m in ours["methods"] if m["name"] == "S-MSJPDA")
    return other["methods"][1:]


def dense_crossing_companion(name: str) -> list[dict]:
    return companion_rows("dense_crossing.yaml", name)


def test_the_ghost_companion_is_dense_crossing_but_for_its_rows():
    """``evaluate/dense_crossing_ghosts.yaml``: every row after S-MSJPDA is S-MSJPDA with the
    innovation bias test (the hybrid's rows of its record left with the hybrid, issue 56)."""
    rows = dense_crossing_companion("dense_crossing_ghosts.yaml")
    assert rows and all(m["kind"] == "s_msjpda" and m["options"]["bias_window"] == 20 for m in rows)


def test_the_ghost_companion_of_one_sky_is_one_sky_but_for_its_rows():
    """``evaluate/one_sky_ghosts.yaml``: one_sky's draws, S-MSJPDA and the same tracker with the
    innovation bias test as its only rows."""
    (row,) = companion_rows("one_sky.yaml", "one_sky_ghosts.yaml")
    assert row["kind"] == "s_msjpda" and row["options"] == {"initiation": "detections", "bias_window": 20}


def test_the_burn_in_companion_is_dense_crossing_but_for_its_rows():
    """``evaluate/dense_crossing_burn_in.yaml``: S-MSJPDA with the innovation bias test at each
    burn-in the document's table names, nothing else changed."""
    rows = dense_crossing_companion("dense_crossing_burn_in.yaml")
    assert [m["options"]["bias_burn_in"] for m in rows] == [0, 5, 10, 20]
    for m in rows:
        assert m["kind"] == "s_msjpda" and m["options"] == {"initiation": "detections", "bias_window": 20,
                                                             "bias_burn_in": m["options"]["bias_burn_in"]}
