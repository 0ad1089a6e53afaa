"""SMC-PHD filter, GTDA and Hungarian labelling, aircraft flights, and the kinds smc_phd_pair and
known_association_kf_pair on the runner (scored in one pair's bistatic plane).

References: a direct evaluation of the PHD update equation (loops over particles and
detections), the Kalman filter (exact for the linear-Gaussian single-target case), brute-force
assignment enumeration, and the recursion's own conservation of the expected number.
"""

import itertools
import json
import math
import time

import numpy as np
import pytest
import torch

from pmsr_nn.errors import ConfigError
from pmsr_nn.metrics import fragmentations, label_switches, set_scores
from pmsr_nn.simulation.aircraft import AircraftSpec, LegSpec, fly
from pmsr_nn.trackers.gtda import GameSpec, play, resolve_conflicts
from pmsr_nn.trackers.labelling import LabelSpec, hungarian, label_tracks
from pmsr_nn.trackers.phd import PHDSpec, PHDState, SMCPHD, cv_matrices

SD = torch.tensor([30.0, 4.5], dtype=torch.float64)
BOX_LO = torch.tensor([0.0, -300.0], dtype=torch.float64)
BOX_SPAN = torch.tensor([60_000.0, 600.0], dtype=torch.float64)


def cv_truth(x0: torch.Tensor, B: int, K: int, g: torch.Generator, sigma: float = 20.0) -> torch.Tensor:
    """``(B, K, N, 2)`` CV flights in [r, rdot] with the seed's discrete white-acceleration noise."""
    G = sigma * torch.tensor([0.5, 1.0], dtype=torch.float64)
    F, _ = cv_matrices(1.0, sigma)
    xs = [x0.expand(B, *x0.shape).clone()]
    for _ in range(K - 1):
        xs.append(xs[-1] @ F.T + torch.randn(B, x0.shape[0], 1, generator=g, dtype=torch.float64) * G)
    return torch.stack(xs, 1)


def detections(truth: torch.Tensor, pd: float, clutter: int, g: torch.Generator):
    B, K, N, _ = truth.shape
    det = torch.rand(B, K, N, generator=g, dtype=torch.float64) < pd
    zt = truth + torch.randn(B, K, N, 2, generator=g, dtype=torch.float64) * SD
    zc = BOX_LO + BOX_SPAN * torch.rand(B, K, clutter, 2, generator=g, dtype=torch.float64)
    return torch.cat([zt, zc], 2), torch.cat([det, torch.ones(B, K, clutter, dtype=torch.bool)], 2)


def kappa(clutter: float) -> float:
    return max(clutter, 1e-3) / float(BOX_SPAN.prod())


def kalman_rmse(z: torch.Tensor, truth: torch.Tensor, from_scan: int) -> torch.Tensor:
    """RMSE ``(2,)`` of the exact Kalman filter (H = I) started at the first measurement."""
    F, Q = cv_matrices(1.0, 20.0)
    R = torch.diag(SD**2)
    x, P = z[:, 0].clone(), R.expand(z.shape[0], 2, 2).clone()
    err = []
    for k in range(1, z.shape[1]):
        x, P = x @ F.T, F @ P @ F.T + Q
        S = P + R
        Kg = P @ torch.linalg.inv(S)
        x = x + (Kg @ (z[:, k] - x)[..., None])[..., 0]
        P = (torch.eye(2, dtype=torch.float64) - Kg) @ P
        if k >= from_scan:
            err.append(x - truth[:, k])
    return torch.stack(err).pow(2).mean((0, 1)).sqrt()


@pytest.mark.integration
def test_one_target_no_clutter_pd_1_cardinality_and_error_against_the_kalman_filter():
    g = torch.Generator().manual_seed(1)
    B, K, burn = 40, 60, 10
    truth = cv_truth(torch.tensor([[20_000.0, -100.0]], dtype=torch.float64), B, K, g)
    z, valid = detections(truth, 1.0, 0, g)
    est = SMCPHD(PHDSpec(), SD, 1.0, kappa(0), 1.0).run(z, valid, g)
    # the PHD's integral: 1 - kappa / (kappa + taken) per scan, kappa ~ 6e-11 against taken ~ 1e-4
    assert abs(float(est.expected[:, burn:].mean()) - 1.0) < 0.05
    assert bool((est.exists[:, burn:].sum(-1) == 1).all())
    x = est.x[:, burn:][est.exists[:, burn:]].reshape(B, K - burn, 2)
    phd = (x - truth[:, burn:, 0]).pow(2).mean((0, 1)).sqrt()
    kf = kalman_rmse(z[:, :, 0], truth[:, :, 0], burn)
    assert bool((phd <= 1.2 * kf).all()), (phd, kf)


