"""Networks, the FIR filter layer and the sliding-window splice, against closed forms."""

import pytest
import torch

from pmsr_nn.errors import MeasurementError
from pmsr_nn.nets.config import ModelConfig
from pmsr_nn.nets.inference import fill_missing, splice_plan
from pmsr_nn.nets.layers import FIRFilter
from pmsr_nn.nets.networks import build_network


def fir_by_hand(h, taps, behind, ahead):
    """h~_k = sum_j taps[:, j] * h_{k + ahead - j}, zeros outside the sequence."""
    B, T, C = h.shape
    M = taps.shape[-1]
    out = torch.zeros_like(h)
    for k in range(T):
        for j in range(M):
            src = k + ahead - j
            if 0 <= src < T:
                out[:, k] += taps[:, j] * h[:, src]
    return out


@pytest.mark.parametrize("window", ["causal", "centred"])
@pytest.mark.parametrize("taps", ["shared", "per_channel"])
def test_fir_layer_matches_the_sum_it_defines(window, taps):
    g = torch.Generator().manual_seed(0)
    layer = FIRFilter(4, 5, window, taps).double()
    with torch.no_grad():
        layer.taps.copy_(torch.randn(layer.taps.shape, generator=g, dtype=torch.float64))
    h = torch.randn(3, 11, 4, generator=g, dtype=torch.float64)
    behind, ahead = layer.extent
    assert behind + ahead == 4
    torch.testing.assert_close(layer(h), fir_by_hand(h, layer.taps.detach(), behind, ahead), rtol=0, atol=1e-12)


def test_untrained_fir_layer_is_a_moving_average_padded_with_zeros():
    layer = FIRFilter(1, 4).double()
    h = torch.ones(1, 6, 1, dtype=torch.float64)
    assert layer(h)[0, :, 0].tolist() == pytest.approx([0.25, 0.5, 0.75, 1.0, 1.0, 1.0])


def _net(**kw):
    torch.manual_seed(0)
    cfg = ModelConfig(**{"hidden": (16, 12, 16), "filter_order": 4, **kw})
    return build_network(cfg, 9, 6).double().eval()


@pytest.mark.parametrize("kw", [{"kind": "mdfnn"}, {"kind": "mdfnn", "filter_window": "centred"},
                                {"kind": "dfnn"}, {"kind": "rnn", "rnn_hidden": 8}, {"kind": "rnn", "rnn_cell": "gru", "rnn_hidden": 8}])
def test_estimate_at_k_reads_exactly_its_stated_context(kw):
    """Perturbing z outside [k - behind, k + ahead] leaves the estimate at k unchanged; inside, it moves it."""
    net = _net(**kw)
    behind, ahead = net.context
    g = torch.Generator().manual_seed(1)
    z = torch.randn(1, 30, 9, generator=g, dtype=torch.float64)
    k = 20
    base = net(z)[0, k]
    for j in range(30):
        zp = z.clone()
        zp[0, j] += 1.0
        moved = not torch.allclose(net(zp)[0, k], base, rtol=0, atol=1e-12)
        inside = (behind is None or j >= k - behind) and j <= k + ahead
        assert moved == inside, (j, behind, ahead)


def test_mdfnn_context_is_M_minus_1_per_filter_layer():
    assert _net().context == (2 * 3, 0)
    assert _net(filter_window="centred").context == (2 * 1, 2 * 2)
    assert _net(kind="dfnn").context == (0, 0)
    assert ModelConfig(filter_window="centred").looks_ahead and not ModelConfig().looks_ahead


def test_table_2_sizes_by_default():
    net = build_network(ModelConfig(), 9, 6)
    assert [l.out_features for l in net.hidden] == [384, 225, 540]
    assert [f.channels for f in net.filters] == [384, 225] and all(f.order == 20 for f in net.filters)
    assert net.out.out_features == 6


@pytest.mark.parametrize("steps,window,stride", [(50, 20, 1), (50, 20, 7), (57, 20, 20), (20, 20, 5)])
def test_splice_plan_covers_every_sample_once_from_a_window_that_holds_it(steps, window, stride):
    starts, which, off = splice_plan(steps, window, stride, (6, 0))
    assert starts[0] == 0 and starts[-1] == steps - window
    assert ((off >= 0) & (off < window)).all()
    assert torch.equal(starts[which] + off, torch.arange(steps))


def test_splice_plan_refuses_a_sequence_shorter_than_the_window():
    with pytest.raises(MeasurementError, match="shorter than the network's window"):
        splice_plan(10, 20, 1, (0, 0))


def test_hold_carries_the_last_valid_scan_and_error_names_the_row():
    z = torch.arange(12.0).reshape(1, 4, 3)
    z[0, 2, 1] = float("nan")
    held = fill_missing(z, "hold")
    assert torch.equal(held[0, 2], z[0, 1]) and torch.equal(held[0, 3], z[0, 3])
    with pytest.raises(MeasurementError, match="row 2 of sequence 0"):
        fill_missing(z, "error")
    z[0, 0, 0] = float("nan")
    with pytest.raises(MeasurementError, match="starts with a NaN"):
        fill_missing(z, "hold")
