"""The innovation bias test: a track held beside its target, found from its own innovations.

A track whose association is right sees white innovations: per pair, the whitened combined
innovation ``e = L^-1 nu_c`` (``S = L L^T`` the predicted innovation covariance, ``nu_c`` the
association-weighted innovation) is zero-mean with at most unit covariance (unit for a detection
that is surely the target's; a miss, or weight spread over several detections, shrinks it). A
track started on a wrong combination of several targets' detections (a *ghost* of a formation:
each pair's detection is a real target's, so every gate keeps passing) sees innovations with a
persistent mean: its bistatic ranges are each a little off, scan after scan. The test keeps, per
track, pair and component, an exponentially weighted mean of ``e`` with weight ``a = 2 / (W + 1)``
(``W`` the window in scans) and compares

    q = sum over pairs and components of m^2 / v_k,     v_k = a / (2 - a) (1 - (1 - a)^(2 k)),

``v_k`` the variance of the weighted mean of ``k`` white unit innovations, with the chi-square
quantile of ``probability`` on ``S d`` degrees of freedom (``S`` pairs, ``d`` components). For a
track that is right, ``q`` is at most chi-square (misses and spread weights only shrink it), so a
confirmed track flagged this way is off its target's detections with at least that confidence
per scan (the time-averaged innovation tests of filter consistency, Bar-Shalom, Li & Kirubarajan 2001,
ch. 5, here on a sliding exponential window so it follows a track's whole life).

A track's first ``burn_in`` updates are left out (:attr:`BiasTest.burn_in`): a track started by
the fix initiator is not yet consistent (its start is biased outward, and the filter takes about
20 scans to forget it; evaluate/RESULTS.md, "Burn-in"). Of 40 runs of 60 scans of one drone the
test at 0.999 deleted and restarted the track in 10 with no burn-in, 3 with 5 updates, 2 with 10,
1 with 20 (``evaluate/innovation_bias_burn_in.py``, record
``evaluate/results/innovation_bias_burn_in.json``). A ghost is best deleted early, before it holds the
formation's detections for long: on dense_crossing's draws of another seed than the recorded one
the burn-in of 10 updates gave the lowest GOSPA of 0, 5, 10 and 20 (``evaluate/RESULTS.md``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import torch
from scipy.stats import chi2

from ..config import require

BiasAction = Literal["delete"]


@dataclass(frozen=True)
class BiasTest:
    """``window`` (scans) of the exponentially weighted innovation mean, ``probability`` of the
    chi-square quantile a confirmed track's statistic must exceed to be flagged, and what a
    tracker does with a flagged track: ``delete`` it (its detections are then free for the
    initiator; ``learn``, a learned gain correction acting on flagged tracks only, left with the
    hybrid tracker under issue 56). ``burn_in``: updates of a track's life left out of its mean."""

    window: float = 20.0
    probability: float = 0.999
    action: BiasAction = "delete"
    burn_in: int = 10

    def __post_init__(self) -> None:
        require(self.window >= 1.0, f"the bias test's window must be at least 1 scan, got {self.window}")
        require(0.5 <= self.probability < 1.0, f"the bias test's probability must be in [0.5, 1), got {self.probability}")
        require(self.action == "delete", f"the bias test's action must be delete (learn left with the hybrid tracker, "
                                         f"issue 56), got {self.action!r}")
        require(self.burn_in >= 0, f"the bias test's burn-in must be at least 0 scans, got {self.burn_in}")

    @property
    def weight(self) -> float:
        return 2.0 / (self.window + 1.0)

    def threshold(self, dof: int) -> float:
        return float(chi2.ppf(self.probability, dof))

    def update(self, mean: torch.Tensor, pair: int, e: torch.Tensor, active: torch.Tensor) -> torch.Tensor:
        """``mean (B, C, S, d)`` with pair ``pair``'s whitened combined innovations ``e (B, C, d)``
        of the ``active (B, C)`` tracks folded in."""
        a = self.weight
        row = torch.where(active[..., None], (1.0 - a) * mean[:, :, pair] + a * e, mean[:, :, pair])
        return torch.cat([mean[:, :, :pair], row.unsqueeze(2), mean[:, :, pair + 1:]], 2)

    def statistic(self, mean: torch.Tensor, updates: torch.Tensor) -> torch.Tensor:
        """``q (B, C)`` of the means ``(B, C, S, d)`` after ``updates (B, C)`` scans (0 where none)."""
        a = self.weight
        v = a / (2.0 - a) * (1.0 - (1.0 - a) ** (2 * updates.to(mean.dtype)))
        q = (mean * mean).sum((-1, -2)) / v.clamp(min=1e-300)
        return torch.where(updates > 0, q, mean.new_zeros(()))

    def flags(self, mean: torch.Tensor, updates: torch.Tensor) -> torch.Tensor:
        """``(B, C)`` bool: the statistic beyond the quantile."""
        return self.statistic(mean, updates) > self.threshold(mean.shape[-2] * mean.shape[-1])
