"""The multi-sensor Cartesian SMC-PHD (pmsr_nn.trackers.phd_cartesian) and its method kind smc_phd.

References: the PHD update equation evaluated particle by particle with the bistatic geometry
written out by hand (not the measurement model's ``h``); the mass the recursion's formulas give
in closed form (survival, birth mass, missed detection); truth on a clutter-free case with births
and deaths, with an error bound from the single-scan position information of the noise; the
runner and the report; one-line refusals."""

from __future__ import annotations

import json
import math

import pytest
import torch
import yaml

from pmsr_nn.cli import main
from pmsr_nn.errors import ConfigError
from pmsr_nn.geometry import Geometry, Receiver, Transmitter
from pmsr_nn.harness.run.blocks import call_method, draw_block
from pmsr_nn.harness.run.runner import prepare
from pmsr_nn.harness.scenario.schema import load_scenario
from pmsr_nn.measurements import MeasurementModel
from pmsr_nn.metrics import set_scores, track_scores
from pmsr_nn.motion import ConstantAcceleration
from pmsr_nn.trackers.phd import PHDState
from pmsr_nn.trackers.phd_cartesian import CartesianPHD, CartesianPHDSpec
from test_track_management import scenario

NOISE = (30.0, 2.0, math.radians(3.0))
TX = (0.0, 0.0)
RX = ((-7000.0, -3000.0), (-8000.0, 500.0), (-7500.0, 4000.0))
OTHER_SD = torch.tensor([100.0, 5.0, 0.02] * 2, dtype=torch.float64)
SMALL = {"particles_per_target": 300, "particles_per_birth": 40}


def model(pairs: int = 3) -> MeasurementModel:
    """One transmitter at the origin and up to three receivers about 8 km west (the FITEE geometry)."""
    g = Geometry.all_pairs([Transmitter(TX, 650e6)], [Receiver(r) for r in RX[:pairs]])
    return MeasurementModel(g, ("range", "range_rate", "azimuth"), NOISE, (0, 3), (1, 4), layout="pair")


def by_hand(x: list[float], rx: tuple[float, float]) -> list[float]:
    """Bistatic range, range-rate and azimuth (clockwise from north, at the receiver) of CA state ``x``."""
    px, vx, _, py, vy, _ = x
    dt_, dr = math.hypot(px - TX[0], py - TX[1]), math.hypot(px - rx[0], py - rx[1])
    rate = vx * ((px - TX[0]) / dt_ + (px - rx[0]) / dr) + vy * ((py - TX[1]) / dt_ + (py - rx[1]) / dr)
    return [dt_ + dr, rate, math.atan2(px - rx[0], py - rx[1])]


def phd(pairs=3, pd=0.7, kappa=1e-6, **spec) -> CartesianPHD:
    return CartesianPHD(CartesianPHDSpec(**{**SMALL, **spec}), ConstantAcceleration(), 1.0, 1e-7, model(pairs), pd,
                        [kappa] * pairs, OTHER_SD)


def test_one_update_matches_the_phd_update_equation_evaluated_particle_by_particle():
    x = torch.tensor([[[3000.0, 5.0, 0.0, 6000.0, -2.0, 0.0], [3020.0, 6.0, 0.01, 5990.0, -1.0, 0.0],
                       [3100.0, 2.0, 0.0, 6050.0, 0.0, 0.0], [2950.0, 5.5, 0.0, 6010.0, -3.0, 0.0]]],
                     dtype=torch.float64)
    w = torch.tensor([[0.3, 0.5, 0.2, 0.4]], dtype=torch.float64)
    zs = [by_hand(x[0, 0].tolist(), RX[0]), by_hand(x[0, 2].tolist(), RX[0])]
    zs[0] = [zs[0][0] + 25.0, zs[0][1] - 1.5, zs[0][2] + 0.03]
    zs[1] = [zs[1][0] - 40.0, zs[1][1] + 2.0, zs[1][2] - 0.02]
    z = torch.tensor([zs + [[0.0, 0.0, 0.0]]], dtype=torch.float64)
    valid = torch.tensor([[True, True, False]])
    pd, kappa = 0.7, 1e-6
    f = phd(pairs=1, pd=pd, kappa=kappa)
    new, part_x, part_w, part_P = f.update(PHDState(x, w, w.sum(1)), 0, z, valid)

    def g(zj, xi):
        h = by_hand(xi, RX[0])
        r = [zj[0] - h[0], zj[1] - h[1], (zj[2] - h[2] + math.pi) % (2 * math.pi) - math.pi]
        norm = (2 * math.pi) ** 1.5 * math.prod(NOISE)
        return math.exp(-0.5 * sum((r[c] / NOISE[c]) ** 2 for c in range(3))) / norm

    xs, ws = x[0].tolist(), w[0].tolist()
    denom = [kappa + sum(pd * g(zj, xl) * wl for xl, wl in zip(xs, ws)) for zj in zs]
    direct = [(1 - pd) * wi + sum(pd * g(zj, xi) * wi / dj for zj, dj in zip(zs, denom)) for xi, wi in zip(xs, ws)]
    assert torch.allclose(new.w[0], torch.tensor(direct, dtype=torch.float64), rtol=1e-9, atol=0.0)
    taken = [(dj - kappa) / dj for dj in denom]
    assert torch.allclose(part_w[0, :2], torch.tensor(taken, dtype=torch.float64), rtol=1e-9)
    assert float(part_w[0, 2]) < 0  # padding is no partition
    # the partition's mean and position spread: the likelihood-weighted moments of the particles
    for j, zj in enumerate(zs):
        a = [pd * g(zj, xi) * wi for xi, wi in zip(xs, ws)]
        mean = [sum(ai * xi[d] for ai, xi in zip(a, xs)) / sum(a) for d in range(6)]
        assert torch.allclose(part_x[0, j], torch.tensor(mean, dtype=torch.float64), rtol=1e-9, atol=1e-9)
        cxy = sum(ai * (xi[0] - mean[0]) * (xi[3] - mean[3]) for ai, xi in zip(a, xs)) / sum(a)
        assert float(part_P[0, j, 0, 1]) == pytest.approx(cxy, rel=1e-6, abs=1e-6)
    assert torch.equal(new.x, x)  # the update moves no particle


