"""The set tracker's Gauss-Newton refinement (pmsr_nn/nets/set_refine.py) against the truth of
noise-free detections, against scipy's nonlinear least squares on noisy ones, and with clutter
the redescending kernel must drop."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.optimize import least_squares

from pmsr_nn.geometry import Geometry, Receiver, Transmitter
from pmsr_nn.measurements import MeasurementModel, wrap_angle
from pmsr_nn.nets.set_refine import gauss_newton, state_vector, token_residuals

L, DT = 6, 1.0


def model() -> MeasurementModel:
    g = Geometry.all_pairs([Transmitter((0.0, 0.0), 650e6)],
                           [Receiver((-7000.0, -3000.0)), Receiver((-8000.0, 500.0)), Receiver((-7500.0, 4000.0))])
    return MeasurementModel(g, ("range", "range_rate", "azimuth"), (30.0, 2.0, math.radians(3.0)), (0, 3), (1, 4),
                            layout="pair")


def detections(m, p, v, noise: bool, seed: int = 0):
    """Every pair's detection at each of the window's scans of a target at ``p, v`` (last scan):
    ``z (L S, 3)``, ``pair``, ``age``."""
    age = torch.arange(L - 1, -1, -1).repeat_interleave(m.n_pairs)
    pair = torch.arange(m.n_pairs).repeat(L)
    at = p - (age.double() * DT)[:, None] * v
    z = m.h(state_vector(m, at, v.expand_as(at), 6)).reshape(-1, m.n_pairs, 3)[torch.arange(len(age)), pair]
    if noise:
        g = torch.Generator().manual_seed(seed)
        z = z + torch.randn(z.shape, generator=g, dtype=torch.float64) * torch.tensor(m.noise_std)
    return z, pair, age


P_TRUE, V_TRUE = torch.tensor([3000.0, 6000.0], dtype=torch.float64), torch.tensor([8.0, -5.0], dtype=torch.float64)


def test_noise_free_detections_bring_a_start_300_m_off_to_the_truth():
    m = model()
    z, pair, age = detections(m, P_TRUE, V_TRUE, noise=False)
    p, v, support = gauss_newton(P_TRUE + torch.tensor([250.0, -170.0]), V_TRUE + 5.0, z, pair, age,
                                 torch.ones(len(z)), m, DT, 6, 8, (1e6, 1e6))
    assert torch.allclose(p, P_TRUE, atol=1e-3, rtol=0) and torch.allclose(v, V_TRUE, atol=1e-4, rtol=0)
    assert float(support) == pytest.approx(len(z), abs=1e-6)  # every residual ~0: every kernel weight 1


@pytest.mark.parametrize("seed", range(3))
def test_without_kernel_it_is_the_least_squares_fit_scipy_finds(seed):
    m = model()
    z, pair, age = detections(m, P_TRUE, V_TRUE, noise=True, seed=seed)
    w = torch.linspace(0.3, 1.0, len(z), dtype=torch.float64)
    prior = (400.0, 10.0)
    p0, v0 = P_TRUE + torch.tensor([120.0, 90.0]), V_TRUE - 3.0
    p, v, _ = gauss_newton(p0, v0, z, pair, age, w, m, DT, 6, 12, prior, kernel_scales=(None,))
    std = np.array(m.noise_std)
    s0 = torch.cat([p0, v0]).numpy()
    sd = np.array([prior[0]] * 2 + [prior[1]] * 2)

    def residuals(s):
        s_t = torch.from_numpy(s)
        at = s_t[:2] - (age.double() * DT)[:, None] * s_t[2:]
        h = m.h(state_vector(m, at, s_t[2:].expand_as(at), 6)).reshape(-1, m.n_pairs, 3)[torch.arange(len(age)), pair]
        r = z - h
        r[:, 2] = wrap_angle(r[:, 2])
        return np.concatenate([(np.sqrt(w.numpy())[:, None] * r.numpy() / std).ravel(), (s - s0) / sd])

    ref = least_squares(residuals, s0, jac="3-point", xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    assert np.allclose(torch.cat([p, v]).numpy(), ref, atol=1e-6, rtol=0)


def test_the_kernel_drops_clutter_the_network_half_chose():
    m = model()
    z, pair, age = detections(m, P_TRUE, V_TRUE, noise=True)
    g = torch.Generator().manual_seed(5)
    n = 12
    clutter = torch.stack([torch.rand(n, generator=g, dtype=torch.float64) * 20000,
                           torch.rand(n, generator=g, dtype=torch.float64) * 80 - 40,
                           (torch.rand(n, generator=g, dtype=torch.float64) * 2 - 1) * math.pi], -1)
    start = (P_TRUE + torch.tensor([150.0, -100.0]), V_TRUE + 2.0)
    args = (m, DT, 6, 20, (1000.0, 30.0))  # 20 steps: both runs settle at the kernel's fixed point
    clean = gauss_newton(*start, z, pair, age, torch.ones(len(z)), *args)
    zc = torch.cat([z, clutter])
    pc = torch.cat([pair, torch.randint(0, 3, (n,), generator=g)])
    ac = torch.cat([age, torch.randint(0, L, (n,), generator=g)])
    wc = torch.cat([torch.ones(len(z)), torch.full((n,), 0.05)])
    mixed = gauss_newton(*start, zc, pc, ac, wc, *args)
    # no kernel: the clutter's pull is plain to see
    plain = gauss_newton(*start, zc, pc, ac, wc, *args[:-1], (1000.0, 30.0), kernel_scales=(None,))
    assert float((plain[0] - clean[0]).norm()) > 50.0
    # with the kernel every clutter point weighs about 0.05 exp(-400 / 18) ~ 1e-11: the same fit and support
    assert float((mixed[0] - clean[0]).norm()) < 1e-6 and abs(float(mixed[2] - clean[2])) < 1e-6


def test_token_residuals_are_zero_for_a_targets_own_noise_free_detections_and_match_one_by_one_evaluation():
    m = model()
    z, pair, age = detections(m, P_TRUE, V_TRUE, noise=False)
    other = P_TRUE + torch.tensor([400.0, 0.0])
    pos = torch.stack([P_TRUE, other])[None]  # (W=1, Q=2, 2)
    vel = V_TRUE.expand(1, 2, 2)
    e2 = token_residuals(pos, vel, z[None], pair[None], age[None], m, DT, 6)
    assert e2.shape == (1, 2, len(z)) and float(e2[0, 0].max()) < 1e-12
    # the second query, 400 m east, one token at a time through the model's own h
    for t in range(len(z)):
        at = other - age[t] * DT * V_TRUE
        h = m.h(state_vector(m, at, V_TRUE, 6)).reshape(m.n_pairs, 3)[pair[t]]
        r = z[t] - h
        r[2] = wrap_angle(r[2])
        assert float(e2[0, 1, t]) == pytest.approx(float(((r / torch.tensor(m.noise_std)) ** 2).sum()), rel=1e-12)
