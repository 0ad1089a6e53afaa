"""The information bound of a target seen through range-Doppler maps (issue 58, :mod:`pmsr_nn.tbd.bound`):
the closed form of one map and one frame, autograd through the response, finite differences
through the geometry, and the ML estimate's spread at high SNR inside its chi-square interval."""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy import stats

from pmsr_nn.motion import ConstantVelocity
from pmsr_nn.rng import seeded_generator
from pmsr_nn.tbd.bound import _cells, cell_information, cell_jacobian, map_bound, map_information, sinc_derivative
from pmsr_nn.tbd.maps import MapSpec, frame_at_cells, response, triangle
from pmsr_nn.tbd.multibernoulli import BirthBox
from pmsr_nn.tbd.scene import MapExtent, MapScene


def _sinc_derivative_tail(gap: float) -> float:
    """An upper bound of ``sum sinc'(x)^2`` over the rows beyond a map's edge, ``gap`` the distance
    (cells) from the target to the first row outside: ``|sinc'(x)| <= 1/|x| + 1/(pi x^2)``."""
    x = gap + np.arange(0, 10_000_000, dtype=np.float64)
    return float(((1 / x + 1 / (math.pi * x * x)) ** 2).sum() + 1 / x[-1])  # the rest: below the integral of 1/x^2


def test_one_map_one_frame_is_the_closed_form():
    """A target at a half-cell range offset with a triangle of half-width 2 cells reaches four
    columns at 0.25 and 0.75 of its peak: ``sum tri^2 = 1.25`` and ``sum tri'^2 = 4 / 4 = 1``. On a
    map without edges the Doppler sums are ``pi^2 / 3`` and 1 (module docstring), so
    ``J = 2 SNR diag(1.25 pi^2 / 3, 1)``; a map of 80 rows holds all but a tail bounded here."""
    D, U, L = 80, 40, 2.0
    d, u = torch.tensor(40.3, dtype=torch.float64), torch.tensor(20.5, dtype=torch.float64)
    J = cell_information(d, u, D, U, L)
    tail_dd = _sinc_derivative_tail(min(float(d) + 1, D - float(d))) * 2  # both edges, each bounded by the nearer
    assert 2 * 1.25 * (math.pi ** 2 / 3 - tail_dd) <= float(J[0, 0]) <= 2 * 1.25 * math.pi ** 2 / 3
    tail_ss = 2 / (math.pi ** 2 * (min(float(d) + 1, D - float(d)) - 1))  # sum of 1 / (pi x)^2 beyond the edges
    assert 2 * (1 - tail_ss) <= float(J[1, 1]) <= 2.0
    # the cross term: sum sinc sinc' is a tail quantity; sum tri tri' is 0 at a half-cell offset
    assert abs(float(J[0, 1])) < 1e-12
    # a map 20001 rows tall: the tail is 1e-4 of the sum
    Jw = cell_information(torch.tensor(10_000.3, dtype=torch.float64), u, 20_001, U, L)
    torch.testing.assert_close(Jw, torch.tensor([[2 * 1.25 * math.pi ** 2 / 3, 0.0], [0.0, 2.0]], dtype=torch.float64),
                               rtol=2e-4, atol=1e-12)


def test_cell_information_is_autograd_through_the_response():
    """``2 sum grad h grad h^T`` with ``h`` the maps' own :func:`~pmsr_nn.tbd.maps.response` over every
    cell, differentiated by autograd, at offsets that are not on a cell (the triangle's kinks)."""
    D, U, L = 30, 24, 2.5
    rows = torch.arange(D, dtype=torch.float64)[:, None]
    cols = torch.arange(U, dtype=torch.float64)[None, :]
    for d0, u0 in ((14.37, 11.21), (3.9, 20.66), (0.2, 1.8)):  # centre, near the edges
        du = torch.tensor([d0, u0], dtype=torch.float64, requires_grad=True)
        h = response(rows, cols, du[0], du[1], L).flatten()
        grads = torch.stack([torch.autograd.grad(h[i], du, retain_graph=True)[0] for i in range(h.numel())])
        ref = 2 * grads.T @ grads
        torch.testing.assert_close(cell_information(du[0].detach(), du[1].detach(), D, U, L), ref, rtol=1e-12, atol=1e-12)


def test_sinc_derivative_matches_autograd_and_its_taylor_form():
    x = torch.tensor([-3.7, -1.0, -1e-3, -2e-5, 0.0, 3e-5, 0.5, 2.0, 41.3], dtype=torch.float64, requires_grad=True)
    ref = torch.autograd.grad(torch.sinc(x).sum(), x)[0]
    torch.testing.assert_close(sinc_derivative(x.detach()), ref, rtol=1e-9, atol=1e-9)


def _scene(P=2, snr=(12.0, 9.0)):
    tx = ((20_000.0, 3_000.0, 0.0), (-5_000.0, 18_000.0, 0.0))[:P]
    return MapScene(tuple(f"m{p}" for p in range(P)), tx, ((0.0, 0.0, 0.0),) * P, ((0.0, 0.0, 0.0),) * P,
                    (3.06,) * P, snr[:P], MapSpec(sample_rate_hz=2.0e6, chip_rate_hz=1.0e6, doppler_cell_hz=1.0,
                                                  altitude_m=0.0),
                    BirthBox(x_m=(4_000.0, 8_000.0), y_m=(2_000.0, 6_000.0), vx_mps=(-20.0, 20.0), vy_mps=(-20.0, 20.0)),
                    frames=12, frame_s=1.0, map_extent=MapExtent(range_m=(-2_000.0, 40_000.0), doppler_hz=(-30.0, 30.0)))
    # a fixed extent: every scene has the same cells, so a map's information does not depend on the others