@pytest.mark.parametrize("adaptive", [True, False])
def test_the_expected_number_equals_the_sum_of_weights_after_every_step(adaptive):
    """The recursion's count (births added, Pd / clutter update per detection partition, kept by
    resampling) against the particle weights; float64 sums of ~1e5 terms agree to ~1e-11."""
    g = torch.Generator().manual_seed(2)
    truth = cv_truth(torch.tensor([[15_000.0, 50.0], [30_000.0, -120.0], [45_000.0, 10.0]], dtype=torch.float64), 3, 25, g)
    z, valid = detections(truth, 0.8, 6, g)
    f = SMCPHD(PHDSpec(particles_per_target=500, particles_per_birth=100, birth_particles_min=20, adaptive_birth=adaptive),
               SD, 0.8, kappa(6), 1.0)
    st = f.empty(3)
    for k in range(25):
        for step in ("predict", "update", "resample"):
            if step == "predict":
                st = f.predict(st, z[:, k - 1] if k else None, valid[:, k - 1] if k else None, g)
            elif step == "update":
                st = f.update(st, z[:, k], valid[:, k])[0]
            else:
                st = f.resample(st, g)
            total = st.w.sum(1)
            assert torch.allclose(total, st.expected, rtol=1e-9, atol=0.0), (k, step, total, st.expected)
    assert float(st.expected.min()) > 1.5  # the check ran on a populated PHD


def tracked_target(clutter: int, g: torch.Generator):
    """One target (Pd 1) tracked for 15 clutter-free scans, then a last update with its detection and
    ``clutter`` points far from it (row 0: the target's): the filter, the state and those detections."""
    truth = cv_truth(torch.tensor([[20_000.0, -100.0]], dtype=torch.float64), 1, 16, g)
    z, valid = detections(truth, 1.0, 0, g)
    f = SMCPHD(PHDSpec(), SD, 1.0, kappa(clutter), 1.0)
    st = f.empty(1)
    for k in range(15):
        st = f.predict(st, z[:, k - 1] if k else None, valid[:, k - 1] if k else None, g)
        st = f.resample(f.update(st, z[:, k], valid[:, k])[0], g)
    far = torch.stack([35_000.0 + 600.0 * torch.arange(clutter, dtype=torch.float64),
                       torch.linspace(-250.0, 250.0, clutter, dtype=torch.float64)], -1)
    zl = torch.cat([z[:, 15], far[None]], 1)
    st = f.predict(st, z[:, 14], valid[:, 14], g)
    st = f.resample(f.update(st, zl, torch.ones(1, 1 + clutter, dtype=torch.bool))[0], g)
    return f, st, zl


@pytest.mark.parametrize("clutter", [0, 10, 30])
def test_births_only_where_no_target_explains_a_detection_and_their_particles_follow_their_mass(clutter):
    """Adaptive births (Ristic et al. 2012): the tracked target's detection, of which the persistent
    PHD took all but u0 = kappa / (kappa + taken) (about 1e-2 at 30 clutter points, below 1e-3
    without), seeds round(u0 x per) particles, none or a few; each of the ``clutter`` unexplained
    points (u = 1) seeds per = max(100, 800 / clutter) particles with birth_rate / clutter of mass.
    One scan's births then cost 800 particles or 100 per unexplained detection, where the filter
    before issue 37 put 800 on every detection (800 x 31 at 30 clutter points)."""
    f, st, zl = tracked_target(clutter, torch.Generator().manual_seed(7))
    spec = f.spec
    assert abs(float(st.expected[0]) - 1.0) < 0.05  # the target is held: its PHD mass is ~1 at Pd 1
    u0 = 1.0 - float(st.explained[0, 0])
    assert u0 < 0.05 and bool((st.explained[0, 1:] == 0).all())
    born = f.predict(st, zl, torch.ones(1, zl.shape[1], dtype=torch.bool), torch.Generator().manual_seed(8))
    xb, wb = born.x[0, born.persistent:], born.w[0, born.persistent:]
    xb = xb[wb > 0]
    per = max(spec.birth_particles_min, spec.particles_per_birth / max(clutter + u0, 1.0))
    # which detection each birth particle came from: within 6 deviations of it after one move (range
    # spread sqrt(30^2 + 4.5^2 + 10^2) m, range-rate sqrt(4.5^2 + 20^2) m/s; the points are >= 600 m apart)
    spread = torch.tensor([32.0, 20.6], dtype=torch.float64)
    d = ((xb[:, None, :] - (zl[0] @ f.F.T)[None]) / spread).abs().amax(-1)  # (births, detections)
    on_target = int((d[:, 0] < 6).sum())
    assert on_target == round(u0 * per) and on_target <= 0.05 * per
    assert bool((d.amin(1) < 6).all())  # and every other one on a clutter point
    assert xb.shape[0] == on_target + clutter * round(per)
    # the births' mass: birth_rate shared among the detections by how unexplained they are (a birth
    # given no particle gets no mass)
    birth_mass = float(born.expected[0] - spec.survival * st.expected[0])
    shared = (clutter + (u0 if on_target else 0.0)) / max(clutter + u0, 1.0)
    assert birth_mass == pytest.approx(spec.birth_rate * shared, rel=1e-9, abs=1e-15)
    assert float(born.w.sum()) == pytest.approx(float(born.expected[0]), rel=1e-9)