def test_the_windowed_likelihood_is_the_full_product_where_every_pair_is_formed():
    """Each particle reads only the detections inside its range window; the pairs left out are those
    whose exponent is below -700, which the full ``(B, M, J)`` product sets to 0 too. Particles over
    +-3 km of the detections put many pairs just inside and just outside the window's edge (range
    residuals of 0.5-1.2 km, exponents from -140 to -800); a window half as wide would drop pairs the
    full product keeps. Two runs, padding on both sides."""
    f = phd(pairs=1)
    g = torch.Generator().manual_seed(3)
    B, M, J = 2, 400, 12
    centre = torch.tensor([3000.0, 5.0, 0.0, 6000.0, -2.0, 0.0], dtype=torch.float64)
    x = centre + torch.randn(B, M, 6, generator=g, dtype=torch.float64) * torch.tensor([1500, 3, 0.01, 1500, 3, 0.01])
    w = torch.rand(B, M, generator=g, dtype=torch.float64) * 1e-3
    w[1, 300:] = 0.0  # padding particles (log w = -inf)
    z = f.pairs[0].h(x[:, :J] + torch.randn(B, J, 6, generator=g, dtype=torch.float64) * 100.0)
    valid = torch.ones(B, J, dtype=torch.bool)
    valid[0, 9:] = False
    st = PHDState(x, w, w.sum(1))
    assert f.window_component == 0  # windows in range
    particle, _ = f._windows(f.pairs[0].h(x), torch.log(f.pd * w) + f._log_norm, z, valid)
    assert len(particle) < 0.5 * int(valid.sum(1) @ (w > 0).sum(1))  # fewer than half the pairs are formed
    windowed = f.weighted_likelihood(st, 0, z, valid)
    f.window_component = None
    full = f.weighted_likelihood(st, 0, z, valid)
    kept = full > 0
    exponent = torch.log(full[kept])
    assert float(exponent.min()) < -600.0 and int(kept.sum()) > 10 * B * J  # the scene reaches the cut
    # the same numbers: each is the exp of the same exponent (vectorised and scalar exp differ by at most an ulp)
    assert torch.equal(windowed > 0, kept)
    assert torch.allclose(windowed, full, rtol=4e-16, atol=0.0)
    assert not bool(windowed[0, :, 9:].any()) and not bool(windowed[1, 300:].any())


