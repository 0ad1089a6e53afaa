"""Track management (pmsr_nn.trackers.management) and the trackers that start their own tracks:
each component against a hand-worked case, births and deaths on a clutter-free case, refusals."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch
import yaml

from pmsr_nn.cli import main
from pmsr_nn.errors import ConfigError
from pmsr_nn.geometry import Geometry, Receiver, Transmitter
from pmsr_nn.harness import evaluate
from pmsr_nn.harness.run.blocks import call_method, draw_block
from pmsr_nn.harness.run.runner import prepare
from pmsr_nn.harness.scenario.schema import load_scenario
from pmsr_nn.measurements import MeasurementModel
from pmsr_nn.metrics import set_scores, track_scores
from pmsr_nn.filters.gaussian import Gaussian
from pmsr_nn.trackers.management import (CONFIRMED, FREE, TENTATIVE, Confirmer, Deleter, FixInitiator, Management,
                                         TrackReport, TrackTable)

CA_POS, CA_VEL = (0, 3), (1, 4)


def model(noise=(30.0, 2.0, math.radians(3.0))) -> MeasurementModel:
    """One transmitter at the origin and three receivers about 8 km west (the FITEE geometry)."""
    g = Geometry.all_pairs([Transmitter((0.0, 0.0), 650e6)],
                           [Receiver((-7000.0, -3000.0)), Receiver((-8000.0, 500.0)), Receiver((-7500.0, 4000.0))])
    return MeasurementModel(g, ("range", "range_rate", "azimuth"), noise, CA_POS, CA_VEL, layout="pair")


def ca_state(x, vx, y, vy) -> torch.Tensor:
    return torch.tensor([x, vx, 0.0, y, vy, 0.0], dtype=torch.float64)


# -- confirmer and deleter ------------------------------------------------------------------------

def test_m_of_n_confirms_and_gives_up_as_worked_by_hand():
    c = Confirmer(2, 3)
    # hits so far (the initiation scan counts) after age + 1 scans
    hits = torch.tensor([1, 2, 1, 1, 2])
    age = torch.tensor([0, 1, 1, 2, 2])
    assert c.confirms(hits).tolist() == [False, True, False, False, True]
    # 1 hit after 2 scans: one scan left of the first three, 1 + 1 >= 2 still possible;
    # 1 hit after 3 scans: none left, hopeless
    assert c.hopeless(hits, age).tolist() == [False, False, False, True, False]
    assert Confirmer(3, 3).hopeless(torch.tensor([1]), torch.tensor([1])).tolist() == [True]


@pytest.mark.parametrize("make, message", [
    (lambda: Confirmer(4, 3), "M = 4, N = 3: a track could never be confirmed"),
    (lambda: Confirmer(0, 3), "1 <= M <= N"),
    (lambda: Deleter(0), "0 would delete every track at its birth"),
    (lambda: Deleter(2, min_existence=1.0), "delete_existence must be in"),
    (lambda: FixInitiator(min_pairs=0), "min_pairs must be at least 1"),
])
def test_components_that_could_never_work_are_refused(make, message):
    with pytest.raises(ConfigError, match=message):
        make()


# -- the initiator ---------------------------------------------------------------------------------

def test_a_fix_is_the_position_that_produced_the_range_and_azimuth():
    m = model()
    truth = torch.stack([ca_state(3000.0, 5.0, 6000.0, -2.0), ca_state(-1000.0, 0.0, 9000.0, 3.0)])
    z = m.h(truth).reshape(2, 3, 3).transpose(0, 1).unsqueeze(0)  # (B=1, S=3, M=2, d=3)
    pos, cov, ok = FixInitiator().fixes(z, m, 6)
    assert bool(ok.all())
    expect = truth[:, list(CA_POS)].expand(3, 2, 2)
    assert torch.allclose(pos[0], expect, rtol=0, atol=1e-8)  # exact geometry: only rounding
    # covariance: J R J^T with J the finite-difference Jacobian of the fix by (range, azimuth),
    # independent of the model's analytic Jacobian the initiator uses
    R2 = torch.diag(torch.tensor([30.0, math.radians(3.0)], dtype=torch.float64) ** 2)
    for s in range(3):
        for j in range(2):
            J = torch.zeros(2, 2, dtype=torch.float64)
            for col, (c, h) in enumerate(((0, 1e-3), (2, 1e-7))):
                zp, zm = z.clone(), z.clone()
                zp[0, s, j, c] += h
                zm[0, s, j, c] -= h
                J[:, col] = (FixInitiator().fixes(zp, m, 6)[0][0, s, j] - FixInitiator().fixes(zm, m, 6)[0][0, s, j]) / (2 * h)
            assert torch.allclose(cov[0, s, j], J @ R2 @ J.T, rtol=1e-5), (s, j)


def test_a_range_inside_the_baseline_has_no_fix():
    m = model()
    z = torch.zeros(1, 3, 1, 3, dtype=torch.float64)
    z[..., 0] = 100.0  # shorter than every baseline (about 7.6 km): no ellipse
    assert not bool(FixInitiator().fixes(z, m, 6)[2].any())


def test_groups_join_agreeing_fixes_of_different_pairs_and_use_each_once():
    # hand-made fixes (B=1, S=3, M=2): pair 0's fix 0 and pair 1's fix 1 agree (10 m apart, 100 m
    # deviations); pair 2's fixes are 5 km away; pair 1's fix 0 agrees with nothing
    pos = torch.tensor([[[[0.0, 0.0], [20000.0, 0.0]],
                         [[9000.0, 9000.0], [10.0, 0.0]],
                         [[5000.0, 0.0], [5000.0, 100.0]]]], dtype=torch.float64)
    cov = (100.0**2 * torch.eye(2, dtype=torch.float64)).expand(1, 3, 2, 2, 2)
    ok = torch.ones(1, 3, 2, dtype=torch.bool)
    groups = FixInitiator(min_pairs=2).groups(pos, cov, ok)
    # pair 2's two fixes agree with each other but belong to one pair: no group of two pairs
    assert groups.tolist() == [[[0, 1, -1]]]
    # two anchors of pair 0 want pair 1's fix 1 (at 10 m): the nearer (2 m) keeps it, the other (10 m) goes without
    pos2 = pos.clone()
    pos2[0, 0, 1] = torch.tensor([12.0, 0.0])
    groups = FixInitiator(min_pairs=2).groups(pos2, cov, ok)
    assert groups.tolist() == [[[1, 1, -1]]]
    assert FixInitiator(min_pairs=3).groups(pos, cov, ok).shape == (1, 0, 3)


def test_the_initial_velocity_is_the_linear_least_squares_fit_of_the_range_rates():
    m = model()
    truth = ca_state(3000.0, 8.0, 6000.0, -4.0)
    z = m.h(truth).reshape(3, 3).unsqueeze(0).unsqueeze(2)  # (1, S=3, M=1, 3)
    ini = FixInitiator(velocity_sd_mps=20.0, min_pairs=3)
    other = torch.tensor([100.0, 5.0, 0.3] * 2, dtype=torch.float64)
    g, real = ini.initiate(z, torch.ones(1, 3, 1, dtype=torch.bool), m, 6, other)
    assert real.tolist() == [[True]]
    p = g.x[0, 0, list(CA_POS)]
    assert torch.allclose(p, truth[list(CA_POS)], atol=1e-6)
    # closed form at that position: rows u_tx + u_rx (unit vectors from the sensors), prior N(0, 20^2 I)
    tx = torch.tensor([0.0, 0.0], dtype=torch.float64)
    G = torch.stack([(p - tx) / (p - tx).norm() + (p - r) / (p - r).norm()
                     for r in m.geometry.pair_rx_positions(torch.float64)])
    A = G.T @ G / 2.0**2 + torch.eye(2, dtype=torch.float64) / 20.0**2
    v = torch.linalg.solve(A, G.T @ z[0, :, 0, 1] / 2.0**2)
    assert torch.allclose(g.x[0, 0, list(CA_VEL)], v, rtol=1e-9)
    assert torch.allclose(g.P[0, 0][[1, 4]][:, [1, 4]], torch.linalg.inv(A), rtol=1e-9)
    assert g.x[0, 0, 2] == 0 and g.P[0, 0, 2, 2] == pytest.approx(0.3**2)  # acceleration from the prior


# -- the table ---------------------------------------------------------------------------------------

def test_the_table_starts_confirms_and_deletes_as_worked_by_hand():
    B, n = 2, 6
    t = TrackTable.empty(B, n, torch.full((n,), 1e6, dtype=torch.float64), capacity=2)
    new = Gaussian(torch.arange(3 * n, dtype=torch.float64).reshape(1, 3, n).expand(B, 3, n).clone(),
                   torch.eye(n, dtype=torch.float64).expand(B, 3, n, n).clone())
    t.add(new, torch.tensor([[True, True, True], [False, True, False]]), initial_existence=0.4)
    assert t.g.x.shape[1] >= 3  # grown
    assert t.status[0, :3].tolist() == [TENTATIVE] * 3 and t.status[1].tolist().count(TENTATIVE) == 1
    assert torch.equal(t.g.x[1, 0], new.x[1, 1]) and t.existence[1, 0] == pytest.approx(0.4)
    conf, dele = Confirmer(2, 3), Deleter(misses=2)
    # scan 1: run 0's tracks detected at 2, 1 and 0 pairs (hit needs 2); run 1's at 2
    t.record(torch.tensor([[2, 1, 0] + [0] * (t.g.x.shape[1] - 3), [2] + [0] * (t.g.x.shape[1] - 1)]), hit_pairs=2)
    t.manage(conf, dele, list(CA_POS))
    assert t.status[0, :3].tolist() == [CONFIRMED, TENTATIVE, TENTATIVE] and t.track_id[0, 0] == 0
    assert t.status[1, 0] == CONFIRMED and t.track_id[1, 0] == 0 and t.next_id.tolist() == [1, 1]
    # scan 2: nothing detected anywhere: the tentative tracks (1 hit in 3 scans) are given up,
    # the confirmed ones have missed once
    t.record(torch.zeros_like(t.status), hit_pairs=2)
    t.manage(conf, dele, list(CA_POS))
    assert t.status[0, :3].tolist() == [CONFIRMED, FREE, FREE]
    assert t.g.x[0, 1].tolist() == [1e6] * n  # parked
    t.record(torch.zeros_like(t.status), hit_pairs=2)  # a second miss in a row deletes
    t.manage(conf, dele, list(CA_POS))
    assert not bool(t.active.any())


def test_a_track_whose_existence_falls_below_delete_existence_is_deleted_tentative_or_confirmed():
    """JIPDA's termination: existences 0.004 (confirmed), 0.02 (confirmed), 0.009 (tentative), 0.6
    (confirmed), each detected at every pair (no miss counts): below 0.01 goes, whatever its status;
    without the threshold (0, the default) nothing does."""
    t = TrackTable.empty(1, 6, torch.zeros(6, dtype=torch.float64), capacity=4)
    t.add(Gaussian(torch.zeros(1, 4, 6, dtype=torch.float64), torch.eye(6, dtype=torch.float64).expand(1, 4, 6, 6)),
          torch.ones(1, 4, dtype=torch.bool))
    t.status = torch.tensor([[CONFIRMED, CONFIRMED, TENTATIVE, CONFIRMED]])
    t.existence = torch.tensor([[0.004, 0.02, 0.009, 0.6]], dtype=torch.float64)
    kept = TrackTable(**{k: getattr(t, k) for k in t.__dataclass_fields__})
    t.record(torch.full((1, 4), 3), hit_pairs=2)
    kept.record(torch.full((1, 4), 3), hit_pairs=2)
    kept.manage(Confirmer(2, 3), Deleter(misses=2), list(CA_POS))
    assert kept.status.tolist() == [[CONFIRMED, CONFIRMED, CONFIRMED, CONFIRMED]]  # 2 hits confirm the tentative one
    t.manage(Confirmer(2, 3), Deleter(misses=2, min_existence=0.01), list(CA_POS))
    assert t.status.tolist() == [[FREE, CONFIRMED, FREE, CONFIRMED]]


def test_existence_follows_the_ipda_update():
    t = TrackTable.empty(1, 6, torch.zeros(6, dtype=torch.float64), capacity=2)
    t.add(Gaussian(torch.zeros(1, 2, 6, dtype=torch.float64), torch.eye(6, dtype=torch.float64).expand(1, 2, 6, 6)),
          torch.tensor([[True, True]]), initial_existence=0.9)
    t.predict_existence(0.99)
    t.update_existence(torch.tensor([[0.0, 50.0]], dtype=torch.float64), pd_pg=0.9)
    # nothing in the gate: odds times (1 - PdPg); likelihood ratio 50: odds times (1 - delta) with delta = 0.9 * (1 - 50)
    e = 0.9 * 0.99
    odds = e / (1 - e)
    assert t.existence[0, 0] == pytest.approx(odds * 0.1 / (1 + odds * 0.1), rel=1e-12)
    d = 0.9 * (1 - 50.0)
    assert t.existence[0, 1] == pytest.approx((1 - d) * e / (1 - d * e), rel=1e-12)


def test_the_report_numbers_tracks_by_confirmation_and_hides_the_doubtful():
    t = TrackTable.empty(1, 6, torch.zeros(6, dtype=torch.float64), capacity=3)
    t.add(Gaussian(torch.arange(18, dtype=torch.float64).reshape(1, 3, 6), torch.eye(6, dtype=torch.float64).expand(1, 3, 6, 6)),
          torch.tensor([[True, True, True]]))
    t.status = torch.tensor([[CONFIRMED, TENTATIVE, CONFIRMED]])
    t.track_id = torch.tensor([[1, -1, 0]])
    t.existence = torch.tensor([[0.9, 0.9, 0.2]], dtype=torch.float64)
    rep = TrackReport.empty(1, 2, 6)
    rep.write(1, t, report_existence=0.5)
    assert rep.exists[0, 1, :2].tolist() == [False, True] and not bool(rep.exists[0, 0].any())
    assert torch.equal(rep.x[0, 1, 1], t.g.x[0, 0]) and rep.existence[0, 1, 0] == pytest.approx(0.2)
    assert rep.trimmed().x.shape == (1, 2, 2, 6)


# -- trackers that start their own tracks ------------------------------------------------------------

FLIGHT = {"start_range_m": 4000.0, "start_bearing_deg": 130.0, "speed_mps": 10.0, "heading_deg": 20.0,
          "segments": [{"duration_s": 200.0}]}
OTHER = {"start_range_m": 7800.0, "start_bearing_deg": 140.0, "speed_mps": 12.0, "heading_deg": 0.0,
         "segments": [{"duration_s": 200.0}]}


def scenario(tmp_path: Path, pd=1.0, clutter=0, methods=None, **over) -> Path:
    d = {"name": "births", "seed": 3, "mc_runs": 2, "block_runs": 2, "warmup_steps": 10, "random_streams": "per_product",
         "detections": {"pd": pd, "clutter": {"per_scan": clutter, "range_m": [0.0, 25000.0],
                                              "range_rate_mps": [-40.0, 40.0]}},
         "set_metrics": {"c_m": 300.0, "p": 2.0},
         "cases": [{"name": "c", "targets": [{"name": "a", "death_s": 40.0, **FLIGHT},
                                             {"name": "b", "birth_s": 15.0, "death_s": 60.0, **OTHER}]}],
         "methods": methods or [{"name": "S", "kind": "s_msjpda", "options": {"initiation": "detections"}},
                                {"name": "P", "kind": "p_msjpda", "options": {"initiation": "detections"}}]}
    d.update(over)
    path = tmp_path / "births.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


@pytest.mark.parametrize("method", [0, 1])
def test_births_and_deaths_without_clutter_give_one_confirmed_track_per_target(tmp_path, method):
    setup = prepare(load_scenario(scenario(tmp_path)))
    case = setup.cases[0]
    truth, products = draw_block(setup, 0, 0)
    est = call_method(setup, setup.methods[method], case, products, (3, 0, 0))
    assert not est.paired and est.x.shape[2] == 2  # two tracks in all, per run
    B, K, _ = est.exists.shape
    alive = case.alive.expand(B, K, 2)
    sets = set_scores(est.x[..., [0, 3]], est.exists, truth.x[..., [0, 3]], alive, 300.0, 2.0)
    ts = track_scores(sets.assignment, est.exists, alive)
    assert ts.tracks_per_target.tolist() == [[1.0, 1.0]] * B and ts.false_tracks.tolist() == [0.0] * B
    # Pd 1 at three pairs: a 3-pair fix at birth, a hit the next scan confirms (2 of 3): reported from birth + 1
    assert ts.scans_to_first_track.tolist() == [[1.0, 1.0]] * B
    assert ts.missed_scans.tolist() == [[1.0, 1.0]] * B and not bool(ts.lost.any())
    # no detection after death: existence falls below 0.5 at once, so no scan is reported after it
    for t, (k0, k1) in enumerate(((0, 40), (15, 60))):
        track = sets.assignment[:, k1 - 1].tolist()
        slot = [row.index(t) for row in track]
        for b in range(B):
            assert est.exists[b, k0 + 1:k1, slot[b]].all() and not est.exists[b, k1:, slot[b]].any()


@pytest.mark.parametrize("kind", ["s_msjpda", "p_msjpda"])
def test_one_of_one_confirms_and_reports_a_track_at_the_scan_that_starts_it(tmp_path, kind):
    """``confirm_m: 1`` (the initiation scan is a hit): the same scenes as above, each target
    reported from its birth scan, one track each, none false, with its fix as its state there."""
    options = {"initiation": "detections", "confirm_m": 1, "confirm_n": 1}
    setup = prepare(load_scenario(scenario(tmp_path, methods=[{"name": "S", "kind": kind, "options": options}])))
    case = setup.cases[0]
    truth, products = draw_block(setup, 0, 0)
    est = call_method(setup, setup.methods[0], case, products, (3, 0, 0))
    B, K, _ = est.exists.shape
    alive = case.alive.expand(B, K, 2)
    sets = set_scores(est.x[..., [0, 3]], est.exists, truth.x[..., [0, 3]], alive, 300.0, 2.0)
    ts = track_scores(sets.assignment, est.exists, alive)
    assert ts.tracks_per_target.tolist() == [[1.0, 1.0]] * B and ts.false_tracks.tolist() == [0.0] * B
    assert ts.scans_to_first_track.tolist() == [[0.0, 0.0]] * B and ts.missed_scans.tolist() == [[0.0, 0.0]] * B
    # missed 0 with c = 300 m: at its birth scan each target's track (the multi-pair fix) is within 300 m
    assert bool(est.exists[:, 0].any(-1).all()) and int(est.exists[:, 14].sum()) == B  # b is born at 15 s


@pytest.mark.integration
def test_initiation_from_detections_is_scored_as_tracks_in_the_report(tmp_path):
    path = scenario(tmp_path, pd=0.9, clutter=3, methods=[{"name": "S-MSJPDA", "kind": "s_msjpda"},
                    {"name": "S-MSJPDA (initiates)", "kind": "s_msjpda", "options": {"initiation": "detections"}}])
    res = evaluate(path, tmp_path / "out", progress=False)
    rows = res["cases"]["c"]["methods"]
    assert rows["S-MSJPDA"]["initiation"] == "oracle" and rows["S-MSJPDA (initiates)"]["initiation"] == "detections"
    own = rows["S-MSJPDA (initiates)"]
    assert own["confirmed_tracks_per_target"] == pytest.approx(1.0) and own["false_tracks_per_run"] == 0.0
    assert own["scans_to_first_track"] >= 1.0 and "swap_probability" not in own
    assert rows["S-MSJPDA"]["scans_to_first_track"] == 0.0
    report = (tmp_path / "out" / "report.md").read_text()
    assert "S-MSJPDA | detections (oracle births) |" in report
    assert "| S-MSJPDA (initiates) | own, from detections | 1.00 | 0.00 |" in report


@pytest.mark.parametrize("options, message", [
    ({"confirm_m": 4, "confirm_n": 3}, "method 'S': confirmation needs 1 <= M <= N <= 62 (M of N scans); got M = 4, N = 3"),
    ({"delete_misses": 0}, "method 'S': a deleter needs misses >= 1"),
    ({"merge_scans": 0}, "method 'S': a merge window needs at least 1 scan (merge_scans), got 0"),
    ({"hit_pairs": 4}, "method 'S': initiation from detections: hit_pairs (4) must be in [1, 3]"),
    ({"init_pairs": 4}, "method 'S': min_pairs (4) is more than the 3 pairs"),
    ({"report_existence": 1.5}, "method 'S': option report_existence must be a number in [0.0, 1.0], got 1.5"),
    ({"delete_existence": 0.0}, "method 'S': option delete_existence must be"),
    ({"delete_existence": 0.5}, "method 'S': delete_existence (0.5) must be below report_existence (0.5)"),
])
def test_settings_that_never_confirm_are_one_line_errors_and_write_nothing(tmp_path, capsys, options, message):
    path = scenario(tmp_path, methods=[{"name": "S", "kind": "s_msjpda",
                                        "options": {"initiation": "detections", **options}}])
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["evaluate", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_initiation_from_range_and_doppler_at_pairs_that_share_no_sensor_is_refused(tmp_path, capsys):
    """The Access study measures range and Doppler only: no single-pair fix, so the spherical
    initiator takes it (tests/test_spherical_initiator.py); with a second receiver its pairs
    share neither a transmitter nor a receiver, which neither initiator handles: refused by name
    (oracle initiation still runs)."""
    root = Path(__file__).resolve().parents[1]
    data = yaml.safe_load((root / "evaluate" / "access2019_msjpda.yaml").read_text())
    data["methods"] = [{"name": "S", "kind": "s_msjpda", "options": {"initiation": "detections"}}]
    data["mc_runs"], data["block_runs"] = 1, 1
    data["world"]["geometry"]["receivers"].append({"position_m": [5000.0, 5000.0]})
    if "reference" in data:
        data["reference"]["file"] = str((root / "evaluate" / data["reference"].get("file", "reference/paper_tables.json")))
    path = tmp_path / "a.yaml"
    path.write_text(yaml.safe_dump(data))
    assert main(["evaluate", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "method 'S'" in err
    assert "share one transmitter or one receiver" in err and "use initiation: oracle" in err
    assert not (tmp_path / "out").exists()


def test_every_refusal_of_one_file_comes_in_one_message(tmp_path, capsys):
    path = scenario(tmp_path, methods=[
        {"name": "S", "kind": "s_msjpda", "options": {"initiation": "detections", "confirm_m": 5, "confirm_n": 3}},
        {"name": "P", "kind": "p_msjpda", "options": {"initiation": "detections", "delete_misses": 0}}])
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["evaluate", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "method 'S': confirmation needs" in err[0] and "method 'P': a deleter needs" in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


@pytest.mark.parametrize("kind, message", [
    ("true_assignment", "method 'T': kind true_assignment starts every track at scan 0; case 'c' has targets born later"),
    ("true_assignment_smoother", "method 'T': kind true_assignment_smoother keeps every track from scan 0 to the end; "
                                 "case 'c' has targets born later or dying earlier"),
])
def test_the_true_assignment_references_refuse_births_in_one_line(tmp_path, capsys, kind, message):
    path = scenario(tmp_path, methods=[{"name": "T", "kind": kind}])
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["evaluate", str(path), "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.strip() == f"pmsr: error: {message}"
    assert sorted(p.name for p in tmp_path.iterdir()) == before
