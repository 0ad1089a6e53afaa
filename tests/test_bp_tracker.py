"""The belief-propagation tracker (pmsr_nn.trackers.bp_tracker, kind: bp): its seed of a new
potential target against the truth, the undetected targets' mass against its recursion, births
and deaths on a clutter-free case, no track from clutter alone, and refusals in one line."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch
import yaml
from scipy.stats import chi2

from pmsr_nn.cli import main
from pmsr_nn.filters.gaussian import Gaussian
from pmsr_nn.harness.run.blocks import call_method, draw_block
from pmsr_nn.harness.run.runner import prepare
from pmsr_nn.harness.scenario.schema import load_scenario
from pmsr_nn.motion import ConstantAcceleration
from pmsr_nn.metrics import set_scores, track_scores
from pmsr_nn.rng import seeded_generator
from pmsr_nn.simulation.detections import ClutterSpec, simulate_scans
from pmsr_nn.trackers.bp_tracker import BPSettings, BPTracks, bp_tracker, one_detection_seed
from pmsr_nn.trackers.management import TrackTable
from test_track_management import ca_state, model, scenario

OTHER_SD = torch.tensor([300.0, 20.0, 0.5, 300.0, 20.0, 0.5], dtype=torch.float64)


def test_a_new_potential_target_from_one_detection_holds_the_truth_within_its_covariance():
    """Noise-free detections of known states at every pair: the seed's position is the fix (the
    truth, to round-off); with noisy ones, its position error is consistent with its covariance
    (NEES over 2000 draws within the chi-square interval of 2 x 2000 degrees of freedom)."""
    m = model()
    truth = torch.stack([ca_state(3000.0 + 500 * i, 5.0, 2000.0 - 300 * i, -3.0) for i in range(4)])  # (4, 6)
    seed = one_detection_seed(m, 6, OTHER_SD, 20.0)
    z = m.h(truth).unflatten(-1, (m.n_pairs, -1))  # (4, S, d)
    g, ok = seed(z.transpose(0, 1)[None], torch.ones(1, m.n_pairs, 4, dtype=torch.bool))  # every pair at once
    assert ok.all()
    for s in range(m.n_pairs):
        torch.testing.assert_close(g.x[0, s][:, [0, 3]], truth[:, [0, 3]], rtol=0, atol=1e-6)
    gen = seeded_generator(7)
    draws = 2000
    x = truth[0].expand(draws, 6)
    noisy = z[0, 0] + torch.randn(draws, 3, generator=gen, dtype=torch.float64) * torch.tensor(m.noise_std[:3])
    at_pair_0 = torch.zeros(1, m.n_pairs, draws, dtype=torch.bool)
    at_pair_0[:, 0] = True
    g, ok = seed(noisy.expand(m.n_pairs, draws, 3)[None], at_pair_0)  # pair 0's list (the others' not valid)
    g, ok = Gaussian(g.x[:, 0], g.P[:, 0]), ok[:, 0]
    e = (g.x[0] - x)[ok[0]][:, [0, 3]]
    P = g.P[0][ok[0]][:, [0, 3]][:, :, [0, 3]]
    nees = float((e.unsqueeze(-2) @ torch.linalg.solve(P, e.unsqueeze(-1))).sum())
    dof = 2 * int(ok.sum())
    # the fix is linearised: allow the 99.99 % interval (a wrong covariance is off by far more)
    assert chi2.ppf(1e-4, dof) < nees < chi2.ppf(1 - 1e-4, dof), (nees, dof)


def test_the_seeds_of_a_scan_are_each_pairs_own_as_the_fix_initiator_gives_them():
    """The seed computes every pair at once: each pair's seeds equal the fix initiator's track
    from that one detection with that pair's own model (a group of one member, its covariance the
    sigma-point spread), on random lists with invalid entries and fixes that fail; the velocity
    exactly as the per-pair fit. Round-off only: the same arithmetic in another batch shape."""
    from pmsr_nn.trackers.fix_initiator import FixInitiator, range_azimuth_fix

    m = model()
    gen = seeded_generator(3)
    B, S, M = 2, m.n_pairs, 6
    z = torch.stack([torch.rand(B, S, M, generator=gen, dtype=torch.float64) * 20000.0,
                     (torch.rand(B, S, M, generator=gen, dtype=torch.float64) - 0.5) * 120.0,
                     (torch.rand(B, S, M, generator=gen, dtype=torch.float64) - 0.5) * 2 * math.pi], -1)
    valid = torch.rand(B, S, M, generator=gen) < 0.8
    g, real = one_detection_seed(m, 6, OTHER_SD, 10.0)(z, valid)
    initiator = FixInitiator(10.0, min_pairs=1)
    step = math.sqrt(3.0) * torch.tensor([m.noise_std[0], m.noise_std[2]], dtype=torch.float64)
    for s in range(S):
        sub, zs = m.for_pairs([s]), z[:, s:s + 1]
        pos, _, ok = initiator.fixes(zs, sub, 6)
        spread = torch.zeros(B, 1, M, 2, 2, dtype=torch.float64)
        for c, dz in ((0, step[0]), (0, -step[0]), (2, step[1]), (2, -step[1])):
            moved = zs.clone()
            moved[..., c] += dz
            p, fine = range_azimuth_fix(moved, sub)
            spread += (p - pos).unsqueeze(-1) * (p - pos).unsqueeze(-2) / 6.0
            ok &= fine
        ok = ok[:, 0] & valid[:, s]
        assert torch.equal(real[:, s], ok) and 0 < int(ok.sum()) < B * M  # some fixes fail
        groups = torch.where(ok, torch.arange(M), -1).unsqueeze(-1)
        want, _ = initiator.states(zs, groups, pos, spread, sub, 6, OTHER_SD)
        torch.testing.assert_close(g.x[:, s][ok], want.x[ok], rtol=1e-12, atol=1e-9)
        torch.testing.assert_close(g.P[:, s][ok], want.P[ok], rtol=1e-12, atol=1e-9)


def _settings(**over) -> BPSettings:
    return BPSettings(**{"pd": 0.9, "clutter_count": 5.0, "clutter_density": 1e-7, **over})


def test_the_undetected_mass_follows_its_recursion_when_nothing_is_detected():
    """No detections at all: every scan the mass survives, grows by the birth rate and each of
    the S pairs takes Pd of it, ``mu <- (ps mu + b) (1 - Pd)^S`` (the first scan without the
    prediction), and no track is ever started."""
    m = model()
    B, K = 2, 5
    scans = simulate_scans(torch.zeros(B, K, 0, 6, dtype=torch.float64), m, 0.9, ClutterSpec(per_scan=0),
                           seeded_generator(1))
    assert not scans.valid.any()
    s = _settings(survival=0.95, birth_rate=0.2, initial_targets=3.0)
    seen = []
    tracks_cls = BPTracks.updated

    def spy(self, k, step, z, valid):
        tracks_cls(self, k, step, z, valid)
        seen.append(self.undetected.clone())

    BPTracks.updated = spy
    try:
        rep = bp_tracker(scans, _motion(), 1.0, 1.0, m, m.R(), s, OTHER_SD)
    finally:
        BPTracks.updated = tracks_cls
    expected, mu = [], 3.0
    for k in range(K):
        if k > 0:
            mu = 0.95 * mu + 0.2
        mu = mu * 0.1 ** m.n_pairs
        expected.append(mu)
    torch.testing.assert_close(torch.stack(seen), torch.tensor(expected, dtype=torch.float64)[:, None].expand(K, B),
                               rtol=1e-12, atol=0)
    assert rep.exists.shape[2] == 0


def _motion():
    return ConstantAcceleration(2)


def test_clutter_alone_confirms_no_track():
    """Clutter only (5 per pair and scan over the whole space), no target, 30 scans, 4 runs: new
    potential targets are born every scan, and none reaches the confirmation threshold."""
    m = model()
    truth = torch.full((4, 30, 0, 6), 0.0, dtype=torch.float64)
    clutter = ClutterSpec(per_scan=5, range_m=(0.0, 25000.0), range_rate_mps=(-40.0, 40.0),
                          azimuth_deg=(-180.0, 180.0))
    scans = simulate_scans(truth, m, 0.9, clutter, seeded_generator(3))
    s = _settings(clutter_density=clutter.density_of(m.components))
    rep = bp_tracker(scans, _motion(), 1.0, 1.0, m, m.R(), s, OTHER_SD)
    assert not rep.exists.any()


@pytest.mark.parametrize("pd, clutter, first", [(1.0, 0, 0.0), (0.9, 3, 1.0)])
def test_births_and_deaths_give_one_confirmed_track_per_target_from_the_first_scan(tmp_path, pd, clutter, first):
    """Two drones, one born at 15 s (three pairs): BP confirms one track per drone at the scan
    of its first detections (one detection seeds a potential target that the other pairs'
    detections confirm within the scan; with Pd 0.9 a drone may be seen at one pair only at its
    birth, so within a scan), no other, and ends it when the drone dies."""
    path = scenario(tmp_path, pd=pd, clutter=clutter, methods=[{"name": "BP", "kind": "bp"}])
    setup = prepare(load_scenario(path))
    case = setup.cases[0]
    truth, products = draw_block(setup, 0, 0)
    est = call_method(setup, setup.methods[0], case, products, (3, 0, 0))
    assert not est.paired and est.x.shape[2] == 2  # two track ids in all, per run
    B, K, _ = est.exists.shape
    alive = case.alive.expand(B, K, 2)
    sets = set_scores(est.x[..., [0, 3]], est.exists, truth.x[..., [0, 3]], alive, 300.0, 2.0)
    ts = track_scores(sets.assignment, est.exists, alive)
    assert ts.tracks_per_target.tolist() == [[1.0, 1.0]] * B and ts.false_tracks.tolist() == [0.0] * B
    assert float(ts.scans_to_first_track.max()) == first
    for t, k1 in enumerate((40, 60)):
        slot = [row.index(t) for row in sets.assignment[:, k1 - 1].tolist()]
        for b in range(B):
            assert not est.exists[b, k1 + 1:, slot[b]].any()


def test_table_add_takes_each_new_tracks_existence():
    park = torch.zeros(2, dtype=torch.float64)
    t = TrackTable.empty(1, 2, park, capacity=2)
    g = Gaussian(torch.tensor([[[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]]], dtype=torch.float64),
                 torch.eye(2, dtype=torch.float64).expand(1, 3, 2, 2))
    t.add(g, torch.tensor([[True, False, True]]), torch.tensor([[0.3, 0.9, 0.7]], dtype=torch.float64))
    assert t.existence[0, :2].tolist() == [0.3, 0.7] and t.g.x[0, :2, 0].tolist() == [1.0, 3.0]


@pytest.mark.parametrize("options, message", [
    ({"confirm_existence": 1.0}, "option confirm_existence must be"),
    ({"delete_existence": 0.0}, "option delete_existence must be"),
    ({"confirm_existence": 0.01, "delete_existence": 0.1}, "confirm_existence (0.01) is below delete_existence (0.1)"),
    ({"birth_rate": -0.1}, "option birth_rate must be"),
])
def test_settings_that_never_confirm_are_one_line_errors_and_write_nothing(tmp_path, capsys, options, message):
    path = scenario(tmp_path, methods=[{"name": "B", "kind": "bp", "options": options}])
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["evaluate", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "method 'B'" in err[0] and message in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_bp_on_a_scenario_without_detections_is_refused_in_one_line(tmp_path, capsys):
    path = scenario(tmp_path, methods=[{"name": "B", "kind": "bp"}])
    data = yaml.safe_load(path.read_text())
    del data["detections"]
    path.write_text(yaml.safe_dump(data))
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["evaluate", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'B'" in err[0] and "detections" in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_the_bp_companion_is_one_sky_but_for_its_rows_and_maps():
    """``evaluate/one_sky_bp.yaml`` puts BP on one_sky's draws: every setting but the name, the
    description, the rows and the maps section (no row reads maps) is one_sky.yaml's, and its
    S-MSJPDA rows are one_sky's."""
    root = Path(__file__).resolve().parents[1] / "evaluate"
    main_, bp = (yaml.safe_load((root / f).read_text()) for f in ("one_sky.yaml", "one_sky_bp.yaml"))
    rest = lambda d: {k: v for k, v in d.items() if k not in ("name", "description", "methods", "rd_maps")}  # noqa: E731
    assert rest(bp) == rest(main_) and "rd_maps" not in bp
    theirs = {m["name"]: m for m in main_["methods"]}
    assert [m for m in bp["methods"] if m["kind"] != "bp"] == [theirs["S-MSJPDA (oracle births)"], theirs["S-MSJPDA"]]
    assert [m for m in bp["methods"] if m["kind"] == "bp"] == [theirs["BP"]]


