"""Labelled tracks from unlabelled estimates (a PHD filter's, one set per scan), batched over runs.

A track holds the last estimate it took and is predicted with the CV model between scans. At
each scan the living tracks (players) and the scan's estimates are associated by

* ``gtda``: the regret-matching game of :mod:`.gtda` (Daniyan et al.), or
* ``hungarian``: the optimal assignment (``scipy.optimize.linear_sum_assignment``) minimising
  ``sum min(d2, gate)``, i.e. with a null option of cost ``gate`` per track: the plain baseline,

``d2`` being the Mahalanobis distance of an estimate from a track's prediction (covariance: the
track's predicted one plus the estimate's). A track that takes an estimate reports it under its
label; a track missing more than ``max_missed`` scans in a row ends (a player leaves); an estimate
no track takes starts a new, tentative track (a player joins). A tentative track is confirmed by
the shared M-of-N :class:`~.management.Confirmer` (``confirm_m`` estimates taken in its first
``confirm_n`` scans; 1 of 1, the default, confirms at once) and only then gets a label and is
reported, from that scan on; one that can no longer be confirmed ends. Labels count up per run
from 0, in order of confirmation. A living confirmed track that took no estimate reports its
prediction (it coasts) once it has taken at least two estimates, so a missed detection does not
cut a labelled track while a one-scan false estimate does not linger. With a coalescence rule
(``LabelSpec.coalescence``, :mod:`.coalescence`: issue 55's duplicate-free management), two
labelled tracks whose states agree for its ``scans`` scans in a row hold one target: the younger
label (the higher number) ends and the older one goes on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment

from ..config import require
from .gating import gate_threshold, inside_gate, mahalanobis
from .base import Estimates
from .coalescence import Coalescence, CoalescenceTest
from .gtda import GameSpec, play
from .management import Confirmer

@dataclass(frozen=True)
class LabelSpec:
    """``method`` (``gtda`` or ``hungarian``), ``gate`` on ``d2``, ``max_missed`` scans a track
    coasts before it ends, ``confirm_m`` of its first ``confirm_n`` scans a new track must take an
    estimate in before it is reported, ``game`` the GTDA settings, ``coalescence`` the rule that
    ends the younger of two labelled tracks holding one target (None: none)."""

    method: Literal["gtda", "hungarian"] = "gtda"
    gate_probability: float = 0.999
    max_missed: int = 3
    confirm_m: int = 1
    confirm_n: int = 1
    game: GameSpec = field(default_factory=GameSpec)
    coalescence: Coalescence | None = None

    @property
    def confirmer(self) -> Confirmer:
        return Confirmer(self.confirm_m, self.confirm_n)

    @property
    def gate(self) -> float:
        """The gate on the squared Mahalanobis distance (chi-square, 2 degrees of freedom)."""
        return gate_threshold(self.gate_probability, 2)

    def __post_init__(self) -> None:
        require(self.method in ("gtda", "hungarian"), f"labelling must be gtda or hungarian, got {self.method!r}")
        require(0 < self.gate_probability < 1, f"gate_probability must be in (0, 1), got {self.gate_probability}")
        require(self.max_missed >= 0, f"max_missed must be >= 0, got {self.max_missed}")
        self.confirmer  # refuses an M-of-N that could never confirm


def track_distances(x: torch.Tensor, P: torch.Tensor, e: torch.Tensor, Pe: torch.Tensor) -> torch.Tensor:
    """``d2 (B, tracks, estimates)`` of estimates ``e (B, estimates, 2)`` (covariances ``Pe``) from
    tracks ``x (B, tracks, 2)`` (covariances ``P``) under the summed covariance
    (:func:`~.gating.mahalanobis`); NaN inputs give NaN, a sum that is not positive definite ``inf``."""
    return mahalanobis(e[:, None, :, :] - x[:, :, None, :], P[:, :, None] + Pe[:, None, :])


def hungarian(d2: torch.Tensor, player: torch.Tensor, strategy_ok: torch.Tensor, gate: float) -> torch.Tensor:
    """``choice (B, tracks)`` (-1: none) of ``d2 (B, tracks, estimates)``: per run, the assignment
    minimising ``sum min(d2, gate)``; a track takes its estimate only inside the gate
    (:func:`~.gating.inside_gate`)."""
    B, n_tracks, _ = d2.shape
    choice = np.full((B, n_tracks), -1, dtype=np.int64)
    cost = torch.nan_to_num(d2, nan=gate).clamp(max=gate).cpu().numpy()
    inside = inside_gate(d2, gate).cpu().numpy()
    pl, ok = player.cpu().numpy(), strategy_ok.cpu().numpy()
    for b in range(B):
        rows, cols = np.flatnonzero(pl[b]), np.flatnonzero(ok[b])
        if len(rows) == 0 or len(cols) == 0:
            continue
        c = cost[b][np.ix_(rows, cols)]
        r, k = linear_sum_assignment(c)
        take = inside[b, rows[r], cols[k]]
        choice[b, rows[r[take]]] = cols[k[take]]
    return torch.from_numpy(choice).to(d2.device)


def label_tracks(x: torch.Tensor, P: torch.Tensor, exists: torch.Tensor, F: torch.Tensor, Q: torch.Tensor,
                 spec: LabelSpec, g: torch.Generator, merge_idx: list[int] | None = None) -> Estimates:
    """Labelled tracks (module docstring) of estimates ``x (B, K, C, n)`` (positions first),
    ``P (B, K, C, n, n)``, ``exists (B, K, C)``; ``merge_idx``: the state entries the coalescence
    test compares (None: all): :class:`~.base.Estimates` with one slot per label (unpaired); extras
    ``game_rounds (K,)`` and ``repaired (B,)`` (GTDA only), ``labels (B,)`` labels confirmed per run,
    ``started (B,)`` tracks started per run (tentative ones included)."""
    B, K, C, n = x.shape
    dev = x.device
    cap = max(C, 1)
    tx = torch.zeros(B, cap, n, dtype=torch.float64, device=dev)
    tP = torch.eye(n, dtype=torch.float64, device=dev).expand(B, cap, n, n).clone()
    alive = torch.zeros(B, cap, dtype=torch.bool, device=dev)
    label = torch.full((B, cap), -1, dtype=torch.int64, device=dev)
    missed = torch.zeros(B, cap, dtype=torch.int64, device=dev)
    hits = torch.zeros(B, cap, dtype=torch.int64, device=dev)
    age = torch.zeros(B, cap, dtype=torch.int64, device=dev)
    next_label = torch.zeros(B, dtype=torch.int64, device=dev)
    started = torch.zeros(B, dtype=torch.int64, device=dev)
    confirmer = spec.confirmer
    at_once = bool(confirmer.confirms(torch.ones((), dtype=torch.int64, device=dev)))  # 1 of 1: labelled when started
    rounds, repaired = [], torch.zeros(B, dtype=torch.int64, device=dev)
    rows_out = []  # per scan: (b, label, estimate index)
    gate = spec.gate
    merging = None if spec.coalescence is None else CoalescenceTest(
        spec.coalescence, B, list(range(n)) if merge_idx is None else merge_idx, dev)
    for k in range(K):
        tx, tP = tx @ F.T, F @ tP @ F.T + Q
        ek, Pk, ok = torch.nan_to_num(x[:, k]), P[:, k], exists[:, k]
        d2 = track_distances(tx, tP, ek, Pk)
        # inf: no gate
        d2 = torch.where(alive[:, :, None] & ok[:, None, :] & ~d2.isnan(), d2, d2.new_full((), math.inf))
        if spec.method == "gtda":
            res = play(d2, alive, ok, gate, spec.game, g)
            choice = res.choice
            rounds.append(res.rounds)
            repaired += res.repaired
        else:
            choice = hungarian(d2, alive, ok, gate)
        took = choice >= 0
        pick = choice.clamp(min=0)
        tx = torch.where(took[..., None], ek.gather(1, pick[..., None].expand(B, cap, n)), tx)
        tP = torch.where(took[..., None, None], Pk.gather(1, pick[..., None, None].expand(B, cap, n, n)), tP)
        missed = torch.where(took, torch.zeros_like(missed), missed + 1)
        hits = hits + took
        age = age + alive
        alive = alive & (missed <= spec.max_missed)
        tentative = alive & (label < 0)
        alive = alive & ~(tentative & confirmer.hopeless(hits, age))
        new_conf = alive & (label < 0) & confirmer.confirms(hits)
        rank = new_conf.cumsum(1) - 1
        label = torch.where(new_conf, next_label[:, None] + rank, label)
        next_label += new_conf.sum(1)
        ended = torch.zeros_like(alive)
        if merging is not None:  # the younger of two labels agreeing for the rule's scans ends; its
            ended = merging.step(tx, tP, alive & (label >= 0), label).any(1)  # estimate starts nothing
            alive = alive & ~ended
        shown = took & ~ended & (label >= 0)
        b, p = shown.nonzero(as_tuple=True)
        rows_out.append((k, b, label[b, p], ek[b, choice[b, p]], Pk[b, choice[b, p]]))
        b, p = (alive & ~took & (hits >= 2) & (label >= 0)).nonzero(as_tuple=True)  # coasting: the prediction under the label
        rows_out.append((k, b, label[b, p], tx[b, p], tP[b, p]))
        # estimates no track took start tracks in free slots
        taken = torch.zeros(B, C + 1, dtype=torch.bool, device=dev).scatter_(1, torch.where(took, choice, C),
                                                                             True)[:, :C]
        new = ok & ~taken
        n_new = new.sum(1)
        short = int((n_new - (~alive).sum(1)).max()) if B else 0
        if short > 0:
            grow = lambda t, fill: torch.cat([t, t.new_full((B, short) + t.shape[2:], fill)], 1)
            tx, alive, label, missed, hits, age = (grow(tx, 0.0), grow(alive, False), grow(label, -1), grow(missed, 0),
                                                   grow(hits, 0), grow(age, 0))
            tP = torch.cat([tP, torch.eye(n, dtype=torch.float64, device=dev).expand(B, short, n, n)], 1)
            cap += short
        if bool(new.any()):
            free_first = torch.sort(alive.to(torch.int8), dim=1, stable=True).indices  # free slots first
            b, c = new.nonzero(as_tuple=True)
            rank = (new.cumsum(1) - 1)[b, c]
            slot = free_first[b, rank]
            tx[b, slot], tP[b, slot] = ek[b, c], Pk[b, c]
            alive[b, slot], missed[b, slot], hits[b, slot], age[b, slot] = True, 0, 1, 0
            started += n_new
            if at_once:
                label[b, slot] = next_label[b] + rank
                next_label += n_new
                rows_out.append((k, b, label[b, slot], ek[b, c], Pk[b, c]))
            else:
                label[b, slot] = -1
    L = int(next_label.max()) if B else 0
    out_x = torch.full((B, K, L, n), float("nan"), dtype=torch.float64, device=dev)
    out_P = torch.zeros(B, K, L, n, n, dtype=torch.float64, device=dev)
    out_e = torch.zeros(B, K, L, dtype=torch.bool, device=dev)
    for k, b, lab, xv, Pv in rows_out:
        out_x[b, k, lab], out_P[b, k, lab], out_e[b, k, lab] = xv, Pv, True
    extras = {"labels": next_label, "started": started}
    if spec.method == "gtda":
        extras.update(game_rounds=torch.tensor(rounds, device=dev), repaired=repaired)
    return Estimates(out_x, out_e, out_P, extras, paired=False)
