"""Neural-enhanced BP (issue 56): the learned corrections of :mod:`pmsr_nn.trackers.message_refiner`,
the network and checkpoint of :mod:`pmsr_nn.nets.nebp`, its training (:mod:`pmsr_nn.nets.nebp_training`)
and ``kind: nebp``."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from pmsr_nn.config import from_dict
from pmsr_nn.errors import CheckpointError
from pmsr_nn.filters.gaussian import Gaussian
from pmsr_nn.nets.nebp import NEBPNet, load_nebp_checkpoint, nebp_metadata, save_nebp_checkpoint
from pmsr_nn.nets.nebp_training import (CLUTTER, LEGACY, NEW, NEBPTrainConfig, Problem, association_loss,
                                        batch_figures, existence_loss, node_labels)
from pmsr_nn.trackers.bp_association import bp_associate
from pmsr_nn.trackers.bp_tracker import bp_tracker
from pmsr_nn.trackers.message_refiner import apply_corrections, graph_features

ROOT = Path(__file__).resolve().parents[1]


def _problem(**scenes) -> Problem:
    s = {"window": 12, "targets": [2, 3], "clutter_per_scan": [10, 20], "pd": [0.8, 0.9], **scenes}
    cfg = from_dict(NEBPTrainConfig, {"kind": "nebp", "recipe": str(ROOT / "datasets/fitee2023_ca.yaml"), "scenes": s,
                                      "model": {"hidden": 8}, "optim": {"batch_size": 2, "val_scenes": 4}}, where="test")
    return Problem(cfg)


def _net(pr: Problem, **kw) -> NEBPNet:
    torch.manual_seed(0)
    return NEBPNet(pr.model.n_pairs, pr.model.components, **{"hidden": 8, **kw})


def _track(pr: Problem, refiner=None, seed=(7, 0), B=2):
    scans, truth, pd, clutter, _ = pr.sampler.draw(seed, B)
    with torch.no_grad():
        return bp_tracker(scans, pr.motion, pr.dt, pr.q, pr.model, pr.model.R(), pr.settings(pd, clutter), pr.prior_sd,
                          10.0, refiner=refiner)


# -- the corrections -----------------------------------------------------------------------------------

def test_zero_corrections_reproduce_bp_and_a_nonzero_one_does_not():
    pr = _problem()
    plain = _track(pr)
    same = _track(pr, pr.refiner(_net(pr)))
    assert plain.exists.any()
    assert torch.equal(same.exists, plain.exists)
    ex = plain.exists
    assert (same.x[ex] - plain.x[ex]).abs().max() <= 1e-9 * plain.x[ex].abs().max()
    assert (same.existence[ex] - plain.existence[ex]).abs().max() <= 1e-9
    pushed = _net(pr)
    torch.nn.init.constant_(pushed.det_out.bias, 2.0)  # every new-target weight x e^(4 tanh(1/2))
    moved = _track(pr, pr.refiner(pushed))
    both = moved.exists & plain.exists
    assert not torch.equal(moved.exists, plain.exists) or (moved.x[both] - plain.x[both]).abs().max() > 1e-3


def test_corrections_move_a_nodes_likelihood_among_its_detections_and_weigh_a_detection_against_clutter():
    B, C, M, d = 1, 2, 4, 3
    ratio = torch.tensor([[[2.0, 0.0, 0.5, 0.0], [0.0, 3.0, 0.0, 0.0]]], dtype=torch.float64)
    birth = torch.tensor([[0.1, 0.2, 0.3, 0.4]], dtype=torch.float64)
    prior = torch.tensor([[0.9, 0.5]], dtype=torch.float64)
    valid = torch.tensor([[True, True, True, False]])
    z = torch.zeros(B, M, d, dtype=torch.float64)
    graph = graph_features(1, 3, ("range", "range_rate", "azimuth"), torch.tensor([1e4, 40.0, 1.0]), 30.0,
                           torch.zeros(B, C, M, d, dtype=torch.float64), torch.ones(B, C, dtype=torch.float64), ratio,
                           birth, prior, z, valid)
    assert graph.edges.tolist() == [[0, 0, 0], [0, 0, 2], [0, 1, 1]]
    assert graph.det_x[:, -3:].tolist() == [[0.0, 1.0, 0.0]] * 3  # the pair, one-hot
    r2, b2 = apply_corrections(graph, torch.tensor([1.0, 0.0, -1.0]), torch.zeros(3), ratio, birth)
    keep = 2.5 / (2.0 * math.e + 0.5)  # node 0 keeps its summed ratio, 2.5
    expected = torch.tensor([[[2.0 * math.e * keep, 0.0, 0.5 * keep, 0.0], [0.0, 3.0, 0.0, 0.0]]], dtype=torch.float64)
    assert torch.allclose(r2, expected, rtol=1e-14)  # node 1's one edge: nothing to move
    assert torch.equal(b2, birth)
    # a detection's weight: every target hypothesis of detection 0 (node 0's edge, its new target) x e^0.5
    r3, b3 = apply_corrections(graph, torch.zeros(3), torch.tensor([0.5, 0.0, 0.0]), ratio, birth)
    assert torch.allclose(r3, ratio * torch.tensor([math.exp(0.5), 1.0, 1.0, 1.0], dtype=torch.float64), rtol=1e-14)
    assert torch.allclose(b3, torch.tensor([[0.1 * math.exp(0.5), 0.2, 0.3, 0.4]], dtype=torch.float64), rtol=1e-14)


# -- labels and loss -----------------------------------------------------------------------------------

def test_the_edge_and_detection_loss_by_hand_on_two_tracks_and_two_detections():
    association = torch.tensor([[[0.7, 0.1, 0.2], [0.2, 0.5, 0.3]]], dtype=torch.float64)
    gated = torch.tensor([[[True, True], [False, True]]])
    target = torch.tensor([[[True, False], [False, True]]])
    new = torch.tensor([[0.1, 0.6]], dtype=torch.float64)
    legacy = torch.tensor([[0.8, 0.3]], dtype=torch.float64)
    det_class = torch.tensor([[LEGACY, NEW]])
    es, ds, ne, nd = association_loss(association, new, legacy, gated, target, det_class, torch.tensor([[True, True]]))
    assert (ne, nd) == (3, 2)
    # edges (0,0) y=1 p=0.7; (0,1) y=0 p=0.1; (1,1) y=1 p=0.5; (1,0) is not gated
    assert float(es) == pytest.approx(-math.log(0.7) - math.log(0.9) - math.log(0.5), rel=1e-12)
    assert float(ds) == pytest.approx(-math.log(0.8) - math.log(0.6), rel=1e-12)
    # optim.new_weight weighs the new target's detection (detection 1) only; the edges keep their sum
    es3, ds3, _, _ = association_loss(association, new, legacy, gated, target, det_class, torch.tensor([[True, True]]),
                                      new_weight=3.0)
    assert float(ds3) == pytest.approx(-math.log(0.8) - 3.0 * math.log(0.6), rel=1e-12) and float(es3) == float(es)
    clutter = torch.tensor([[CLUTTER, CLUTTER]])  # p(clutter) = 1 - 0.8 - 0.1 and 1 - 0.3 - 0.6
    _, ds2, _, _ = association_loss(association, new, legacy, gated, target, clutter, torch.tensor([[True, False]]))
    assert float(ds2) == pytest.approx(-math.log(0.1), rel=1e-9)
    # the updated existences: node 0 describes a target (y = 1), node 1 not (y = 0), node 2 is not live
    xs, nx = existence_loss(torch.tensor([[0.9, 0.2, 0.5]], dtype=torch.float64), torch.tensor([[True, True, False]]),
                            torch.tensor([[True, False, True]]))
    assert nx == 2 and float(xs) == pytest.approx(-math.log(0.9) - math.log(0.8), rel=1e-12)


def test_scenes_with_births_hold_targets_absent_and_undetected_before_their_birth_scan():
    """``scenes.births``: a target other than target 0 may be born at a scan of the window's first
    half; before it its state is NaN and no detection comes from it, after it it stays."""
    pr = _problem(births=0.7, targets=[4, 4])
    scans, truth, *_ = pr.sampler.draw((3, 0), 6)
    alive = torch.isfinite(truth).all(-1)  # (B, K, N)
    K = truth.shape[1]
    assert bool(alive[:, :, 0].all()) and bool(alive[:, K // 2].all())  # target 0 throughout; all born by K / 2
    assert not bool(alive[:, 0].all())  # some are born later
    assert bool((alive[:, 1:] >= alive[:, :-1]).all())  # once born, alive to the end of the window
    B, _, S, M = scans.origin.shape
    o = scans.origin
    b, k, s, m = (o >= 0).nonzero(as_tuple=True)
    assert len(b) > 0 and bool(alive[b, k, o[b, k, s, m]].all())  # every target detection is of a living target
    plain = _problem(targets=[4, 4]).sampler.draw((3, 0), 6)[1]
    assert bool(torch.isfinite(plain).all())  # without births every target lives throughout


def test_a_narrow_track_holds_its_target_against_a_wide_newborn_and_a_ghost_gets_none():
    x = torch.tensor([[[0.0, 0.0], [50.0, 0.0], [400.0, 0.0]]], dtype=torch.float64)
    P = torch.stack([torch.eye(2) * 30.0**2, torch.eye(2) * 500.0**2, torch.eye(2) * 30.0**2]).unsqueeze(0).double()
    live = torch.tensor([[True, True, True]])
    targets = torch.tensor([[[10.0, 0.0]]], dtype=torch.float64)
    labels = node_labels(x, P, live, targets, torch.tensor([[True]]), 13.8)
    # by squared Mahalanobis distance alone the newborn (0.01) would beat the track (0.11)
    assert labels.tolist() == [[0, -1, -1]]
    two = node_labels(x, P, live, torch.tensor([[[10.0, 0.0], [380.0, 0.0]]], dtype=torch.float64),
                      torch.tensor([[True, False]]), 13.8)
    assert two.tolist() == [[0, -1, -1]]  # a dead target is nobody's


def test_a_few_differentiable_passes_from_the_fixed_point_keep_its_beliefs():
    torch.manual_seed(1)
    ratio = torch.rand(2, 4, 5, dtype=torch.float64) * 3
    r = torch.rand(2, 4, dtype=torch.float64) * 0.9
    birth = torch.rand(2, 5, dtype=torch.float64)
    full = bp_associate(ratio, r, 0.9, birth, None, 1000, 1e-14)
    again = bp_associate(ratio, r, 0.9, birth, None, 3, 0.0, start=full.messages)
    assert torch.allclose(again.association, full.association, atol=1e-12)
    assert torch.allclose(again.new_existence, full.new_existence, atol=1e-12)


# -- training ------------------------------------------------------------------------------------------

def test_a_tiny_model_trained_for_seconds_beats_bp_where_the_clutter_is_not_what_bp_assumes():
    """Stationary clutter (range-rates within 1 m/s, the zero-Doppler residue of a passive radar's
    cancellation), the drones at 5-50 m/s: BP takes one clutter density over the measurement
    space, here the narrow box's, so it distrusts every detection alike; the network reads each
    detection's range-rate. Twenty Adam steps on scenes of ten scans (seconds) lower the beliefs'
    cross-entropy on fixed validation scenes: what each detection is (clutter, a track's, a new
    target's) by at least 30 %, the whole loss by at least 15 %."""
    pr = _problem(clutter_per_scan=[20, 20], range_rate_mps=[-1.0, 1.0], window=10)
    cfg = pr.cfg
    net = _net(pr)
    val = [(99, 1_000_000, i) for i in range(2)]

    def figures():
        with torch.no_grad():
            rows = [batch_figures(cfg, pr, net, v, False) for v in val]
        return {k: sum(float(r[k]) for r in rows) / len(rows) for k in ("loss", "detection_loss")}

    before = figures()
    opt = torch.optim.Adam(net.parameters(), lr=1e-2)
    for i in range(20):
        opt.zero_grad()
        batch_figures(cfg, pr, net, (99, i), True)["loss"].backward()
        opt.step()
    after = figures()
    assert after["detection_loss"] < 0.7 * before["detection_loss"], (before, after)
    assert after["loss"] < 0.85 * before["loss"], (before, after)


# -- the method kind and bad input ---------------------------------------------------------------------

def _scenario(tmp_path, recipe: str | None = None, checkpoint: str = "n.pt", components=None):
    """A small scenario of two drones with clutter: BP and NEBP from an untrained checkpoint made for
    the sensors of ``recipe`` (None: the scenario's own), its measurement set ``components``."""
    import yaml

    from pmsr_nn.harness.run.runner import prepare
    from pmsr_nn.harness.scenario.schema import load_scenario

    flight = lambda r, b, h: {"start_range_m": r, "start_bearing_deg": b, "speed_mps": 10.0, "heading_deg": h,
                              "segments": [{"duration_s": 30.0}]}
    d = {"name": "nebp", "seed": 3, "mc_runs": 2, "block_runs": 2, "warmup_steps": 5, "random_streams": "per_product",
         "detections": {"pd": 0.9, "components": ["range", "range_rate", "azimuth"],
                        "clutter": {"per_scan": 5, "range_m": [0.0, 25000.0], "range_rate_mps": [-40.0, 40.0]}},
         "set_metrics": {"c_m": 300.0, "p": 2.0},
         "cases": [{"name": "c", "targets": [{"name": "a", **flight(4000.0, 130.0, 20.0)},
                                             {"name": "b", **flight(7800.0, 100.0, 0.0)}]}],
         "methods": [{"name": "BP", "kind": "bp"}, {"name": "N", "kind": "nebp", "checkpoint": checkpoint}]}
    plain = {**d, "methods": d["methods"][:1]}
    if recipe is not None:
        plain["recipe"] = str(ROOT / recipe)
    (tmp_path / "plain.yaml").write_text(yaml.safe_dump(plain))
    det = prepare(load_scenario(tmp_path / "plain.yaml")).cases[0].sensing.detection_model
    (tmp_path / "plain.yaml").unlink()
    comps = list(components or det.components)
    torch.manual_seed(0)
    net = NEBPNet(det.n_pairs, comps, hidden=8)
    meta = nebp_metadata(det.geometry.to_dict(), comps, list(det.noise_std), 1.0, 6, net, [25000.0, 40.0, 1.0])
    if checkpoint == "n.pt":
        save_nebp_checkpoint(tmp_path / "n.pt", meta, net)
    path = tmp_path / "nebp.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


@pytest.mark.integration
def test_an_untrained_checkpoint_scores_as_bp_in_pmsr_evaluate(tmp_path):
    from pmsr_nn.harness import evaluate

    res = evaluate(_scenario(tmp_path), tmp_path / "out", progress=False)
    rows = res["cases"]["c"]["methods"]
    for key in ("gospa_m", "ospa_m", "false_tracks_per_run", "confirmed_tracks_per_target"):
        assert rows["N"][key] == pytest.approx(rows["BP"][key], rel=1e-9, abs=1e-9), key


def _refused(tmp_path, capsys, path, needle):
    from pmsr_nn.cli import main

    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["evaluate", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_a_checkpoint_for_another_pair_count_is_one_line_exit_2_and_nothing_written(tmp_path, capsys):
    path = _scenario(tmp_path, recipe="datasets/one_sky_fm.yaml")  # made for 6 pairs; the scenario has the default 3
    _refused(tmp_path, capsys, path, "method 'N': the checkpoint was trained for 6 transmitter-receiver pairs, the "
                                     "scenario has 3")


def test_a_checkpoint_for_another_measurement_set_is_one_line_exit_2_and_nothing_written(tmp_path, capsys):
    path = _scenario(tmp_path, components=["range", "doppler", "azimuth"])
    _refused(tmp_path, capsys, path, "method 'N': the checkpoint reads ['range', 'doppler', 'azimuth'], the detections "
                                     "are ['range', 'range_rate', 'azimuth']")


def test_a_checkpoint_of_another_kind_is_one_line_exit_2_and_nothing_written(tmp_path, capsys):
    import shutil

    shutil.copy(ROOT / "models/released/rnn.pt", tmp_path / "g.pt")
    path = _scenario(tmp_path, checkpoint="g.pt")
    _refused(tmp_path, capsys, path, "is not a NEBP checkpoint (format 'pmsr_nn.tracker') (a learned tracker of clean "
                                     "streams: use it with kind learned)")


@pytest.mark.parametrize("override, message", [("scenes.pd=[0.0,0.0]", "scenes.pd must lie in (0, 1]"),
                                               ("optim.new_weight=0", "optim.new_weight must be in (0, 100], got 0")])
def test_a_training_config_it_can_not_train_is_one_line_exit_2_and_nothing_written(tmp_path, capsys, override,
                                                                                    message):
    from pmsr_nn.cli import main

    cfg = (ROOT / "train/nebp.yaml").read_text().replace("../datasets/", str(ROOT / "datasets") + "/")
    (tmp_path / "nebp.yaml").write_text(cfg)
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["train", str(tmp_path / "nebp.yaml"), "--out", str(tmp_path / "run"), override]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_a_checkpoint_round_trips_and_an_edited_one_is_refused(tmp_path):
    pr = _problem()
    net = _net(pr)
    torch.nn.init.constant_(net.det_out.bias, 0.3)
    meta = nebp_metadata({"g": 1}, list(pr.model.components), list(pr.noise_std), 1.0, 6, net, pr.scales, seed=4)
    save_nebp_checkpoint(tmp_path / "n.pt", meta, net)
    ck = load_nebp_checkpoint(tmp_path / "n.pt")
    assert ck.meta["training"] == {"seed": 4} and float(ck.net.det_out.bias.detach()) == pytest.approx(0.3)
    blob = torch.load(tmp_path / "n.pt", weights_only=True)
    blob["pmsr"]["scales"] = [1.0]
    torch.save(blob, tmp_path / "bad.pt")
    with pytest.raises(CheckpointError, match="scales or sizes are inconsistent"):
        load_nebp_checkpoint(tmp_path / "bad.pt")


@pytest.mark.parametrize("main_name, companion, oracle, stem", [
    ("dense_crossing", "dense_crossing_nebp", "S-MSJPDA (oracle births)", "nebp"),
    ("shared_drones", "shared_drones_nebp", "S-MSJPDA", "nebp"),
    ("one_sky_bp", "one_sky_nebp", "S-MSJPDA (oracle births)", "nebp_one_sky"),
    ("one_sky_bp", "one_sky_nebp_births", "S-MSJPDA (oracle births)", "nebp_one_sky_births")])
def test_the_nebp_companions_are_their_studies_but_for_the_rows(main_name, companion, oracle, stem):
    """``evaluate/<study>_nebp.yaml``: every setting but the name, the description and the rows is
    the study's (the draws do not depend on those), its first rows are the study's oracle row and
    BP, the others NEBP from the released checkpoints made for its sensors."""
    import yaml

    root = ROOT / "evaluate"
    main_, nebp = (yaml.safe_load((root / f"{f}.yaml").read_text()) for f in (main_name, companion))
    rest = lambda d: {k: v for k, v in d.items() if k not in ("name", "description", "methods")}  # noqa: E731
    assert rest(nebp) == rest(main_)
    assert nebp["methods"][:2] == [next(m for m in main_["methods"] if m["name"] == oracle), {"name": "BP", "kind": "bp"}]
    assert [(m["kind"], m["checkpoint"]) for m in nebp["methods"][2:]] == [
        ("nebp", f"../models/released/{stem}_s{s}.pt") for s in range(3)]


def test_the_births_variants_are_their_studies_but_for_the_checkpoints():
    """``one_sky_nebp_births.yaml`` / ``one_sky_hard_births.yaml``: one_sky_nebp's / one_sky_hard's
    draws, settings and rows, each NEBP row reading the network of the same seed trained with births."""
    import yaml

    root = ROOT / "evaluate"
    for base in ("one_sky_nebp", "one_sky_hard"):
        a, b = (yaml.safe_load((root / f"{f}.yaml").read_text()) for f in (base, f"{base}_births"))
        rest = lambda d: {k: v for k, v in d.items() if k not in ("name", "description", "methods")}  # noqa: E731
        assert rest(a) == rest(b) and b["name"] == f"{base}_births"
        moved = [{**m, "checkpoint": m["checkpoint"].replace("nebp_one_sky_s", "nebp_one_sky_births_s")} if "checkpoint" in m
                 else m for m in a["methods"]]
        assert b["methods"] == moved and sum("births_s" in m.get("checkpoint", "") for m in b["methods"]) == 3
    a, c = (yaml.safe_load((root / f"{f}.yaml").read_text()) for f in ("one_sky_nebp", "one_sky_bp_birth_rate"))
    assert rest(a) == rest(c)  # the birth-rate control: the same draws, BP at two birth rates
    assert [m.get("options", {}).get("birth_rate") for m in c["methods"]] == [None, pytest.approx(0.01 * math.exp(2), 1e-3)]


def test_the_hard_one_sky_is_one_sky_nebp_but_for_pd_and_clutter():
    """``evaluate/one_sky_hard.yaml``: one_sky_nebp's draws, rows and settings, but Pd 0.7 (0.85) and
    40 clutter points per pair (80 per receiver's pooled list of two pairs; one_sky 10 and 20)."""
    import yaml

    root = ROOT / "evaluate"
    nebp, hard = (yaml.safe_load((root / f).read_text()) for f in ("one_sky_nebp.yaml", "one_sky_hard.yaml"))
    rest = lambda d: {k: v for k, v in d.items() if k not in ("name", "description", "detections")}  # noqa: E731
    assert rest(hard) == rest(nebp)
    d_nebp, d_hard = nebp["detections"], hard["detections"]
    assert (d_nebp["pd"], d_hard["pd"]) == (0.85, 0.7) and d_hard["illuminator_known"] is False
    assert (d_nebp["clutter"]["per_scan"], d_hard["clutter"]["per_scan"]) == (20, 80)
    assert {**d_hard, "pd": 0.85, "clutter": {**d_hard["clutter"], "per_scan": 20}} == d_nebp
