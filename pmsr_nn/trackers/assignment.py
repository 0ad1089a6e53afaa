"""(S+1)-D assignment of a multi-sensor JPDA by Lagrangian relaxation.

* :func:`sd_assign` solves the (S+1)-D assignment (targets x one measurement or a miss per
  sensor) by Lagrangian relaxation (Deb et al. 1997);
* :func:`m_best_sd` ranks its ``m`` cheapest events by Murty partitioning over events (Popp,
  Pattipati & Bar-Shalom 2001).

The ranked 2-D assignment (Murty) is :mod:`.assignment_2d`.

Problem format: ``N`` targets, ``S`` sensors, sensor ``s`` has ``n_s`` measurements. A
candidate ``l`` is a row of ``tuples (L, 1 + S)`` int: column 0 the target, column ``1 + s`` the
measurement of sensor ``s`` or -1 (missed), with cost ``costs[l]``. An event picks one candidate
per target, no measurement used twice (unused ones are clutter); its cost is the sum of its
candidates' costs. Every target must have an all-(-1) candidate, so an event always exists.
"""

from __future__ import annotations

import heapq
import itertools
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from ..errors import ConfigError
from .assignment_2d import check_integer

__all__ = ["SDSolution", "brute_force_events", "m_best_sd", "sd_assign"]

BRUTE_FORCE_MAX_EVENTS = 200_000
STEP_FACTOR = 2.0
"""Initial factor of the Polyak step of the subgradient method."""
STALL_PATIENCE = 2
"""Iterations without a better dual value before the step factor is halved."""



@dataclass(frozen=True)
class SDSolution:
    """A feasible event: ``picks (N,)`` the candidate (index into ``tuples``/``costs``) of each
    target, ``cost`` its cost, ``lower_bound`` a Lagrangian lower bound on the optimum of the
    problem it solves (``lower_bound <= optimum <= cost``)."""

    picks: np.ndarray
    cost: float
    lower_bound: float

    @property
    def gap(self) -> float:
        """Duality gap ``cost - lower_bound`` (>= 0) in the costs' units. With costs that are
        negative log-likelihoods (nats) the returned event is at least ``exp(-gap)`` times as
        probable as the best one. (A gap relative to ``|cost|`` would mislead: a JPDA event's
        cost, a sum of log-likelihood ratios, can be near zero.)"""
        return max(self.cost - self.lower_bound, 0.0)


@dataclass
class _Result:
    picks: np.ndarray  # (N,) indices into the candidates given to _solve
    cost: float
    lower_bound: float
    u: np.ndarray  # multipliers of sensors 2..S, all their measurements (warm start)


def check_problem(tuples, costs, n_meas, n_targets):
    """Validated ``(target (L,), meas (L, S), costs (L,), n_meas (S,), N)``."""
    N = check_integer(n_targets, "n_targets", 0)
    try:
        nm = np.asarray(n_meas)
    except (TypeError, ValueError) as e:  # ragged input
        raise ConfigError(f"n_meas must be a sequence of integers: {e}") from None
    if nm.ndim != 1 or len(nm) < 1 or not np.issubdtype(nm.dtype, np.integer):
        raise ConfigError(f"n_meas must be a non-empty sequence of integers, got {n_meas!r}")
    if (nm < 0).any():
        raise ConfigError(f"n_meas must be >= 0, got {nm.tolist()}")
    S = len(nm)
    t = np.asarray(tuples)
    if t.size == 0:
        t = t.reshape(0, 1 + S).astype(np.intp)
    if t.ndim != 2 or t.shape[1] != 1 + S:
        raise ConfigError(f"tuples must have shape (L, {1 + S}) for {S} sensors, got {t.shape}")
    if not np.issubdtype(t.dtype, np.integer):
        raise ConfigError(f"tuples must be integers, got dtype {t.dtype}")
    c = np.asarray(costs, dtype=np.float64)
    if c.shape != (len(t),):
        raise ConfigError(f"costs must have shape ({len(t)},) like tuples, got {c.shape}")
    if not np.isfinite(c).all():
        raise ConfigError("costs must be finite (no NaN or inf)")
    tg, meas = t[:, 0].astype(np.intp), t[:, 1:].astype(np.intp)
    if len(t) and (tg.min() < 0 or tg.max() >= N):
        raise ConfigError(f"target indices must be in [0, {N}), got [{tg.min()}, {tg.max()}]")
    if ((meas < -1) | (meas >= nm)).any():
        raise ConfigError(f"measurement indices must be in [-1, n_s) with n_meas={nm.tolist()}")
    has_miss = np.zeros(N, dtype=bool)
    has_miss[tg[(meas == -1).all(axis=1)]] = True
    if not has_miss.all():
        raise ConfigError(f"target {int(np.argmin(has_miss))} has no all-(-1) (missed) candidate")
    return tg, meas, c, nm.astype(np.intp), N


