"""State fixes, window-local inputs, residual outputs and the KalmanNet-style tracker."""

import json
from dataclasses import replace

import pytest
import torch
import yaml

from pmsr_nn.cli import main
from pmsr_nn.data.normalise import MinMaxScaler
from pmsr_nn.filters import Gaussian, ekf
from pmsr_nn.filters.fixes import hold_missing_fixes, state_fixes
from pmsr_nn.filters.gaussian import predict
from pmsr_nn.nets.config import ModelConfig
from pmsr_nn.nets.inference import Tracker
from pmsr_nn.nets.kalmannet import EKFGain, KalmanNetTracker
from pmsr_nn.nets.networks import build_network
from pmsr_nn.nets.representation import Representation
from pmsr_nn.rng import seeded_generator
from pmsr_nn.simulation.recipe import TrackRecipe
from pmsr_nn.simulation.tracks import build_models, generate_tracks

from test_training import write_config


@pytest.fixture(scope="module")
def tracks():
    recipe = TrackRecipe().with_overrides(tracks=20)
    motion, model = build_models(recipe)
    batch, _ = generate_tracks(recipe, 6, seeded_generator(3))
    return recipe, motion, model, batch


def test_noise_free_state_fixes_are_the_true_position_and_velocity(tracks):
    _, _, model, b = tracks
    s = state_fixes(model.h(b.states), model, 6)
    err = (s - b.states)[..., [0, 1, 3, 4]].abs()
    # Gauss-Newton on exact ranges converges to round-off (m at ~10 km: 1e-8 is 1e3 ulps).
    assert err[..., [0, 2]].max() < 1e-6 and err[..., [1, 3]].max() < 1e-8
    assert (s[..., [2, 5]] == 0).all()


def test_velocity_fix_is_the_least_squares_solution(tracks):
    _, _, model, b = tracks
    z = b.measurements[:2, :50]
    s = state_fixes(z, model, 6)
    H = model.jacobian(s)
    J = H[..., [0, 1, 2], :][..., [0, 3]]
    ref = torch.linalg.lstsq(J, z[..., 3:6].unsqueeze(-1)).solution.squeeze(-1)
    torch.testing.assert_close(s[..., [1, 4]], ref, rtol=1e-9, atol=1e-9)


def test_missing_fixes_are_held_and_a_missing_first_fix_is_refused():
    s = torch.arange(12.0).reshape(1, 4, 3)
    s[0, 2] = float("nan")
    held = hold_missing_fixes(s)
    assert torch.equal(held[0, 2], s[0, 1]) and torch.equal(held[0, 3], s[0, 3])
    s[0, 0] = float("nan")
    with pytest.raises(Exception, match="first scan"):
        hold_missing_fixes(s)


def _rep(cfg, model, b):
    z, x = b.measurements, b.states
    zs = MinMaxScaler(z.reshape(-1, 9).min(0).values, z.reshape(-1, 9).max(0).values)
    xs = MinMaxScaler(x.reshape(-1, 6).min(0).values, x.reshape(-1, 6).max(0).values)
    return Representation.fit(cfg, model, 6, zs, xs, z, x)


@pytest.mark.parametrize("inputs,output", [("local_fixes", "residual"), ("measurements", "state"),
                                           ("local_fixes", "state"), ("measurements", "residual")])
def test_targets_and_states_are_exact_inverses(tracks, inputs, output):
    _, _, model, b = tracks
    rep = _rep(ModelConfig(inputs=inputs, output=output), model, b)
    z, x = b.measurements, b.states
    s = rep.fixes(z) if rep.needs_fixes else None
    base = rep.base(z, s)
    torch.testing.assert_close(rep.states(rep.targets(x, base), base), x, rtol=1e-12, atol=1e-9)


def test_local_features_are_translation_invariant_except_the_position_itself(tracks):
    _, _, model, b = tracks
    rep = _rep(ModelConfig(inputs="local_fixes", output="residual"), model, b)
    s = rep.fixes(b.measurements)
    shifted = s.clone()
    shifted[..., [0, 3]] += torch.tensor([250.0, -400.0], dtype=s.dtype)
    f, g = rep.raw_features(s), rep.raw_features(shifted)
    torch.testing.assert_close(f[..., :4], g[..., :4], rtol=0, atol=1e-9)  # increments, velocity
    assert not torch.allclose(f[..., 4:], g[..., 4:])
    u = rep.features(b.measurements)  # standardised on these tracks
    torch.testing.assert_close(u.reshape(-1, 6).mean(0), torch.zeros(6, dtype=u.dtype), rtol=0, atol=1e-9)


def test_a_zero_residual_reproduces_the_base_exactly(tracks):
    """A network whose residual base is the true state and whose correction is zero returns the truth."""
    _, _, model, b = tracks
    cfg = ModelConfig(hidden=(16, 8, 16), filter_order=3, inputs="local_fixes", output="residual")
    rep = _rep(cfg, model, b)
    net = build_network(cfg, 9, 6).float()
    y = net(rep.features(b.measurements).float())
    assert torch.count_nonzero(y) == 0  # the read-out starts at zero
    assert torch.equal(rep.states(y, b.states), b.states)


