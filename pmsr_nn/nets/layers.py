"""The FIR filter layer of the MDFNN (Eqs. 22-23 and Fig. 4b of the MDFNN paper).

A filter layer turns the hidden outputs ``h_1 .. h_k`` of the previous layer into
``h~_k = sum_{j=0}^{M-1} c_j h_{k-j}``: a finite impulse response of order ``M`` along time,
with learnable taps ``c``. Before the sequence start the layer sees zeros (Eq. 23 pads
``c_k`` with zeros for ``k < M``). The paper shares one set of taps over all channels; a
per-channel set is an option. A *centred* window (``h~_k`` from ``h_{k-M/2} .. h_{k+M/2}``)
looks ahead in time and so makes the network a smoother, not a filter.
"""

from __future__ import annotations

from typing import Literal

import torch
import torch.nn.functional as F
from torch import nn

Window = Literal["causal", "centred"]


def window_extent(order: int, window: Window) -> tuple[int, int]:
    """Samples a filter of ``order`` taps reads (behind, ahead) of the current one."""
    if window == "causal":
        return order - 1, 0
    behind = (order - 1) // 2
    return behind, order - 1 - behind


class FIRFilter(nn.Module):
    """``(B, T, C) -> (B, T, C)``: an order-``M`` FIR filter along time, one per channel.

    ``taps='shared'`` learns ``M`` coefficients used by every channel (the paper's ``c``);
    ``'per_channel'`` learns ``(C, M)``. The taps start as a moving average (``1/M``), so an
    untrained layer passes a smoothed copy of its input. Tap ``j`` multiplies the sample ``j``
    steps behind the newest one the window reads.
    """

    def __init__(self, channels: int, order: int, window: Window = "causal",
                 taps: Literal["shared", "per_channel"] = "shared"):
        super().__init__()
        if order < 1:
            raise ValueError(f"filter order must be at least 1, got {order}")
        self.channels, self.order, self.window = channels, order, window
        rows = 1 if taps == "shared" else channels
        self.taps = nn.Parameter(torch.full((rows, order), 1.0 / order))

    @property
    def extent(self) -> tuple[int, int]:
        return window_extent(self.order, self.window)

    def forward(self, h: torch.Tensor) -> torch.Tensor:
        behind, ahead = self.extent
        x = F.pad(h.transpose(1, 2), (behind, ahead))  # (B, C, T + M - 1), zeros outside the sequence
        # conv1d correlates: weight[..., i] meets the i-th oldest sample of the window, so the
        # taps are flipped to make taps[:, j] act on the sample j steps behind the newest.
        w = self.taps.flip(-1).expand(self.channels, -1).unsqueeze(1)
        return F.conv1d(x, w, groups=self.channels).transpose(1, 2)