def measurement_slots(meas: np.ndarray, n_meas: np.ndarray) -> tuple[np.ndarray, int]:
    """Global measurement slots ``(L, S)`` (sensor offset + index; misses -> ``total``), total."""
    cum = np.cumsum(n_meas)
    total = int(cum[-1]) if len(cum) else 0
    return np.where(meas >= 0, cum - n_meas + meas, total), total


def _run_starts(sorted_keys: np.ndarray) -> np.ndarray:
    """Positions where a run of equal keys starts in ``sorted_keys (L,)``."""
    return np.flatnonzero(np.concatenate(([True], sorted_keys[1:] != sorted_keys[:-1])))[: len(sorted_keys)]


class _Cells:
    """The 2-D problem targets x (sensor-1 measurements + one miss column per target).

    Cell ``(k, i)`` costs the minimum over the candidates of target ``k`` with sensor-1
    measurement ``i``; cell ``(k, n1 + k)`` the minimum over its candidates that miss sensor 1.
    """

    def __init__(self, tg: np.ndarray, i1: np.ndarray, n1: int, N: int):
        self.width = n1 + N
        self.shape = (N, self.width)
        self.cell = tg * self.width + np.where(i1 >= 0, i1, n1 + tg)
        cs = np.sort(self.cell)
        self.starts = _run_starts(cs)
        self.uniq = cs[self.starts]
        self.group = np.full(N * self.width, -1, dtype=np.intp)
        self.group[self.uniq] = np.arange(len(self.uniq))

    def solve(self, values: np.ndarray) -> tuple[np.ndarray, float] | None:
        """Cheapest choice (one candidate per target, sensor-1 measurements distinct) under
        ``values (L,)``: ``(picks (N,), value)`` or None when infeasible."""
        # Sorted by (cell, value), a cell's cheapest candidate is the first of its run.
        best = np.lexsort((values, self.cell))[self.starts]
        mat = np.full(self.shape, np.inf)
        mat.flat[self.uniq] = values[best]
        try:  # every row has a finite cell (checked by the caller); Hall's condition may fail
            rows, cols = linear_sum_assignment(mat)
        except ValueError:
            return None
        picks = best[self.group[rows * self.width + cols]]
        return picks, float(values[picks].sum())


def _greedy(tg, slot, costs, N, total) -> np.ndarray | None:
    """A feasible event, targets without a miss candidate first, each taking its cheapest
    candidate free of measurements already used; None if that fails."""
    missed = (slot == total).all(axis=1)
    has_miss = np.zeros(N, dtype=bool)
    has_miss[tg[missed]] = True
    used = np.zeros(total + 1, dtype=bool)
    picks = np.full(N, -1, dtype=np.intp)
    for k in np.argsort(has_miss, kind="stable"):
        ok = np.flatnonzero((tg == k) & ~used[slot].any(axis=1))
        if len(ok) == 0:
            return None
        p = ok[np.argmin(costs[ok])]
        picks[k] = p
        used[slot[p]] = True
        used[total] = False
    return picks


def _improve(picks, tg, slot, costs, total):
    """Coordinate descent: each target in turn takes its cheapest candidate compatible with the
    others' picks, until no target changes."""
    picks = picks.copy()
    changed = True
    while changed:
        changed = False
        for k in range(len(picks)):
            used = np.zeros(total + 1, dtype=bool)
            used[slot[np.delete(picks, k)]] = True
            used[total] = False
            ok = np.flatnonzero((tg == k) & ~used[slot].any(axis=1))
            p = ok[np.argmin(costs[ok])]
            if costs[p] < costs[picks[k]]:
                picks[k], changed = p, True
    return picks