def test_the_birth_options_of_the_kind_reach_the_filter_and_bad_ones_are_refused():
    from pmsr_nn.harness.scenario.method_spec import MethodSpec
    from pmsr_nn.methods.phd_pair import phd_settings

    spec = phd_settings(MethodSpec("p", "smc_phd_pair"))
    assert spec.adaptive_birth and spec.birth_particles_min == 100  # the defaults: adaptive births on
    spec = phd_settings(MethodSpec("p", "smc_phd_pair", options={"births": "every_detection"}))
    assert not spec.adaptive_birth
    spec = phd_settings(MethodSpec("p", "smc_phd_pair", options={"birth_particles_min": 50}))
    assert spec.adaptive_birth and spec.birth_particles_min == 50
    # every_detection births put particles_per_birth on each detection: a minimum there is never read
    with pytest.raises(ConfigError, match="option.s. birth_particles_min are read only with births: adaptive, and "
                                          "this row has births: every_detection"):
        MethodSpec("p", "smc_phd_pair", options={"births": "every_detection", "birth_particles_min": 50})
    with pytest.raises(ConfigError, match="option.s. forgetting, conflict are read only with labelling: gtda, and "
                                          "this row has labelling: hungarian"):
        MethodSpec("p", "smc_phd_pair", options={"labelling": "hungarian", "forgetting": 0.5, "conflict": 2.0})
    with pytest.raises(ConfigError, match="option births must be one of adaptive, every_detection"):
        MethodSpec("p", "smc_phd_pair", options={"births": "some"})
    with pytest.raises(ConfigError, match="option birth_particles_min must be an integer"):
        MethodSpec("p", "smc_phd_pair", options={"birth_particles_min": 5})


def test_the_update_weights_match_a_direct_evaluation_of_the_update_equation():
    x = torch.tensor([[[20_000.0, 10.0], [20_040.0, 12.0], [20_100.0, 3.0]]], dtype=torch.float64)
    w = torch.tensor([[0.3, 0.5, 0.2]], dtype=torch.float64)
    z = torch.tensor([[[20_020.0, 8.0], [20_090.0, 5.0], [0.0, 0.0]]], dtype=torch.float64)
    valid = torch.tensor([[True, True, False]])
    pd, kap = 0.7, 1e-5
    f = SMCPHD(PHDSpec(), SD, pd, kap, 1.0)
    new, part_x, part_w = f.update(PHDState(x, w, w.sum(1)), z, valid)

    def g(zj, xi):
        return math.exp(-0.5 * sum(((zj[d] - xi[d]) / float(SD[d])) ** 2 for d in range(2))) / (
            2 * math.pi * float(SD.prod()))

    xs, ws, zs = x[0].tolist(), w[0].tolist(), z[0, :2].tolist()
    denom = [kap + sum(pd * g(zj, xl) * wl for xl, wl in zip(xs, ws)) for zj in zs]
    direct = [(1 - pd) * wi + sum(pd * g(zj, xi) * wi / dj for zj, dj in zip(zs, denom)) for xi, wi in zip(xs, ws)]
    # the exponent is formed as |x|^2 + |z|^2 - 2 x.z in units of the deviations: ~|x / sd|^2 eps ~ 1e-10
    assert torch.allclose(new.w[0], torch.tensor(direct, dtype=torch.float64), rtol=1e-8, atol=0.0)
    taken = [sum(pd * g(zj, xi) * wi for xi, wi in zip(xs, ws)) / dj for zj, dj in zip(zs, denom)]
    assert torch.allclose(part_w[0, :2], torch.tensor(taken, dtype=torch.float64), rtol=1e-8)
    assert float(part_w[0, 2]) < 0  # padding is no partition


def test_bad_settings_and_detections_are_refused_with_one_line():
    for kwargs, text in (({"particles_per_target": 9}, "at least 10"), ({"particles_per_birth": 5}, "at least 10"),
                         ({"birth_rate": 0.0}, "no mass"), ({"survival": 1.5}, "survival"),
                         ({"birth_particles_min": 9}, "birth_particles_min must be at least 10"),
                         ({"adaptive_birth": "yes"}, "adaptive_birth must be true or false")):
        with pytest.raises(ConfigError, match=text):
            PHDSpec(**kwargs)
    for forgetting in (0.0, 1.01, float("nan")):
        with pytest.raises(ConfigError, match="forgetting factor"):
            GameSpec(forgetting=forgetting)
    z = torch.zeros(1, 3, 2, 2, dtype=torch.float64)
    z[0, 1, 0, 1] = float("nan")
    valid = torch.ones(1, 3, 2, dtype=torch.bool)
    with pytest.raises(ConfigError, match="detection 0 of scan 1 .* not finite"):
        SMCPHD(PHDSpec(), SD, 0.9, 1e-9, 1.0).run(z, valid, torch.Generator())
    valid[0, 1, 0] = False  # a NaN in padding is fine
    SMCPHD(PHDSpec(particles_per_target=20, particles_per_birth=10), SD, 0.9, 1e-9, 1.0).run(z, valid, torch.Generator())


def test_gtda_with_one_player_and_one_strategy_is_the_identity():
    g = torch.Generator().manual_seed(0)
    one = torch.ones(1, 1, dtype=torch.bool)
    res = play(torch.tensor([[[3.0]]], dtype=torch.float64), one, one, 13.8, GameSpec(), g)
    assert res.choice.tolist() == [[0]] and res.rounds == 1 and int(res.repaired.sum()) == 0
    res = play(torch.tensor([[[30.0]]], dtype=torch.float64), one, one, 13.8, GameSpec(), g)  # outside the gate
    assert res.choice.tolist() == [[-1]]


