"""Trajectory GOSPA with switching cost (García-Fernández, Rahmathullah & Svensson, IEEE TSP 2020), alpha = 2.

Inputs are padded, masked tensors over runs ``B`` and scans ``K`` (the conventions of
:mod:`pmsr_nn.metrics.sets`): estimated tracks ``est (B, K, M, D)`` with ``exists (B, K, M)`` (one
track per slot for the whole run: a slot's scans form one estimated trajectory) and truth
``truth (B, K, N, D)`` with ``alive (B, K, N)``. Positions are in metres; padding may hold NaN.

With ``pi^k`` the assignment at scan ``k`` of each target ``i`` to a track ``pi^k_i`` or to nothing
(each track to one target at most), the metric of order ``p``, cut-off ``c`` (m) and switching
cost ``gamma`` (m) is

``d^p = min over pi^1..pi^K of  sum_k [ sum_{i, j = pi^k_i, both exist, d < c} d_ij^p
+ c^p / 2 * (#targets and #tracks existing at k and not in such a pair) ]  +  gamma^p * sum_{k < K} s(pi^k, pi^{k+1})``

where ``s`` counts, per target, 1 for a change from one track to another and 1/2 for a change from
or to nothing (a half switch): a full switch costs ``gamma^p``, a half switch ``gamma^p / 2``.
``total = d`` is in metres: the p-th root of the sum over scans (not the mean) of each scan's
GOSPA^p plus the switching costs. With ``gamma = 0`` it is the p-th root of the sum over scans of
per-scan GOSPA^p (:func:`pmsr_nn.metrics.sets.gospa`). ``per_scan = (d^p / K)^(1/p)`` (m) is the
p-th root of the mean over scans, the normalisation of the harness's ``gospa_m`` per run: with
``gamma = 0`` the two are equal.

It is solved per run as the paper's linear programme over ``W^k`` (the assignment matrices, with a
row and a column for "nothing") and auxiliary ``e >= |W^k - W^{k+1}|`` (switching cost
``gamma^p / 2 * sum e``): ``integer=True`` solves the mixed-integer programme
(``scipy.optimize.milp``, HiGHS, zero gap): the metric itself; ``integer=False`` the LP relaxation
(``scipy.optimize.linprog``, HiGHS), also a metric (the paper's Section IV) and a lower bound of
the integer value, equal to it where its solution is integral (``integral``). Only pairs
``(target, track)`` that are nearer than ``c`` at some scan get a variable: assigning a target to
any other track costs the same as leaving both unassigned at every scan and never switches less,
so the optimum is unchanged. The matrices are built vectorised; the only loop is over runs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from scipy import sparse
from scipy.optimize import Bounds, LinearConstraint, linprog, milp


@dataclass
class TrajectoryGOSPA:
    """:func:`trajectory_gospa` per run, each ``(B,)`` float64 unless said otherwise.

    ``total`` (m) with ``total**p == localisation + missed + false + switching`` (each m^p, summed
    over scans): ``localisation`` the sum of ``d^p`` over assigned pairs nearer than ``c``;
    ``missed`` / ``false`` ``c^p / 2`` per target-scan / track-scan not in such a pair; ``switching``
    ``gamma^p`` per switch. ``n_missed``, ``n_false`` (scans) and ``n_switches`` (a half switch counts
    1/2) are their counts, fractional where the LP solution is; with ``gamma = 0`` switching is free
    and ``n_switches`` is whatever the solver chose. ``per_scan = (total**p / K)**(1/p)`` (m).
    ``assignment (B, K, N)`` int64: the track slot of each target at each scan where they form a pair
    nearer than ``c``, else -1 (for the LP: the largest weight). ``integral (B,)`` bool: the
    solution is integral (always with ``integer=True``).
    """

    total: torch.Tensor
    localisation: torch.Tensor
    missed: torch.Tensor
    false: torch.Tensor
    switching: torch.Tensor
    n_missed: torch.Tensor
    n_false: torch.Tensor
    n_switches: torch.Tensor
    per_scan: torch.Tensor
    assignment: torch.Tensor
    integral: torch.Tensor


def _check(est, exists, truth, alive, c, p, gamma) -> None:
    if not (math.isfinite(c) and c > 0):
        raise ValueError(f"cut-off c must be a finite positive distance, got {c!r}")
    if not (math.isfinite(p) and p >= 1):
        raise ValueError(f"order p must be finite and >= 1, got {p!r}")
    if not (math.isfinite(gamma) and gamma >= 0):
        raise ValueError(f"switching cost gamma must be finite and >= 0, got {gamma!r}")
    if est.dim() != 4 or truth.dim() != 4:
        raise ValueError(f"est and truth must be (B, K, M, D) and (B, K, N, D), got {tuple(est.shape)} and {tuple(truth.shape)}")
    if exists.shape != est.shape[:-1] or alive.shape != truth.shape[:-1]:
        raise ValueError(f"exists {tuple(exists.shape)} / alive {tuple(alive.shape)} must be est {tuple(est.shape)} / "
                         f"truth {tuple(truth.shape)} without the last dim")
    if est.shape[:2] != truth.shape[:2] or est.shape[-1] != truth.shape[-1]:
        raise ValueError(f"est {tuple(est.shape)} and truth {tuple(truth.shape)} differ in runs, scans or D")
    if exists.dtype != torch.bool or alive.dtype != torch.bool:
        raise ValueError("exists and alive must be bool tensors")
    if not (bool(torch.isfinite(est[exists]).all()) and bool(torch.isfinite(truth[alive]).all())):
        raise ValueError("existing tracks and living targets must have finite positions")


def _run_arrays(dist, alive, exists, c: float, p: float):
    """One run's candidate pairs and costs: ``dist (K, N, M)`` m, ``alive (K, N)``, ``exists (K, M)``.

    Returns ``pi, pj (P,)`` the pairs nearer than ``c`` at some scan, ``near (K, P)`` (both exist,
    ``d < c``), ``dp (K, P)`` ``d^p`` there (0 elsewhere), ``cost (K, P)`` the pair's cost per scan."""
    both = alive[:, :, None] & exists[:, None, :]
    near_all = both & (dist < c)
    pi, pj = np.nonzero(near_all.any(0))
    near = near_all[:, pi, pj]
    d = np.where(both[:, pi, pj], dist[:, pi, pj], c)
    dp = np.where(near, d**p, 0.0)
    one = alive[:, pi] ^ exists[:, pj]
    cost = np.where(both[:, pi, pj], np.minimum(d, c) ** p, np.where(one, c**p / 2, 0.0))
    return pi, pj, near, dp, cost


