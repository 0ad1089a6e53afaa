"""The roles a multi-target tracker is assembled from, and what they hand each other.

One batched loop (:func:`~.loop.run_tracker`) runs every tracker that keeps tracks, scan by scan:

    predict -> associate and update -> existence -> manage -> initiate -> report

Two roles fill it (Stone Soup's initiator / deleter / data associator / updater, batched over
runs and track slots):

* an :class:`Associator` (with its updater inside: the sigma-point moments, and a learned
  :class:`MeanCorrection` where a hybrid has one) associates one scan's detections with the
  tracks and updates them: :class:`AssociationStep`;
* a :class:`TrackManagement` holds the tracks and, around the association, predicts their
  existence, confirms and deletes them and starts new ones (its initiator, confirmer and deleter
  are components of :mod:`.management`); handing a tracker its targets' births is one such
  management (:class:`~.handed_births.HandedBirths`), starting its own tracks another
  (:class:`~.own_tracks.OwnTracks`).

Shapes: ``B`` runs, ``C`` track slots, ``S`` pairs, ``M`` detections per list, ``n`` state
dimension, ``d`` measurement components per pair.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import torch

from ..filters.gaussian import Gaussian


@dataclass
class AssociationStep:
    """What one scan's association and update give each track slot.

    ``posterior`` the updated tracks ``(B, C, n)``; ``detected (B, C)`` at how many pairs the
    likeliest association was a detection; ``miss_likeliest (B, C)`` no detection was the
    likeliest association at any pair (the loss rule of Lyu & Wang); ``gated (B, C, S, M)`` the
    detections inside each track's gate; ``ratio (B, C, S)`` each pair's summed likelihood of
    the gated detections over the clutter density (the IPDA existence update's); ``whitened
    (B, C, S, d)`` each pair's whitened combined innovation ``L^-1 sum_i alpha_i nu_i`` (None
    where the associator does not form one: the innovation bias test's); ``range_sd_m (B, C)``
    the largest predicted bistatic-range deviation over the pairs (R included); ``duality_gap``
    the largest Lagrangian-relaxation duality gap met (nats; 0 for exact events)."""

    posterior: Gaussian
    detected: torch.Tensor
    miss_likeliest: torch.Tensor
    gated: torch.Tensor
    ratio: torch.Tensor
    range_sd_m: torch.Tensor
    whitened: torch.Tensor | None = None
    duality_gap: float = 0.0

    @property
    def explained(self) -> torch.Tensor:
        """``(B, S, M)``: the detections some track gated (they start no new track)."""
        return self.gated.any(1)


class MeanCorrection(Protocol):
    """A learned part of the updater (:class:`~pmsr_nn.trackers.learned_gain.GainCorrection`):
    a correction of each track's updated mean from one pair's association, with a memory per
    slot."""

    confirmed_only: bool

    def start(self, B: int, C: int) -> None: ...

    def step(self, pair: int, w: torch.Tensor, nu: torch.Tensor, gate: torch.Tensor, mom,
             active: torch.Tensor | None) -> torch.Tensor: ...

    def forget(self, where: torch.Tensor) -> None: ...


class Associator(Protocol):
    """Associates one scan's detections ``z (B, S, M, d)`` (``valid (B, S, M)``) with the tracks
    ``g (B, C, n)`` and updates them. Only the slots ``associating (B, C)`` gate detections
    (None: every slot); a learned correction acts on ``learned (B, C)`` (None: the associating
    slots)."""

    correction: MeanCorrection | None

    def associate(self, g: Gaussian, z: torch.Tensor, valid: torch.Tensor, associating: torch.Tensor | None,
                  learned: torch.Tensor | None = None) -> AssociationStep: ...


class TrackManagement(Protocol):
    """Holds a tracker's tracks and manages them around the association (module docstring).

    :meth:`begin` once, then every scan ``k``: :meth:`predicted` after the loop's prediction of
    :attr:`g` (``k > 0``), :meth:`associating` and :meth:`learned` before the association,
    :meth:`updated` after it; :meth:`result` at the end."""

    g: Gaussian

    def begin(self, B: int, K: int) -> None: ...

    def predicted(self, k: int) -> None: ...

    def associating(self, k: int) -> torch.Tensor | None: ...

    def learned(self, correction: MeanCorrection | None) -> torch.Tensor | None: ...

    def updated(self, k: int, step: AssociationStep, z: torch.Tensor, valid: torch.Tensor,
                correction: MeanCorrection | None) -> None: ...

    def result(self): ...
