"""JPDA association probabilities from ranked association events.

An association event assigns every track either one detection or a miss, no detection to two
tracks (the rest are clutter). With detection probability ``Pd`` and clutter density ``lambda``
(per unit of measurement space) its posterior probability is proportional to

    prod_{detected tracks} Pd N(z_i; z_hat_t, S_t) / lambda  *  prod_{missed tracks} (1 - Pd),

so with the cost of an event = minus the log of that product, the most probable events are the
cheapest assignments: the m-best events of Eqs. 12 and 19 of the S-MSJPDA paper come from a
ranked (m-best) assignment solver, and the marginal probability that track ``t`` took detection
``i`` (``alpha`` / ``beta``) is the normalised sum over the events that contain the pair.
"""

from __future__ import annotations

import math

import numpy as np

from .assignment import m_best_sd
from .assignment_2d import murty

MIN_MISS_PROBABILITY = 1e-300
"""``1 - Pd`` is floored here, so a miss stays a finite (if absurdly costly) option at Pd = 1 and an
event always exists."""


def miss_cost(pd: float) -> float:
    """``-log(1 - Pd)``: the cost of a track taking no detection."""
    return -math.log(max(1.0 - pd, MIN_MISS_PROBABILITY))


def floored_clutter_density(clutter, components) -> float:
    """Expected clutter per unit of the measurement space of ``components`` (a ``ClutterSpec``),
    floored at 1e-3 points per box: a tracker needs a positive density even where none is simulated."""
    return max(clutter.density_of(components), 1e-3 / clutter.volume_of(components))


def detection_costs(log_lik: np.ndarray, pd: float, density: float) -> np.ndarray:
    """``-log(Pd N / lambda)`` for each (track, detection) from ``log_lik (..., M)`` (``log N``)."""
    if pd <= 0.0:
        return np.full(log_lik.shape, np.inf)
    return -(log_lik + math.log(pd) - math.log(max(density, 1e-300)))


def event_probabilities(costs: np.ndarray) -> np.ndarray:
    """Normalised ``exp(-cost)`` of ranked events ``costs (E,)``."""
    w = np.exp(-(costs - costs.min()))
    return w / w.sum()


def single_sensor_marginals(cost: np.ndarray, m: int | None) -> np.ndarray:
    """Association probabilities of one sensor's tracks from detection costs ``cost (T, M)``
    (``inf`` where a detection is outside a track's gate) and the miss cost on the diagonal of
    ``T`` extra columns: the cost matrix is ``(T, M + T)``.

    ``m`` events from Murty's ranked assignment (``None``: all events, by brute force; small
    problems only). Returns ``alpha (T, M + 1)``: column ``i < M`` the probability of detection
    ``i``, the last column the probability of a miss.
    """
    from .assignment_2d import brute_force_assignments

    T, MT = cost.shape
    M = MT - T
    if T == 1 and m is not None:  # one track: its events are its options, the m cheapest (what Murty ranks)
        c = cost[0]
        finite = np.flatnonzero(np.isfinite(c))
        best = finite[np.argsort(c[finite], kind="stable")][:m]
        alpha = np.zeros((1, M + 1))
        np.add.at(alpha, (0, np.minimum(best, M)), event_probabilities(c[best]))
        return alpha
    events = brute_force_assignments(cost) if m is None else murty(cost, m)
    cols = np.stack([e.cols for e in events])  # (E, T)
    p = event_probabilities(np.array([e.cost for e in events]))
    alpha = np.zeros((T, M + 1))
    cols = np.minimum(cols, M)  # every miss column -> the last column
    np.add.at(alpha, (np.arange(T), cols), p[:, None])
    return alpha


def assignment_matrix(det_cost: np.ndarray, miss: float) -> np.ndarray:
    """``(T, M)`` detection costs and a miss cost -> the ``(T, M + T)`` matrix with the misses on a
    diagonal block (``inf`` elsewhere): track ``t``'s miss is column ``M + t``."""
    T, M = det_cost.shape
    extra = np.full((T, T), np.inf)
    np.fill_diagonal(extra, miss)
    return np.concatenate([det_cost, extra], axis=1)


def candidate_marginals(tuples: np.ndarray, costs: np.ndarray, n_meas: list[int], n_targets: int, m: int,
                        iterations: int) -> tuple[np.ndarray, float]:
    """Probabilities ``beta (L,)`` of the multi-sensor candidates ``tuples (L, 1 + N)`` (track,
    detection per sensor or -1) from the m-best (N+1)-D events, and the largest duality gap met."""
    events = m_best_sd(tuples, costs, n_meas, n_targets, m, iterations=iterations)
    p = event_probabilities(np.array([e.cost for e in events]))
    beta = np.zeros(len(costs))
    for w, e in zip(p, events):
        beta[e.picks] += w
    return beta, max(e.gap for e in events)
