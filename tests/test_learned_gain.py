"""The hybrid tracker on detections (pmsr_nn.trackers.learned_gain, pmsr_nn.nets.jpda_gain): with
a zero correction it is S-MSJPDA; its PDA update against the textbook formulas on moments from
filterpy's unscented transform; the correction is the learned gain times the combined
innovation; the training scenes; the checkpoint and its refusals."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from filterpy.kalman import MerweScaledSigmaPoints, unscented_transform

from pmsr_nn.errors import CheckpointError, ConfigError
from pmsr_nn.filters.gaussian import Gaussian
from pmsr_nn.geometry import Geometry, Receiver, Transmitter
from pmsr_nn.measurements import MeasurementModel
from pmsr_nn.motion import ConstantAcceleration
from pmsr_nn.nets.jpda_gain import (GainNet, check_gain_compatible, gain_metadata, load_gain_checkpoint,
                                    save_gain_checkpoint)
from pmsr_nn.rng import seeded_generator
from pmsr_nn.simulation.detections import ClutterSpec, Scans, simulate_scans
from pmsr_nn.trackers.jpda_associators import pda_marginals
from pmsr_nn.trackers.learned_gain import GainCorrection
from pmsr_nn.trackers.management import Confirmer, Deleter, FixInitiator, Management
from pmsr_nn.trackers.msjpda import JPDASettings, msjpda
from pmsr_nn.trackers.msjpda_managed import managed_msjpda

ROOT = Path(__file__).resolve().parents[1]
NOISE = (30.0, 2.0, math.radians(3.0))
S_Z = torch.tensor(NOISE, dtype=torch.float64)
S_X = torch.tensor([100.0, 5.0, 0.1] * 2, dtype=torch.float64)
MOTION = ConstantAcceleration(spatial_dim=2)


def geometry() -> Geometry:
    return Geometry.all_pairs([Transmitter((0.0, 0.0), 650e6)],
                              [Receiver((-7000.0, -3000.0)), Receiver((-8000.0, 500.0)), Receiver((-7500.0, 4000.0))])


def model(components=("range", "range_rate", "azimuth"), noise=NOISE) -> MeasurementModel:
    return MeasurementModel(geometry(), components, noise, (0, 3), (1, 4), layout="pair")


def two_drones(B: int = 3, K: int = 30, apart_m: float = 300.0) -> torch.Tensor:
    x0 = torch.tensor([[3000.0, 8.0, 0.0, 6000.0, -5.0, 0.0], [3000.0 + apart_m, 8.0, 0.0, 6100.0, -5.0, 0.0]],
                      dtype=torch.float64)
    F = MOTION.F(1.0, torch.float64)
    return torch.stack([x0 @ torch.linalg.matrix_power(F, k).T for k in range(K)])[None].expand(B, K, 2, 6).contiguous()


def scene(pd=0.8, clutter=15):
    truth = two_drones()
    m = model()
    scans = simulate_scans(truth, m, pd, ClutterSpec(per_scan=clutter, range_m=(0, 25000), range_rate_mps=(-40, 40)),
                           seeded_generator(3))
    density = clutter / (25000 * 80 * 2 * math.pi)
    return truth, m, scans, JPDASettings(pd, density)


def management() -> Management:
    return Management(FixInitiator(20.0, 2, 0.999), Confirmer(2, 3), Deleter(2), S_X)


class ConstantGain(torch.nn.Module):
    """A stand-in network: ``G`` and ``scale`` constant, memory counting the steps."""

    hidden_size, n_pairs = 1, 3

    def __init__(self, G: torch.Tensor, scale: float = 0.0):
        super().__init__()
        self.G, self.scale = G, scale

    def forward(self, features, memory):
        return (self.G.expand(len(features), *self.G.shape), torch.full((len(features),), self.scale, dtype=self.G.dtype),
                memory + 1)


# -- an untrained hybrid is S-MSJPDA ----------------------------------------------------------------

@pytest.mark.parametrize("association", ["jpda", "pda"])
def test_a_zero_correction_reproduces_s_msjpda_with_oracle_births(association):
    truth, m, scans, s = scene()
    prior = Gaussian(truth[:, 0], torch.diag(S_X**2).expand(3, 2, 6, 6))
    plain = msjpda(scans, prior, MOTION, 1.0, 0.01, m, m.R(), s, "sequential", association=association)
    hybrid = msjpda(scans, prior, MOTION, 1.0, 0.01, m, m.R(), s, "sequential", association=association,
                    correction=GainCorrection(GainNet(3, 3, 6), S_Z, S_X))
    assert torch.allclose(hybrid.x, plain.x, rtol=0, atol=1e-9)
    assert torch.allclose(hybrid.P, plain.P, rtol=0, atol=1e-9)


def test_a_zero_correction_reproduces_s_msjpda_that_starts_its_own_tracks():
    truth, m, scans, s = scene()
    plain = managed_msjpda(scans, MOTION, 1.0, 0.01, m, m.R(), s, "sequential", management())
    hybrid = managed_msjpda(scans, MOTION, 1.0, 0.01, m, m.R(), s, "sequential", management(),
                            correction=GainCorrection(GainNet(3, 3, 6), S_Z, S_X))
    assert plain.exists.any()  # the case confirms tracks, so the comparison means something
    assert torch.equal(hybrid.exists, plain.exists)
    assert torch.allclose(hybrid.x.nan_to_num(), plain.x.nan_to_num(), rtol=0, atol=1e-9)


def test_the_parallel_tracker_refuses_a_learned_gain():
    truth, m, scans, s = scene()
    prior = Gaussian(truth[:, 0], torch.diag(S_X**2).expand(3, 2, 6, 6))
    with pytest.raises(ConfigError, match="no pda association or learned gain"):
        msjpda(scans, prior, MOTION, 1.0, 0.01, m, m.R(), s, "parallel", correction=GainCorrection(GainNet(3, 3, 6), S_Z, S_X))


# -- the PDA update against the textbook, on filterpy's moments -------------------------------------

def test_one_track_one_sensor_pda_is_the_textbook_update_on_filterpys_unscented_moments():
    m = MeasurementModel(Geometry.all_pairs([Transmitter((0.0, 0.0), 650e6)], [Receiver((-7000.0, -3000.0))]),
                         ("range", "range_rate"), (30.0, 2.0), (0, 3), (1, 4), layout="pair")
    x = torch.tensor([3000.0, 8.0, 0.1, 6000.0, -5.0, -0.1], dtype=torch.float64)
    P = torch.diag(torch.tensor([80.0, 4.0, 0.2, 60.0, 3.0, 0.2], dtype=torch.float64) ** 2)
    zc = m.h(x[None])[0]
    z = torch.stack([zc + torch.tensor([20.0, 1.0]), zc + torch.tensor([-60.0, 2.5]), zc + torch.tensor([5.0, -4.0]),
                     zc + torch.tensor([5000.0, 0.0])]).to(torch.float64)  # the last is far outside the gate
    scans = Scans(z[None, None, None], torch.ones(1, 1, 1, 4, dtype=torch.bool), torch.full((1, 1, 1, 4), -1))
    pd, lam = 0.8, 1e-5
    s = JPDASettings(pd, lam)
    got = msjpda(scans, Gaussian(x[None, None], P[None, None]), MOTION, 1.0, 0.01, m, m.R(), s, "sequential",
                 association="pda")

    # independent: filterpy's scaled sigma points (alpha 1, beta 2, kappa 3 - n) and the textbook PDA
    pts = MerweScaledSigmaPoints(6, alpha=1.0, beta=2.0, kappa=-3.0)
    X = pts.sigma_points(x.numpy(), P.numpy())
    Z = m.h(torch.from_numpy(X)).numpy()
    Rn = np.diag([30.0**2, 2.0**2])
    zhat, S = unscented_transform(Z, pts.Wm, pts.Wc, Rn)
    C = ((X - x.numpy()).T * pts.Wc) @ (Z - zhat)
    K = C @ np.linalg.inv(S)
    nu = z.numpy() - zhat
    d2 = np.einsum("mi,ij,mj->m", nu, np.linalg.inv(S), nu)
    from scipy.stats import chi2

    gated = d2 <= chi2.ppf(0.999, 2)
    assert gated.tolist() == [True, True, True, False]
    e = np.where(gated, pd * np.exp(-0.5 * d2) / (2 * np.pi * np.sqrt(np.linalg.det(S))) / lam, 0.0)
    beta = e / (1 - pd + e.sum())
    beta0 = (1 - pd) / (1 - pd + e.sum())
    nu_c = (beta[:, None] * nu).sum(0)
    mean = x.numpy() + K @ nu_c
    spread = (beta[:, None, None] * nu[:, :, None] * nu[:, None, :]).sum(0) - np.outer(nu_c, nu_c)
    cov = beta0 * P.numpy() + (1 - beta0) * (P.numpy() - K @ S @ K.T) + K @ spread @ K.T
    assert np.allclose(got.x[0, 0, 0].numpy(), mean, rtol=0, atol=1e-9 * 1e4)
    assert np.allclose(got.P[0, 0, 0].numpy(), cov, rtol=1e-9, atol=1e-9)
    # and the JPDA of a lone track (three gated detections, fewer than m_best) agrees
    jpda = msjpda(scans, Gaussian(x[None, None], P[None, None]), MOTION, 1.0, 0.01, m, m.R(), s, "sequential")
    assert torch.allclose(jpda.x, got.x, rtol=0, atol=1e-9)


def test_pda_marginals_sum_to_one_and_ignore_what_is_not_gated():
    log_lik = torch.tensor([[-3.0, -5.0, 100.0]], dtype=torch.float64)
    a = pda_marginals(log_lik, torch.tensor([[True, True, False]]), 0.9, 1e-3)
    e = 0.9 * np.exp([-3.0, -5.0]) / 1e-3
    assert np.allclose(a[0].numpy(), np.r_[e, 0.0, 0.1] / (e.sum() + 0.1), rtol=1e-12)


# -- the correction ----------------------------------------------------------------------------------

def test_the_correction_is_the_learned_gain_times_the_combined_innovation():
    m = MeasurementModel(Geometry.all_pairs([Transmitter((0.0, 0.0), 650e6)], [Receiver((-7000.0, -3000.0))]),
                         ("range", "range_rate", "azimuth"), NOISE, (0, 3), (1, 4), layout="pair")
    x = torch.tensor([[3000.0, 8.0, 0.0, 6000.0, -5.0, 0.0]], dtype=torch.float64)
    z = m.h(x)[:, None] + torch.tensor([40.0, 1.5, 0.01], dtype=torch.float64)  # one detection, off the prediction
    scans = Scans(z[None, None], torch.ones(1, 1, 1, 1, dtype=torch.bool), torch.zeros(1, 1, 1, 1, dtype=torch.int64))
    prior = Gaussian(x[None], torch.diag(S_X**2)[None, None])
    s = JPDASettings(0.9, 1e-6)
    G = torch.arange(18, dtype=torch.float64).reshape(6, 3) / 100
    net = ConstantGain(G, scale=0.3)
    net.n_pairs = 1
    plain = msjpda(scans, prior, MOTION, 1.0, 0.01, m, m.R(), s, "sequential")
    corr = GainCorrection(net, S_Z, S_X)
    got = msjpda(scans, prior, MOTION, 1.0, 0.01, m, m.R(), s, "sequential", correction=corr)
    # one detection of weight alpha: the plain update moves the mean by alpha K nu, the learned
    # part adds (0.3 K + diag(s_x) G diag(1/s_z)) alpha nu, with the same alpha
    from pmsr_nn.filters.gaussian import unscented_moments

    mom = unscented_moments(Gaussian(x[None], torch.diag(S_X**2)[None, None]), m, m.R())
    K = torch.linalg.solve(mom.S, mom.C.transpose(-1, -2)).transpose(-1, -2)[0, 0]
    nu = m.residual(z[0, 0], mom.z[0, 0])
    step = plain.x[0, 0, 0] - x[0]
    a = float(step[0] / (K @ nu)[0])
    assert 0.0 < a < 1.0
    assert torch.allclose(step, a * (K @ nu), rtol=1e-9, atol=1e-9)
    dK = 0.3 * K + S_X[:, None] * G / S_Z
    assert torch.allclose(got.x[0, 0, 0] - plain.x[0, 0, 0], a * (dK @ nu), rtol=1e-9, atol=1e-9)
    assert float(corr.memory.sum()) == 1.0  # one step of one track


def test_inactive_tracks_get_no_correction_and_freed_slots_forget():
    from pmsr_nn.filters.gaussian import MeasurementMoments

    net = ConstantGain(torch.ones(6, 3, dtype=torch.float64))
    corr = GainCorrection(net, S_Z, S_X)
    corr.start(1, 2)

    def step(T, active):  # one detection per track, taken with probability 1
        mom = MeasurementMoments(torch.zeros(1, T, 3), torch.eye(3, dtype=torch.float64).expand(1, T, 3, 3),
                                 torch.zeros(1, T, 6, 3, dtype=torch.float64))
        w = torch.tensor([1.0, 0.0], dtype=torch.float64).expand(1, T, 2)
        return corr.step(0, w, torch.ones(1, T, 1, 3, dtype=torch.float64), torch.ones(1, T, 1, dtype=torch.bool), mom,
                         active)

    dx = step(2, torch.tensor([[True, False]]))
    assert bool((dx[0, 0] != 0).all()) and bool((dx[0, 1] == 0).all())
    assert corr.memory[0, :, 0].tolist() == [1.0, 0.0]
    step(3, None)
    assert corr.memory.shape == (1, 3, 1) and corr.memory[0, :, 0].tolist() == [2.0, 1.0, 1.0]  # a grown table
    corr.forget(torch.tensor([[True, False, False]]))
    assert corr.memory[0, :, 0].tolist() == [0.0, 1.0, 1.0]


def test_the_features_say_how_much_the_association_is_in_doubt():
    from pmsr_nn.trackers.learned_gain import feature_count, gain_features

    S = torch.diag(torch.tensor([4.0, 1.0], dtype=torch.float64))
    nu = torch.tensor([[2.0, 0.0], [-2.0, 1.0], [50.0, 50.0]], dtype=torch.float64)
    w = torch.tensor([0.5, 0.25, 0.0, 0.25], dtype=torch.float64)  # the third detection is outside the gate
    gate = torch.tensor([True, True, False])
    nu_c, f = gain_features(1, 3, w, nu, gate, S, torch.tensor([2.0, 1.0], dtype=torch.float64))
    assert f.shape == (feature_count(2, 3),)
    assert torch.allclose(nu_c, torch.tensor([0.5, 0.25], dtype=torch.float64))
    # spread: sum_i alpha_i nu_i^2 - nu_c^2, over diag S: (0.5*4 + 0.25*4 - 0.25) / 4, (0.25 - 0.0625) / 1
    expect = [0.25, 0.25, 0.25, 0.0, 0.0, 2.75 / 4, 0.1875, 0.5, math.log(3.0),
              math.log1p(0.5**2 / 4 + 0.25**2), 0.0, 1.0, 0.0]
    assert torch.allclose(f, torch.tensor(expect, dtype=torch.float64), rtol=1e-12, atol=1e-12)


# -- training scenes ----------------------------------------------------------------------------------

def _recipe():
    from pmsr_nn.simulation.recipe import load_recipe

    return load_recipe("datasets/fitee2023_ca.yaml")


@pytest.mark.parametrize("kind", ["formation", "crossing"])
def test_scene_mates_fly_beside_or_across_the_first_target(kind):
    from pmsr_nn.simulation.scenes import draw_scenes

    recipe = _recipe()
    g = seeded_generator(11)
    B, K = 40, 60
    x = draw_scenes(recipe, recipe.geometry.build(2), B, 2, K, g, formation=float(kind == "formation"),
                    crossing=float(kind == "crossing"))
    assert x.shape == (B, K, 2, 6) and bool(torch.isfinite(x).all())
    gap = (x[:, :, 0, [0, 3]] - x[:, :, 1, [0, 3]]).norm(dim=-1)  # (B, K)
    if kind == "formation":
        assert torch.allclose(gap, gap[:, :1].expand(B, K), rtol=0, atol=1e-6)  # the same flight, shifted
        assert bool(((gap[:, 0] >= 100.0) & (gap[:, 0] <= 500.0)).all())
    else:
        # the same point at one scan of the middle half (rotation about it), apart at the window's ends
        at = gap.argmin(1)
        assert bool((gap.amin(1) < 1e-6).all())
        assert bool(((at >= K // 4) & (at < 3 * K // 4)).all())
        assert bool((torch.maximum(gap[:, 0], gap[:, -1]) > 10.0).all())
        speed = lambda i: x[:, :, i, [1, 4]].norm(dim=-1)
        assert torch.allclose(speed(0), speed(1), rtol=1e-12)  # a rotation keeps the speed


def test_the_same_seed_draws_the_same_scenes():
    from pmsr_nn.simulation.scenes import draw_scenes

    recipe = _recipe()
    a = draw_scenes(recipe, recipe.geometry.build(2), 4, 3, 20, seeded_generator(5))
    b = draw_scenes(recipe, recipe.geometry.build(2), 4, 3, 20, seeded_generator(5))
    assert torch.equal(a, b)


# -- checkpoint --------------------------------------------------------------------------------------

def _saved(tmp_path, **change):
    net = GainNet(3, 3, 6, hidden=8)
    m = model()
    meta = gain_metadata(geometry().to_dict(), list(m.components), list(NOISE), 1.0, net, S_X.tolist(), seed=0)
    meta.update(change)
    return save_gain_checkpoint(tmp_path / "g.pt", meta, net), net


def test_a_checkpoint_round_trips_and_is_checked_against_the_scenario(tmp_path):
    path, net = _saved(tmp_path)
    ck = load_gain_checkpoint(path)
    assert all(torch.equal(a, b) for a, b in zip(ck.net.state_dict().values(), net.state_dict().values()))
    check_gain_compatible(ck, geometry().to_dict(), model().components, NOISE, 1.0, 6, "here")
    other = Geometry.all_pairs([Transmitter((0.0, 0.0), 650e6)], [Receiver((-7000.0, -3000.0))]).to_dict()
    with pytest.raises(ConfigError, match="another sensor geometry"):
        check_gain_compatible(ck, other, model().components, NOISE, 1.0, 6, "here")
    with pytest.raises(ConfigError, match="reads"):
        check_gain_compatible(ck, geometry().to_dict(), ("range", "doppler"), NOISE[:2], 1.0, 6, "here")
    with pytest.raises(ConfigError, match="dt = 1 s"):
        check_gain_compatible(ck, geometry().to_dict(), model().components, NOISE, 2.0, 6, "here")
    with pytest.raises(ConfigError, match="deviations"):
        check_gain_compatible(ck, geometry().to_dict(), model().components, (20.0, 2.0, NOISE[2]), 1.0, 6, "here")


def test_saving_never_overwrites_or_removes_a_temporary_name_it_did_not_write(tmp_path):
    """The checkpoint goes through a temporary file beside it; one of that name that is not ours is
    refused in one line and left as it was, and nothing else is written."""
    import os

    from pmsr_nn.errors import OutputError

    path, _ = _saved(tmp_path)
    before = path.read_bytes()
    theirs = tmp_path / f".{path.name}.partial-{os.getpid()}"
    theirs.write_text("someone else's")
    with pytest.raises(OutputError, match="temporary name .* is taken"):
        _saved(tmp_path)
    assert theirs.read_text() == "someone else's" and path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([path.name, theirs.name])


def test_foreign_corrupted_and_edited_checkpoints_are_refused(tmp_path):
    path, _ = _saved(tmp_path)
    blob = path.read_bytes()
    (tmp_path / "cut.pt").write_bytes(blob[: len(blob) // 2])
    with pytest.raises(CheckpointError, match="not a readable torch checkpoint"):
        load_gain_checkpoint(tmp_path / "cut.pt")
    torch.save({"pmsr": {"format": "pmsr_nn.tracker"}}, tmp_path / "clean.pt")
    with pytest.raises(CheckpointError, match="use it with kind learned"):
        load_gain_checkpoint(tmp_path / "clean.pt")
    bad, _ = _saved(tmp_path, state_scale=[1.0] * 5)
    with pytest.raises(CheckpointError, match="scales or sizes"):
        load_gain_checkpoint(bad)
    import datetime

    torch.save({"pmsr": datetime.date(2026, 1, 1)}, tmp_path / "pickled.pt")  # needs unpickling a class
    with pytest.raises(CheckpointError, match="refusing to unpickle"):
        load_gain_checkpoint(tmp_path / "pickled.pt")


# -- as a method kind, through pmsr evaluate ------------------------------------------------------------

def _scenario_and_checkpoint(tmp_path, **noise):
    """A small scenario of two drones with clutter, S-MSJPDA and the hybrid from an untrained
    checkpoint (zero correction) for the scenario's own sensors."""
    import yaml

    from pmsr_nn.harness.run.runner import prepare
    from pmsr_nn.harness.scenario.schema import load_scenario

    flight = lambda r, b, h: {"start_range_m": r, "start_bearing_deg": b, "speed_mps": 10.0, "heading_deg": h,
                              "segments": [{"duration_s": 40.0}]}
    d = {"name": "hybrid", "seed": 3, "mc_runs": 2, "block_runs": 2, "warmup_steps": 5, "random_streams": "per_product",
         "detections": {"pd": 0.9, "components": ["range", "range_rate", "azimuth"],
                        "clutter": {"per_scan": 5, "range_m": [0.0, 25000.0], "range_rate_mps": [-40.0, 40.0]}},
         "set_metrics": {"c_m": 300.0, "p": 2.0},
         "cases": [{"name": "c", "targets": [{"name": "a", **flight(4000.0, 130.0, 20.0)},
                                             {"name": "b", **flight(7800.0, 100.0, 0.0)}]}],
         "methods": [{"name": "S", "kind": "s_msjpda", "options": {"initiation": "detections"}},
                     {"name": "H", "kind": "jpda_learned_gain", "checkpoint": "g.pt",
                      "options": {"initiation": "detections"}}]}
    if noise:
        d["noise"] = noise
    path = tmp_path / "hybrid.yaml"
    path.write_text(yaml.safe_dump(d))
    plain = {**d, "methods": d["methods"][:1]}
    (tmp_path / "plain.yaml").write_text(yaml.safe_dump(plain))
    det = prepare(load_scenario(tmp_path / "plain.yaml")).cases[0].sensing.detection_model
    net = GainNet(det.n_pairs, len(det.components), 6, hidden=8)
    meta = gain_metadata(det.geometry.to_dict(), list(det.components), list(det.noise_std), 1.0, net, S_X.tolist())
    save_gain_checkpoint(tmp_path / "g.pt", meta, net)
    (tmp_path / "plain.yaml").unlink()
    return path


