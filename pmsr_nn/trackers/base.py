"""What every tracker returns to the harness: labelled estimates per run and scan.

A single-target filter, a learned tracker and a multi-target tracker all answer with
:class:`Estimates`: ``M`` labelled slots (track ids ``0..M-1``) per run and scan, each with a
mean, optionally a covariance, and whether the slot holds a track at that scan. Method-specific
diagnostics (the JPDA's loss-rule flags, a relaxation's duality gap) travel in ``extras``, read
only by the metrics the method's kind declares (:mod:`pmsr_nn.methods.kind_metrics`), so the
harness never reads a field only one tracker has.

Two kinds of slots:

* ``paired=True``: slot ``i`` is target ``i``'s track for the whole run (``M = N``). Single-target
  methods on each target's own stream and trackers handed their targets' births (the *oracle
  initiator*) answer so, and are scored against their own target.
* ``paired=False``: the slots are tracks the tracker started itself (``M`` is the most it kept in
  any run; a slot holds one track id for the whole run and never a second). ``exists`` is where
  the track is *reported* (confirmed and not yet deleted); scoring matches reported tracks to
  the living targets scan by scan (:mod:`pmsr_nn.metrics.tracks`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch


@dataclass
class Estimates:
    """``x (B, K, M, n)`` means (float64, SI), ``P (B, K, M, n, n)`` covariances or ``None``,
    ``exists (B, K, M)`` bool (the slot holds a reported track at that scan; ``x`` there is
    meaningless otherwise), ``extras`` named diagnostics (tensors or floats) a metric may read,
    ``paired`` whether slot ``i`` is target ``i`` (module docstring) and ``existence (B, K, M)``
    the track's existence probability where the tracker carries one."""

    x: torch.Tensor
    exists: torch.Tensor
    P: torch.Tensor | None = None
    extras: dict = field(default_factory=dict)
    paired: bool = True
    existence: torch.Tensor | None = None

    def __post_init__(self) -> None:
        B, K, M, n = self.x.shape
        if tuple(self.exists.shape) != (B, K, M):
            raise ValueError(f"exists must be (B, K, M) = {(B, K, M)}, got {tuple(self.exists.shape)}")
        if self.P is not None and tuple(self.P.shape) != (B, K, M, n, n):
            raise ValueError(f"P must be (B, K, M, n, n) = {(B, K, M, n, n)}, got {tuple(self.P.shape)}")
        if self.existence is not None and tuple(self.existence.shape) != (B, K, M):
            raise ValueError(f"existence must be (B, K, M) = {(B, K, M)}, got {tuple(self.existence.shape)}")

    def to(self, device: torch.device | str) -> "Estimates":
        """The same estimates on ``device``, their tensor ``extras`` too."""
        extras = {k: v.to(device) if isinstance(v, torch.Tensor) else v for k, v in self.extras.items()}
        move = lambda t: None if t is None else t.to(device)  # noqa: E731
        return Estimates(self.x.to(device), self.exists.to(device), move(self.P), extras, self.paired,
                         move(self.existence))

    @property
    def labels(self) -> torch.Tensor:
        """Track ids ``(M,)``: slot ``i`` is track ``i`` for the whole run."""
        return torch.arange(self.x.shape[2], device=self.x.device)
