import math

import pytest
import torch

from pmsr_nn.errors import GeometryError
from pmsr_nn.geometry import Geometry, Receiver, Transmitter, polar_position


def test_polar_position_is_clockwise_from_north():
    east = polar_position(1000.0, 90.0)
    north = polar_position(1000.0, 0.0)
    assert east == pytest.approx((1000.0, 0.0), abs=1e-9)
    assert north == pytest.approx((0.0, 1000.0), abs=1e-9)


def test_all_pairs_order_and_tensors():
    g = Geometry.all_pairs(
        [Transmitter((0.0, 0.0), 1e8), Transmitter((1e4, 0.0), 2e8)],
        [Receiver((0.0, 5e3)), Receiver((5e3, 5e3))],
    )
    assert g.pairs == ((0, 0), (0, 1), (1, 0), (1, 1))
    assert g.pair_tx_positions().shape == (4, 2)
    assert g.pair_carriers().tolist() == [1e8, 1e8, 2e8, 2e8]
    assert g.baselines_m()[3] == pytest.approx(math.hypot(5e3, 5e3))


def test_receiver_on_transmitter_is_rejected():
    with pytest.raises(GeometryError, match="placed on transmitter"):
        Geometry.all_pairs([Transmitter((10.0, 10.0), 1e8)], [Receiver((10.0, 10.5))])


def test_lifted_geometry_puts_sensors_on_the_ground():
    g = Geometry.all_pairs([Transmitter((0.0, 0.0), 1e8)], [Receiver((1.0e3, 0.0))]).lifted(3)
    assert g.dim == 3
    assert g.pair_rx_positions()[0, 2] == 0


def test_round_trip_through_dict():
    g = Geometry.all_pairs([Transmitter((0.0, 0.0), 1e8)], [Receiver((1.0e3, 2.0))])
    assert Geometry.from_dict(g.to_dict()) == g


@pytest.mark.parametrize("bad", [
    dict(transmitters=(Transmitter((0.0, 0.0), -1.0),), receivers=(Receiver((1e3, 0.0)),), pairs=((0, 0),)),
    dict(transmitters=(Transmitter((0.0, 0.0), 1e8),), receivers=(Receiver((1e3, 0.0, 0.0)),), pairs=((0, 0),)),
    dict(transmitters=(Transmitter((0.0, 0.0), 1e8),), receivers=(Receiver((1e3, 0.0)),), pairs=((0, 1),)),
    dict(transmitters=(Transmitter((float("nan"), 0.0), 1e8),), receivers=(Receiver((1e3, 0.0)),), pairs=((0, 0),)),
])
def test_invalid_geometries(bad):
    with pytest.raises(GeometryError):
        Geometry(**bad)


def test_tensors_follow_dtype():
    g = Geometry.all_pairs([Transmitter((0.0, 0.0), 1e8)], [Receiver((1.0e3, 0.0))])
    assert g.pair_tx_positions(torch.float32).dtype == torch.float32