def test_gtda_resolves_a_contested_estimate_and_never_leaves_a_conflict():
    g = torch.Generator().manual_seed(3)
    # two players want estimate 0; player 1 has a good alternative (estimate 1), player 0 has none
    d2 = torch.tensor([[[1.0, 12.0], [2.0, 3.0]]], dtype=torch.float64)
    ok = torch.ones(1, 2, dtype=torch.bool)
    res = play(d2, ok, ok, 13.8, GameSpec(), g)
    assert res.choice.tolist() == [[0, 1]]
    # random problems: every estimate goes to at most one player, only inside the gate
    B, P, T = 200, 4, 4
    d2 = torch.rand(B, P, T, generator=g, dtype=torch.float64) * 20
    res = play(d2, torch.ones(B, P, dtype=torch.bool), torch.ones(B, T, dtype=torch.bool), 13.8, GameSpec(), g)
    c = res.choice
    for b in range(B):
        taken = [v for v in c[b].tolist() if v >= 0]
        assert len(taken) == len(set(taken))
        assert all(float(d2[b, p, v]) < 13.8 for p, v in enumerate(c[b].tolist()) if v >= 0)


def test_resolve_conflicts_keeps_the_nearest_player():
    d2 = torch.tensor([[[5.0], [2.0], [9.0]]], dtype=torch.float64)
    choice, repaired = resolve_conflicts(torch.tensor([[0, 0, 0]]), d2)
    assert choice.tolist() == [[-1, 0, -1]] and repaired.tolist() == [2]


def test_hungarian_is_the_brute_force_optimum_with_a_null_option():
    g = torch.Generator().manual_seed(4)
    gate = 10.0
    for _ in range(30):
        P, T = int(torch.randint(1, 4, (1,), generator=g)), int(torch.randint(1, 4, (1,), generator=g))
        d2 = torch.rand(1, P, T, generator=g, dtype=torch.float64) * 15
        choice = hungarian(d2, torch.ones(1, P, dtype=torch.bool), torch.ones(1, T, dtype=torch.bool), gate)[0].tolist()
        cost = lambda ch: sum(float(d2[0, p, c]) if c >= 0 else gate for p, c in enumerate(ch))
        best = min(cost(ch) for ch in itertools.product(range(-1, T), repeat=P)
                   if len([c for c in ch if c >= 0]) == len({c for c in ch if c >= 0})
                   and all(c < 0 or float(d2[0, p, c]) < gate for p, c in enumerate(ch)))
        assert abs(cost(choice) - best) < 1e-12


@pytest.mark.parametrize("method", ["gtda", "hungarian"])
def test_two_well_separated_targets_never_switch_labels(method):
    g = torch.Generator().manual_seed(5)
    B, K = 30, 80
    truth = cv_truth(torch.tensor([[20_000.0, 100.0], [38_000.0, -100.0]], dtype=torch.float64), B, K, g, sigma=2.0)
    # no clutter: a clutter point next to a target takes part of its PHD mass and can make a second
    # estimate beside it for a scan, which the OSPA assignment may match instead of the held track
    z, valid = detections(truth, 0.9, 0, g)
    f = SMCPHD(PHDSpec(particles_per_target=1000, particles_per_birth=200), SD, 0.9, kappa(0), 1.0)
    est = f.run(z, valid, g)
    lab = label_tracks(est.x, est.P, est.exists, f.F, f.Q, LabelSpec(method=method), g)
    mask = torch.ones(B, K, 2, dtype=torch.bool)
    sc = set_scores(torch.nan_to_num(lab.x[..., :1]), lab.exists, truth[..., :1], mask, 1000.0, 2.0)
    assert int(label_switches(sc.assignment, mask).sum()) == 0
    after = sc.assignment[:, 5:]  # both targets held by a track on nearly every scan after the start
    assert float((after >= 0).sum(-1).double().mean()) > 1.9


def test_fragmentations_count_interrupted_and_resumed_coverage():
    a = torch.tensor([[[0], [-1], [0], [0], [-1], [-1]]])
    alive = torch.ones(1, 6, 1, dtype=torch.bool)
    assert fragmentations(a, alive).tolist() == [[1]]  # the gap at scan 1; the loss at the end never resumes
    assert label_switches(a, alive).tolist() == [[0]]
    alive[0, 1, 0] = False  # not a fragmentation while the target is absent
    assert fragmentations(a, alive).tolist() == [[0]]


def test_an_aircraft_flies_its_legs_climbs_and_is_sampled_as_cv_states():
    a = AircraftSpec("a", (1000.0, 2000.0), 500.0, 100.0, 0.0, (LegSpec(10.0, climb_mps=5.0), LegSpec(5.0)), birth_s=2.0)
    x, flying = fly(a, 20, 1.0)
    assert flying.tolist() == [False] * 2 + [True] * 16 + [False] * 2
    assert torch.allclose(x[12], torch.tensor([1000.0, 0.0, 3000.0, 100.0, 550.0, 0.0], dtype=torch.float64), atol=1e-9)
    assert torch.allclose(x[5, 4], torch.tensor(515.0, dtype=torch.float64)) and float(x[5, 5]) == 5.0


