"""Exact m-best events of the (S+1)-D assignment by vectorised branch and bound.

The problem is :mod:`.assignment`'s (targets, one candidate each, no measurement used twice).
:func:`m_best_bnb` returns its ``m`` cheapest events exactly, or None when the search would
need more than ``max_states`` partial events (the caller then falls back on
:func:`.assignment.m_best_sd`'s Lagrangian relaxation, which can miss cheaper events where a
duality gap stays open).

The search fixes one target per level (fewest candidates first) over an array of partial
events: each is extended by every candidate of the next target, and an extension survives
when it shares no measurement with the partial event and ``its cost + the cheapest candidate of
each target still to fix <= U``. That sum bounds every completion from below, so every feasible
event of cost ``<= U`` is found. ``U`` starts :data:`FIRST_WINDOW_NATS` above the lower bound of
the whole problem (the sum of each target's cheapest candidate) and widens by
:data:`WINDOW_GROWTH` until at least ``m`` events are found, or every event is (``U`` at the sum
of each target's dearest candidate); the ``m`` cheapest found are then the ``m`` cheapest of the
problem (ties at the ``m``-th aside).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from .assignment import SDSolution, check_problem, measurement_slots
from .assignment_2d import check_integer

__all__ = ["MAX_STATES", "m_best_bnb"]

MAX_STATES = 200_000
"""Partial events a search may hold at one level before it gives up (about 10 MB per word of
measurement mask)."""
FIRST_WINDOW_NATS = 8.0
"""First cost window above the lower bound: the m-th best event of a JPDA cluster usually lies
a few nats above the best."""
WINDOW_GROWTH = 1.5
"""Factor by which the window widens when it holds fewer than m events."""
PAIRS_PER_CHUNK = 1 << 20
"""Extensions (partial event x candidate) tested at once: bounds the search's temporary memory."""


def _measurement_masks(slot: np.ndarray, total: int) -> np.ndarray:
    """Bit masks ``(L, W)`` uint64 of the measurements each candidate uses (``slot (L, S)``
    global slots, ``total`` = a miss)."""
    W = max(1, -(-total // 64))
    masks = np.zeros((len(slot), W), dtype=np.uint64)
    rows, cols = np.nonzero(slot < total)
    s = slot[rows, cols]
    np.bitwise_or.at(masks, (rows, s // 64), np.left_shift(np.uint64(1), (s % 64).astype(np.uint64)))
    return masks


def _search(lists: list[np.ndarray], costs: np.ndarray, masks: np.ndarray, U: float, rest: np.ndarray,
            max_states: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Every feasible event of cost ``<= U``: ``(picks (E, N) in the order of lists, cost (E,))``,
    or None past ``max_states``. ``lists[j]`` the candidates of level j, ``rest[j]`` the least
    cost of the levels after j."""
    tol = 1e-9 * (1.0 + abs(U)) if math.isfinite(U) else 0.0  # admits events lost to summation order
    picks = np.zeros((1, 0), dtype=np.intp)
    cost = np.zeros(1)
    used = np.zeros((1, masks.shape[1]), dtype=np.uint64)
    for j, cand in enumerate(lists):
        if not len(cost):  # nothing within U: no event either
            return np.zeros((0, len(lists)), dtype=np.intp), cost
        step = max(1, PAIRS_PER_CHUNK // len(cand))  # rows of partial events per chunk of extensions
        pi, ci, kept = [], [], 0
        for start in range(0, len(cost), step):
            r, k = np.nonzero(cost[start:start + step, None] + (costs[cand] + rest[j])[None, :] <= U + tol)
            r += start
            free = ~(used[r] & masks[cand[k]]).any(axis=1)
            pi.append(r[free])
            ci.append(k[free])
            kept += len(pi[-1])
            if kept > max_states:
                return None
        pi, ci = np.concatenate(pi), np.concatenate(ci)
        picks = np.concatenate([picks[pi], cand[ci][:, None]], axis=1)
        cost, used = cost[pi] + costs[cand[ci]], used[pi] | masks[cand[ci]]
    return picks, cost


def m_best_bnb(tuples: np.ndarray, costs: np.ndarray, n_meas: Sequence[int], n_targets: int, m: int,
               max_states: int = MAX_STATES) -> list[SDSolution] | None:
    """The ``m`` cheapest events (fewer if fewer exist), in non-decreasing cost order, each with
    ``lower_bound == cost`` (exact: no gap); None when the search exceeds ``max_states`` partial
    events at a level. Problem format as :func:`.assignment.m_best_sd` (every target needs an
    all-(-1) candidate)."""
    tg, meas, c, nm, N = check_problem(tuples, costs, n_meas, n_targets)
    m = check_integer(m, "m", 1)
    max_states = check_integer(max_states, "max_states", 1)
    if N == 0:
        return [SDSolution(picks=np.zeros(0, dtype=np.intp), cost=0.0, lower_bound=0.0)]
    slot, total = measurement_slots(meas, nm)
    masks = _measurement_masks(slot, total)
    per = [np.flatnonzero(tg == k) for k in range(N)]
    order = np.argsort([len(p) for p in per], kind="stable")  # fewest candidates first: fewer partial events
    lists = [per[k] for k in order]
    least = np.array([c[p].min() for p in lists])
    rest = np.concatenate([np.cumsum(least[::-1])[::-1][1:], [0.0]])
    lower, upper = float(least.sum()), float(sum(c[p].max() for p in lists))
    window = FIRST_WINDOW_NATS
    while True:
        U = lower + window
        found = _search(lists, c, masks, U if U < upper else math.inf, rest, max_states)
        if found is None:
            return None
        if len(found[1]) >= m or U >= upper:
            break
        window *= WINDOW_GROWTH
    picks_level, cost = found
    keep = np.argsort(cost, kind="stable")[:m]
    picks = np.empty((len(keep), N), dtype=np.intp)
    picks[:, order] = picks_level[keep]
    out = []
    for p in picks:
        e = float(c[p].sum())
        out.append(SDSolution(picks=p, cost=e, lower_bound=e))
    out.sort(key=lambda s: s.cost)  # the search summed in level order: equal up to rounding
    return out