def _programme(pi, pj, N: int, M: int, K: int, switching: bool):
    """The constraint matrices over the variables ``[W_i0 (K, N), W_0j (K, M), W_pair (K, P), e (K-1, P)]``
    (``e`` only when ``switching``): per scan each target's row and each track's column sum to 1,
    and ``+-(W^k - W^{k+1}) - e^k <= 0`` per pair. Returns ``(A_eq, A_ub, n_vars, n_W)``."""
    P = len(pi)
    per = N + M + P
    n_W = K * per
    base = (np.arange(K) * per)[:, None]
    v_i0, v_0j, v_p = base + np.arange(N), base + N + np.arange(M), base + N + M + np.arange(P)
    # equality rows: scan k's target i is row k*(N+M)+i, its track j row k*(N+M)+N+j
    rbase = (np.arange(K) * (N + M))[:, None]
    rows = np.concatenate([(rbase + np.arange(N)).ravel(), (rbase + N + np.arange(M)).ravel(),
                           (rbase + pi).ravel(), (rbase + N + pj).ravel()])
    cols = np.concatenate([v_i0.ravel(), v_0j.ravel(), v_p.ravel(), v_p.ravel()])
    n_e = (K - 1) * P if switching else 0
    n_vars = n_W + n_e
    A_eq = sparse.csr_array((np.ones(len(rows)), (rows, cols)), shape=(K * (N + M), n_vars))
    if n_e == 0:
        return A_eq, None, n_vars, n_W
    e = n_W + np.arange(n_e).reshape(K - 1, P)
    r = np.arange(n_e).reshape(K - 1, P)
    a, b = v_p[:-1], v_p[1:]
    rows = np.concatenate([r, r, r, n_e + r, n_e + r, n_e + r], axis=None)
    cols = np.concatenate([a, b, e, a, b, e], axis=None)
    vals = np.repeat([1.0, -1.0, -1.0, -1.0, 1.0, -1.0], n_e)
    A_ub = sparse.csr_array((vals, (rows, cols)), shape=(2 * n_e, n_vars))
    return A_eq, A_ub, n_vars, n_W