def test_cell_jacobian_matches_central_differences():
    scene = _scene()
    x = torch.tensor([[6_000.0, 12.0, 4_000.0, -7.0], [5_100.0, -3.0, 2_500.0, 15.0]], dtype=torch.float64)
    frames = torch.tensor([0, 7])
    H = cell_jacobian(scene, x, frames)  # (L, P, 2, 4)
    step = torch.tensor([1e-2, 1e-4, 1e-2, 1e-4], dtype=torch.float64)
    for i in range(4):
        e = torch.zeros(4, dtype=torch.float64)
        e[i] = step[i]
        (dp, up), (dm, um) = _cells(scene, x + e, frames), _cells(scene, x - e, frames)
        fd = torch.stack([(dp - dm), (up - um)], -1) / (2 * step[i])  # (L, P, 2)
        torch.testing.assert_close(H[..., i], fd, rtol=1e-6, atol=1e-9)


def test_map_information_sums_each_maps_snr_weighted_information():
    """Two maps equal the sum of each alone (each at its own SNR), and 10 dB more SNR is 10x the
    information; the state information has the rank of the cells it is seen through (2 per map)."""
    x = torch.tensor([[6_000.0, 12.0, 4_000.0, -7.0]], dtype=torch.float64)
    frames = torch.tensor([3])
    both = map_information(_scene(2), x, frames)
    one = map_information(_scene(1), x, frames)
    other = map_information(dataclass_replace(_scene(2), keep=1), x, frames)
    torch.testing.assert_close(both, one + other, rtol=1e-12, atol=0.0)
    louder = map_information(_scene(1, snr=(22.0,)), x, frames)
    torch.testing.assert_close(louder, 10 * one, rtol=1e-12, atol=0.0)
    assert int(torch.linalg.matrix_rank(one[0])) == 2 and int(torch.linalg.matrix_rank(both[0])) == 4


def dataclass_replace(scene: MapScene, keep: int) -> MapScene:
    """The scene with map ``keep`` alone."""
    import dataclasses
    pick = lambda t: (t[keep],)
    return dataclasses.replace(scene, names=pick(scene.names), tx_position_m=pick(scene.tx_position_m),
                               tx_velocity_mps=pick(scene.tx_velocity_mps), rx_position_m=pick(scene.rx_position_m),
                               wavelength_m=pick(scene.wavelength_m), snr_db=pick(scene.snr_db))


def test_ml_doppler_spread_at_high_snr_is_the_bound():
    """The known-amplitude, unknown-phase ML estimate of a target's Doppler row (its range column
    known) over 1000 maps at 25 dB: ``N var / CRB`` inside the chi-square interval of 99.9 %.
    ML: the maximum over ``d`` of ``2 A |<h(d), z>| - A^2 |h(d)|^2`` on a 1e-4-cell grid near the
    truth (at this SNR the estimate's spread is 0.02 cells)."""
    N, D, U, L = 1000, 48, 12, 2.0
    snr = 10 ** 2.5
    d0, u0 = 23.37, 6.0
    A = math.sqrt(snr)  # noise power 1
    g = seeded_generator(58, 1)
    d = torch.full((N, 1, 1), d0, dtype=torch.float64)
    u = torch.full((N, 1, 1), u0, dtype=torch.float64)
    z = frame_at_cells(d, u, torch.ones(N, 1, dtype=torch.bool), torch.tensor([A], dtype=torch.float64), (D, U), 1.0, L,
                       g)[:, 0].to(torch.complex128)  # (N, D, U)
    t = triangle((torch.arange(U, dtype=torch.float64) - u0) / L)  # the known range profile
    y = z @ t.to(torch.complex128)  # (N, D): the map projected on it
    cand = d0 + torch.arange(-0.1, 0.1, 1e-4, dtype=torch.float64)
    S = torch.sinc(torch.arange(D, dtype=torch.float64)[:, None] - cand[None, :])  # (D, C)
    score = 2 * A * (y @ S.to(torch.complex128)).abs() - A * A * (S * S).sum(0) * (t * t).sum()
    est = cand[score.argmax(1)]
    crb = 1 / (snr * float(cell_information(torch.tensor(d0), torch.tensor(u0), D, U, L)[0, 0]))
    ratio = float(((est - d0) ** 2).sum()) / crb
    lo, hi = stats.chi2.ppf([0.0005, 0.9995], N)
    assert lo < ratio < hi, (ratio / N, lo / N, hi / N)


def test_map_bound_shrinks_with_frames_and_snr():
    """The recursion on the maps' information (CV, no process noise): each frame adds information,
    so the position bound falls frame after frame, and 10 dB more SNR divides a static bound's
    steady information by 10 (its RMSE by about sqrt(10) once the prior no longer counts)."""
    motion = ConstantVelocity()
    truth = torch.tensor([[6_000.0 + 12.0 * k, 12.0, 4_000.0 - 7.0 * k, -7.0] for k in range(10)], dtype=torch.float64)
    P0 = torch.diag(torch.tensor([1e3, 20.0, 1e3, 20.0], dtype=torch.float64) ** 2)
    b = map_bound(_scene(2), truth, 0, motion, 1.0, 0.0, P0)
    pos = b.position_rmse()
    assert bool((pos[1:] < pos[:-1]).all())
    loud = map_bound(_scene(2, snr=(22.0, 19.0)), truth, 0, motion, 1.0, 0.0, P0).position_rmse()
    assert 0.9 * math.sqrt(10) < float(pos[-1] / loud[-1]) < 1.01 * math.sqrt(10)
