"""DFNN, MDFNN and RNN trackers: ``z (B, T, dim_z) -> x (B, T, dim_x)``, both normalised.

Every network maps a measurement sequence to a state sequence of the same length, one
estimate per sample. :attr:`context` says how many samples before and after ``k`` the estimate
at ``k`` can depend on; the sliding-window inference (:mod:`pmsr_nn.nets.inference`) uses it to
splice windows without changing a single estimate.
"""

from __future__ import annotations

import torch
from torch import nn

from .config import ModelConfig
from .layers import FIRFilter

_ACTIVATIONS = {"tanh": nn.Tanh, "sigmoid": nn.Sigmoid, "relu": nn.ReLU, "gelu": nn.GELU, "identity": nn.Identity}


def activation(name: str) -> nn.Module:
    return _ACTIVATIONS[name]()


class FeedforwardTracker(nn.Module):
    """MDFNN (with filter layers) or DFNN (without), Eqs. 21-27.

    Hidden layer ``i + 1`` sees the previous hidden output and, in an MDFNN, the filter layer's
    output of it: ``h_{i+1,k} = f(W_{i+1} h_{i,k} + W_{F,i} h~_{i,k} + kappa_{i+1})``. The output
    layer is affine followed by ``output_activation``.
    """

    def __init__(self, cfg: ModelConfig, dim_z: int, dim_x: int):
        super().__init__()
        self.cfg = cfg
        sizes = (dim_z, *cfg.hidden)
        self.hidden = nn.ModuleList(nn.Linear(a, b) for a, b in zip(sizes[:-1], sizes[1:]))
        self.act = activation(cfg.activation)
        self.drop = nn.Dropout(cfg.dropout)
        use_filters = cfg.kind == "mdfnn"
        # Filter layer i filters hidden layer i and feeds hidden layer i + 1 through W_{F,i}.
        self.filters = nn.ModuleList(
            FIRFilter(w, cfg.filter_order, cfg.filter_window, cfg.filter_taps) for w in cfg.hidden[:-1]
        ) if use_filters else nn.ModuleList()
        self.filter_in = nn.ModuleList(
            nn.Linear(a, b, bias=False) for a, b in zip(cfg.hidden[:-1], cfg.hidden[1:])
        ) if use_filters else nn.ModuleList()
        self.out = nn.Linear(cfg.hidden[-1], dim_x)
        self.out_act = activation(cfg.output_activation)

    @property
    def context(self) -> tuple[int | None, int]:
        """(behind, ahead): samples on either side of ``k`` the estimate at ``k`` reads."""
        behind = sum(f.extent[0] for f in self.filters)
        ahead = sum(f.extent[1] for f in self.filters)
        return behind, ahead

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        h = self.drop(self.act(self.hidden[0](z)))
        for i, layer in enumerate(self.hidden[1:]):
            pre = layer(h)
            if self.filters:
                pre = pre + self.filter_in[i](self.filters[i](h))
            h = self.drop(self.act(pre))
        return self.out_act(self.out(h))


class RecurrentTracker(nn.Module):
    """A recurrent baseline: an RNN / LSTM / GRU over the sequence and an affine read-out.

    Causal with unbounded memory (``context == (None, 0)``); the state starts at zero at the
    start of every sequence it is given.
    """

    def __init__(self, cfg: ModelConfig, dim_z: int, dim_x: int):
        super().__init__()
        self.cfg = cfg
        cell = {"rnn": nn.RNN, "lstm": nn.LSTM, "gru": nn.GRU}[cfg.rnn_cell]
        self.rnn = cell(dim_z, cfg.rnn_hidden, num_layers=cfg.rnn_layers, batch_first=True,
                        dropout=cfg.dropout if cfg.rnn_layers > 1 else 0.0)
        self.out = nn.Linear(cfg.rnn_hidden, dim_x)
        self.out_act = activation(cfg.output_activation)

    @property
    def context(self) -> tuple[int | None, int]:
        return None, 0

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        h, _ = self.rnn(z)
        return self.out_act(self.out(h))


def build_network(cfg: ModelConfig, dim_z: int, dim_x: int, representation=None, dt: float | None = None) -> nn.Module:
    """The network ``cfg`` describes, for ``dim_z`` measurement rows and ``dim_x`` states.

    Its input width follows ``cfg.inputs``; with ``output: residual`` the read-out starts at zero
    (an untrained network returns the base, the state fixes, exactly). A KalmanNet also needs
    its ``representation`` (measurement model and scales) and the sampling interval ``dt`` (s)."""
    dim_in = cfg.input_dim(dim_z, dim_x)
    if cfg.kind == "kalmannet":
        from .kalmannet import KalmanNetTracker

        if representation is None or dt is None:
            raise ValueError("a KalmanNet needs the representation and dt it was trained with")
        return KalmanNetTracker(cfg, representation.model, dt, representation.noise_scale, representation.residual_scale)
    net = RecurrentTracker(cfg, dim_in, dim_x) if cfg.kind == "rnn" else FeedforwardTracker(cfg, dim_in, dim_x)
    if cfg.output == "residual":
        nn.init.zeros_(net.out.weight)
        nn.init.zeros_(net.out.bias)
    return net