def test_kalmannet_with_the_ekf_gain_is_the_ekf(tracks):
    recipe, motion, model, b = tracks
    z = b.measurements[:4, :150]
    R = torch.stack([model.R(s) for s in b.noise_std[:4]])
    dt, q = recipe.motion.dt_s, recipe.effective_motion().q_psd
    fix0 = state_fixes(z[:, :1], model, 6)[:, 0]
    cfg = ModelConfig(kind="kalmannet", inputs="measurements_and_fixes", output="residual", rnn_hidden=8)
    net = KalmanNetTracker(cfg, model, dt, torch.ones(9), torch.ones(6)).double()
    P0 = torch.diag(torch.tensor([100.0, 5, 0.02, 100, 5, 0.02], dtype=torch.float64) ** 2).expand(4, 6, 6)
    F, Q = motion.F(dt), motion.Q(dt, q)
    x = net.filter(z, fix0, gain=EKFGain(P0.clone(), F, Q, model, R))
    # Our EKF updates at its first step; KalmanNet starts at the fix, so the EKF is given the
    # fix's prediction as its prior and the scans from 1 on.
    prior = predict(Gaussian(fix0, P0), F, Q)
    ref = ekf(prior, z[:, 1:], motion, dt, q, model, R)
    err = (x[:, 1:] - ref.x).abs().max() / ref.x.abs().max()
    assert err < 1e-8


# -- training and inference end to end ---------------------------------------------------------

@pytest.mark.parametrize("model", [
    {"kind": "mdfnn", "hidden": [32, 24, 32], "filter_order": 5, "inputs": "local_fixes", "output": "residual",
     "filter_taps": "per_channel"},
    {"kind": "kalmannet", "rnn_hidden": 8, "inputs": "measurements_and_fixes", "output": "residual"},
])
def test_new_representations_train_checkpoint_and_track(tmp_path, model):
    cfg = write_config(tmp_path / "c.yaml", tmp_path / "data", model=model, optim={"acceleration_weight": 0.1},
                       trainer={"max_epochs": 1, "train_batches_per_epoch": 3, "val_batches": 2})
    raw = yaml.safe_load(cfg.read_text())
    raw["model"] = model
    cfg.write_text(yaml.safe_dump(raw))
    assert main(["train", str(cfg), "--out", str(tmp_path / "run")]) == 0
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["val"]["pos_rmse_m"] < 1e4
    t = Tracker.load(tmp_path / "run" / "tracker.pt")
    assert t.meta["normalisation"]["representation"]["output"] == "residual"
    recipe = TrackRecipe()
    recipe = recipe.with_overrides(tracks=20, motion=replace(recipe.motion, steps=120))
    b, _ = generate_tracks(recipe, 2, seeded_generator(9))
    est = t.track(b.measurements)
    assert est.shape == b.states.shape and torch.isfinite(est).all()
    if model["kind"] == "mdfnn":  # splicing keeps every estimate's context: equal to one pass
        rep = t.representation
        full = rep.states(t.net(rep.features(b.measurements).float()), rep.base(b.measurements))
        torch.testing.assert_close(est, full, rtol=0, atol=1e-3)
        assert t.context == (2 * 4 + 1, 0)


def test_clipped_innovations_bound_an_outliers_influence(tracks):
    """With innovation_clip = 5, a 1000-sigma range outlier moves the filter exactly as a 60-sigma
    one does (both are clipped to 5 sigma in the update and to 50 sigma in the features)."""
    recipe, _, model, b = tracks
    cfg = ModelConfig(kind="kalmannet", inputs="measurements_and_fixes", output="residual", rnn_hidden=8,
                      gain_scale=0.1, innovation_clip=5.0)
    torch.manual_seed(0)
    s_z = torch.tensor([30.0] * 3 + [2.0] * 3 + [0.05] * 3)
    net = KalmanNetTracker(cfg, model, recipe.motion.dt_s, s_z, torch.tensor([50.0, 5, 0.1] * 2)).double()
    torch.nn.init.normal_(net.out.weight, std=0.1)  # a non-zero gain
    z = b.measurements[:2, :60].clone()
    fix0 = state_fixes(z[:, :1], model, 6)[:, 0]
    with torch.no_grad():
        big, small = z.clone(), z.clone()
        big[:, 30, 0] += 1000 * 30.0
        small[:, 30, 0] += 60 * 30.0
        x_big, x_small, x_clean = (net.filter(v, fix0) for v in (big, small, z))
    torch.testing.assert_close(x_big, x_small, rtol=0, atol=1e-9)
    assert (x_big[:, 31:] - x_clean[:, 31:]).abs().max() > 1e-3  # the outlier does act, boundedly


def test_kalmannet_options_are_checked():
    with pytest.raises(Exception, match="kalmannet"):
        ModelConfig(kind="kalmannet", inputs="measurements", output="residual")
    with pytest.raises(Exception, match="innovation_clip"):
        ModelConfig(kind="kalmannet", inputs="measurements_and_fixes", output="residual", innovation_clip=0.0)
