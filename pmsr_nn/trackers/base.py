"""What every tracker returns to the harness: labelled estimates per run and scan.

A single-target filter, a learned tracker and a multi-target tracker all answer with
:class:`Estimates`: ``N`` labelled slots (track ids ``0..N-1``) per run and scan, each with a
mean, optionally a covariance, and whether the slot holds a track at that scan. Method-specific
diagnostics (the JPDA's loss-rule flags, a relaxation's duality gap) travel in ``extras``, so
the harness never reads a field only one tracker has.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch


@dataclass
class Estimates:
    """``x (B, K, N, n)`` means (float64, SI), ``P (B, K, N, n, n)`` covariances or ``None``,
    ``exists (B, K, N)`` bool (the slot holds a track at that scan; ``x`` there is meaningless
    otherwise), ``extras`` named diagnostics (tensors or floats) a metric may read."""

    x: torch.Tensor
    exists: torch.Tensor
    P: torch.Tensor | None = None
    extras: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        B, K, N, n = self.x.shape
        if tuple(self.exists.shape) != (B, K, N):
            raise ValueError(f"exists must be (B, K, N) = {(B, K, N)}, got {tuple(self.exists.shape)}")
        if self.P is not None and tuple(self.P.shape) != (B, K, N, n, n):
            raise ValueError(f"P must be (B, K, N, n, n) = {(B, K, N, n, n)}, got {tuple(self.P.shape)}")

    @property
    def labels(self) -> torch.Tensor:
        """Track ids ``(N,)``: slot ``i`` is track ``i`` for the whole run."""
        return torch.arange(self.x.shape[2])