def _solve(tg, meas, costs, n_meas, N, iterations, tol, u0=None, cutoff=math.inf) -> _Result | None:
    """Best feasible event found for a validated problem (no all-(-1) guarantee needed).

    None when the problem is infeasible, or when its optimum is proven to be >= ``cutoff`` (the
    caller has something as good). ``u0`` warm-starts the multipliers (layout: all measurements
    of sensors 2..S, as the returned ``u``).
    """
    S = len(n_meas)
    n_relaxed = int(n_meas[1:].sum())
    # Per-target cheapest candidates: optimal (and certified) when they share no measurement.
    order = np.lexsort((costs, tg))
    ts = tg[order]
    starts = _run_starts(ts)
    if len(starts) < N:
        return None  # a target without candidates
    picks = order[starts]
    slot_p, total = measurement_slots(meas[picks], n_meas)
    if np.bincount(slot_p.ravel(), minlength=total + 1)[:total].max(initial=0) <= 1:
        c = float(costs[picks].sum())
        return _Result(picks, c, c, np.zeros(n_relaxed) if u0 is None else u0)
    if float(costs[picks].sum()) >= cutoff:
        return None

    cells = _Cells(tg, meas[:, 0], int(n_meas[0]), N)
    if S == 1:
        res = cells.solve(costs)
        if res is None or res[1] >= cutoff:
            return None
        c = float(costs[res[0]].sum())
        return _Result(res[0], c, c, np.zeros(0))

    # Relax "used at most once" of sensors 2..S, only for measurements that candidates of two or
    # more targets share: the others can never be used twice, their optimal multiplier is 0.
    g, _ = measurement_slots(meas[:, 1:], n_meas[1:])
    pairs = np.unique(tg[:, None] * (n_relaxed + 1) + g)
    shared = np.flatnonzero(np.bincount(pairs % (n_relaxed + 1), minlength=n_relaxed + 1)[:n_relaxed] >= 2)
    n_shared = len(shared)
    compact = np.full(n_relaxed + 1, n_shared, dtype=np.intp)
    compact[shared] = np.arange(n_shared)
    gc = compact[g]  # (L, S-1), n_shared = no penalty
    u = np.zeros(n_shared) if u0 is None else np.maximum(np.asarray(u0, dtype=np.float64)[shared], 0.0)
    u_pad = np.zeros(n_shared + 1)
    off2 = int(n_meas[1])  # sensors 3..S start here in the layout of sensors 2..S
    i1 = meas[:, 0]

    def full(v: np.ndarray) -> np.ndarray:
        out = np.zeros(n_relaxed)
        out[shared] = v
        return out

    best_ub, best_picks = math.inf, None
    best_lb, best_u = -math.inf, u
    cache: dict[bytes, tuple[np.ndarray, float] | None] = {}
    factor, stall = STEP_FACTOR, 0
    for _ in range(iterations):
        u_pad[:n_shared] = u
        relaxed = cells.solve(costs + u_pad[gc].sum(axis=1))
        if relaxed is None:
            return None  # the relaxation is infeasible, so is the problem
        rp, value = relaxed
        lb = value - float(u.sum())
        if lb > best_lb:
            best_lb, best_u, stall = lb, u, 0
        else:
            stall += 1
            if stall >= STALL_PATIENCE:  # the dual stopped improving: shorter steps
                factor, stall = factor / 2, 0
        if best_lb >= min(cutoff, best_ub):
            break
        uses = np.bincount(gc[rp].ravel(), minlength=n_shared + 1)[:n_shared]
        if uses.max(initial=0) <= 1:  # the relaxed solution is itself feasible
            c = float(costs[rp].sum())
            if c < best_ub:
                best_ub, best_picks = c, rp
        # Recovery, Deb's successive relaxation widened: each target keeps its sensor-1
        # measurement of the relaxed solution or misses sensor 1 (a superset of Deb's choice;
        # the misses keep the all-(-1) guarantee alive down the recursion), and sensors 2..S
        # are solved recursively with the true costs.
        fixed = np.empty(N, dtype=np.intp)
        fixed[tg[rp]] = i1[rp]
        key = fixed.tobytes()
        if key not in cache:
            idx = np.flatnonzero((i1 == -1) | (i1 == fixed[tg]))
            sub = _solve(tg[idx], meas[idx, 1:], costs[idx], n_meas[1:], N, iterations, tol,
                         full(u)[off2:], min(cutoff, best_ub))
            cache[key] = None if sub is None else (idx[sub.picks], sub.cost)
        rec = cache[key]
        if rec is not None and rec[1] < best_ub:
            best_ub, best_picks = rec[1], rec[0]
        if math.isfinite(best_ub) and best_ub - best_lb <= tol * max(abs(best_ub), 1e-12):
            break
        grad = uses - 1.0
        grad[(u <= 0) & (grad < 0)] = 0.0  # projected: u cannot go below 0
        norm2 = float(grad @ grad)
        if norm2 == 0.0:
            break  # complementary slackness holds: the relaxed solution is optimal
        target = min(cutoff, best_ub)
        if not math.isfinite(target):
            target = lb + abs(lb) + 1.0
        u = np.maximum(u + factor * max(target - lb, 0.0) / norm2 * grad, 0.0)

    if best_picks is None:
        if best_lb >= cutoff:
            return None
        best_picks = _greedy(tg, measurement_slots(meas, n_meas)[0], costs, N, total)
        if best_picks is None:
            return None
    if best_ub - best_lb > tol * max(abs(best_ub), 1e-12):
        best_picks = _improve(best_picks, tg, measurement_slots(meas, n_meas)[0], costs, total)
    c = float(costs[best_picks].sum())
    if c >= cutoff and best_lb >= cutoff:
        return None
    return _Result(best_picks, c, min(best_lb, c), full(best_u))


