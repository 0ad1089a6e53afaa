"""The set tracker's parts (pmsr_nn/nets/set_tracker.py, set_inference.py): the matching against
brute force, the set loss at a known matching, the tokens against the closed-form fixes, the
linking of per-scan sets into tracks, and a tiny network that fits a fixed batch."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch

from pmsr_nn.geometry import Geometry, Receiver, Transmitter
from pmsr_nn.measurements import MeasurementModel
from pmsr_nn.nets.set_inference import link_tracks
from pmsr_nn.nets.set_refine import gauss_newton
from pmsr_nn.nets.set_tracker import SetOutput, SetTracker, SetTrackerConfig, detection_tokens, match, set_loss
from pmsr_nn.trackers.fix_initiator import range_azimuth_fix


def model() -> MeasurementModel:
    g = Geometry.all_pairs([Transmitter((0.0, 0.0), 650e6)],
                           [Receiver((-7000.0, -3000.0)), Receiver((-8000.0, 500.0)), Receiver((-7500.0, 4000.0))])
    return MeasurementModel(g, ("range", "range_rate", "azimuth"), (30.0, 2.0, math.radians(3.0)), (0, 3), (1, 4),
                            layout="pair")


@pytest.mark.parametrize("seed", range(5))
def test_the_matching_is_the_cheapest_injection_found_by_brute_force(seed):
    rng = np.random.default_rng(seed)
    Q, N = 5, 3
    cost = rng.uniform(0, 1, (Q, N))
    r, c = match(cost)
    best = min(sum(cost[p[j], j] for j in range(N)) for p in itertools.permutations(range(Q), N))
    assert cost[r, c].sum() == pytest.approx(best, abs=1e-12)


def test_the_set_loss_is_zero_state_error_where_the_set_is_right_and_counts_false_predictions():
    true_pos = torch.tensor([[[1000.0, 2000.0], [3000.0, -500.0]]], dtype=torch.float64)
    true_vel = torch.tensor([[[5.0, 0.0], [0.0, -3.0]]], dtype=torch.float64)
    # predictions: the two truths in the other order, and a third far away
    pos = torch.tensor([[[3000.0, -500.0], [1000.0, 2000.0], [9000.0, 9000.0]]], dtype=torch.float64)
    vel = torch.tensor([[[0.0, -3.0], [5.0, 0.0], [0.0, 0.0]]], dtype=torch.float64)
    logit = torch.tensor([[4.0, 4.0, -4.0]], dtype=torch.float64)
    # association logits over 4 tokens: token 0 is truth 0's, token 1 truth 1's, 2 clutter, 3 padding
    assoc = torch.tensor([[[-3.0, 3.0, -3.0, -math.inf], [3.0, -3.0, -3.0, -math.inf], [0.0, 0.0, 0.0, -math.inf]]],
                         dtype=torch.float64)
    out = SetOutput(pos, vel, logit, assoc, pos.clone(), torch.full((1, 4), -math.inf, dtype=torch.float64))
    alive = torch.ones(1, 2, dtype=torch.bool)
    loss, parts = set_loss(out, true_pos, true_vel, alive, 500.0)
    assert parts["matched"] == 2 and parts["state"] == 0.0 and parts["association"] == 0.0
    bce = -(2 * math.log(1 / (1 + math.exp(-4.0))) + math.log(1 - 1 / (1 + math.exp(4.0)))) / 3
    assert float(loss) == pytest.approx(bce, rel=1e-9)
    # association: per matched query the mean softplus over its own tokens plus over the other usable ones
    origin = torch.tensor([[0, 1, -1, -2]])
    _, parts = set_loss(out, true_pos, true_vel, alive, 500.0, origin)
    sp = lambda a: math.log1p(math.exp(a))
    assert parts["association"] == pytest.approx(sp(-3.0) + sp(-3.0), rel=1e-9)  # own at +3, the two others at -3
    # a target nobody is near: still matched (its query is pulled towards it and told it exists)
    far = true_pos.clone()
    far[0, 1] = torch.tensor([-9000.0, 0.0])
    _, parts = set_loss(out, far, true_vel, alive, 500.0)
    assert parts["matched"] == 2 and parts["state"] > 100.0


def test_tokens_carry_the_closed_form_fixes_and_mask_the_padding():
    m = model()
    cfg = SetTrackerConfig(window=2)
    x = torch.tensor([[3000.0, 8.0, 0.0, 6000.0, -5.0, 0.0]], dtype=torch.float64)
    z = m.h(x).reshape(1, 3, 1, 3).expand(1, 3, 2, 3).clone()  # (S, M=2, d): two copies per pair
    z = z[None].expand(1, 2, 3, 2, 3).clone()  # (W=1, L=2, S, M, d)
    valid = torch.ones(1, 2, 3, 2, dtype=torch.bool)
    valid[0, 0, :, 1] = False  # padding in the first scan
    feats, pair, age, mask, raw = detection_tokens(z, valid, m, cfg)
    assert feats.shape == (1, 12, 7) and mask.sum() == 3 and raw.shape == (1, 12, 3)
    assert torch.equal(raw[0, 6:], z[0, 1].reshape(6, 3)) and not raw[0, :6][mask[0, :6]].any()
    pos, ok = range_azimuth_fix(z[0, 1], m)
    assert bool(ok.all())
    got = feats[0].reshape(2, 3, 2, 7)[1, ..., :2].double() * cfg.position_scale_m
    assert torch.allclose(got, pos, rtol=0, atol=1e-2)  # float32 tokens
    assert torch.allclose(pos, x[0, [0, 3]].expand(3, 2, 2), rtol=0, atol=1e-6)  # noise-free: the true position
    assert age[0].reshape(2, 3, 2)[:, 0, 0].tolist() == [1, 0] and pair[0].reshape(2, 3, 2)[0, :, 0].tolist() == [0, 1, 2]


def test_linking_keeps_a_track_through_scans_and_starts_another_after_a_gap():
    K, Q = 6, 3
    pos = torch.zeros(1, K, Q, 2, dtype=torch.float64)
    vel = torch.zeros(1, K, Q, 2, dtype=torch.float64)
    p = torch.zeros(1, K, Q, dtype=torch.float64)
    for k in range(K):
        pos[0, k, k % Q] = torch.tensor([100.0 * k, 0.0])  # target A at 100 m/s, answered by a changing query
        vel[0, k, k % Q] = torch.tensor([100.0, 0.0])
        p[0, k, k % Q] = 0.9
        if k != 3:  # target B, missed at scan 3
            pos[0, k, (k + 1) % Q] = torch.tensor([0.0, 5000.0])
            p[0, k, (k + 1) % Q] = 0.8
    x, exists = link_tracks(pos, vel, p, dt=1.0, gate_m=50.0)
    assert x.shape[2] == 3  # A, B before the gap, B after it
    assert exists[0, :, 0].all() and torch.allclose(x[0, :, 0, 0], torch.arange(K, dtype=torch.float64) * 100)
    assert exists[0, :3, 1].all() and not exists[0, 3:, 1].any() and exists[0, 4:, 2].all()


def test_a_tiny_set_tracker_fits_a_fixed_batch():
    """Forty Adam steps on one fixed batch must cut the set loss by half: gradients reach every
    part (a network that could not learn the batch would fail here)."""
    torch.manual_seed(0)
    m = model()
    cfg = SetTrackerConfig(window=2, d_model=32, heads=2, encoder_layers=1, decoder_layers=1, queries=4)
    x = torch.tensor([[3000.0, 8.0, 0.0, 6000.0, -5.0, 0.0], [5000.0, -4.0, 0.0, 7000.0, 3.0, 0.0]], dtype=torch.float64)
    z = m.h(x).reshape(2, 3, 3).transpose(0, 1)[None, None].expand(4, 2, 3, 2, 3).clone()
    valid = torch.ones(4, 2, 3, 2, dtype=torch.bool)
    toks = detection_tokens(z, valid, m, cfg)
    tp, tv = x[:, [0, 3]].expand(4, 2, 2), x[:, [1, 4]].expand(4, 2, 2)
    net = SetTracker(cfg, m, 1.0)
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    first = None
    for _ in range(40):
        loss, _ = set_loss(net(toks), tp, tv, torch.ones(4, 2, dtype=torch.bool), 500.0)
        first = float(loss.detach()) if first is None else first
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert float(loss.detach()) < 0.5 * first, (first, float(loss.detach()))


def test_a_saved_set_tracker_loads_back_with_its_sensors_and_answers_the_same(tmp_path):
    from pmsr_nn.nets.set_inference import load_set_checkpoint, save_set_checkpoint, set_metadata

    torch.manual_seed(1)
    m = model()
    cfg = SetTrackerConfig(window=2, d_model=16, heads=2, encoder_layers=1, decoder_layers=1, queries=3, reassociate=1)
    net = SetTracker(cfg, m, 1.0).eval()
    x = torch.tensor([[3000.0, 8.0, 0.0, 6000.0, -5.0, 0.0]], dtype=torch.float64)
    z = m.h(x).reshape(1, 3, 1, 3)[None].expand(2, 2, 3, 1, 3).clone()
    toks = detection_tokens(z, torch.ones(2, 2, 3, 1, dtype=torch.bool), m, cfg)
    save_set_checkpoint(tmp_path / "ck.pt", set_metadata(cfg, m, 1.0, 6, seed=0), net)
    back = load_set_checkpoint(tmp_path / "ck.pt")
    assert back.net.model == m and back.net.dt == 1.0 and back.net.cfg == cfg
    with torch.no_grad():
        a, b = net(toks), back.net(toks)
    assert a.pos.shape == (2, 3, 2) and torch.isfinite(a.pos).all()
    assert torch.equal(a.pos, b.pos) and torch.equal(a.logit, b.logit)


def test_existence_near_calls_present_only_the_matched_queries_within_the_cutoff():
    true_pos = torch.tensor([[[1000.0, 2000.0], [3000.0, -500.0]]], dtype=torch.float64)
    pos = torch.tensor([[[1000.0, 2100.0], [3900.0, -500.0], [9000.0, 9000.0]]], dtype=torch.float64)  # 100 m, 900 m off
    out = SetOutput(pos, torch.zeros(1, 3, 2, dtype=torch.float64), torch.zeros(1, 3, dtype=torch.float64),
                    torch.zeros(1, 3, 1, dtype=torch.float64), pos.clone(), torch.zeros(1, 1, dtype=torch.float64))
    alive = torch.ones(1, 2, dtype=torch.bool)
    zero_v = torch.zeros(1, 2, 2, dtype=torch.float64)
    _, matched = set_loss(out, true_pos, zero_v, alive, 500.0)
    _, near = set_loss(out, true_pos, zero_v, alive, 500.0, existence="near")
    # every logit is 0: the existence term is log 2 whatever the targets; so compare through the gradient
    logit = torch.zeros(1, 3, dtype=torch.float64, requires_grad=True)
    set_loss(out._replace(logit=logit), true_pos, zero_v, alive, 500.0, existence="near")[0].backward()
    # d BCE / d logit = (sigmoid(0) - target) / 3: target 1 only for the query 100 m off
    assert torch.allclose(logit.grad, torch.tensor([[-0.5, 0.5, 0.5]], dtype=torch.float64) / 3)
    assert matched["matched"] == near["matched"] == 2
    with pytest.raises(Exception, match="existence must be"):
        set_loss(out, true_pos, zero_v, alive, 500.0, existence="sometimes")


def test_fine_tuning_starts_from_a_checkpoint_of_the_same_size_and_refuses_another(tmp_path):
    from pathlib import Path

    from pmsr_nn.errors import CheckpointError
    from pmsr_nn.nets.scene_data import SceneConfig, SceneSampler
    from pmsr_nn.nets.set_inference import save_set_checkpoint, set_metadata
    from pmsr_nn.nets.set_training import start_from

    recipe = Path(__file__).resolve().parents[1] / "datasets" / "fitee2023_ca.yaml"
    sampler = SceneSampler(str(recipe), SceneConfig(window=5))
    cfg = SetTrackerConfig(window=5, d_model=16, heads=2, encoder_layers=1, decoder_layers=1, queries=3)
    torch.manual_seed(0)
    trained = SetTracker(cfg, sampler.model, sampler.dt)
    save_set_checkpoint(tmp_path / "ck.pt", set_metadata(cfg, sampler.model, sampler.dt, 6), trained)
    fresh = SetTracker(cfg, sampler.model, sampler.dt)
    start_from(fresh, str(tmp_path / "ck.pt"), sampler)
    assert all(torch.equal(a, b) for a, b in zip(fresh.state_dict().values(), trained.state_dict().values()))
    wider = SetTracker(SetTrackerConfig(window=5, d_model=32, heads=2, encoder_layers=1, decoder_layers=1, queries=3),
                       sampler.model, sampler.dt)
    with pytest.raises(CheckpointError, match="another size"):
        start_from(wider, str(tmp_path / "ck.pt"), sampler)
