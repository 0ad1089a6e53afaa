"""Ranked 2-D assignment: the ``m`` cheapest assignments of a cost matrix (Murty 1968, with the
Miller-Stone-Cox 1997 improvements that apply on top of scipy's ``linear_sum_assignment``), and
brute-force enumeration for tests. The (S+1)-D assignment of a multi-sensor JPDA is
:mod:`.assignment`.
"""

from __future__ import annotations

import heapq
import itertools
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from ..errors import ConfigError

__all__ = ["Assignment", "brute_force_assignments", "check_integer", "murty"]

BRUTE_FORCE_MAX_ROWS = 7


@dataclass(frozen=True)
class Assignment:
    """One assignment of a 2-D problem: ``cols (n_rows,)`` the column of each row, ``cost`` the total."""

    cols: np.ndarray
    cost: float


def check_integer(value: object, name: str, minimum: int) -> int:
    """``value`` as an int, or a one-line error unless it is an integer (not a bool) >= ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ConfigError(f"{name} must be an integer, got {value!r}")
    if value < minimum:
        raise ConfigError(f"{name} must be >= {minimum}, got {value}")
    return int(value)


def _check_matrix(cost: np.ndarray) -> np.ndarray:
    c = np.asarray(cost, dtype=np.float64)
    if c.ndim != 2:
        raise ConfigError(f"cost must be a 2-D matrix, got shape {c.shape}")
    if c.shape[0] > c.shape[1]:
        raise ConfigError(f"cost must have no more rows than columns, got shape {c.shape}")
    if np.isnan(c).any() or (c == -np.inf).any():
        raise ConfigError("cost must not contain NaN or -inf (use +inf for forbidden pairs)")
    return c


def _lsa(cost: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Cheapest assignment of every row of ``cost (r, c)``, ``r <= c``: ``(cols (r,), cost)``, or
    None when no assignment avoids the ``inf`` entries."""
    if cost.shape[0] == 0:
        return np.zeros(0, dtype=np.intp), 0.0
    if not np.isfinite(cost).any(axis=1).all():
        return None
    try:
        rows, cols = linear_sum_assignment(cost)
    except ValueError:  # scipy: "cost matrix is infeasible"
        return None
    return cols, float(cost[rows, cols].sum())


def _total(cost: np.ndarray, cols: np.ndarray) -> float:
    # One summation rule for every reported cost, so equal assignments report equal costs.
    return float(cost[np.arange(len(cols)), cols].sum())


def murty(cost: np.ndarray, m: int) -> list[Assignment]:
    """The ``m`` cheapest assignments of ``cost (n_rows, n_cols)``, ``n_rows <= n_cols``, in
    non-decreasing cost order.

    Every row gets a distinct column; ``inf`` entries are forbidden pairs. Returns fewer than
    ``m`` when fewer feasible assignments exist (an empty list when none does).

    Murty's partitioning with the Miller-Stone-Cox (1997) improvements that need no dual
    variables: (a) a subproblem inherits its parent's solution, so only the reduced matrix of its
    free rows and columns is solved; (b) the children of a node are made in one pass, each
    solved exactly once and queued with its cost; (c) the queue never keeps more nodes than
    answers still wanted (the costliest are dropped: they and their descendants cannot rank).
    Their dual-variable inheritance (warm-starting each child's Hungarian solve, and sorting
    children by dual lower bounds) is not used: scipy does not expose the duals.
    """
    c = _check_matrix(cost)
    m = check_integer(m, "m", 1)
    n_rows, n_cols = c.shape
    first = _lsa(c)
    if first is None:
        return []
    sub_cols, _ = first
    counter = itertools.count()
    # Node: (cost, tie-break, full cols, reduced matrix, its rows, its columns, its solution).
    heap = [(_total(c, sub_cols), next(counter), sub_cols, c, np.arange(n_rows), np.arange(n_cols), sub_cols)]
    out: list[Assignment] = []
    while heap and len(out) < m:
        total, _, cols, sub, rows, colidx, sol = heapq.heappop(heap)
        out.append(Assignment(cols=cols, cost=total))
        if len(out) == m:
            break
        # Child j forbids the node's pair of free row j and fixes its pairs of rows 0..j-1;
        # fixing a pair removes its row and column from the reduced matrix.
        mat, r, cx, s = sub, rows, colidx, sol
        for _ in range(len(rows)):
            child = mat.copy()
            child[0, s[0]] = np.inf
            res = _lsa(child)
            if res is not None:
                child_cols = cols.copy()
                child_cols[r] = cx[res[0]]
                heapq.heappush(heap, (_total(c, child_cols), next(counter), child_cols, child, r, cx, res[0]))
            keep = np.arange(mat.shape[1]) != s[0]
            mat, r, cx = mat[1:, keep], r[1:], cx[keep]
            s = s[1:] - (s[1:] > s[0])
        wanted = m - len(out)
        if len(heap) > wanted:
            heap = heapq.nsmallest(wanted, heap)  # sorted, hence a valid heap
    return out


def brute_force_assignments(cost: np.ndarray) -> list[Assignment]:
    """All feasible assignments of ``cost (n_rows, n_cols)``, ``n_rows <= n_cols``, sorted by cost
    (stable).

    Enumerates ``itertools.permutations``: for tests and small problems only (``n_rows <= 7``).
    """
    c = _check_matrix(cost)
    n_rows, n_cols = c.shape
    if n_rows > BRUTE_FORCE_MAX_ROWS:
        raise ConfigError(f"brute force is limited to {BRUTE_FORCE_MAX_ROWS} rows, got {n_rows}")
    out = []
    for perm in itertools.permutations(range(n_cols), n_rows):
        cols = np.array(perm, dtype=np.intp)
        if np.isfinite(c[np.arange(n_rows), cols]).all():
            out.append(Assignment(cols=cols, cost=_total(c, cols)))
    out.sort(key=lambda a: a.cost)
    return out
