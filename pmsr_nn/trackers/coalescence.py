"""The coalescence test: two confirmed tracks that hold one target are merged.

Two confirmed tracks *agree* at a scan when the difference of their states (the entries ``idx``:
position, or position and velocity) is within the chi-square gate of ``probability`` under the
sum of their covariances, ``d2 = D^T (P_1 + P_2)^-1 D <= gamma`` (``len(idx)`` degrees of
freedom; ``P_1 + P_2`` ignores the correlation of two tracks fed by the same detections, which
only widens the gate). A pair that agrees at each of ``scans`` consecutive scans is merged: the
older track (the lower track id: ids are numbered in order of confirmation) survives, with the
larger of the two existence probabilities, and the other's slot is freed. A slot that is not
confirmed at a scan (free, tentative, just deleted or reused) breaks every count it is part of.

Batched over runs and slot pairs. Shapes: ``B`` runs, ``C`` track slots, ``n`` state dimension,
``k = len(idx)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..config import require
from ..filters.gaussian import safe_cholesky
from .gating import gate_threshold


@dataclass(frozen=True)
class Coalescence:
    """The merge rule (module docstring): ``scans`` consecutive agreeing scans (>= 1),
    ``probability`` the chi-square gate probability of one scan's agreement."""

    scans: int
    probability: float = 0.99

    def __post_init__(self) -> None:
        require(self.scans >= 1, f"a merge window needs at least 1 scan (merge_scans), got {self.scans}")
        require(0.0 < self.probability < 1.0, f"merge_probability must be in (0, 1), got {self.probability}")

    def agree(self, x: torch.Tensor, P: torch.Tensor, confirmed: torch.Tensor, idx: list[int]) -> torch.Tensor:
        """``(B, C, C)``: the pairs of distinct confirmed tracks (``confirmed (B, C)``) whose states
        ``x (B, C, n)``, ``P (B, C, n, n)`` agree on the entries ``idx`` (symmetric, False on the
        diagonal)."""
        xs = x[..., idx]
        Ps = P[..., idx, :][..., idx]
        D = xs[:, :, None, :] - xs[:, None, :, :]  # (B, C, C, k)
        L = safe_cholesky(Ps[:, :, None] + Ps[:, None, :])
        e = torch.linalg.solve_triangular(L, D.unsqueeze(-1), upper=False).squeeze(-1)
        d2 = (e * e).sum(-1)
        C = x.shape[1]
        both = confirmed[:, :, None] & confirmed[:, None, :] & ~torch.eye(C, dtype=torch.bool, device=confirmed.device)
        return both & (d2 <= gate_threshold(self.probability, len(idx)))


class CoalescenceTest:
    """The running counts of one tracker's coalescence test over ``B`` runs: ``count (B, C, C)``
    the consecutive scans each slot pair has agreed (slots grow as the track table does), on
    ``device`` (the tracks')."""

    def __init__(self, rule: Coalescence, B: int, idx: list[int], device: torch.device | str | None = None):
        self.rule, self.idx = rule, list(idx)
        self.count = torch.zeros(B, 0, 0, dtype=torch.int64, device=device)

    def step(self, x: torch.Tensor, P: torch.Tensor, confirmed: torch.Tensor, track_id: torch.Tensor) -> torch.Tensor:
        """One scan of tracks ``x (B, C, n)``, ``P``, ``confirmed (B, C)`` with ids ``track_id (B,
        C)``: the counts go on (or restart at 0). Returns ``merged (B, C, C)``: ``merged[b, i, j]``
        where track ``j`` has agreed with the older track ``i`` (a lower id) for ``scans`` scans
        and merges into it; ``merged.any(1)`` are the slots to free. The counts of a freed slot
        restart."""
        B, C = confirmed.shape
        old = self.count.shape[1]
        if old < C:
            count = self.count.new_zeros(B, C, C)
            count[:, :old, :old] = self.count
            self.count = count
        ok = self.rule.agree(x, P, confirmed, self.idx)
        self.count = torch.where(ok, self.count + 1, 0)
        merged = (self.count >= self.rule.scans) & (track_id[:, :, None] < track_id[:, None, :])
        loser = merged.any(1)
        self.count = torch.where(loser[:, :, None] | loser[:, None, :], 0, self.count)
        return merged


def merged_existence(existence: torch.Tensor, merged: torch.Tensor) -> torch.Tensor:
    """``existence (B, C)`` with each surviving track of ``merged (B, C, C)`` (:meth:`CoalescenceTest.step`)
    raised to the largest existence of the tracks merged into it."""
    into = torch.where(merged, existence[:, None, :], existence.new_zeros(())).amax(-1)
    return torch.maximum(existence, into)
