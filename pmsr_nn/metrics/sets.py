"""Multi-object metrics on padded, masked sets, batched over any leading dims (e.g. runs B, scans K).

Conventions: estimates ``est (..., M, d)`` with ``est_mask (..., M)`` (bool: which slots exist),
truth ``truth (..., N, d)`` with ``truth_mask (..., N)``; ``d`` are position columns in metres.
Padding slots may hold anything (NaN included) and are ignored; existing slots must be finite.
Distances are Euclidean, in metres; ``c`` (cut-off) is in metres, ``p >= 1`` is the order.

The distance matrices and every metric are vectorised in torch; sets of up to
:data:`SMALL_SETS` slots are matched by enumerating permutations as one tensor operation, larger
ones by ``scipy.optimize.linear_sum_assignment`` once per leading item whose two sets are both
non-empty.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment


def _check_cp(c: float, p: float) -> None:
    if not (math.isfinite(c) and c > 0):
        raise ValueError(f"cut-off c must be a finite positive distance, got {c!r}")
    if not (math.isfinite(p) and p >= 1):
        raise ValueError(f"order p must be finite and >= 1, got {p!r}")


def _check_sets(est: torch.Tensor, est_mask: torch.Tensor, truth: torch.Tensor, truth_mask: torch.Tensor) -> None:
    if est.dim() < 2 or truth.dim() < 2:
        raise ValueError(f"est and truth must be (..., M, d) and (..., N, d), got {tuple(est.shape)} and {tuple(truth.shape)}")
    if est_mask.shape != est.shape[:-1] or truth_mask.shape != truth.shape[:-1]:
        raise ValueError(
            f"masks must be est/truth without the last dim: est {tuple(est.shape)} mask {tuple(est_mask.shape)}, "
            f"truth {tuple(truth.shape)} mask {tuple(truth_mask.shape)}"
        )
    if est.shape[:-2] != truth.shape[:-2] or est.shape[-1] != truth.shape[-1]:
        raise ValueError(f"est {tuple(est.shape)} and truth {tuple(truth.shape)} differ in leading dims or in d")
    if est_mask.dtype != torch.bool or truth_mask.dtype != torch.bool:
        raise ValueError("est_mask and truth_mask must be bool tensors")


def _sq_distances(est, est_mask, truth, truth_mask) -> torch.Tensor:
    """``(..., M, N)`` squared distances; padded slots are zeroed first so NaN padding cannot leak."""
    e = torch.where(est_mask.unsqueeze(-1), est, torch.zeros((), dtype=est.dtype, device=est.device))
    t = torch.where(truth_mask.unsqueeze(-1), truth, torch.zeros((), dtype=truth.dtype, device=truth.device))
    return ((e.unsqueeze(-2) - t.unsqueeze(-3)) ** 2).sum(-1)


SMALL_SETS = 4
"""Up to this many slots a side, every item's matching is found by enumerating the permutations
as one tensor operation (24 at most) instead of a SciPy call per item."""


def _solve_small(cost: torch.Tensor, row_ok: torch.Tensor, col_ok: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
    """:func:`_solve` by enumeration on the padded square: a pair with a missing row or column
    costs more than any real pair, so the best permutation holds a full matching of the existing
    rows and columns with the least cost."""
    lead, M, N = cost.shape[:-2], cost.shape[-2], cost.shape[-1]
    S = max(M, N)
    C = cost.detach().reshape(-1, M, N).to(torch.float64)
    ok = row_ok.reshape(-1, M, 1) & col_ok.reshape(-1, 1, N)
    real = torch.where(ok, C, torch.zeros((), dtype=C.dtype))
    pad = float(real.max()) + 1.0 if real.numel() else 1.0
    sq = torch.full((C.shape[0], S, S), pad, dtype=C.dtype)
    sq[:, :M, :N] = torch.where(ok, C, torch.full((), pad, dtype=C.dtype))
    rows_exist = torch.zeros(C.shape[0], S, dtype=torch.bool)
    rows_exist[:, :M] = row_ok.reshape(-1, M)
    cols_exist = torch.zeros(C.shape[0], S, dtype=torch.bool)
    cols_exist[:, :N] = col_ok.reshape(-1, N)
    sq = torch.where(~rows_exist[:, :, None] & ~cols_exist[:, None, :], torch.zeros((), dtype=C.dtype), sq)
    perms = torch.tensor(list(itertools.permutations(range(S))), dtype=torch.int64)  # (P, S)
    total = sq[:, torch.arange(S), perms].sum(-1)  # (L, P)
    best = perms[total.argmin(-1)][:, :M]  # (L, M): column of each row
    col = best.clamp(max=N - 1)
    valid = (best < N) & ok.gather(2, col[..., None]).squeeze(-1) & keep.reshape(-1, M, N).gather(2, col[..., None]).squeeze(-1)
    return torch.where(valid, best, torch.full_like(best, -1)).reshape(*lead, M).to(cost.device)


def _solve(cost: torch.Tensor, row_ok: torch.Tensor, col_ok: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
    """Minimum-cost one-to-one matching of the existing rows and columns of each ``cost (..., M, N)``
    item; returns ``(..., M)`` int64 column per row, -1 where unmatched or where ``keep`` is False."""
    lead, M, N = cost.shape[:-2], cost.shape[-2], cost.shape[-1]
    if 0 < M <= SMALL_SETS and 0 < N <= SMALL_SETS:
        return _solve_small(cost, row_ok, col_ok, keep)
    L = math.prod(lead)
    C = cost.detach().reshape(L, M, N).to("cpu", torch.float64).numpy()
    R = row_ok.reshape(L, M).cpu().numpy()
    Q = col_ok.reshape(L, N).cpu().numpy()
    Kp = keep.reshape(L, M, N).cpu().numpy()
    out = np.full((L, M), -1, dtype=np.int64)
    for l in np.flatnonzero(R.any(1) & Q.any(1)):  # the only Python loop; sets are small
        rows, cols = np.flatnonzero(R[l]), np.flatnonzero(Q[l])
        r, q = linear_sum_assignment(C[l][np.ix_(rows, cols)])
        ok = Kp[l, rows[r], cols[q]]
        out[l, rows[r[ok]]] = cols[q[ok]]
    return torch.from_numpy(out).reshape(*lead, M).to(cost.device)


def _assign(est, est_mask, truth, truth_mask, c: float, p: float) -> tuple[torch.Tensor, torch.Tensor]:
    _check_cp(c, p)
    _check_sets(est, est_mask, truth, truth_mask)
    D = _sq_distances(est, est_mask, truth, truth_mask).sqrt()
    assign = _solve(D.clamp(max=c) ** p, est_mask, truth_mask, D < c)
    return assign, D


def _assigned_terms(D: torch.Tensor, assign: torch.Tensor, p: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Sum of ``d**p`` over assigned pairs and their number (same dtype as ``D``), ``(...)`` each."""
    valid = assign >= 0
    d = D.gather(-1, assign.clamp(min=0).unsqueeze(-1)).squeeze(-1)
    loc = torch.where(valid, d**p, torch.zeros((), dtype=D.dtype, device=D.device)).sum(-1)
    return loc, valid.sum(-1).to(D.dtype)