@pytest.mark.integration
def test_an_untrained_checkpoint_scores_as_s_msjpda_in_pmsr_evaluate(tmp_path):
    from pmsr_nn.harness import evaluate

    res = evaluate(_scenario_and_checkpoint(tmp_path), tmp_path / "out", progress=False)
    rows = res["cases"]["c"]["methods"]
    assert rows["H"]["initiation"] == "detections"
    for key in ("gospa_m", "ospa_m", "false_tracks_per_run", "confirmed_tracks_per_target"):
        assert rows["H"][key] == pytest.approx(rows["S"][key], rel=1e-9, abs=1e-9), key


def test_a_checkpoint_for_other_sensors_is_one_line_exit_2_and_nothing_written(tmp_path, capsys):
    from pmsr_nn.cli import main

    path = _scenario_and_checkpoint(tmp_path)
    text = path.read_text().replace("name: hybrid", "name: hybrid\nnoise: {range_m: 20.0, range_rate_mps: 2.0, "
                                                  "azimuth_deg: 3.0}", 1)
    path.write_text(text)
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["evaluate", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "method 'H': the checkpoint was trained for measurement deviations" in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_commands_for_clean_stream_trackers_refuse_the_hybrids_checkpoint_in_one_line(tmp_path, capsys):
    from pmsr_nn.cli import main

    path, _ = _saved(tmp_path)
    (tmp_path / "z.csv").write_text("a\n1\n")
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["track", "--checkpoint", str(path), "--input", str(tmp_path / "z.csv"), "--out",
                 str(tmp_path / "est.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "kind jpda_learned_gain" in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


# -- training ----------------------------------------------------------------------------------------

@pytest.mark.integration
def test_a_tiny_trained_gain_beats_the_untrained_one_where_the_model_is_wrong():
    """The tracker is sure there is no acceleration (prior deviation 1e-3 m/s^2, q = 1e-9) while the
    target accelerates: S-MSJPDA lags. Eight Adam steps on one draw must at least halve the mean
    squared position error on another draw of the noise (gradients flow through the gain, the
    UKF moments and the means; with them cut the error could not move)."""
    torch.manual_seed(0)
    m, B, K = model(), 4, 30
    x0 = torch.tensor([3000.0, 8.0, 0.3, 6000.0, -5.0, 0.2], dtype=torch.float64)
    F = MOTION.F(1.0, torch.float64)
    truth = torch.stack([x0 @ torch.linalg.matrix_power(F, k).T for k in range(K)])[None, :, None]
    truth = truth.expand(B, K, 1, 6).contiguous()
    box = ClutterSpec(per_scan=0, range_m=(0, 25000), range_rate_mps=(-40, 40))
    draws = [simulate_scans(truth, m, 1.0, box, seeded_generator(seed)) for seed in (1, 2)]
    P0 = torch.diag(torch.tensor([30.0, 2.0, 1e-3] * 2, dtype=torch.float64) ** 2)
    prior = Gaussian(truth[:, 0] * torch.tensor([1, 1, 0, 1, 1, 0.0], dtype=torch.float64), P0.expand(B, 1, 6, 6))

    def mse(net, scans):
        x = msjpda(scans, prior, MOTION, 1.0, 1e-9, m, m.R(), JPDASettings(1.0, 1e-9), "sequential",
                   correction=GainCorrection(net, S_Z, S_X)).x
        return (x[..., [0, 3]] - truth[..., [0, 3]]).norm(dim=-1)[:, 5:].square().mean()

    net = GainNet(3, 3, 6, hidden=8, gain_scale=0.1)
    with torch.no_grad():
        before = float(mse(net, draws[1]))
    opt = torch.optim.Adam(net.parameters(), lr=1e-2)
    for _ in range(8):
        opt.zero_grad()
        mse(net, draws[0]).backward()
        opt.step()
    with torch.no_grad():
        after = float(mse(net, draws[1]))
    assert after < 0.5 * before, (before, after)


def _one_detection_step(corr, T, nu_value, active=None):
    from pmsr_nn.filters.gaussian import MeasurementMoments

    mom = MeasurementMoments(torch.zeros(1, T, 3), torch.eye(3, dtype=torch.float64).expand(1, T, 3, 3),
                             torch.zeros(1, T, 6, 3, dtype=torch.float64))
    w = torch.tensor([1.0, 0.0], dtype=torch.float64).expand(1, T, 2)
    nu = torch.full((1, T, 1, 3), nu_value, dtype=torch.float64)
    return corr.step(0, w, nu, torch.ones(1, T, 1, dtype=torch.bool), mom, active)


def test_the_memory_is_cleared_every_horizon_steps():
    corr = GainCorrection(ConstantGain(torch.ones(6, 3, dtype=torch.float64)), S_Z, S_X, horizon=3)
    corr.start(1, 1)
    seen = []
    for _ in range(7):
        _one_detection_step(corr, 1, 0.5)
        seen.append(float(corr.memory[0, 0, 0]))
    assert seen == [1.0, 2.0, 3.0, 1.0, 2.0, 3.0, 1.0]  # counts steps since the last clearing


def test_an_inconsistent_combined_innovation_gets_the_models_gain_alone():
    # S = I: nu_c^T S^-1 nu_c = 3 v^2; the 99 % chi-square gate of 3 dof is 11.34
    corr = GainCorrection(ConstantGain(torch.ones(6, 3, dtype=torch.float64)), S_Z, S_X, consistency=11.34)
    corr.start(1, 1)
    assert bool((_one_detection_step(corr, 1, 1.9) != 0).all())  # NIS 10.8: the learned part acts
    assert bool((_one_detection_step(corr, 1, 2.0) == 0).all())  # NIS 12.0: it does not


def test_pmsr_train_of_the_hybrid_prints_a_line_per_validation_and_writes_the_tracker(tmp_path, capsys):
    """A tiny `pmsr train` of the hybrid: one line per validation (step, loss and the best so far,
    the validation RMSE), the summary, and a checkpoint that loads."""
    from pmsr_nn.cli import main

    recipe = ROOT / "datasets" / "fitee2023_ca.yaml"
    cfg = tmp_path / "g.yaml"
    cfg.write_text(f"kind: jpda_gain\nrecipe: {recipe}\nthreads: 1\nscenes: {{window: 8, targets: [1, 2]}}\n"
                   "optim: {steps: 2, val_every: 1, val_scenes: 2, batch_size: 2}\n")
    assert main(["train", str(cfg), "--out", str(tmp_path / "run")]) == 0
    lines = capsys.readouterr().out.splitlines()
    steps = [line for line in lines if line.startswith("step ")]
    assert [s.split()[1] for s in steps] == ["1/2", "2/2"], lines
    for s in steps:
        loss, best = float(s.split("validation loss ")[1].split()[0]), float(s.split("(best ")[1].split(")")[0])
        assert best <= loss and "position RMSE" in s
    summary = next(line for line in lines if line.startswith("trained   2 steps"))
    # the checkpoint keeps the step of lowest validation loss (with validation at every step too)
    best = float(summary.split("best validation loss ")[1].split()[0])
    printed = min(float(s.split("validation loss ")[1].split()[0]) for s in steps)  # 4 significant digits
    assert best == pytest.approx(printed, rel=5e-4)
    # the tracker is the recipe's (its sensors and interval, read from the recipe file itself) and holds a
    # trained network
    import yaml

    ck = load_gain_checkpoint(tmp_path / "run" / "tracker.pt")
    r = yaml.safe_load(recipe.read_text())
    assert ck.meta["n_pairs"] == len(r["geometry"]["transmitters"]) * len(r["geometry"]["receivers"])
    assert ck.meta["dt_s"] == r["motion"]["dt_s"]
    # trained: its output layer differs from an untrained network's of the same shape (which is zero)
    fresh = GainNet(ck.net.n_pairs, ck.net.d, ck.net.n, ck.net.hidden_size, ck.net.gain_scale)
    assert not torch.equal(ck.net.out.weight, fresh.out.weight)


def test_the_default_management_is_the_method_kinds_default_options():
    """`Management.defaults` (what managed training starts tracks with) is what a row with
    `initiation: detections` and no other option gets, for either initiator."""
    from types import SimpleNamespace

    from pmsr_nn.methods.msjpda import OPTIONS
    from pmsr_nn.methods.track_management import management as of_options

    spec = SimpleNamespace(kind="s_msjpda", option=lambda name: OPTIONS[name].default)
    for components in (("range", "range_rate", "azimuth"), ("range", "range_rate")):
        m = model(components, NOISE[:len(components)])
        assert Management.defaults(m, S_X) == of_options(spec, SimpleNamespace(detection_model=m, prior_sd=S_X))


@pytest.mark.parametrize("p", [1.0, 2.0])
def test_the_managed_training_loss_is_gospa_and_pulls_each_track_to_its_target(p):
    """Per scan: GOSPA^p (cut-off c) by brute force over the track-to-target matchings, its
    gradient ``p d^(p-1)`` times the unit vector from each assigned track towards its target (none
    for a track beyond c), and GOSPA^2 (p = 2) as the metric module gives it."""
    import itertools

    from pmsr_nn.metrics.sets import gospa
    from pmsr_nn.nets.jpda_training import GainTrainConfig, Problem

    from pmsr_nn.nets.jpda_training import GainOptimConfig

    cfg = GainTrainConfig(kind="jpda_gain", recipe=str(ROOT / "datasets" / "fitee2023_ca.yaml"), tracking="managed",
                          optim=GainOptimConfig(loss_order=p))
    problem = Problem(cfg)
    c, k0 = cfg.optim.loss_cutoff_m, cfg.optim.skip_scans
    g = torch.Generator().manual_seed(5)
    B, K, N, T = 2, k0 + 3, 3, 4
    truth = torch.randn(B, K, N, 6, generator=g, dtype=torch.float64) * 300.0
    truth[1, :, 2] = math.nan  # a target not alive in run 1
    x = truth[:, :, [0, 1, 2, 0]].clone() + torch.randn(B, K, T, 6, generator=g, dtype=torch.float64) * 150.0
    x[0, :, 3] = math.nan  # a slot without a track (in run 1 a second track near target 0, and none in slot 2)
    exists = torch.isfinite(x[..., 0])
    x[1, :, 1, [0, 3]] += 2000.0  # beyond the cut-off: a false track and a missed target
    x = x.requires_grad_()
    g1, g2 = problem.set_errors(x, exists, truth)
    pos = [0, 3]
    for b in range(B):
        for k in range(K - k0):
            est = [x[b, k0 + k, t, pos].detach() for t in range(T) if exists[b, k0 + k, t]]
            tgt = [truth[b, k0 + k, n, pos] for n in range(N) if torch.isfinite(truth[b, k0 + k, n, 0])]
            best = min(sum(min(float((est[i] - tgt[j]).norm()), c) ** p for i, j in zip(perm_e, perm_t))
                       + c ** p / 2 * (len(est) - len(perm_e) + len(tgt) - len(perm_t))
                       for r in range(min(len(est), len(tgt)) + 1)
                       for perm_e in itertools.permutations(range(len(est)), r)
                       for perm_t in itertools.combinations(range(len(tgt)), r))
            assert float(g1[b, k].detach()) == pytest.approx(best, rel=1e-9)
    e0 = torch.where(exists[..., None], x.detach(), torch.zeros(()))[:, k0:][..., pos]
    ref = gospa(e0, exists[:, k0:], torch.nan_to_num(truth[:, k0:][..., pos]), torch.isfinite(truth[:, k0:, :, 0]), c, 2.0)
    assert torch.allclose(g2, ref.total ** 2, rtol=1e-12)
    g1.sum().backward()
    grad = x.grad[..., pos]
    norms = grad.norm(dim=-1)[:, k0:]
    d = (x.detach()[:, k0:, :3][..., pos] - truth[:, k0:, :3][..., pos]).norm(dim=-1)  # run 0: each track on its own target
    assert torch.allclose(norms[0, :, :3], p * d[0] ** (p - 1), rtol=1e-9)  # every track assigned
    assert float(norms[1, :, 1].abs().max()) == 0.0  # beyond the cut-off: no pull
    assert float(x.grad[:, :k0].abs().max()) == 0.0  # scans before skip_scans are not scored


def test_pmsr_train_of_the_hybrid_starting_its_own_tracks(tmp_path, capsys):
    """`tracking: managed`: the tracker starts its own tracks in training and validation; the
    console says so and reports GOSPA, and the plain S-MSJPDA's GOSPA on the same scenes."""
    from pmsr_nn.cli import main

    cfg = tmp_path / "g.yaml"
    cfg.write_text(f"kind: jpda_gain\nrecipe: {ROOT / 'datasets' / 'fitee2023_ca.yaml'}\nthreads: 1\ntracking: managed\n"
                   "scenes: {window: 12, targets: [2, 2], clutter_per_scan: [5, 10]}\n"
                   "optim: {steps: 2, val_every: 1, val_scenes: 2, batch_size: 2}\n")
    assert main(["train", str(cfg), "--out", str(tmp_path / "run")]) == 0
    out = capsys.readouterr().out
    assert "S-MSJPDA alone on the validation scenes (managed tracking)" in out and "GOSPA" in out
    steps = [line for line in out.splitlines() if line.startswith("step ")]
    assert len(steps) == 2 and all("GOSPA" in s for s in steps)
    meta = load_gain_checkpoint(tmp_path / "run" / "tracker.pt").meta
    assert meta["training"]["config"]["tracking"] == "managed"


def test_a_correction_on_confirmed_tracks_only_leaves_tentative_tracks_to_the_model():
    """`confirmed_only`: the correction sees only the confirmed tracks (none at the scan after the
    first tracks start, as tentative tracks), the tracks it reaches being the ones the report
    holds; without it every active track is corrected from its first update on."""
    seen = {False: [], True: []}

    class Spy(GainCorrection):
        def step(self, pair, w, nu, gate, mom, active):
            seen[self.confirmed_only].append(int(active.sum()))
            return super().step(pair, w, nu, gate, mom, active)

    truth, m, scans, s = scene()
    for only in (False, True):
        managed_msjpda(scans, MOTION, 1.0, 0.01, m, m.R(), s, "sequential", management(),
                       correction=Spy(GainNet(3, 3, 6), S_Z, S_X, confirmed_only=only))
    first = next(i for i, n in enumerate(seen[False]) if n > 0)  # the first sensor step with a track
    assert seen[True][first] == 0 and max(seen[True]) > 0
    assert all(a <= b for a, b in zip(seen[True], seen[False]))
