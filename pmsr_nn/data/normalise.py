"""Min-max normalisation to [-1, 1] (Section 3.1 of the MDFNN paper), fitted on training data only."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch


@dataclass(frozen=True)
class MinMaxScaler:
    """Per-column affine map ``x -> 2 (x - lo) / (hi - lo) - 1`` and its inverse.

    ``lo`` and ``hi`` are ``(D,)`` tensors in the data's physical units. A constant column
    (``hi == lo``, e.g. the vertical states of level flight) is only shifted.
    """

    lo: torch.Tensor
    hi: torch.Tensor

    @property
    def span(self) -> torch.Tensor:
        s = self.hi - self.lo
        return torch.where(s > 0, s, torch.ones_like(s))

    def normalise(self, x: torch.Tensor) -> torch.Tensor:
        lo, span = self.lo.to(x), self.span.to(x)
        return 2.0 * (x - lo) / span - 1.0

    def denormalise(self, y: torch.Tensor) -> torch.Tensor:
        lo, span = self.lo.to(y), self.span.to(y)
        return (y + 1.0) * 0.5 * span + lo

    def to_dict(self) -> dict:
        return {"min": self.lo.tolist(), "max": self.hi.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "MinMaxScaler":
        return cls(torch.tensor(d["min"], dtype=torch.float64), torch.tensor(d["max"], dtype=torch.float64))


class RunningMinMax:
    """Accumulates per-column minima and maxima over chunks ``(..., D)`` (NumPy, float64)."""

    def __init__(self, dim: int):
        self.lo = np.full(dim, np.inf)
        self.hi = np.full(dim, -np.inf)

    def update(self, x: np.ndarray) -> None:
        if x.size:
            flat = x.reshape(-1, x.shape[-1])
            self.lo = np.minimum(self.lo, flat.min(0))
            self.hi = np.maximum(self.hi, flat.max(0))

    def scaler(self) -> MinMaxScaler:
        return MinMaxScaler(torch.from_numpy(self.lo.copy()), torch.from_numpy(self.hi.copy()))