def test_the_stonesoup_companion_is_one_sky_bp_on_its_first_runs():
    """``evaluate/one_sky_stonesoup.yaml``: one_sky_bp's settings but for fewer runs, one per
    block (so its blocks are one_sky_bp's first ones), BP as one_sky's and Stone Soup's JPDA as
    one_sky's."""
    root = Path(__file__).resolve().parents[1] / "evaluate"
    main_, bp, ss = (yaml.safe_load((root / f).read_text())
                     for f in ("one_sky.yaml", "one_sky_bp.yaml", "one_sky_stonesoup.yaml"))
    rest = lambda d: {k: v for k, v in d.items() if k not in ("name", "description", "methods", "mc_runs")}  # noqa: E731
    assert rest(ss) == rest(bp) and ss["block_runs"] == 1 and ss["mc_runs"] < bp["mc_runs"]
    theirs = {m["name"]: m for m in main_["methods"]}
    assert ss["methods"] == [theirs["BP"], theirs["Stone Soup JPDA"]]


@pytest.mark.parametrize("main_name, oracle", [("dense_crossing", "S-MSJPDA (oracle births)"),
                                               ("shared_drones", "S-MSJPDA")])
def test_the_bp_companions_are_their_studies_but_for_the_rows(main_name, oracle):
    """``evaluate/<study>_bp.yaml``: every setting but the name, the description and the rows is
    the study's (the draws do not depend on those), its oracle row is the study's, and BP is the
    other row."""
    root = Path(__file__).resolve().parents[1] / "evaluate"
    main_, bp = (yaml.safe_load((root / f).read_text()) for f in (f"{main_name}.yaml", f"{main_name}_bp.yaml"))
    rest = lambda d: {k: v for k, v in d.items() if k not in ("name", "description", "methods")}  # noqa: E731
    assert rest(bp) == rest(main_)
    assert bp["methods"][:2] == [next(m for m in main_["methods"] if m["name"] == oracle), {"name": "BP", "kind": "bp"}]
    assert {m["kind"] for m in bp["methods"][2:]} <= {"bp"}