def _check_iterations(iterations: int, tol: float = 0.0) -> int:
    it = check_integer(iterations, "iterations", 1)
    if not (isinstance(tol, (int, float, np.floating)) and tol >= 0):
        raise ConfigError(f"tol must be a number >= 0, got {tol!r}")
    return it


def sd_assign(tuples: np.ndarray, costs: np.ndarray, n_meas: Sequence[int], n_targets: int,
              iterations: int = 20, tol: float = 1e-6) -> SDSolution:
    """Cheapest event of the (S+1)-D assignment (format in the module docstring).

    ``tuples (L, 1 + S)`` int, ``costs (L,)`` finite, ``n_meas (S,)``, ``n_targets`` = N.
    Returns the best feasible event found with a lower bound on the optimum.

    With ``S == 1`` the problem is an exact 2-D assignment (gap 0). With ``S >= 2`` (Deb et al.
    1997) the at-most-once constraints of sensors 2..S are relaxed with multipliers ``u >= 0``:
    the relaxed problem is a 2-D assignment of targets to sensor-1 measurements (cell = cheapest
    penalised candidate), whose value minus ``sum(u)`` bounds the optimum from below. ``u``
    follows projected subgradients with Polyak steps towards the best feasible cost, the step
    factor halved when the dual stalls. Every iteration recovers a feasible event by successive
    relaxation: each target keeps its relaxed sensor-1 measurement *or misses sensor 1* (a
    superset of Deb's choice that keeps an event feasible at every level), and sensors 2..S are
    solved recursively down to an exact 2-D problem; the best event is polished by coordinate
    descent (one target at a time). Stops after ``iterations`` or when the relative gap is
    <= ``tol``. Only multipliers of measurements that two targets' candidates share are used
    (the others are 0 at the optimum), and when every target's cheapest candidate is compatible
    with the others' the answer is immediate and exact.
    """
    tg, meas, c, nm, N = check_problem(tuples, costs, n_meas, n_targets)
    it = _check_iterations(iterations, tol)
    res = _solve(tg, meas, c, nm, N, it, float(tol))
    assert res is not None, "an all-(-1) event always exists"
    return SDSolution(picks=res.picks, cost=res.cost, lower_bound=res.lower_bound)


