"""Motion models against the papers' matrices and closed forms."""

import math

import pytest
import torch

from pmsr_nn.errors import ConfigError
from pmsr_nn.motion import ConstantAcceleration, ConstantVelocity, motion_model


def eq12(T, q):
    """Eq. 12 of the MDFNN paper, written out independently."""
    return q * torch.tensor([
        [T**5 / 20, T**4 / 8, T**3 / 6],
        [T**4 / 8, T**3 / 3, T**2 / 2],
        [T**3 / 6, T**2 / 2, T],
    ])


@pytest.mark.parametrize("T", [0.5, 1.0, 2.0])
def test_ca_Q_is_eq12_per_axis(T):
    Q = ConstantAcceleration().Q(T, 4.0)
    expected = torch.zeros(6, 6)
    expected[:3, :3] = eq12(T, 4.0)
    expected[3:, 3:] = eq12(T, 4.0)
    torch.testing.assert_close(Q, expected, rtol=1e-15, atol=0)


def test_cv_Q_is_the_sjpda_matrix():
    T, q = 2.0, 0.3
    Q = ConstantVelocity().Q(T, q)
    blk = q * torch.tensor([[T**4 / 4, T**3 / 2], [T**3 / 2, T**2]])
    torch.testing.assert_close(Q[:2, :2], blk)
    torch.testing.assert_close(Q[2:, 2:], blk)
    assert torch.count_nonzero(Q[:2, 2:]) == 0


@pytest.mark.parametrize("model", [ConstantVelocity(2), ConstantAcceleration(2), ConstantAcceleration(3)])
def test_Q_symmetric_positive_semidefinite(model):
    Q = model.Q(1.3, 2.5)
    torch.testing.assert_close(Q, Q.T, rtol=0, atol=0)
    eig = torch.linalg.eigvalsh(Q)
    assert eig.min() >= -1e-12 * eig.max()


def test_ca_Q_is_the_exact_discretisation():
    """Continuous white jerk: Q(2T) = F(T) Q(T) F(T)^T + Q(T). Fails for any other matrix."""
    m = ConstantAcceleration()
    T, q = 0.8, 3.0
    F = m.F(T)
    torch.testing.assert_close(m.Q(2 * T, q), F @ m.Q(T, q) @ F.T + m.Q(T, q), rtol=1e-13, atol=1e-15)


@pytest.mark.parametrize("model", [ConstantVelocity(2), ConstantAcceleration(3)])
def test_F_semigroup(model):
    torch.testing.assert_close(model.F(0.7) @ model.F(1.1), model.F(1.8), rtol=1e-14, atol=1e-14)


def test_per_run_and_per_axis_q():
    m = ConstantAcceleration(3)
    Q = m.Q(1.0, torch.tensor([[1.0, 2.0, 0.0], [3.0, 3.0, 3.0]]))
    assert Q.shape == (2, 9, 9)
    torch.testing.assert_close(Q[0, 3:6, 3:6], eq12(1.0, 2.0))
    assert torch.count_nonzero(Q[0, 6:, 6:]) == 0
    L = m.noise_factor(1.0, torch.tensor([1.0, 2.0, 0.0]))
    torch.testing.assert_close(L @ L.T, m.Q(1.0, torch.tensor([1.0, 2.0, 0.0])))
    with pytest.raises(ConfigError):
        m.Q(1.0, -1.0)


@pytest.mark.parametrize("model", [ConstantVelocity(2), ConstantAcceleration(2), ConstantAcceleration(3)])
def test_propagate_equals_matrix_recursion(model):
    g = torch.Generator().manual_seed(0)
    x0 = torch.randn(7, model.dim_x, generator=g) * 100
    w = torch.randn(7, 49, model.dim_x, generator=g)
    T = 0.9
    got = model.propagate(x0, w, T)
    x, ref = x0, [x0]
    for k in range(49):
        x = x @ model.F(T).T + w[:, k]
        ref.append(x)
    torch.testing.assert_close(got, torch.stack(ref, 1), rtol=1e-12, atol=1e-9)


def test_noise_free_ca_trajectory_is_the_parabola():
    m = ConstantAcceleration()
    x0 = torch.tensor([[100.0, 3.0, 0.5, -50.0, -2.0, 0.1]])
    traj = m.propagate(x0, torch.zeros(1, 99, 6), 1.0)[0]
    t = torch.arange(100.0)
    torch.testing.assert_close(traj[:, 0], 100 + 3 * t + 0.25 * t**2)
    torch.testing.assert_close(traj[:, 4], -2 + 0.1 * t)
    torch.testing.assert_close(traj[:, 5], torch.full((100,), 0.1))


def test_sampled_increments_have_covariance_Q():
    m = ConstantAcceleration()
    T, q = 1.0, 4.0
    traj = m.sample(torch.zeros(4000, 6), 26, T, q, torch.Generator().manual_seed(1))
    w = traj[:, 1:] - traj[:, :-1] @ m.F(T).T  # the increments w_k
    white = torch.linalg.solve_triangular(torch.linalg.cholesky(m.Q(T, q)), w.reshape(-1, 6).T, upper=False).T
    n = white.shape[0]
    cov = white.T @ white / n
    # Entries of a sample covariance of n white vectors: sd 1/sqrt(n) off the diagonal, sqrt(2/n) on it.
    assert bool(((cov - torch.eye(6)).abs() < 5 * math.sqrt(2 / n)).all())


def test_zero_vertical_noise_keeps_altitude():
    m = ConstantAcceleration(3)
    x0 = torch.zeros(3, 9)
    x0[:, 6] = 150.0
    traj = m.sample(x0, 50, 1.0, [4.0, 4.0, 0.0], torch.Generator().manual_seed(2))
    assert torch.equal(traj[..., 6], torch.full((3, 50), 150.0))
    assert traj[..., 0].abs().max() > 0


def test_sampling_is_deterministic_by_generator():
    m = ConstantVelocity()
    a = m.sample(torch.zeros(2, 4), 10, 1.0, 1.0, torch.Generator().manual_seed(5))
    b = m.sample(torch.zeros(2, 4), 10, 1.0, 1.0, torch.Generator().manual_seed(5))
    c = m.sample(torch.zeros(2, 4), 10, 1.0, 1.0, torch.Generator().manual_seed(6))
    assert torch.equal(a, b) and not torch.equal(a, c)


def test_motion_model_lookup():
    assert motion_model("ca", 3).dim_x == 9
    assert motion_model("cv").pos_idx == (0, 2)
    with pytest.raises(ConfigError):
        motion_model("singer")


def test_transition_for_a_tensor_of_intervals_matches_one_at_a_time():
    for model in (ConstantVelocity(), ConstantAcceleration(spatial_dim=3)):
        T = torch.tensor([[0.5, -2.0], [3.0, 0.0]], dtype=torch.float64)
        batched = model.F(T)
        assert batched.shape == (2, 2, model.dim_x, model.dim_x)
        for i in range(2):
            for j in range(2):
                torch.testing.assert_close(batched[i, j], model.F(float(T[i, j])), rtol=0, atol=0)
        # F(-T) undoes F(T): what SI+KF uses to move a later fix back to step 0.
        torch.testing.assert_close(model.F(-T) @ batched, torch.eye(model.dim_x).expand_as(batched), rtol=0, atol=1e-12)