def test_a_target_seeded_at_one_pair_is_a_track_for_the_next_in_closed_form():
    """One target, two pairs, one scan, no clutter, no track yet: pair 0's detection seeds a new
    potential target with existence ``mu / (1 + mu)`` (``mu = mu_u Pd / Lambda_c``); at pair 1 it
    is the one track, and the one-track, one-detection factor graph is a tree, so BP is exact:
    with ``L`` its likelihood ratio (sigma-point moments, independently computed) and ``mu_1 =
    mu_u (1 - Pd) Pd / Lambda_c``, its existence becomes ``r (Pd L + (1 - Pd)(1 + mu_1)) / D`` and
    pair 1's own new potential target ``mu_1 (1 - r Pd) / D``, ``D = r Pd L + (1 - r Pd)(1 +
    mu_1)``; the undetected mass ends at ``mu_u (1 - Pd)^2``."""
    from pmsr_nn.filters import unscented_moments
    from pmsr_nn.filters.gaussian import Gaussian as G
    from pmsr_nn.trackers.bp_associator import Births, BPAssociator

    full = model()
    m = full.for_pairs([0, 1])
    x = ca_state(3000.0, 5.0, 2000.0, -3.0)
    z = m.h(x[None]).reshape(1, 2, 1, 3)  # (B, S, M, d): noise-free
    valid = torch.ones(1, 2, 1, dtype=torch.bool)
    pd, count, density, mu_u = 0.9, 5.0, 1e-7, 0.02
    seed = one_detection_seed(m, 6, OTHER_SD, 20.0)
    births = Births(lambda: torch.tensor([mu_u], dtype=torch.float64), pd, count, seed, 1e-12)
    bp = BPAssociator(m, m.R(), pd, density, existence=lambda: torch.zeros(1, 0, dtype=torch.float64),
                      gate_probability=1 - 1e-12, births=births)
    empty = G(torch.zeros(1, 0, 6, dtype=torch.float64), torch.zeros(1, 0, 6, 6, dtype=torch.float64))
    step = bp.associate(empty, z, valid, torch.zeros(1, 0, dtype=torch.bool))
    mu0 = mu_u * pd / count
    r = mu0 / (1 + mu0)
    g0, _ = seed(z, valid)
    g0 = G(g0.x[:, 0], g0.P[:, 0])
    sub = m.for_pairs([1])
    R1 = m.R()[3:, 3:]
    mom = unscented_moments(g0, sub, R1)
    nu = sub.residual(z[0, 1, 0], mom.z[0, 0])
    S = mom.S[0, 0]
    L = float(torch.exp(-0.5 * nu @ torch.linalg.solve(S, nu)) / torch.sqrt(torch.linalg.det(2 * math.pi * S))) / density
    mu1 = mu_u * (1 - pd) * pd / count
    D = r * pd * L + (1 - r * pd) * (1 + mu1)
    assert step.existence.shape == (1, 2) and step.born.tolist() == [[True, True]]
    assert math.isclose(float(step.existence[0, 0]), r * (pd * L + (1 - pd) * (1 + mu1)) / D, rel_tol=1e-9)
    assert math.isclose(float(step.existence[0, 1]), mu1 * (1 - r * pd) / D, rel_tol=1e-9)
    assert math.isclose(float(step.undetected[0]), mu_u * (1 - pd) ** 2, rel_tol=1e-12)


