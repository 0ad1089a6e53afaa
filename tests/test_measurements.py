"""Measurement functions against hand-computed values and their Jacobians against autograd."""

import math

import pytest
import torch
from torch.func import jacrev, vmap

from pmsr_nn import SPEED_OF_LIGHT
from pmsr_nn.errors import ConfigError
from pmsr_nn.geometry import Geometry, Receiver, Transmitter
from pmsr_nn.measurements import COMPONENTS, MeasurementModel, wrap_angle
from pmsr_nn.motion import ConstantAcceleration, ConstantVelocity

FC = 100e6


def simple_model(components=("range", "range_rate", "azimuth"), layout="component", motion=None):
    motion = motion or ConstantVelocity()
    g = Geometry.all_pairs([Transmitter((0.0, 0.0), FC)], [Receiver((4000.0, 0.0))])
    return MeasurementModel(g, components, (10.0,) * len(components), motion.pos_idx, motion.vel_idx, layout)


def test_hand_computed_values():
    # Target at (0, 3000) moving east at 10 m/s; Tx at the origin, Rx at (4000, 0).
    # |p - tx| = 3000, |p - rx| = 5000; u_tx = (0, 1), u_rx = (-0.8, 0.6); rdot = 10 * (-0.8) = -8.
    model = simple_model(("range", "range_rate", "doppler", "delay", "azimuth"))
    x = torch.tensor([0.0, 10.0, 3000.0, 0.0])  # CV [x, vx, y, vy]
    r, rdot, fd, tau, phi = model.h(x).tolist()
    assert r == pytest.approx(8000.0, rel=1e-15)
    assert rdot == pytest.approx(-8.0, rel=1e-14)
    assert fd == pytest.approx(8.0 * FC / SPEED_OF_LIGHT, rel=1e-14)  # approaching: positive Doppler
    assert tau == pytest.approx(8000.0 / SPEED_OF_LIGHT, rel=1e-15)
    assert phi == pytest.approx(math.atan2(-4000.0, 3000.0), rel=1e-15)  # north-referenced, at the receiver
    assert math.degrees(phi) == pytest.approx(-53.130102354, abs=1e-8)


def test_azimuth_is_clockwise_from_north_at_the_receiver():
    model = simple_model(("azimuth",))
    rx = (4000.0, 0.0)
    for bearing in (0.0, 45.0, 90.0, 135.0, -90.0):
        b = math.radians(bearing)
        x = torch.tensor([rx[0] + 100 * math.sin(b), 0.0, rx[1] + 100 * math.cos(b), 0.0])
        assert model.h(x).item() == pytest.approx(b, abs=1e-12)


STATE_CASES = [
    ("cv2", ConstantVelocity(2)),
    ("ca2", ConstantAcceleration(2)),
    ("ca3", ConstantAcceleration(3)),
]


@pytest.mark.parametrize("layout", ["component", "pair"])
@pytest.mark.parametrize("name,motion", STATE_CASES)
def test_jacobian_matches_autograd(name, motion, layout):
    tx = [Transmitter((0.0, 0.0), 93.1e6), Transmitter((-2.0e4, 1.5e4), 99.9e6)]
    rx = [Receiver((7000.0, -3000.0)), Receiver((-4000.0, -6000.0))]
    g = Geometry.all_pairs(tx, rx).lifted(motion.spatial_dim)
    model = MeasurementModel(g, COMPONENTS, (1.0,) * len(COMPONENTS), motion.pos_idx, motion.vel_idx, layout)
    gen = torch.Generator().manual_seed(3)
    x = torch.randn(16, motion.dim_x, generator=gen) * 3000.0
    x[:, list(motion.vel_idx)] /= 100.0
    auto = vmap(jacrev(model.h))(x)
    analytic = model.jacobian(x)
    assert analytic.shape == (16, model.dim_z, motion.dim_x)
    # Both are exact derivatives in float64: they differ by rounding only.
    torch.testing.assert_close(analytic, auto, rtol=1e-10, atol=1e-14)


def test_layouts_hold_the_same_rows():
    comp = simple_model(("range", "doppler"), "component")
    pair = simple_model(("range", "doppler"), "pair")
    x = torch.tensor([[100.0, 3.0, 2000.0, -4.0]])
    assert comp.labels == ["range_1", "doppler_1"] and pair.labels == ["range_1", "doppler_1"]
    torch.testing.assert_close(comp.h(x), pair.h(x))