def test_the_mass_follows_the_expected_number_in_closed_form_and_after_every_step():
    """Survival, birth mass and a scan without detections in closed form; then, on three pairs with
    clutter, the particle weights against the recursion's count after every step (float64 sums of
    ~1e4 terms agree to ~1e-11)."""
    f = phd(pd=0.8, kappa=1e-7)
    g = torch.Generator().manual_seed(3)
    m = model()
    truth = torch.tensor([[3000.0, 5.0, 0.0, 6000.0, -2.0, 0.0], [-1000.0, 0.0, 0.0, 9000.0, 3.0, 0.0]],
                         dtype=torch.float64)
    z0 = m.h(truth).reshape(2, 3, 3).transpose(0, 1)[None]  # (B=1, S=3, J=2, 3)
    born = f.births(z0, torch.ones(1, 3, 2, dtype=torch.bool), g)
    assert born.x.shape == (1, 3 * 2 * SMALL["particles_per_birth"], 6)
    assert float(born.w.sum()) == pytest.approx(f.spec.birth_rate, rel=1e-12)
    assert float(born.expected) == f.spec.birth_rate
    st = PHDState(born.x, born.w * 4.0, born.expected * 4.0)  # 0.2 expected targets
    pred = f.predict(st, g)
    assert float(pred.w.sum()) == pytest.approx(0.2 * f.spec.survival, rel=1e-12)
    none = torch.zeros(1, 2, 3, dtype=torch.float64)
    after, _, part_w, _ = f.update(pred, 0, none, torch.zeros(1, 2, dtype=torch.bool))
    assert float(after.w.sum()) == pytest.approx(0.2 * f.spec.survival * (1 - 0.8), rel=1e-12)
    assert bool((part_w < 0).all())

    # three pairs, Pd 0.8, clutter: every step keeps the weights on the recursion's count
    B, K = 2, 6
    scans = []
    for k in range(K):
        t = truth.clone()
        t[:, [0, 3]] += k * t[:, [1, 4]]
        zt = m.h(t).reshape(2, 3, 3).transpose(0, 1).expand(B, 3, 2, 3) + torch.randn(
            B, 3, 2, 3, generator=g, dtype=torch.float64) * torch.tensor(NOISE, dtype=torch.float64)
        clutter = torch.stack([torch.rand(B, 3, 3, generator=g, dtype=torch.float64) * span + lo for lo, span in
                               ((0.0, 25000.0), (-40.0, 80.0), (-math.pi, 2 * math.pi))], -1)
        scans.append(torch.cat([zt, clutter], 2))
    z = torch.stack(scans, 1)  # (B, K, S, J = 5, 3)
    valid = torch.rand(B, K, 3, 5, generator=g) < 0.8
    st = f.empty(B)
    for k in range(K):
        steps = [("predict", lambda s: f.predict(s, g))]
        if k:
            def birth(s, k=k):
                b = f.births(z[:, k - 1], valid[:, k - 1], g)
                return PHDState(torch.cat([s.x, b.x], 1), torch.cat([s.w, b.w], 1), s.expected + b.expected)
            steps.append(("birth", birth))
        parts = []
        for s in range(3):
            def update(st, s=s):
                st, *part = f.update(st, s, z[:, k, s], valid[:, k, s])
                parts.append(part)
                return st
            steps.append((f"update {s}", update))
        for name, step in steps:
            st = step(st)
            assert torch.allclose(st.w.sum(1), st.expected, rtol=1e-9, atol=0.0), (k, name)
        _, P, _, _, owner = f.estimate(st, *(torch.cat(v, 1) for v in zip(*parts)))
        st = f.resample(st, owner, P, g)
        assert torch.allclose(st.w.sum(1), st.expected, rtol=1e-9, atol=0.0), (k, "resample")
    assert float(st.expected.max()) > 1.0 and bool((st.w > 0).sum(1).min() > 100)  # the checks ran on a populated PHD


def test_the_filter_is_reproducible_from_its_generator_and_refuses_non_finite_detections():
    m = model()
    truth = torch.tensor([[3000.0, 5.0, 0.0, 6000.0, -2.0, 0.0]], dtype=torch.float64)
    z = m.h(truth).reshape(1, 3, 1, 3).expand(1, 4, 3, 1, 3).clone()  # (B=1, K=4, S=3, J=1, 3)
    valid = torch.ones(1, 4, 3, 1, dtype=torch.bool)
    runs = [phd().run(z, valid, torch.Generator().manual_seed(s)) for s in (7, 7, 8)]
    assert torch.equal(runs[0].expected, runs[1].expected)
    assert torch.equal(runs[0].x.nan_to_num(), runs[1].x.nan_to_num())
    assert not torch.equal(runs[0].expected, runs[2].expected)
    z[0, 2, 1, 0, 1] = float("nan")
    with pytest.raises(ConfigError, match=r"detection 0 of pair 1, scan 2 \(run 0\) is not finite"):
        phd().run(z, valid, torch.Generator())


def single_scan_position_sd(m: MeasurementModel, x: torch.Tensor) -> float:
    """Root of the trace of the position covariance one scan of every pair's range and azimuth gives
    at state ``x (6,)``: ``(sum_s H_s^T R^-1 H_s)^-1``, ``H_s`` their rows by position."""
    J = m.jacobian(x)[:, [0, 3]]  # (3 pairs x 3 components, 2)
    keep = [i for i, c in enumerate(m.components * m.n_pairs) if c in ("range", "azimuth")]
    var = torch.tensor([s**2 for s in NOISE * m.n_pairs], dtype=torch.float64)[keep]
    info = J[keep].T @ (J[keep] / var[:, None])
    return float(torch.linalg.inv(info).trace().sqrt())