def test_a_pooled_list_is_one_association_over_the_illuminators_as_enumerated():
    """Two transmitters 300 m apart, one receiver, their detections pooled (the illuminator
    unknown): the list's one detection fits the track under both illuminators. BP associates it
    with one (track, illuminator) node at most, as the enumeration of the three joint events
    gives on this tree: node k takes it with ``r Pd L_k (1 - r Pd)``, neither with ``(1 - r
    Pd)^2 (1 + mu)`` (``L_k`` from the sigma-point moments of pair k, independently computed)."""
    from pmsr_nn.filters import unscented_moments
    from pmsr_nn.filters.gaussian import Gaussian as G
    from pmsr_nn.geometry import Geometry, Receiver, Transmitter
    from pmsr_nn.measurements import MeasurementModel
    from pmsr_nn.trackers.bp_associator import BPAssociator

    geo = Geometry.all_pairs([Transmitter((0.0, 0.0), 98e6), Transmitter((300.0, 0.0), 98e6)],
                             [Receiver((-7000.0, -3000.0))])
    m = MeasurementModel(geo, ("range", "range_rate", "azimuth"), (30.0, 2.0, math.radians(3.0)), (0, 3), (1, 4),
                         layout="pair")
    x = ca_state(3000.0, 5.0, 2000.0, -3.0)
    P = torch.diag(torch.tensor([150.0, 3.0, 0.1, 150.0, 3.0, 0.1], dtype=torch.float64) ** 2)
    g = G(x[None, None], P[None, None])
    z = m.h(x[None]).reshape(1, 2, 1, 3)[:, :1] + torch.tensor([60.0, 1.0, 0.01], dtype=torch.float64)  # (B, L=1, M, d)
    valid = torch.ones(1, 1, 1, dtype=torch.bool)
    r, pd, density, mu = 0.6, 0.9, 1e-7, 0.3
    bp = BPAssociator(m, m.R(), pd, density, existence=lambda: torch.tensor([[r]], dtype=torch.float64), birth=mu,
                      gate_probability=1 - 1e-12, lists=[0, 0])
    step = bp.associate(g, z, valid, None)
    L = []
    for k in range(2):
        mom = unscented_moments(g, m.for_pairs([k]), m.R()[3 * k:3 * k + 3, 3 * k:3 * k + 3])
        nu = m.for_pairs([k]).residual(z[0, 0, 0], mom.z[0, 0])
        S = mom.S[0, 0]
        L.append(float(torch.exp(-0.5 * nu @ torch.linalg.solve(S, nu)) / torch.sqrt(torch.linalg.det(2 * math.pi * S)))
                 / density)
    q = 1 - r * pd
    events = [r * pd * L[0] * q, q * r * pd * L[1], q * q * (1 + mu)]
    Z = sum(events)
    assert min(events[:2]) / Z > 0.05, "the detection fits the track under both illuminators"
    for k in range(2):
        assert math.isclose(float(step.association[0, 0, k, 0]), events[k] / Z, rel_tol=1e-9)
    assert math.isclose(float(step.legacy[0, 0, 0]), (events[0] + events[1]) / Z, rel_tol=1e-9)


