"""The one tracker loop (pmsr_nn/trackers/loop.py) and its roles: a new associator plugs in as the
worked GNN example of docs/examples/gnn_tracker.py, checked against independent references."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch
import yaml
from scipy.stats import chi2

from pmsr_nn.filters import Gaussian
from pmsr_nn.harness import evaluate
from pmsr_nn.methods import REGISTRY
from pmsr_nn.rng import seeded_generator
from pmsr_nn.simulation.detections import ClutterSpec, simulate_scans
from pmsr_nn.trackers.handed_births import HandedBirths
from pmsr_nn.trackers.loop import run_tracker
from pmsr_nn.trackers.management import Confirmer, Deleter, Management
from pmsr_nn.trackers.own_tracks import OwnTracks
from pmsr_nn.trackers.spherical_initiator import SphericalInitiator
from script_loader import load_script
from test_msjpda import MOTION, _formation, _model, _prior, _sequential_ukf
from test_one_scenario import two_drones


@pytest.fixture(scope="module")
def gnn():
    """The example module, loaded once; its kind leaves the registry afterwards."""
    REGISTRY.pop("gnn_example", None)
    mod = load_script("docs/examples/gnn_tracker.py")
    yield mod
    REGISTRY.pop("gnn_example", None)


def test_gnn_handed_the_births_of_separated_targets_is_the_sequential_ukf(gnn):
    """No clutter, Pd 1, targets 40 km apart: each track's only gated detection is its target's, so
    GNN on the loop is the pair-by-pair UKF of each target (filters.sequential_update)."""
    model = _model()
    truth = _formation(B=2, K=10, T=2, spacing=40e3)
    scans = simulate_scans(truth, model, 1.0, ClutterSpec(per_scan=0), seeded_generator(2))
    prior = _prior(truth)
    assoc = gnn.GNNAssociator(model, model.R(), pd=1.0 - 1e-9, density=1e-9, gate_probability=1 - 1e-12)
    res = run_tracker(scans, MOTION, 1.0, 1.0, assoc, HandedBirths(prior))
    for t in range(2):
        z = scans.target_measurements(2)[:, :, t].reshape(2, 10, 6)
        expected = _sequential_ukf(Gaussian(prior.x[:, t], prior.P[:, t]), z, model)
        torch.testing.assert_close(res.x[:, :, t], expected, rtol=1e-9, atol=1e-7)
    assert not res.dummy_most_probable.any()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_gnn_assignment_is_the_cheapest_by_brute_force(gnn, seed):
    """3 tracks, 4 detections, some not gated (inf): the solver's choice costs what the cheapest
    of every one-to-one choice (each track a detection or a miss) costs."""
    rng = np.random.default_rng(seed)
    assoc = gnn.GNNAssociator.__new__(gnn.GNNAssociator)
    assoc.pd = 0.8
    cost = np.where(rng.random((3, 4)) < 0.7, rng.normal(0.0, 2.0, (3, 4)), np.inf)
    miss = -math.log(0.2)
    pick = assoc.assign(cost)
    total = lambda p: sum(miss if i < 0 else cost[t, i] for t, i in enumerate(p))  # noqa: E731
    best = min(total(p) for p in itertools.product(range(-1, 4), repeat=3)
               if len([i for i in p if i >= 0]) == len({i for i in p if i >= 0}))
    assert math.isclose(total(pick), best, rel_tol=0, abs_tol=1e-12)


def test_own_tracks_on_the_loop_start_one_confirmed_track_per_separated_target(gnn):
    """No clutter, Pd ~1, two targets 40 km apart: the shared management starts, confirms (2 of 3)
    and keeps exactly one track per target, reported from scan 1 (its second hit) on."""
    model = _model()
    truth = _formation(B=2, K=12, T=2, spacing=40e3)
    scans = simulate_scans(truth, model, 1.0, ClutterSpec(per_scan=0), seeded_generator(4))
    mg = Management(SphericalInitiator(), Confirmer(2, 3), Deleter(2), torch.tensor([300.0, 10.0] * 2,
                                                                                    dtype=torch.float64), hit_pairs=2)
    assoc = gnn.GNNAssociator(model, model.R(), pd=1.0 - 1e-9, density=1e-9, gate_probability=1 - 1e-12)
    rep = run_tracker(scans, MOTION, 1.0, 1.0, assoc, OwnTracks(mg, model, 4, 1.0 - 1e-9))
    assert rep.exists.shape[2] == 2, "one track id per target, no other"
    assert not rep.exists[:, 0].any() and rep.exists[:, 1:].all()
    # each track keeps one target (the nearest at every scan) and is consistent with its own
    # covariance there: its normalised position error squared stays below chi2(2)'s 0.9999 quantile
    err = rep.x[:, 1:, :, None][..., [0, 2]] - truth[:, 1:, None, :][..., [0, 2]]  # (B, K, tracks, N, 2)
    held = err.norm(dim=-1).argmin(-1)  # (B, K, tracks)
    assert (held == held[:, :1]).all() and (held[:, 0, 0] != held[:, 0, 1]).all()
    e = err.gather(3, held[..., None, None].expand(*held.shape, 1, 2)).squeeze(3)  # (B, K, tracks, 2)
    P = rep.P[:, 1:][..., [0, 2], :][..., [0, 2]]
    nees = (e.unsqueeze(-2) @ torch.linalg.solve(P, e.unsqueeze(-1))).squeeze(-1).squeeze(-1)
    assert float(nees.max()) < chi2.ppf(0.9999, 2), nees.max()


@pytest.mark.integration
def test_the_gnn_kind_runs_through_evaluate(gnn, tmp_path):
    path = two_drones(tmp_path, methods=[{"name": "GNN", "kind": "gnn_example"}], mc_runs=2)
    res = evaluate(path, tmp_path / "out", progress=False)
    row = res["cases"]["c"]["methods"]["GNN"]
    # the example tracker finds the drones: its GOSPA is far below what reporting nothing scores
    # (c / 2^(1/p) per missed target and scan: 212 m with c = 300 m, p = 2, whatever the count)
    assert row["gospa_m"] < 0.5 * 300.0 / math.sqrt(2.0)
    assert yaml.safe_load(path.read_text())["methods"][0]["kind"] == "gnn_example"


def test_the_classical_trackers_import_no_learned_part():
    """trackers/ is classical: no module of it imports anything of nets/ (NEBP's network reaches
    BP only as a refiner handed to it)."""
    from test_structure import PACKAGE, ROOT, import_graph

    graph = import_graph(ROOT, PACKAGE)
    assert "pmsr_nn.trackers.msjpda" in graph and "pmsr_nn.trackers.loop" in graph["pmsr_nn.trackers.msjpda"]
    learned = {m for m in graph if m.startswith("pmsr_nn.nets")}
    offenders = {m: sorted(set(edges) & learned) for m, edges in graph.items()
                 if m.startswith("pmsr_nn.trackers") and set(edges) & learned}
    assert not offenders, offenders
