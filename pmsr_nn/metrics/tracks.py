"""Track-level scores of trackers that start and delete their own tracks, from the per-scan assignment.

Conventions: ``assignment (..., K, M)`` int is the per-scan optimal assignment of
:func:`pmsr_nn.metrics.sets.optimal_assignment` / :func:`~pmsr_nn.metrics.sets.set_scores` (truth
index of each track slot at each scan, -1 unassigned; a pair at distance ``>= c`` is unassigned),
``exists (..., K, M)`` bool where each slot holds a reported track (one track id per slot for the
whole run), ``truth_mask (..., K, N)`` bool where each target lives. ``...`` are any leading dims
(e.g. runs ``B``); ``K`` are scans. Counts and durations are in scans, returned in the default float
dtype so they can be averaged over runs. Everything is vectorised in torch over the leading dims
and the scans.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import torch

from .sets import fragmentations, label_switches, target_tracks


def _check_assignment(assignment: torch.Tensor, N: int) -> torch.Tensor:
    """``(..., K, M, N)`` bool: slot ``m`` is assigned target ``n`` at scan ``k``; refuses values outside
    ``[-1, N-1]`` and a target assigned to two slots at one scan."""
    if assignment.dtype.is_floating_point or assignment.dtype.is_complex or assignment.dtype == torch.bool:
        raise ValueError(f"assignment must be an integer tensor, got {assignment.dtype}")
    if assignment.dim() < 2:
        raise ValueError(f"assignment must be (..., K, M), got {tuple(assignment.shape)}")
    if assignment.numel() and (int(assignment.min()) < -1 or int(assignment.max()) >= N):
        raise ValueError(f"assignment values must lie in [-1, {N - 1}]")
    hit = assignment.unsqueeze(-1) == torch.arange(N, device=assignment.device)
    if bool((hit.sum(-2) > 1).any()):
        raise ValueError("assignment gives one target to two track slots at one scan")
    return hit


def _first_index(mask: torch.Tensor) -> torch.Tensor:
    """``(..., N)`` int64: index along dim -2 of the first True of ``mask (..., K, N)``; ``K`` if none."""
    return (mask.to(torch.int64).cumsum(-2) == 0).sum(-2)


@dataclass
class TrackScores:
    """:func:`track_scores` per leading item (e.g. run); counts in scans or tracks, default float dtype.

    * ``tracks_per_target (..., N)``: distinct track slots ever assigned to the target (0: never tracked).
    * ``false_tracks (...)``: reported tracks (``exists`` at one scan or more) never assigned to any
      target at any scan.
    * ``missed_scans (..., N)``: scans at which the target lives and no track is assigned to it.
    * ``alive_scans (..., N)``: scans at which the target lives.
    * ``scans_to_first_track (..., N)``: index of the first scan with a track assigned minus the index
      of the target's first living scan; NaN when the target is never tracked (or never lives).
    * ``lost (..., N)`` bool: the target is assigned a track at some scan and at none of its later
      living scans, of which there are at least ``loss_scans`` (its track was dropped while it lived).
    * ``switches (..., N)``: :func:`~pmsr_nn.metrics.sets.label_switches`.
    * ``fragmentations (..., N)``: :func:`~pmsr_nn.metrics.sets.fragmentations`.
    """

    tracks_per_target: torch.Tensor
    false_tracks: torch.Tensor
    missed_scans: torch.Tensor
    alive_scans: torch.Tensor
    scans_to_first_track: torch.Tensor
    lost: torch.Tensor
    switches: torch.Tensor
    fragmentations: torch.Tensor


def track_scores(assignment: torch.Tensor, exists: torch.Tensor, truth_mask: torch.Tensor, loss_scans: int = 1) -> TrackScores:
    """Track-level scores (:class:`TrackScores`) of ``assignment (..., K, M)`` int, ``exists (..., K, M)``
    bool and ``truth_mask (..., K, N)`` bool (module docstring). ``loss_scans >= 1`` is how many living
    scans without a track after a target's last assigned scan count as a lost track.

    Refuses (ValueError) shapes that disagree, values outside ``[-1, N-1]``, a target assigned to two
    slots at one scan, and an assignment to a slot that does not exist or a target that does not live.
    """
    if not isinstance(loss_scans, int) or isinstance(loss_scans, bool) or loss_scans < 1:
        raise ValueError(f"loss_scans must be an int >= 1, got {loss_scans!r}")
    if exists.dtype != torch.bool or truth_mask.dtype != torch.bool:
        raise ValueError("exists and truth_mask must be bool tensors")
    if exists.shape != assignment.shape or truth_mask.shape[:-1] != assignment.shape[:-1]:
        raise ValueError(
            f"assignment {tuple(assignment.shape)} and exists {tuple(exists.shape)} must be (..., K, M), "
            f"truth_mask {tuple(truth_mask.shape)} (..., K, N) with the same leading dims"
        )
    N = truth_mask.shape[-1]
    hit = _check_assignment(assignment, N)  # (..., K, M, N)
    assigned = assignment >= 0
    if bool((assigned & ~exists).any()):
        raise ValueError("assignment gives a target to a track slot that does not exist at that scan")
    if bool((hit & ~truth_mask.unsqueeze(-2)).any()):
        raise ValueError("assignment gives a track to a target that does not live at that scan")

    f = torch.get_default_dtype()
    track = target_tracks(assignment, truth_mask)  # (..., K, N)
    has = track >= 0
    first_alive, first_track = _first_index(truth_mask), _first_index(has)
    # living scans after the last assigned one: living and not assigned at this scan or any later one
    later = has.flip(-2).to(torch.int64).cumsum(-2).flip(-2) > 0
    after_last = (truth_mask & ~later).sum(-2)
    tracked = has.any(-2)
    return TrackScores(
        tracks_per_target=hit.any(-3).sum(-2).to(f),
        false_tracks=(exists.any(-2) & ~assigned.any(-2)).sum(-1).to(f),
        missed_scans=(truth_mask & ~has).sum(-2).to(f),
        alive_scans=truth_mask.sum(-2).to(f),
        scans_to_first_track=torch.where(tracked, (first_track - first_alive).to(f), torch.full((), float("nan"), dtype=f)),
        lost=tracked & (after_last >= loss_scans),
        switches=label_switches(assignment, truth_mask).to(f),
        fragmentations=fragmentations(assignment, truth_mask).to(f),
    )


def matched_tracks(assignment: torch.Tensor, x: torch.Tensor, P: torch.Tensor | None = None, N: int | None = None
                   ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor]:
    """The track assigned to each target at each scan, as if slot ``i`` were target ``i``'s.

    ``assignment (..., K, M)`` int (module docstring), track means ``x (..., K, M, n)`` and
    covariances ``P (..., K, M, n, n)`` or ``None``; ``N`` targets (default: the largest index
    assigned + 1). Returns ``x (..., K, N, n)``, ``P (..., K, N, n, n)`` or ``None`` (NaN where no
    track is assigned) and ``matched (..., K, N)`` bool.
    """
    if x.dim() != assignment.dim() + 1 or x.shape[:-1] != assignment.shape:
        raise ValueError(f"x {tuple(x.shape)} must be assignment {tuple(assignment.shape)} plus a state dim")
    N = int(assignment.max()) + 1 if N is None and assignment.numel() else (N or 0)
    hit = _check_assignment(assignment, N)  # (..., K, M, N)
    matched = hit.any(-2)
    n = x.shape[-1]
    if x.shape[-2] == 0:
        xm = x.new_full((*matched.shape, n), float("nan"))
        return xm, (None if P is None else x.new_full((*matched.shape, n, n), float("nan"))), matched
    slot = hit.to(torch.int64).argmax(-2)  # (..., K, N); 0 where unmatched, masked below
    nan = torch.full((), float("nan"), dtype=x.dtype, device=x.device)
    xm = torch.where(matched.unsqueeze(-1), x.gather(-2, slot.unsqueeze(-1).expand(*slot.shape, n)), nan)
    if P is None:
        return xm, None, matched
    Pm = P.gather(-3, slot[..., None, None].expand(*slot.shape, n, n))
    return xm, torch.where(matched[..., None, None], Pm, nan), matched


def matched_errors(
    assignment: torch.Tensor, est_x: torch.Tensor, truth_x: torch.Tensor, pos: Sequence[int]
) -> tuple[torch.Tensor, torch.Tensor]:
    """Squared position error of the track assigned to each target, per scan.

    ``assignment (..., K, M)`` int (module docstring), ``est_x (..., K, M, n)`` track states,
    ``truth_x (..., K, N, n)`` target states, ``pos`` the position columns (e.g. ``[0, 3]``). Returns
    ``sq_err (..., K, N)`` in m^2, the squared Euclidean distance over ``pos`` between the target and
    its assigned track, NaN where no track is assigned (so an unmasked mean cannot pass unnoticed),
    and ``matched (..., K, N)`` bool, where a track is assigned.
    """
    if est_x.dim() != assignment.dim() + 1 or est_x.shape[:-1] != assignment.shape:
        raise ValueError(f"est_x {tuple(est_x.shape)} must be assignment {tuple(assignment.shape)} plus a state dim")
    if truth_x.dim() != est_x.dim() or truth_x.shape[:-2] != est_x.shape[:-2] or truth_x.shape[-1] != est_x.shape[-1]:
        raise ValueError(f"truth_x {tuple(truth_x.shape)} must be (..., K, N, n) with est_x {tuple(est_x.shape)}'s leading dims and n")
    n = est_x.shape[-1]
    pos = list(pos)
    if not pos or any(not 0 <= i < n for i in pos):
        raise ValueError(f"pos must be a non-empty list of columns in [0, {n - 1}], got {pos}")
    e, _, matched = matched_tracks(assignment, est_x, None, truth_x.shape[-2])
    return ((e[..., pos] - truth_x[..., pos]) ** 2).sum(-1), matched