def test_the_managed_companion_is_one_sky_bp_but_for_its_rows():
    """``evaluate/one_sky_managed.yaml``: one_sky_bp's draws and scoring, S-MSJPDA with the
    duplicate-free management's options, S- and P-MSJPDA (``one_sky_managed_pmht.yaml``: PMHT on
    the same runs)."""
    from pmsr_nn.methods.track_management import DUPLICATE_FREE

    root = Path(__file__).resolve().parents[1] / "evaluate"
    bp, managed = (yaml.safe_load((root / f).read_text()) for f in ("one_sky_bp.yaml", "one_sky_managed.yaml"))
    rest = lambda d: {k: v for k, v in d.items() if k not in ("name", "description", "methods")}  # noqa: E731
    assert rest(managed) == rest(bp)
    assert [row["kind"] for row in managed["methods"]] == ["s_msjpda", "p_msjpda"]
    for row in managed["methods"]:
        assert row["options"] == {"initiation": "detections", **DUPLICATE_FREE}
    # PMHT on the same runs (one per block: block b is run b of both)
    pmht = yaml.safe_load((root / "one_sky_managed_pmht.yaml").read_text())
    assert rest(pmht) == rest(bp) and pmht["block_runs"] == 1
    [row] = pmht["methods"]
    assert row["kind"] == "pmht" and row["options"] == {"initiation": "detections", **DUPLICATE_FREE}


