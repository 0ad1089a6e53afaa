"""Whole-sequence inference of a recurrent tracker (``Tracker.track(whole=True)``, option
``inference: whole_sequence`` of kind ``learned``): one causal pass over each whole sequence, no
windows, refused for networks of finite context."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from pmsr_nn.errors import ConfigError, MeasurementError
from pmsr_nn.nets.inference import Tracker

RELEASED = Path(__file__).resolve().parents[1] / "models" / "released"


@pytest.fixture(scope="module")
def flight():
    """The released KalmanNet and 260 scans (2.6 windows) of a drone in its geometry (seeded noise)."""
    tracker = Tracker.load(RELEASED / "kalmannet_s0.pt")
    model = tracker.representation.model
    K = 260
    x = torch.zeros(K, 6, dtype=torch.float64)
    x[:, 0], x[:, 3], x[:, 1] = 5000.0 - 8.0 * torch.arange(K, dtype=torch.float64), 4000.0, -8.0
    sd = torch.tensor([30.0] * 3 + [2.0] * 3 + [0.0523599] * 3, dtype=torch.float64)
    z = model.h(x) + torch.randn(K, 9, generator=torch.Generator().manual_seed(3), dtype=torch.float64) * sd
    return tracker, z, x


# float32 network: batches of other shapes sum in another order; 1e-5 relative over ~100 recurrent steps
CLOSE = {"rtol": 1e-5, "atol": 1e-4}


def test_one_window_long_sequence_is_the_same_either_way(flight):
    tracker, z, _ = flight
    w = tracker.window
    assert torch.allclose(tracker.track(z[:w], whole=True), tracker.track(z[:w]), **CLOSE)


def test_the_whole_pass_is_causal_and_remembers_past_a_window(flight):
    """The estimate at scan k reads scans 0..k only (the pass over the first k + 1 scans gives the
    same), and beyond the first window it differs from the spliced windows' (which restart)."""
    tracker, z, _ = flight
    whole = tracker.track(z, whole=True)
    for k in (tracker.window, 180, len(z) - 1):
        assert torch.allclose(tracker.track(z[:k + 1], whole=True)[k], whole[k], **CLOSE)
    spliced = tracker.track(z)
    assert torch.allclose(whole[:tracker.window], spliced[:tracker.window], **CLOSE)
    gap = (whole[tracker.window:, [0, 3]] - spliced[tracker.window:, [0, 3]]).norm(dim=-1)
    assert float(gap.max()) > 0.1  # metres: the windows restart at their first fix, the whole pass does not


def test_a_network_of_finite_context_is_refused_in_one_line(flight):
    _, z, _ = flight
    mdfnn = Tracker.load(RELEASED / "mdfnn_local_s0.pt")
    with pytest.raises(MeasurementError, match="whole-sequence inference is for recurrent networks"):
        mdfnn.track(z, whole=True)


def test_the_method_option_refuses_a_network_of_finite_context_before_anything_runs():
    from pmsr_nn.methods.single_target import _load_learned

    class Spec:
        name, checkpoint = "MDFNN local", "mdfnn_local_s0.pt"

        @staticmethod
        def option(key):
            return {"inference": "whole_sequence", "stride": None}[key]

    meta = Tracker.load(RELEASED / "mdfnn_local_s0.pt").meta

    class Context:
        device, where = "cpu", "scenario"
        geometry, labels, dt = meta["geometry"], meta["measurement_columns"], meta["dt_s"]

        @staticmethod
        def path(p):
            return RELEASED / p

    with pytest.raises(ConfigError, match="inference whole_sequence is for recurrent networks"):
        _load_learned(Spec, Context)