@pytest.mark.parametrize("labelling", ["gtda", "hungarian"])
def test_births_and_deaths_without_clutter_give_one_confirmed_track_per_target_near_the_truth(tmp_path, labelling):
    setup = prepare(load_scenario(scenario(tmp_path, methods=[{"name": "PHD", "kind": "smc_phd",
                                                               "options": {**SMALL, "labelling": labelling}}])))
    case = setup.cases[0]
    truth, products = draw_block(setup, 0, 0)
    est = call_method(setup, setup.methods[0], case, products, (3, 0, 0))
    assert not est.paired and est.x.shape[2] == 2 and est.x.shape[-1] == 6  # two labelled tracks in all, per run
    B, K, _ = est.exists.shape
    alive = case.alive.expand(B, K, 2)
    pos = [0, 3]
    sets = set_scores(est.x[..., pos], est.exists, truth.x[..., pos], alive, 300.0, 2.0)
    ts = track_scores(sets.assignment, est.exists, alive)
    assert ts.tracks_per_target.tolist() == [[1.0, 1.0]] * B and ts.false_tracks.tolist() == [0.0] * B
    # born at k0, the PHD's births come from k0's detections at k0 + 1 (its first estimate at the
    # earliest) and the labelling confirms 2 of 3: a track from k0 + 2 at the earliest; k0 + 3 where
    # the first births (40 particles per fix here) left the partition below estimate_mass
    first = ts.scans_to_first_track
    assert bool(((first >= 2) & (first <= 3)).all()) and float(first.min()) == 2.0, first
    # from 5 scans after birth, against the deviation one scan of the three pairs' ranges and azimuths
    # gives: the filter averages scans, so its RMS error is below that deviation, and every scan's
    # error within 3 of it (a tail bound)
    m = case.sensing.detection_model
    for t, (k0, k1) in enumerate(((0, 40), (15, 60))):
        for b in range(B):
            err, sd = [], []
            for k in range(k0 + 5, k1):
                slot = sets.assignment[b, k].tolist().index(t)
                err.append(float((est.x[b, k, slot, pos] - truth.x[b, k, t, pos]).norm()))
                sd.append(single_scan_position_sd(m, truth.x[b, k, t]))
            assert max(e / s for e, s in zip(err, sd)) < 3.0, (t, b, err)
            assert math.sqrt(sum(e * e for e in err) / len(err)) < sum(sd) / len(sd), (t, b, err)
    # reproducible from the call's seed: a second call gives the same tracks
    again = call_method(setup, setup.methods[0], case, products, (3, 0, 0))
    assert torch.equal(again.x.nan_to_num(), est.x.nan_to_num()) and torch.equal(again.exists, est.exists)


def test_a_scenario_with_smc_phd_is_evaluated_and_reported_as_tracks_from_detections(tmp_path):
    path = scenario(tmp_path, pd=0.9, clutter=3,
                    methods=[{"name": "SMC-PHD + GTDA", "kind": "smc_phd", "options": SMALL}])
    assert main(["evaluate", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    row = json.loads((tmp_path / "out" / "results.json").read_text())["cases"]["c"]["methods"]["SMC-PHD + GTDA"]
    assert row["kind"] == "smc_phd" and row["initiation"] == "detections"
    assert row["confirmed_tracks_per_target"] > 0 and row["gospa_m"] < 300.0
    assert "| SMC-PHD + GTDA | detections |" in (tmp_path / "out" / "report.md").read_text()


@pytest.mark.parametrize("options, detections, message", [
    ({}, {"components": ["range", "range_rate"]},
     "method 'P': kind smc_phd births targets from position fixes of each detection's (bistatic range, azimuth) in "
     "2-D; the detections measure ['range', 'range_rate'] in 2-D"),
    ({"particles_per_target": 5}, {},
     "method 'P': option particles_per_target must be an integer in [10, 1000000], got 5"),
    ({"labelling": "greedy"}, {}, "method 'P': option labelling must be one of gtda, hungarian, got 'greedy'"),
    ({"confirm_m": 4, "confirm_n": 3}, {},
     "method 'P': confirmation needs 1 <= M <= N <= 62 (M of N scans); got M = 4, N = 3"),
    ({"birth_rate": 0.0}, {}, "method 'P': option birth_rate must be a number in [1e-09, 100.0], got 0.0"),
    ({"label_gate_probability": 1.0}, {}, "method 'P': option label_gate_probability must be a number in [0.5, "),
])
def test_what_the_kind_can_not_read_is_refused_in_one_line_and_nothing_is_written(tmp_path, capsys, options,
                                                                                    detections, message):
    path = scenario(tmp_path, methods=[{"name": "P", "kind": "smc_phd", "options": options}])
    if detections:
        data = yaml.safe_load(path.read_text())
        data["detections"].update(detections)
        path.write_text(yaml.safe_dump(data))
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["evaluate", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == before
