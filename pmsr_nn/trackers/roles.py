"""The roles a multi-target tracker is assembled from, and what they hand each other.

One batched loop (:func:`~.loop.run_tracker`) runs every tracker that keeps tracks, scan by scan:

    predict -> associate and update -> existence -> manage -> initiate -> report

Two roles fill it (Stone Soup's initiator / deleter / data associator / updater, batched over
runs and track slots):

* an :class:`Associator` (with its updater inside: the sigma-point moments) associates one scan's detections with the
  tracks and updates them: :class:`AssociationStep`;
* a :class:`TrackManagement` holds the tracks and, around the association, predicts their
  existence, confirms and deletes them and starts new ones (its :class:`Initiator`, confirmer and
  deleter are components of :mod:`.management`); handing a tracker its targets' births is one such
  management (:class:`~.handed_births.HandedBirths`), starting its own tracks another
  (:class:`~.own_tracks.OwnTracks`).

Shapes: ``B`` runs, ``C`` track slots, ``S`` pairs, ``M`` detections per list, ``n`` state
dimension, ``d`` measurement components per pair.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import torch

from ..filters.gaussian import Gaussian, predict


@dataclass
class AssociationStep:
    """What one scan's association and update give each track slot.

    ``posterior`` the updated tracks ``(B, C, n)``; ``detected (B, C)`` at how many pairs the
    likeliest association was a detection; ``ratio (B, C, S)`` each pair's summed likelihood of
    the associated detections over the clutter density (the IPDA existence update's); ``explained
    (B, L, M)`` the detections of each of the scan's ``L`` lists that a track explains (they start
    no new track; ``L = S`` for per-pair lists).

    Where the associator forms them: ``miss_likeliest (B, C)`` no detection was the likeliest
    association at any pair (the loss rule of Lyu & Wang); ``range_sd_m (B, C)`` the largest
    predicted bistatic-range deviation over the pairs (R included); ``whitened (B, C, S, d)`` each
    pair's whitened combined innovation ``L^-1 sum_i alpha_i nu_i`` (the innovation bias test's);
    ``duality_gap`` the largest Lagrangian-relaxation duality gap met (nats; 0 for exact events);
    ``reported`` the tracks to report at this scan where they are not the posterior (a smoother's
    smoothed states); ``taken (B, L, M)`` the probability that each detection is some track's (the
    association probabilities summed over the tracks); ``shared_ratio (B, C, S)`` the JIPDA-style
    counterpart of ``ratio``: the association probabilities' odds of a detection against none,
    ``(1 - Pd) / Pd * (1 - beta_0) / beta_0`` (``beta_0`` the track's probability of no detection
    at the pair), which equals ``ratio`` for a track that competes for no detection and falls
    below it where another track takes the detections."""

    posterior: Gaussian
    detected: torch.Tensor
    ratio: torch.Tensor
    explained: torch.Tensor
    miss_likeliest: torch.Tensor | None = None
    range_sd_m: torch.Tensor | None = None
    whitened: torch.Tensor | None = None
    duality_gap: float = 0.0
    reported: Gaussian | None = None
    taken: torch.Tensor | None = None
    shared_ratio: torch.Tensor | None = None


class Associator:
    """The association and update of one scan (a base: subclasses write :meth:`associate`).

    :meth:`predict` takes the tracks to scan ``k`` (the motion model's ``F``, ``Q``; a windowed
    smoother overrides it), :meth:`associate` associates that scan's detections ``z (B, L, M, d)``
    (``valid (B, L, M)``) with the tracks ``g (B, C, n)`` and updates them: only the slots
    ``associating (B, C)`` gate detections (None: every slot). :meth:`tracks_started` hears of the tracks
    the management started at the scan (``started (B, C)``, their Gaussians in ``g``)."""

    def predict(self, g: Gaussian, k: int, F: torch.Tensor, Q: torch.Tensor) -> Gaussian:
        return predict(g, F, Q)

    def associate(self, g: Gaussian, z: torch.Tensor, valid: torch.Tensor,
                  associating: torch.Tensor | None) -> AssociationStep:
        raise NotImplementedError

    def tracks_started(self, started: torch.Tensor | None, g: Gaussian) -> None:
        """Nothing to do for an associator that keeps no state of its own per track."""


class Initiator(Protocol):
    """Starts tentative tracks from the detections no track explains (:mod:`.initiators`:
    :class:`~.fix_initiator.FixInitiator`, :class:`~.spherical_initiator.SphericalInitiator`; and
    :class:`~.multi_scan_initiator.MultiScanInitiator`, which wraps one of them and keeps its
    candidates across scans).

    :meth:`check` refuses, in one line, a measurement model it can not start tracks from;
    :meth:`begin` starts a batch of ``B`` runs (``F``, ``Q`` ``(n, n)`` one scan's motion; a
    single-scan initiator keeps nothing); :meth:`initiate`, called at every scan after
    :meth:`begin` (with no unused detection too), gives tracks ``(B, G, n)`` and which are real
    ``(B, G)`` from ``z (B, L, M, d)`` where ``unused (B, L, M)`` (``other_sd (n,)`` the
    deviations of the state entries it does not fix; keywords: what else it reads, e.g. the
    ``routes`` of lists pooled per receiver)."""

    def check(self, model, what: str) -> None: ...

    def begin(self, B: int, F: torch.Tensor | None, Q: torch.Tensor | None) -> None: ...

    def initiate(self, z: torch.Tensor, unused: torch.Tensor, model, n: int, other_sd: torch.Tensor,
                 **where) -> tuple[Gaussian, torch.Tensor]: ...


class TrackManagement(Protocol):
    """Holds a tracker's tracks and manages them around the association (module docstring).

    :meth:`begin` once (``B`` runs, ``K`` scans, ``F``, ``Q`` one scan's motion, which an
    initiator that keeps candidates across scans predicts them with), then every scan ``k``: :meth:`predicted` after the loop's prediction of
    :attr:`g` (``k > 0``), :meth:`associating` before the association,
    :meth:`updated` after it, which sets :attr:`started` (the slots ``(B, C)`` it started tracks
    in, None: none); :meth:`result` at the end."""

    g: Gaussian
    started: torch.Tensor | None

    def begin(self, B: int, K: int, F: torch.Tensor, Q: torch.Tensor) -> None: ...

    def predicted(self, k: int) -> None: ...

    def associating(self, k: int) -> torch.Tensor | None: ...

    def updated(self, k: int, step: AssociationStep, z: torch.Tensor, valid: torch.Tensor) -> None: ...

    def result(self): ...
