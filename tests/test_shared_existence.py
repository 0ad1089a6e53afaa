"""The association probabilities that JIPDA-style existence and association-probability seeding
read (pmsr_nn.trackers.jpda_associators): each against its closed form for one detection and one
or two tracks, where the JPDA events can be written out by hand."""

from __future__ import annotations

import math

import pytest
import torch

from pmsr_nn.filters import Gaussian
from pmsr_nn.geometry import Geometry, Receiver, Transmitter
from pmsr_nn.measurements import MeasurementModel
from pmsr_nn.motion import ConstantVelocity
from pmsr_nn.trackers.gating import gate_threshold
from pmsr_nn.trackers.jpda import miss_cost
from pmsr_nn.trackers.jpda_associators import ParallelJPDA, SequentialJPDA, pair_update
from pmsr_nn.trackers.msjpda import JPDASettings

MOTION = ConstantVelocity(2)
PD, DENSITY = 0.85, 1e-6


def model(n_tx=1) -> MeasurementModel:
    tx = [Transmitter((20e3, 0.0), 100e6), Transmitter((0.0, 25e3), 100e6)][:n_tx]
    return MeasurementModel(Geometry.all_pairs(tx, [Receiver((0.0, 0.0))]), ("range", "doppler"), (100.0, 1.0),
                            MOTION.pos_idx, MOTION.vel_idx, layout="pair")


def tracks(*positions) -> Gaussian:
    """Tracks at ``positions`` (x, y) moving at (20, 0) m/s, deviations 200 m and 5 m/s: ``(1, C, 4)``."""
    x = torch.tensor([[[px, 20.0, py, 0.0] for px, py in positions]], dtype=torch.float64)
    P = torch.diag(torch.tensor([200.0**2, 25.0, 200.0**2, 25.0], dtype=torch.float64)).expand(*x.shape[:2], 4, 4)
    return Gaussian(x, P.clone())


def detections(m: MeasurementModel, *states) -> tuple[torch.Tensor, torch.Tensor]:
    """The noiseless measurements of ``states`` (x, vx, y, vy) at every pair: ``z (1, S, M, d)``."""
    x = torch.tensor(states, dtype=torch.float64)
    S, d = m.n_pairs, len(m.components)
    z = m.h(x).reshape(len(states), S, d).transpose(0, 1)[None]
    return z, torch.ones(z.shape[:3], dtype=torch.bool)


def step(g, z, valid, m, association="jpda"):
    gamma = gate_threshold(1 - 1e-9, 2)
    return pair_update(g, z[:, 0], valid[:, 0], m.for_pairs([0]), m.R(), PD, DENSITY, 50, gamma,
                       association=association)


@pytest.mark.parametrize("association", ["jpda", "pda"])
def test_a_lone_track_s_shared_ratio_is_the_ipda_ratio(association):
    m = model()
    g = tracks((5000.0, 5000.0))
    z, valid = detections(m, [5100.0, 20.0, 5000.0, 0.0], [4800.0, 20.0, 5300.0, 0.0], [5000.0, 22.0, 4900.0, 0.0])
    st = step(g, z, valid, m, association)
    assert bool(st.gated.all())
    assert float(st.ratio[0, 0]) > 1.0
    assert float(st.shared_ratio[0, 0]) == pytest.approx(float(st.ratio[0, 0]), rel=1e-9)


def test_two_tracks_on_one_detection_share_it_as_worked_by_hand():
    """One detection, tracks A and B gate it. The events: A takes it (weight Pd r_A q), B takes it
    (Pd r_B q), neither (q^2), with q = 1 - Pd and r the likelihood over the clutter density (the
    ``ratio``). B's probability of no detection is (Pd r_A q + q^2) / sum, so its shared ratio
    ``q / Pd * beta_B / beta_0B = r_B / (1 + Pd r_A / q)``: its ratio with A's likelihood added to
    the clutter's; the detection is some track's with probability Pd (r_A + r_B) / (q + Pd (r_A + r_B))."""
    m = model()
    z, valid = detections(m, [5000.0, 20.0, 5000.0, 0.0])
    st = step(tracks((5000.0, 5050.0), (5200.0, 4700.0)), z, valid, m)
    assert bool(st.gated.all())
    q = math.exp(-miss_cost(PD))
    assert q == pytest.approx(1 - PD)
    rA, rB = (float(r) for r in st.ratio[0])
    assert rA > 2 * rB > 0  # A is nearer
    shared = st.shared_ratio[0].tolist()
    assert shared[0] == pytest.approx(rA / (1 + PD * rB / q), rel=1e-9)
    assert shared[1] == pytest.approx(rB / (1 + PD * rA / q), rel=1e-9)
    assert shared[1] < rB / 10  # B, which only shares A's detection, falls far below its bare ratio
    assert float(st.taken[0, 0]) == pytest.approx(PD * (rA + rB) / (q + PD * (rA + rB)), rel=1e-9)


def test_the_parallel_associator_gives_the_sequential_probabilities_with_one_pair():
    """With one pair P-MSJPDA's (S+1)-D events are the 2-D ones."""
    m = model()
    z, valid = detections(m, [5000.0, 20.0, 5000.0, 0.0], [5300.0, 20.0, 5100.0, 0.0])
    g = tracks((5000.0, 5050.0), (5200.0, 4700.0))
    settings = JPDASettings(PD, DENSITY, m_best=50, gate_probability=1 - 1e-9)
    seq = SequentialJPDA(m, m.R(), settings).associate(g, z, valid, None)
    par = ParallelJPDA(m, m.R(), settings).associate(g, z, valid, None)
    assert bool(seq.explained.all())
    torch.testing.assert_close(par.taken, seq.taken, rtol=1e-9, atol=1e-12)
    torch.testing.assert_close(par.shared_ratio, seq.shared_ratio, rtol=1e-9, atol=1e-12)
    assert bool((seq.shared_ratio < seq.ratio).all())
