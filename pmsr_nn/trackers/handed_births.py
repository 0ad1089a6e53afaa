"""Handing a tracker its targets' births (the *oracle initiator*): one track slot per target,
started at the target's birth from its initiation prior ("the true state plus some random noise",
Lyu & Wang 2019), associating only while the target lives.

A :class:`~.roles.TrackManagement` of :func:`~.loop.run_tracker`: no confirmation, no deletion,
no existence; slot ``t`` is target ``t``'s track for the whole run. A reference row, named so in
every report. Shapes: ``B`` runs, ``K`` scans, ``N`` targets, ``n`` state dimension.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..errors import ConfigError
from ..filters.gaussian import Gaussian
from .roles import AssociationStep


@dataclass
class MultiTargetResult:
    """Per scan and track: means ``x (B, K, N, n)``, covariances ``P (B, K, N, n, n)``,
    ``dummy_most_probable (B, K, N)`` (no detection was the likeliest association at every
    pair), ``gate_range_sd_m (B, K, N)`` (largest predicted bistatic-range deviation over the
    pairs, R included) and, for P-MSJPDA, the largest relaxation duality gap met (nats)."""

    x: torch.Tensor
    P: torch.Tensor
    dummy_most_probable: torch.Tensor
    gate_range_sd_m: torch.Tensor
    max_duality_gap: float = 0.0


def lifespans(active: torch.Tensor | None, B: int, K: int, N: int) -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """``active`` as ``(B, K, N)`` and each target's first active scan ``(B, N)`` (``K`` if never);
    ``(None, None)`` where every target lives at every scan."""
    if active is None:
        return None, None
    if active.shape not in ((K, N), (B, K, N)):
        raise ConfigError(f"active must be (K={K}, N={N}) or (B={B}, K, N), got {tuple(active.shape)}")
    active = active.expand(B, K, N)
    first = torch.where(active.any(1), active.to(torch.int64).argmax(1),
                        torch.full((B, N), K, device=active.device))
    return active, first


class HandedBirths:
    """The management of a tracker handed its targets' births (module docstring).

    ``prior`` the initiation priors ``x (B, N, n)`` (each the state at its target's first active
    scan); ``active (K, N)`` or ``(B, K, N)`` each target's life (None: every target at every
    scan). A slot outside its target's life is only predicted (its estimates there mean nothing);
    at the first active scan it restarts from its prior."""

    started = None  # no track starts from the detections

    def __init__(self, prior: Gaussian, active: torch.Tensor | None = None):
        self.prior, self.active_in = prior, active

    def begin(self, B: int, K: int, F: torch.Tensor | None = None, Q: torch.Tensor | None = None) -> None:
        N, n = self.prior.x.shape[1:]
        self.active, self.first = lifespans(self.active_in, B, K, N)
        self.g = self.prior
        new = self.prior.x.new_empty
        self.x, self.P, self.gate_sd = new(B, K, N, n), new(B, K, N, n, n), new(B, K, N)
        self.dummy = torch.zeros(B, K, N, dtype=torch.bool, device=self.prior.x.device)
        self.gap = 0.0

    def predicted(self, k: int) -> None:
        if self.first is not None and bool((self.first == k).any()):
            born = self.first == k
            self.g = Gaussian(torch.where(born[..., None], self.prior.x, self.g.x),
                              torch.where(born[..., None, None], self.prior.P, self.g.P))

    def associating(self, k: int) -> torch.Tensor | None:
        return None if self.active is None else self.active[:, k]

    def updated(self, k: int, step: AssociationStep, z: torch.Tensor, valid: torch.Tensor) -> None:
        self.g = step.posterior
        self.x[:, k], self.P[:, k] = self.g.x, self.g.P
        self.dummy[:, k] = step.miss_likeliest
        self.gate_sd[:, k] = step.range_sd_m
        self.gap = max(self.gap, step.duality_gap)

    def result(self) -> MultiTargetResult:
        return MultiTargetResult(self.x, self.P, self.dummy, self.gate_sd, self.gap)