def m_best_sd(tuples: np.ndarray, costs: np.ndarray, n_meas: Sequence[int], n_targets: int, m: int,
              iterations: int = 20) -> list[SDSolution]:
    """Up to ``m`` distinct events of the (S+1)-D assignment, in non-decreasing cost order.

    Murty partitioning over events (Popp, Pattipati & Bar-Shalom 2001): from a node's event
    ``p_1..p_K``, child ``j`` forces the picks of the node's free targets ``1..j-1`` (they leave
    the child problem, and so does every candidate that uses one of their measurements) and
    forbids ``p_j``. Each child is solved once by :func:`sd_assign`'s relaxation, warm-started
    with its parent's multipliers, and stopped early once its lower bound shows it cannot enter
    the queue; a child without a feasible event (a target left without candidates, e.g. after
    its all-(-1) candidate was forbidden) is skipped. The queue keeps at most as many nodes as
    answers still wanted. Each event carries the lower bound of its subproblem.

    Ranks are exact for ``S == 1`` (every subproblem is solved exactly); for ``S >= 2`` the
    events are the best the relaxation found in each subproblem, so a cheaper event can be
    missed when a relaxation ends with a duality gap (see :attr:`SDSolution.gap`).
    """
    tg, meas, c, nm, N = check_problem(tuples, costs, n_meas, n_targets)
    m = check_integer(m, "m", 1)
    it = _check_iterations(iterations)
    tol = 1e-6
    slot, total = measurement_slots(meas, nm)
    use = np.zeros((len(c), total + 1))
    use[np.arange(len(c))[:, None], slot] = 1.0
    conflict = (use[:, :total] @ use[:, :total].T) > 0  # (L, L): candidates sharing a measurement

    root = _solve(tg, meas, c, nm, N, it, tol)
    assert root is not None, "an all-(-1) event always exists"
    counter = itertools.count()
    # Node: (cost, tie-break, picks (N,), lower bound, forced targets (N,), live candidates (L,), u).
    heap = [(float(c[root.picks].sum()), next(counter), root.picks, root.lower_bound,
             np.zeros(N, dtype=bool), np.ones(len(c), dtype=bool), root.u)]
    out: list[SDSolution] = []
    remap = np.empty(N, dtype=np.intp)
    while heap and len(out) < m:
        cost, _, picks, lb, forced, live, u = heapq.heappop(heap)
        out.append(SDSolution(picks=picks, cost=cost, lower_bound=lb))
        if len(out) == m:
            break
        forced, live = forced.copy(), live.copy()
        wanted = m - len(out)
        for f in np.flatnonzero(~forced):
            p = picks[f]
            child_live = live.copy()
            child_live[p] = False
            targets = np.flatnonzero(~forced)  # f and the targets after it
            idx = np.flatnonzero(child_live)
            remap[targets] = np.arange(len(targets))
            fixed_cost = float(c[picks[forced]].sum())
            # A child no cheaper than the queue's wanted-th node would be dropped: stop early.
            cutoff = max(e[0] for e in heap) - fixed_cost if len(heap) >= wanted else math.inf
            sub = _solve(remap[tg[idx]], meas[idx], c[idx], nm, len(targets), it, tol, u, cutoff)
            if sub is not None:
                child = picks.copy()
                child[targets] = idx[sub.picks]
                node = (float(c[child].sum()), next(counter), child, fixed_cost + sub.lower_bound,
                        forced.copy(), child_live, sub.u)
                heapq.heappush(heap, node)
                if len(heap) > wanted:
                    heap = heapq.nsmallest(wanted, heap)  # sorted, hence a valid heap
            forced[f] = True
            live &= ~conflict[p] & (tg != f)
    # With S >= 2 a child's relaxation may beat its parent's: report in cost order anyway.
    out.sort(key=lambda s: s.cost)
    return out


def brute_force_events(tuples: np.ndarray, costs: np.ndarray, n_meas: Sequence[int],
                       n_targets: int) -> list[tuple[np.ndarray, float]]:
    """All feasible events ``(picks (N,), cost)`` sorted by cost (stable), by enumeration of
    every combination of one candidate per target: for tests (at most 200,000 combinations)."""
    tg, meas, c, nm, N = check_problem(tuples, costs, n_meas, n_targets)
    if N == 0:
        return [(np.zeros(0, dtype=np.intp), 0.0)]
    per_target = [np.flatnonzero(tg == k) for k in range(N)]
    n_comb = math.prod(len(p) for p in per_target)
    if n_comb > BRUTE_FORCE_MAX_EVENTS:
        raise ConfigError(f"brute force is limited to {BRUTE_FORCE_MAX_EVENTS} combinations, got {n_comb}")
    combos = np.stack(np.meshgrid(*per_target, indexing="ij"), axis=-1).reshape(-1, N)
    slot, total = measurement_slots(meas, nm)
    s = np.sort(slot[combos].reshape(len(combos), -1), axis=1)
    clash = ((s[:, 1:] == s[:, :-1]) & (s[:, 1:] < total)).any(axis=1)
    combos = combos[~clash]
    total_cost = c[combos].sum(axis=1)
    order = np.argsort(total_cost, kind="stable")
    return [(combos[i], float(total_cost[i])) for i in order]