def _solve_run(dist, alive, exists, c: float, p: float, gamma: float, integer: bool) -> dict:
    K, N, M = dist.shape
    if K == 0 or N + M == 0:
        return {"loc": 0.0, "n_missed": 0.0, "n_false": 0.0, "n_switches": 0.0, "integral": True,
                "assignment": np.full((K, N), -1, dtype=np.int64)}
    pi, pj, near, dp, cost = _run_arrays(dist, alive, exists, c, p)
    P = len(pi)
    half = c**p / 2
    switching = gamma > 0 and K > 1 and P > 0
    A_eq, A_ub, n_vars, n_W = _programme(pi, pj, N, M, K, switching)
    obj = np.concatenate([np.hstack([half * alive, half * exists, cost]).ravel(), np.full(n_vars - K * (N + M + P), gamma**p / 2)])
    if integer:
        cons = [LinearConstraint(A_eq, 1.0, 1.0)] + ([LinearConstraint(A_ub, -np.inf, 0.0)] if A_ub is not None else [])
        integrality = np.zeros(n_vars)
        integrality[:n_W] = 1
        res = milp(obj, constraints=cons, integrality=integrality, bounds=Bounds(0.0, 1.0), options={"mip_rel_gap": 0.0})
    else:
        b_ub = None if A_ub is None else np.zeros(A_ub.shape[0])
        res = linprog(obj, A_ub=A_ub, b_ub=b_ub, A_eq=A_eq, b_eq=np.ones(A_eq.shape[0]), bounds=(0.0, 1.0), method="highs")
    if res.status != 0 or res.x is None:
        raise RuntimeError(f"trajectory GOSPA: HiGHS failed ({res.message})")
    W = np.clip(res.x[:n_W], 0.0, 1.0).reshape(K, N + M + P)
    rounded = np.round(W)
    integral = bool(np.all(np.abs(W - rounded) <= 1e-6))
    if integral:
        W = rounded
    w_i0, w_p = W[:, :N], W[:, N + M:]
    matched = w_p * near
    out = {"loc": float((w_p * dp).sum()),
           "n_missed": float(alive.sum() - matched.sum()), "n_false": float(exists.sum() - matched.sum()),
           "n_switches": float(np.abs(np.diff(w_p, axis=0)).sum() / 2) if K > 1 else 0.0, "integral": integral}
    # each target's best option per scan: a pair's track or nothing (-1)
    opts = np.full((K, N, M + 1), -1.0)
    opts[:, :, 0] = w_i0
    opts[:, pi, pj + 1] = w_p
    ok = np.zeros((K, N, M + 1), dtype=bool)
    ok[:, pi, pj + 1] = near
    best = opts.argmax(-1)
    out["assignment"] = np.where(np.take_along_axis(ok, best[..., None], -1)[..., 0], best - 1, -1)
    return out


def trajectory_gospa(est: torch.Tensor, exists: torch.Tensor, truth: torch.Tensor, alive: torch.Tensor, c: float, p: float,
                     gamma: float, integer: bool = True) -> TrajectoryGOSPA:
    """Trajectory GOSPA (alpha = 2) of the tracks ``est (B, K, M, D)`` / ``exists (B, K, M)`` against
    the targets ``truth (B, K, N, D)`` / ``alive (B, K, N)`` per run: cut-off ``c`` (m), order ``p >= 1``,
    switching cost ``gamma >= 0`` (m); ``integer`` chooses the integer programme (the metric) or its
    LP relaxation (module docstring). Pass the scored scans only (e.g. ``[:, warmup:]``): the sum
    runs over every scan given. Bad arguments raise ``ValueError``."""
    _check(est, exists, truth, alive, c, p, gamma)
    B, K, M, _ = est.shape
    N = truth.shape[2]
    e = torch.where(exists[..., None], est, torch.zeros((), dtype=est.dtype, device=est.device))
    t = torch.where(alive[..., None], truth, torch.zeros((), dtype=truth.dtype, device=truth.device))
    dist = (t.unsqueeze(-2) - e.unsqueeze(-3)).to(torch.float64).pow(2).sum(-1).sqrt().cpu().numpy()  # (B, K, N, M)
    al, ex = alive.cpu().numpy(), exists.cpu().numpy()
    runs = [_solve_run(dist[b], al[b], ex[b], c, p, gamma, integer) for b in range(B)]  # runs are independent LPs
    f64 = lambda key: torch.tensor([r[key] for r in runs], dtype=torch.float64, device=truth.device)
    half = c**p / 2
    loc, n_missed, n_false, n_switches = f64("loc"), f64("n_missed"), f64("n_false"), f64("n_switches")
    switching = gamma**p * n_switches
    total_p = loc + half * n_missed + half * n_false + switching
    assignment = torch.as_tensor(np.stack([r["assignment"] for r in runs]) if runs else np.zeros((0, K, N), np.int64),
                                 dtype=torch.int64, device=truth.device)
    return TrajectoryGOSPA(total=total_p ** (1.0 / p), localisation=loc, missed=half * n_missed, false=half * n_false,
                           switching=switching, n_missed=n_missed, n_false=n_false, n_switches=n_switches,
                           per_scan=(total_p / max(K, 1)) ** (1.0 / p), assignment=assignment,
                           integral=torch.tensor([r["integral"] for r in runs], dtype=torch.bool, device=truth.device))