def test_component_layout_is_eq6_order():
    motion = ConstantAcceleration()
    g = Geometry.all_pairs([Transmitter((0.0, 0.0), FC)], [Receiver((1e3, 0.0)), Receiver((0.0, 1e3)), Receiver((-1e3, 0.0))])
    model = MeasurementModel(g, ("range", "range_rate", "azimuth"), (20.0, 3.0, 0.02), motion.pos_idx, motion.vel_idx)
    assert model.labels == [f"{c}_{n}" for c in ("range", "range_rate", "azimuth") for n in (1, 2, 3)]
    assert model.angle_mask.tolist() == [False] * 6 + [True] * 3
    R = model.R()
    assert torch.equal(torch.diag(R), torch.tensor([400.0] * 3 + [9.0] * 3 + [0.0004] * 3))


def test_per_run_noise_covariance():
    model = simple_model()
    std = torch.tensor([[1.0, 2.0, 0.1], [3.0, 4.0, 0.2]])
    R = model.R(std)
    assert R.shape == (2, 3, 3)
    assert torch.allclose(torch.diagonal(R, dim1=-2, dim2=-1), std**2)


def test_residual_wraps_angles_only():
    model = simple_model()
    z = torch.tensor([10.0, 1.0, math.pi - 0.01])
    zp = torch.tensor([12.0, 3.0, -math.pi + 0.01])
    torch.testing.assert_close(model.residual(z, zp), torch.tensor([-2.0, -2.0, -0.02]))


def test_wrap_angle_range():
    a = torch.linspace(-20, 20, 1001)
    w = wrap_angle(a)
    assert bool((w > -math.pi).all() and (w <= math.pi).all())
    torch.testing.assert_close(torch.sin(w), torch.sin(a))
    assert wrap_angle(torch.tensor(-math.pi)).item() == pytest.approx(math.pi)


def test_target_on_a_sensor_gives_finite_values_and_a_flag():
    model = simple_model(COMPONENTS)
    on_tx = torch.tensor([0.0, 5.0, 0.0, 5.0])
    on_rx = torch.tensor([4000.0, 5.0, 0.0, 5.0])
    for x in (on_tx, on_rx):
        assert bool(torch.isfinite(model.h(x)).all())
        assert bool(torch.isfinite(model.jacobian(x)).all())
        assert bool(model.near_sensor(x, 1.0))
    assert not bool(model.near_sensor(torch.tensor([0.0, 5.0, 300.0, 5.0]), 1.0))


def test_sample_noise_has_the_stated_deviation():
    model = simple_model()
    x = torch.tensor([0.0, 10.0, 3000.0, 0.0]).expand(200_000, 4)
    std = torch.tensor([5.0, 0.5, 0.01])
    z = model.sample(x, std.expand(200_000, 3), torch.Generator().manual_seed(0))
    err = model.residual(z, model.h(x)) / std
    # Standard normal: the sample mean has sd 1/sqrt(n) and the sample variance sd sqrt(2/n).
    n = err.shape[0]
    assert bool((err.mean(0).abs() < 5 / math.sqrt(n)).all())
    assert bool(((err.var(0) - 1).abs() < 5 * math.sqrt(2 / n)).all())


def test_invalid_models_are_rejected():
    motion = ConstantVelocity()
    g = Geometry.all_pairs([Transmitter((0.0, 0.0), FC)], [Receiver((4000.0, 0.0))])
    with pytest.raises(ConfigError):
        MeasurementModel(g, ("range", "bearing"), (1.0, 1.0), motion.pos_idx, motion.vel_idx)
    with pytest.raises(ConfigError):
        MeasurementModel(g, ("range",), (0.0,), motion.pos_idx, motion.vel_idx)
    with pytest.raises(ConfigError, match="3-D"):
        MeasurementModel(g, ("range",), (1.0,), ConstantVelocity(3).pos_idx, ConstantVelocity(3).vel_idx)


def test_public_functions_agree_with_the_model():
    from pmsr_nn.measurements import azimuth, bistatic_delay_s, bistatic_range, bistatic_range_rate, doppler_hz

    motion = ConstantAcceleration(3)
    g = Geometry.all_pairs([Transmitter((0.0, 0.0), FC)], [Receiver((4000.0, 0.0)), Receiver((-3000.0, 500.0))]).lifted(3)
    model = MeasurementModel(g, COMPONENTS, (1.0,) * 5, motion.pos_idx, motion.vel_idx)
    x = torch.randn(5, 9, generator=torch.Generator().manual_seed(9)) * 2000
    pos, vel = x[:, list(motion.pos_idx)], x[:, list(motion.vel_idx)]
    tx, rx, fc = g.pair_tx_positions(), g.pair_rx_positions(), g.pair_carriers()
    expected = torch.cat([bistatic_range(pos, tx, rx), bistatic_range_rate(pos, vel, tx, rx),
                          doppler_hz(pos, vel, tx, rx, fc), bistatic_delay_s(pos, tx, rx), azimuth(pos, rx)], -1)
    torch.testing.assert_close(model.h(x), expected, rtol=1e-13, atol=1e-12)