def min_cost_matching(cost: torch.Tensor, row_ok: torch.Tensor, col_ok: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
    """``(..., M)`` int64: a minimum-cost one-to-one matching of the existing rows ``row_ok (..., M)``
    and columns ``col_ok (..., N)`` of each ``cost (..., M, N)`` item (the column of each row), -1
    where a row is unmatched or its pair is not ``keep (..., M, N)``; the solver behind the set
    metrics (enumeration for small sets, SciPy's otherwise)."""
    return _solve(cost, row_ok, col_ok, keep)


def optimal_assignment(
    est: torch.Tensor, est_mask: torch.Tensor, truth: torch.Tensor, truth_mask: torch.Tensor, c: float, p: float
) -> torch.Tensor:
    """``(..., M)`` int64: the truth index assigned to each estimate slot, minimising the sum of
    ``min(d, c)**p`` over the pairs of a full (``min(|X|, |Y|)``) matching. Pairs at ``d >= c`` cost the
    same as leaving both unassigned, so they are reported as -1 (unassigned), as are padded slots."""
    return _assign(est, est_mask, truth, truth_mask, c, p)[0]


def ospa(est: torch.Tensor, est_mask: torch.Tensor, truth: torch.Tensor, truth_mask: torch.Tensor, c: float, p: float) -> torch.Tensor:
    """OSPA distance of order ``p``, cut-off ``c`` (Schuhmacher, Vo & Vo 2008), ``(...)`` in metres:
    ``(min_pi sum min(d, c)**p + c**p * (n - m)) / n) ** (1/p)`` with ``m <= n`` the two set sizes;
    0 when both sets are empty and ``c`` when exactly one is."""
    assign, D = _assign(est, est_mask, truth, truth_mask, c, p)
    return _ospa(D, assign, est_mask, truth_mask, c, p)


def _ospa(D, assign, est_mask, truth_mask, c: float, p: float) -> torch.Tensor:
    loc, a = _assigned_terms(D, assign, p)
    n = torch.maximum(est_mask.sum(-1), truth_mask.sum(-1)).to(D.dtype)
    val = ((loc + c**p * (n - a)) / n.clamp(min=1)) ** (1.0 / p)
    return torch.where(n > 0, val, torch.zeros((), dtype=D.dtype, device=D.device))


@dataclass
class GOSPA:
    """GOSPA and its parts, each ``(...)``. ``total`` is in metres; ``localisation``, ``missed`` and
    ``false`` are its p-th power contributions (``total**p == localisation + missed + false``, m^p);
    ``n_missed`` and ``n_false`` are counts (float)."""

    total: torch.Tensor
    localisation: torch.Tensor
    missed: torch.Tensor
    false: torch.Tensor
    n_missed: torch.Tensor
    n_false: torch.Tensor


def gospa(
    est: torch.Tensor, est_mask: torch.Tensor, truth: torch.Tensor, truth_mask: torch.Tensor, c: float, p: float, alpha: float = 2.0
) -> GOSPA:
    """GOSPA (Rahmathullah, García-Fernández & Svensson 2017), ``alpha = 2`` only:

    ``GOSPA**p = min over assignments of [sum_{assigned, d < c} d**p + c**p / 2 * (#unassigned truths + #unassigned estimates)]``.

    A pair at ``d >= c`` costs ``c**p`` whether assigned or not; by convention it is reported as
    unassigned, i.e. one missed truth plus one false estimate. ``localisation = sum d**p`` over the
    pairs with ``d < c``; ``missed = c**p / 2 * n_missed``; ``false = c**p / 2 * n_false``.
    """
    if alpha != 2:
        raise ValueError(f"gospa supports only alpha=2 (the assignment-based form), got alpha={alpha!r}")
    assign, D = _assign(est, est_mask, truth, truth_mask, c, p)
    return _gospa(D, assign, est_mask, truth_mask, c, p)


def _gospa(D, assign, est_mask, truth_mask, c: float, p: float) -> GOSPA:
    loc, a = _assigned_terms(D, assign, p)
    n_missed = truth_mask.sum(-1).to(D.dtype) - a
    n_false = est_mask.sum(-1).to(D.dtype) - a
    missed = c**p / 2 * n_missed
    false = c**p / 2 * n_false
    total = (loc + missed + false) ** (1.0 / p)
    return GOSPA(total=total, localisation=loc, missed=missed, false=false, n_missed=n_missed, n_false=n_false)


@dataclass
class SetScores:
    """:func:`set_scores` of one pair of sets per leading item: ``ospa`` and ``gospa`` ``(...)``,
    and the optimal assignment ``(..., M)`` (truth index per estimate slot, -1 unassigned)."""

    ospa: torch.Tensor
    gospa: GOSPA
    assignment: torch.Tensor


def set_scores(est: torch.Tensor, est_mask: torch.Tensor, truth: torch.Tensor, truth_mask: torch.Tensor, c: float,
               p: float) -> SetScores:
    """OSPA, GOSPA (alpha = 2) and their common optimal assignment from one solve: both minimise
    the sum of ``min(d, c)**p`` over a full matching (a GOSPA pair at ``d >= c`` costs ``c**p``,
    the same as leaving both unassigned), so one assignment serves all three."""
    assign, D = _assign(est, est_mask, truth, truth_mask, c, p)
    return SetScores(_ospa(D, assign, est_mask, truth_mask, c, p), _gospa(D, assign, est_mask, truth_mask, c, p), assign)


def cardinality_error(est_mask: torch.Tensor, truth_mask: torch.Tensor) -> torch.Tensor:
    """``(...)`` float (default dtype): ``|X_est| - |X_truth|`` (positive: too many estimates)."""
    return (est_mask.sum(-1) - truth_mask.sum(-1)).to(torch.get_default_dtype())


def labelled_assignment(
    est: torch.Tensor, est_mask: torch.Tensor, truth: torch.Tensor, truth_mask: torch.Tensor, c: float
) -> torch.Tensor:
    """One assignment per run of track labels to truth targets, fixed over the whole run.

    ``est (B, K, M, d)``, ``est_mask (B, K, M)``, ``truth (B, K, N, d)``, ``truth_mask (B, K, N)``
    (any leading dims before ``K``). Minimises, over one-to-one label -> target maps, the sum over
    scans of ``min(||e - t||**2, c**2)`` where both exist and ``c**2`` where exactly one exists (an
    unassigned label or target counts as paired with one that never exists). Returns ``(B, M)`` int64
    target per label, -1 for a label left unassigned or whose target never co-exists with it.
    """
    _check_cp(c, 1.0)
    _check_sets(est, est_mask, truth, truth_mask)
    if est.dim() < 3:
        raise ValueError(f"est must be (B, K, M, d), got {tuple(est.shape)}")
    D2 = _sq_distances(est, est_mask, truth, truth_mask)  # (B, K, M, N)
    both = est_mask.unsqueeze(-1) & truth_mask.unsqueeze(-2)
    zero = torch.zeros((), dtype=D2.dtype, device=D2.device)
    # cost of the pair minus the cost of leaving both unassigned: only co-existing scans differ,
    # each by min(d^2, c^2) - 2 c^2 < 0 (so a full matching is optimal)
    reduced = torch.where(both, D2.clamp(max=c * c) - 2 * c * c, zero).sum(-3)
    return _solve(reduced, est_mask.any(-2), truth_mask.any(-2), both.any(-3))


def persistent_assignment(
    est: torch.Tensor, est_mask: torch.Tensor, truth: torch.Tensor, truth_mask: torch.Tensor, c: float, p: float
) -> torch.Tensor:
    """``(..., K, M)`` int64: the CLEAR MOT mapping of track slots to targets (Bernardin &
    Stiefelhagen 2008), scan by scan: a track kept on the target it was matched to at the previous
    scan while both exist and are nearer than ``c``; the other tracks and targets matched as
    :func:`optimal_assignment` matches them (the least sum of ``min(d, c)**p``; pairs at
    ``d >= c`` unassigned).

    ``est (..., K, M, d)``, ``truth (..., K, N, d)`` with their masks (scans on dim -3). Unlike the
    per-scan optimal assignment, where two targets meet (a crossing, a formation) it does not
    swap two tracks that each still follow their own target because the swap costs a little
    less at one scan: what a label switch should count.
    """
    _check_cp(c, p)
    _check_sets(est, est_mask, truth, truth_mask)
    if est.dim() < 3:
        raise ValueError(f"est must be (..., K, M, d), got {tuple(est.shape)}")
    D = _sq_distances(est, est_mask, truth, truth_mask).sqrt()  # (..., K, M, N)
    lead, K, M, N = D.shape[:-3], D.shape[-3], D.shape[-2], D.shape[-1]
    out = torch.full((*lead, K, M), -1, dtype=torch.int64, device=D.device)
    prev = torch.full((*lead, M), -1, dtype=torch.int64, device=D.device)
    for k in range(K):  # in scan order: each scan's mapping starts from the last one
        Dk, em, tm = D[..., k, :, :], est_mask[..., k, :], truth_mask[..., k, :]
        near = em.unsqueeze(-1) & tm.unsqueeze(-2) & (Dk < c)  # (..., M, N)
        if M == 0 or N == 0:
            continue  # nothing to match at any scan
        held = (prev >= 0) & near.gather(-1, prev.clamp(min=0).unsqueeze(-1)).squeeze(-1)
        taken = ((prev.unsqueeze(-1) == torch.arange(N, device=D.device)) & held.unsqueeze(-1)).any(-2)  # (..., N)
        rest = _solve(Dk.clamp(max=c) ** p, em & ~held, tm & ~taken, Dk < c)
        prev = torch.where(held, prev, rest)
        out[..., k, :] = prev
    return out


def target_tracks(assignment_per_scan: torch.Tensor, truth_mask: torch.Tensor) -> torch.Tensor:
    """``(..., K, N)`` int64: the track slot assigned to each living target at each scan (-1: none)."""
    N = truth_mask.shape[-1]
    if assignment_per_scan.shape[:-1] != truth_mask.shape[:-1]:
        raise ValueError(f"assignment {tuple(assignment_per_scan.shape)} and truth_mask {tuple(truth_mask.shape)} differ before the last dim")
    if assignment_per_scan.numel() and (int(assignment_per_scan.min()) < -1 or int(assignment_per_scan.max()) >= N):
        raise ValueError(f"assignment values must lie in [-1, {N - 1}]")
    if assignment_per_scan.shape[-1] == 0:
        return torch.full(truth_mask.shape, -1, dtype=torch.int64, device=truth_mask.device)
    hit = assignment_per_scan.unsqueeze(-1) == torch.arange(N, device=assignment_per_scan.device)  # (B, K, M, N)
    has = hit.any(-2) & truth_mask
    return torch.where(has, hit.to(torch.int64).argmax(-2), torch.full_like(has, -1, dtype=torch.int64))


def label_switches(assignment_per_scan: torch.Tensor, truth_mask: torch.Tensor) -> torch.Tensor:
    """``(B, N)`` int64: how often the track label assigned to each truth target changes between
    consecutive scans ``k-1, k`` at which the target is assigned at both.

    ``assignment_per_scan (B, K, M)`` int64 is :func:`optimal_assignment` per scan (truth index per
    track slot, -1 unassigned); ``truth_mask (B, K, N)``. Any leading dims before ``K`` work.
    """
    track = target_tracks(assignment_per_scan, truth_mask)
    has = track >= 0
    changed = has[..., 1:, :] & has[..., :-1, :] & (track[..., 1:, :] != track[..., :-1, :])
    return changed.sum(-2)


def identity_switches(assignment_per_scan: torch.Tensor, truth_mask: torch.Tensor) -> torch.Tensor:
    """``(..., N)`` int64: CLEAR MOT identity switches of each target (Bernardin & Stiefelhagen 2008,
    counted as the MOTChallenge counts them, Milan et al. 2016): the scans at which the target is
    assigned a track other than the last track assigned to it at an earlier scan, also across
    scans at which it had none (a track lost and another started on the target is a switch; the
    same track back after a gap is not). Arguments as :func:`label_switches` (on
    :func:`persistent_assignment`, a target keeps its track while that track stays within the
    cut-off). At least :func:`label_switches`, which counts only consecutive scans."""
    track = target_tracks(assignment_per_scan, truth_mask)  # (..., K, N)
    K = track.shape[-2]
    has = track >= 0
    scan = torch.arange(K, device=track.device).view(K, 1)
    last = torch.where(has, scan, torch.full_like(track, -1)).cummax(-2).values  # last assigned scan <= k
    before = torch.full_like(last, -1)
    before[..., 1:, :] = last[..., :-1, :]  # last assigned scan < k
    previous = track.gather(-2, before.clamp(min=0))
    return (has & (before >= 0) & (track != previous)).sum(-2)


def fragmentations(assignment_per_scan: torch.Tensor, truth_mask: torch.Tensor) -> torch.Tensor:
    """``(B, N)`` int64: how often each target's track coverage is interrupted (the CLEAR MOT
    "fragmentation"): the target is assigned at scan ``k-1``, alive but unassigned at ``k``, and
    assigned again at a later scan. Arguments as :func:`label_switches`."""
    track = target_tracks(assignment_per_scan, truth_mask)
    has = track >= 0
    later = has.flip(-2).to(torch.int64).cummax(-2).values.flip(-2).bool()  # assigned at k or after
    after = torch.zeros_like(has)
    after[..., :-1, :] = later[..., 1:, :]
    broken = has[..., :-1, :] & truth_mask[..., 1:, :] & ~has[..., 1:, :] & after[..., 1:, :]
    return broken.sum(-2)