TINY = """\
name: phd_tiny
mc_runs: 2
block_runs: 1
world:
  scans: 40
  dimensions: 3
  motion: {dt_s: 1.0}
  geometry:
    transmitters: [{position_m: [6500.0, 0.0], carrier_hz: 106.0e6}]
    receivers: [{position_m: [0.0, 0.0]}]
  max_range_m: 48000.0
warmup_steps: 0
divergence_m: null
loss: {}
noise: {range_m: 30.0, range_rate_mps: 4.5}
detections:
  pd: 0.9
  components: [range, range_rate]
  clutter: {per_scan: 10, model: poisson, range_m: [6500.0, 48000.0], range_rate_mps: [-500.0, 500.0]}
set_metrics: {c_m: 1000.0, p: 2.0}
methods:
  - {name: phd, kind: smc_phd_pair, options: &phd {particles_per_target: 200, particles_per_birth: 50, labelling: none}}
  - {name: kf, kind: known_association_kf_pair}
  - {name: g, kind: smc_phd_pair, options: {<<: *phd, labelling: gtda}}
  - {name: h, kind: smc_phd_pair, options: {<<: *phd, labelling: hungarian}}
cases:
  - name: base
    aircraft: &aircraft
      - {name: over, start_m: [-9000.0, -5000.0], altitude_m: 9000.0, speed_mps: 220.0, heading_deg: 60.0,
         legs: [{duration_s: 40}]}
      - {name: turn, start_m: [-9000.0, 9000.0], altitude_m: 800.0, speed_mps: 80.0, heading_deg: 90.0, birth_s: 10.0,
         legs: [{duration_s: 30, across_mps2: 2.0}]}
  - {name: noisy, aircraft: *aircraft, detections: {clutter: {per_scan: 5}}}
  - {name: pd1, aircraft: *aircraft, detections: {pd: 1.0}}
"""


def tiny_setup(tmp_path, text: str = TINY):
    from pmsr_nn.harness.scenario.loading import load_any
    from pmsr_nn.harness.run.runner import prepare

    (tmp_path / "s.yaml").write_text(text)
    return prepare(load_any(tmp_path / "s.yaml"))