@pytest.mark.parametrize("study", ["dense_crossing", "shared_drones"])
def test_the_duplicate_free_companions_are_their_studies_but_for_their_rows(study):
    """``evaluate/{study}_duplicate_free.yaml``: the study's draws and scoring; its rows with the
    default management are the study's own (so they reproduce its record), and each
    duplicate-free row is one of them with DUPLICATE_FREE added."""
    from pmsr_nn.methods.track_management import DUPLICATE_FREE

    root = Path(__file__).resolve().parents[1] / "evaluate"
    main_study, free = (yaml.safe_load((root / f).read_text()) for f in (f"{study}.yaml", f"{study}_duplicate_free.yaml"))
    rest = lambda d: {k: v for k, v in d.items() if k not in ("name", "description", "methods")}  # noqa: E731
    assert rest(free) == rest(main_study)
    own = {m["name"]: m for m in main_study["methods"]}
    twins = {m["kind"]: m for m in main_study["methods"] if m.get("options", {}).get("initiation") == "detections"}
    new = [m for m in free["methods"] if m["name"] not in own]
    assert [m["kind"] for m in new] == ["s_msjpda", "p_msjpda", "pmht"]
    for m in free["methods"]:
        if m["name"] in own:
            assert m == own[m["name"]]
        else:
            assert m["options"] == {**twins[m["kind"]]["options"], **DUPLICATE_FREE}
    assert {m["kind"] for m in free["methods"] if m["name"] in own and "initiation" in m.get("options", {})} == \
        {"s_msjpda", "p_msjpda", "pmht"}


def test_the_unscented_fixes_companion_is_one_sky_managed_with_the_unscented_fix_covariance():
    """``evaluate/one_sky_unscented_fixes.yaml``: one_sky_bp's draws and scoring; S-, P-MSJPDA and
    PMHT with the duplicate-free management (one_sky_managed's and one_sky_managed_pmht's rows)
    and ``fix_covariance: unscented``, nothing else changed."""
    from pmsr_nn.methods.track_management import DUPLICATE_FREE

    root = Path(__file__).resolve().parents[1] / "evaluate"
    bp, unscented = (yaml.safe_load((root / f).read_text()) for f in ("one_sky_bp.yaml", "one_sky_unscented_fixes.yaml"))
    rest = lambda d: {k: v for k, v in d.items() if k not in ("name", "description", "methods")}  # noqa: E731
    assert rest(unscented) == rest(bp)
    assert [row["kind"] for row in unscented["methods"]] == ["s_msjpda", "p_msjpda", "pmht"]
    for row in unscented["methods"]:
        assert row["options"] == {"initiation": "detections", **DUPLICATE_FREE, "fix_covariance": "unscented"}


@pytest.mark.parametrize("study", ["dense_crossing", "shared_drones"])
def test_the_unscented_fixes_companions_are_the_duplicate_free_rows_with_the_unscented_fix_covariance(study):
    """``evaluate/{study}_unscented_fixes.yaml``: the study's draws and scoring; each row is the
    duplicate-free companion's row of its kind with ``fix_covariance: unscented`` added."""
    root = Path(__file__).resolve().parents[1] / "evaluate"
    main_study, free, unscented = (yaml.safe_load((root / f).read_text()) for f in (
        f"{study}.yaml", f"{study}_duplicate_free.yaml", f"{study}_unscented_fixes.yaml"))
    rest = lambda d: {k: v for k, v in d.items() if k not in ("name", "description", "methods")}  # noqa: E731
    assert rest(unscented) == rest(main_study)
    twins = {m["kind"]: m for m in free["methods"] if "(duplicate-free)" in m["name"]}
    assert [m["kind"] for m in unscented["methods"]] == ["s_msjpda", "p_msjpda", "pmht"]
    for m in unscented["methods"]:
        assert m["options"] == {**twins[m["kind"]]["options"], "fix_covariance": "unscented"}