@pytest.mark.integration
def test_the_kinds_run_through_the_runner_and_the_report_has_the_studys_figures(tmp_path):
    from pmsr_nn.cli import main

    (tmp_path / "s.yaml").write_text(TINY)
    start = time.perf_counter()
    assert main(["evaluate", str(tmp_path / "s.yaml"), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    wall = time.perf_counter() - start
    res = json.loads((tmp_path / "out" / "results.json").read_text())
    assert set(res["cases"]) == {"base", "noisy", "pd1"}
    case = res["cases"]["pd1"]
    rows = case["methods"]
    assert set(rows) == {"phd", "kf", "g", "h"} and rows["g"]["kind"] == "smc_phd_pair"
    assert all(r["space_key"] == "pair 0" and r["position"] == "bistatic range (m)" for r in rows.values())
    assert rows["kf"]["initiation"] == "association known" and rows["g"]["initiation"] == "detections"
    known = rows["kf"]  # association and births known, Pd 1: a track on every aircraft, always
    assert known["cardinality_mean_abs_error"] == 0.0 and known["rmse_pos_pooled_m"] < 30.0  # below one detection's error
    true = np.asarray(case["curves"]["cardinality_truth"])
    assert true[0] == 1 and true[-1] == 2  # the second aircraft is born at 10 s
    assert case["targets"] == ["over", "turn"] and len(rows["g"]["label_switches_per_target"]) == 2
    # 30 m and 4.5 m/s detections, a well-seen pair of aircraft; and worse than the Kalman filter that is
    # told the association and the births (the conditional mean given more than the PHD has)
    assert known["rmse_pos_pooled_m"] < rows["phd"]["rmse_pos_pooled_m"] < 100
    assert known["rmse_vel_pooled_mps"] < rows["phd"]["rmse_vel_pooled_mps"] < 20
    # the PHD's own estimates have no identity: no label-following figures
    assert rows["phd"]["labelled"] is False and rows["phd"]["label_switches_per_run"] is None
    assert rows["g"]["labels_per_run"] >= 2 and "labels_per_run" not in rows["kf"]
    # one PHD run per block shared by the three PHD rows: the same integral, its seconds counted in each
    expected = case["curves"]["set"]["phd"]["phd_expected"]
    assert case["curves"]["set"]["g"]["phd_expected"] == expected == case["curves"]["set"]["h"]["phd_expected"]
    # the shared PHD time was recorded, and is a time: the PHD's seconds of every case and run (2 per
    # case) fit inside the wall-clock time of the whole evaluation (two missing times, 0 == 0, would
    # pass the equality; a time in other units would not fit)
    assert rows["g"]["phd_seconds_per_run"] == rows["phd"]["phd_seconds_per_run"]
    phd_seconds = [c["methods"]["phd"]["phd_seconds_per_run"] * 2 for c in res["cases"].values()]
    assert min(phd_seconds) > 0 and sum(phd_seconds) < wall
    assert rows["g"]["seconds_per_run"] >= rows["g"]["phd_seconds_per_run"]
    report = (tmp_path / "out" / "report.md").read_text()
    assert "Rows scored in a bistatic plane" in report and "g [pair 0: range, range-rate]" in report
    for f in ("base_phd_rr.png", "base_g_time.png", "base_cardinality.png", "noisy_ospa.png", "sweep_clutter.png",
              "sweep_pd.png"):
        assert (tmp_path / "out" / f).is_file() and f in report


def test_the_truth_in_the_bistatic_plane_is_the_measurement_models_h_and_the_bistatic_geometry(tmp_path):
    from pmsr_nn.harness.run.blocks import draw_block, truth_in
    from pmsr_nn.harness.scenario.prepared import method_space

    setup = tiny_setup(tmp_path)
    case = setup.cases[0]
    truth, _ = draw_block(setup, 0, 0)
    spec = next(m for m in setup.methods if m.name == "g")
    z = truth_in(method_space(setup, spec, case), truth, {}).x  # (B, K, N, 2)
    alive = case.alive
    x = truth.x[:, alive]  # (B, L, 6): the living (scan, target) entries
    h = case.sensing.detection_model.h(x)  # the detections' model: [r, rdot] of the one pair
    assert torch.equal(z[:, alive], h)
    assert bool(z[:, ~alive].isnan().all())
    # and from the geometry: r = |p - tx| + |p - rx|, rdot = v . (unit from tx + unit from rx)
    p, v = x[..., [0, 2, 4]], x[..., [1, 3, 5]]
    tx = torch.tensor([6500.0, 0.0, 0.0], dtype=torch.float64)
    u_tx, u_rx = p - tx, p
    r = u_tx.norm(dim=-1) + u_rx.norm(dim=-1)
    rdot = (v * (u_tx / u_tx.norm(dim=-1, keepdim=True) + u_rx / u_rx.norm(dim=-1, keepdim=True))).sum(-1)
    assert torch.allclose(z[:, alive][..., 0], r, rtol=1e-12, atol=1e-9)  # 10 km ranges: a few ulps of 1e4
    assert torch.allclose(z[:, alive][..., 1], rdot, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("d", [0.0, 37.5, 400.0, 1.0e5])
def test_an_estimate_offset_by_d_in_range_scores_d_below_the_cut_off_and_c_above(tmp_path, d):
    """Estimates at the projected truth, every range moved by ``d``: OSPA = min(d, c) at every scan
    with a target (each of the n targets costs min(d, c)^p, over n), 0 where none lives; GOSPA^p =
    n min(d, c)^p; the range RMSE over matched pairs is d and the range-rate one 0 while d < c.
    Below c/2 a shift keeps every estimate its own target's (in one dimension the order-preserving
    matching is optimal for |x|^p, and no pair reaches the cut-off); 100 km is beyond every range
    difference of the scene, so no estimate is within c of any target."""
    from pmsr_nn.harness.run.blocks import draw_block, score, truth_in
    from pmsr_nn.harness.scenario.prepared import method_space
    from pmsr_nn.trackers.base import Estimates

    setup = tiny_setup(tmp_path)
    case = setup.cases[0]
    truth, _ = draw_block(setup, 0, 0)
    spec = next(m for m in setup.methods if m.name == "g")
    space = method_space(setup, spec, case)
    t = truth_in(space, truth, {})
    x = t.x.clone()
    x[..., 0] += d
    exists = case.alive.expand(x.shape[:3]).clone()
    est = Estimates(torch.where(exists[..., None], x, float("nan")), exists, paired=False)
    s = score(setup, case, est, t, space)
    B = x.shape[0]
    c, p = setup.set_metric
    some = case.alive.any(1).numpy()
    want = np.where(some, min(d, c), 0.0)
    np.testing.assert_allclose(s["ospa"] / B, want, rtol=1e-12, atol=1e-9)
    n = case.alive.sum(1).numpy()
    gospa = (s["gospa_loc"] + s["gospa_missed"] + s["gospa_false"]) / B
    # GOSPA^p: n pairs at d^p below the cut-off; beyond it n missed + n false at c^p / 2 each
    np.testing.assert_allclose(gospa, n * min(d, c) ** p, rtol=1e-12, atol=1e-6)
    if d < c:
        matched = s["count"].sum()
        assert matched == B * int(case.alive.sum())
        assert abs(np.sqrt(s["pos"].sum() / matched) - d) <= 1e-9 * max(d, 1.0)
        assert s["vel"].sum() == 0.0
    else:
        assert s["count"].sum() == 0


@pytest.mark.integration
def test_shards_of_a_phd_scenario_merge_to_the_unsharded_results(tmp_path):
    from pmsr_nn.harness.evaluate import evaluate, merge

    text = TINY[: TINY.index("  - {name: noisy")].replace("scans: 40", "scans: 25")  # case base only
    (tmp_path / "s.yaml").write_text(text)
    full = evaluate(tmp_path / "s.yaml", tmp_path / "full", progress=False)
    evaluate(tmp_path / "s.yaml", tmp_path / "a", shard=(1, 2), progress=False)
    evaluate(tmp_path / "s.yaml", tmp_path / "b", shard=(2, 2), progress=False)
    merged = merge([tmp_path / "b", tmp_path / "a"], tmp_path / "m")

    def figures(res):  # timings differ between runs; every other figure must not (NaN where no target lives)
        rows = res["cases"]["base"]["methods"]
        drop = ("seconds_per_run", "phd_seconds_per_run")
        return json.dumps([{m: {k: v for k, v in r.items() if k not in drop} for m, r in rows.items()},
                           res["cases"]["base"]["curves"]], sort_keys=True)

    assert figures(merged) == figures(full)
    assert full["cases"]["base"]["methods"]["g"]["labels_per_run"] > 0  # the comparison ran on real tracks


def test_the_phd_runs_once_per_block_and_the_cache_changes_no_number(tmp_path):
    from pmsr_nn.harness.run.blocks import call_method, draw_block
    from pmsr_nn.methods import phd_pair

    setup = tiny_setup(tmp_path)
    case = setup.cases[0]
    _, products = draw_block(setup, 0, 0)
    g, h = (next(m for m in setup.methods if m.name == n) for n in ("g", "h"))
    phd_pair._CACHE.clear()
    start = time.perf_counter()
    first = call_method(setup, g, case, products, (7, 0, 0))
    wall = time.perf_counter() - start
    again = call_method(setup, h, case, products, (7, 0, 0))  # reads the PHD run of the call above
    # the first call ran the PHD (its time recorded: part of the call's own wall-clock time), the second
    # read it and counts that same time
    assert 0 < first.extras["phd_seconds"] < wall
    assert first.extras["shared_seconds"] == 0.0 and again.extras["shared_seconds"] == first.extras["phd_seconds"]
    assert again.extras["phd_expected"] is first.extras["phd_expected"]
    phd_pair._CACHE.clear()
    fresh = call_method(setup, h, case, products, (7, 0, 0))  # the PHD run anew
    assert fresh.extras["shared_seconds"] == 0.0
    assert torch.equal(fresh.extras["phd_expected"], again.extras["phd_expected"])
    assert torch.equal(fresh.exists, again.exists) and torch.equal(torch.nan_to_num(fresh.x), torch.nan_to_num(again.x))
    other = call_method(setup, h, case, products, (7, 0, 1))  # another block's seed words: another run
    assert other.extras["shared_seconds"] == 0.0


REFUSALS = [
    ("pair out of range", lambda t: t.replace("{name: kf, kind: known_association_kf_pair}",
                                              "{name: kf, kind: known_association_kf_pair, options: {pair: 3}}"),
     "method 'kf' (kind known_association_kf_pair): pair 3 is out of range: the detections have 1 transmitter-receiver "
     "pair(s), 0..0; set option pair to one of them"),
    ("pooled detections", lambda t: t.replace("  pd: 0.9", "  pd: 0.9\n  illuminator_known: false"),
     "method 'phd' (kind smc_phd_pair) reads one pair's detection list; here the detections are pooled per receiver"),
    ("unknown labelling", lambda t: t.replace("labelling: hungarian}", "labelling: jpda}"),
     "method 'h': option labelling must be one of gtda, hungarian, none"),
    ("a study file", lambda t: "kind: phd\n" + t.split("\n", 1)[1], "'kind: phd' study files are gone"),
    ("a retired schema", lambda t: "kind: multitarget\n" + t, "'kind: multitarget' scenarios are retired"),
]


@pytest.mark.parametrize("what, edit, message", REFUSALS, ids=[r[0] for r in REFUSALS])
def test_refusals_name_the_method_and_the_fix_and_write_nothing(tmp_path, capsys, what, edit, message):
    from pmsr_nn.cli import main

    (tmp_path / "s.yaml").write_text(edit(TINY))
    assert main(["evaluate", str(tmp_path / "s.yaml"), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pmsr: error: ") and "\n" not in err and message in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.yaml"]


DESIGNED = """\
name: designed
mc_runs: 1
block_runs: 1
warmup_steps: 2
detections: {pd: 0.9, components: [range, azimuth], clutter: {per_scan: 1, model: poisson}}
methods: [{name: p, kind: smc_phd_pair, options: {particles_per_target: 50, particles_per_birth: 20}}]
cases:
  - {name: a, start_range_m: 5000.0, start_bearing_deg: 90.0, speed_mps: 10.0, heading_deg: 0.0,
     segments: [{duration_s: 20}]}
"""


@pytest.mark.parametrize("edit, message", [
    (lambda t: t, "method 'p' (kind smc_phd_pair) tracks one pair's bistatic range and range-rate; the detections "
                  "measure ['range', 'azimuth']: give detections of range and range_rate"),
    (lambda t: "\n".join(line for line in t.splitlines() if not line.startswith("detections:")),
     "method 'p' (kind smc_phd_pair) reads detections, which this scenario does not make: add a detections section"),
], ids=["without range-rate", "without detections"])
def test_a_designed_scenario_without_the_detections_the_kind_reads_is_refused(tmp_path, capsys, edit, message):
    from pmsr_nn.cli import main

    (tmp_path / "d.yaml").write_text(edit(DESIGNED))
    assert main(["evaluate", str(tmp_path / "d.yaml"), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pmsr: error: ") and "\n" not in err and message in err, err
    assert not (tmp_path / "out").exists()


@pytest.mark.integration
def test_a_case_can_take_its_detections_from_the_fm_front_end(tmp_path):
    """The signal chain's Doppler, turned into range-rate by the kind, feeds the PHD."""
    from pmsr_nn.cli import main

    text = TINY.replace("scans: 40", "scans: 4").replace("mc_runs: 2\nblock_runs: 1", "mc_runs: 2\nblock_runs: 2")
    text = text.replace("  - name: base", "  - name: sig").replace(
        "  pd: 0.9", "  pd: 0.9\n  front_end: {signal: {sample_rate_hz: 320000.0, cpi_s: 1.0}, max_range_m: 48000.0}")
    text = text.replace("noise: {range_m: 30.0, range_rate_mps: 4.5}", "noise: {range_m: 200.0, range_rate_mps: 0.3}")
    text = text.replace("  - {name: kf, kind: known_association_kf_pair}\n", "")
    text = text[: text.index("      - {name: turn")]  # one aircraft, seen from the first scan
    (tmp_path / "s.yaml").write_text(text)
    assert main(["evaluate", str(tmp_path / "s.yaml"), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    case = json.loads((tmp_path / "out" / "results.json").read_text())["cases"]["sig"]
    assert case["detections_from"] == "signals" and case["front_end"]["cpis"] == 2 * 4  # two runs of four scans
    assert case["front_end"]["pd_measured"] > 0.5
    # the PHD's estimates in m/s: within a few of the truth's range-rate (~ -150 m/s), not its Doppler in Hz
    assert case["methods"]["phd"]["rmse_vel_pooled_mps"] < 10
    assert "front end's signal chain" in (tmp_path / "out" / "report.md").read_text()


@pytest.mark.parametrize("method", ["gtda", "hungarian"])
def test_labels_go_only_to_confirmed_tracks(method):
    """Hand-made estimates over 6 scans (one run, [r, rdot]): a steady track at 10 km from scan 0,
    a one-scan false estimate at scan 1 and a second track from scan 2. With 2 of 3 the steady
    track is labelled from scan 1 (its second estimate), the second from scan 3, the false one
    never; 1 of 1 labels all three at first sight."""
    F, Q = cv_matrices(1.0, 20.0)
    K = 6
    x = torch.full((1, K, 3, 2), float("nan"), dtype=torch.float64)
    exists = torch.zeros(1, K, 3, dtype=torch.bool)
    for k in range(K):
        x[0, k, 0] = torch.tensor([10_000.0 + 100.0 * k, 100.0])
        exists[0, k, 0] = True
    x[0, 1, 1], exists[0, 1, 1] = torch.tensor([40_000.0, -50.0]), True
    for k in range(2, K):
        x[0, k, 2], exists[0, k, 2] = torch.tensor([25_000.0 - 80.0 * k, -80.0]), True
    P = torch.diag(SD**2).expand(1, K, 3, 2, 2).clone()
    g = torch.Generator().manual_seed(0)
    lab = label_tracks(x, P, exists, F, Q, LabelSpec(method=method, confirm_m=2, confirm_n=3), g)
    assert not lab.paired and lab.extras["labels"].tolist() == [2] and lab.extras["started"].tolist() == [3]
    assert lab.exists[0, :, 0].tolist() == [False] + [True] * 5  # the steady track, confirmed at scan 1
    assert lab.exists[0, :, 1].tolist() == [False] * 3 + [True] * 3  # the second, confirmed at scan 3
    assert torch.equal(lab.x[0, 3, 1], x[0, 3, 2])
    every = label_tracks(x, P, exists, F, Q, LabelSpec(method=method), torch.Generator().manual_seed(0))
    assert every.extras["labels"].tolist() == [3] and int(every.exists.sum()) == int(exists.sum())


def test_a_labelling_that_could_never_confirm_is_refused():
    with pytest.raises(ConfigError, match="M = 4, N = 3: a track could never be confirmed"):
        LabelSpec(confirm_m=4, confirm_n=3)


@pytest.mark.parametrize("method", ["gtda", "hungarian"])
def test_the_coalescence_test_ends_the_younger_of_two_labels_on_one_target(method):
    """Hand-made estimates over 6 scans (one run, [r, rdot]): a steady target at 10 km and, from
    scan 1, a second estimate 5 m beside it (a PHD's duplicate). 1 of 1 labels the duplicate at
    once (label 1), after that scan's test (a track is compared from the scan after it starts).
    With ``merge_scans: 2`` the two labels agree at scans 2 and 3, so label 1 ends at scan 3 (not
    reported there, and its estimate starts nothing); the duplicate's next estimate starts label 2
    at scan 4, which agrees at scan 5 and would end at scan 6. Label 0, the older, is reported
    throughout. Without the test label 1 lives from scan 1 to the end."""
    from pmsr_nn.trackers.coalescence import Coalescence

    F, Q = cv_matrices(1.0, 20.0)
    K = 6
    x = torch.full((1, K, 2, 2), float("nan"), dtype=torch.float64)
    exists = torch.zeros(1, K, 2, dtype=torch.bool)
    for k in range(K):
        x[0, k, 0], exists[0, k, 0] = torch.tensor([10_000.0 + 100.0 * k, 100.0]), True
        if k >= 1:
            x[0, k, 1], exists[0, k, 1] = torch.tensor([10_005.0 + 100.0 * k, 100.0]), True
    P = torch.diag(SD**2).expand(1, K, 2, 2, 2).clone()
    plain = label_tracks(x, P, exists, F, Q, LabelSpec(method=method), torch.Generator().manual_seed(0))
    assert plain.extras["labels"].tolist() == [2]
    assert plain.exists[0, :, 1].tolist() == [False] + [True] * 5
    merged = label_tracks(x, P, exists, F, Q, LabelSpec(method=method, coalescence=Coalescence(2)),
                          torch.Generator().manual_seed(0))
    assert merged.extras["labels"].tolist() == [3]
    assert merged.exists[0, :, 0].tolist() == [True] * 6
    assert merged.exists[0, :, 1].tolist() == [False, True, True, False, False, False]
    assert merged.exists[0, :, 2].tolist() == [False, False, False, False, True, True]
    assert torch.equal(merged.x[0, 1, 1], x[0, 1, 1])


def test_a_phd_row_refuses_a_merge_window_of_no_scans(tmp_path):
    from pmsr_nn.methods.phd import label_spec
    from pmsr_nn.harness.scenario.schema import MethodSpec

    with pytest.raises(ConfigError, match="merge window needs at least 1 scan"):
        label_spec(MethodSpec(name="PHD", kind="smc_phd", options={"merge_scans": 0}))
