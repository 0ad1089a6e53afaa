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
from .assignment_bnb import m_best_bnb
from .clustering import batched_track_labels
from .assignment_2d import murty

MIN_MISS_PROBABILITY = 1e-300
"""``1 - Pd`` is floored here, so a miss stays a finite (if absurdly costly) option at Pd = 1 and an
event always exists."""


def miss_cost(pd: float) -> float:
    """``-log(1 - Pd)``: the cost of a track taking no detection."""
    return -math.log(max(1.0 - pd, MIN_MISS_PROBABILITY))


MIN_CLUTTER_PER_SCAN = 1e-3
"""A tracker's clutter rate per pair and scan where none is simulated: PMHT, the PHD and BP need a
positive clutter rate (as the JPDA's density floor below)."""


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


M_BEST_SEARCHES = ("branch_and_bound", "relaxation")
"""How P-MSJPDA ranks its (N+1)-D events: exactly by :func:`.assignment_bnb.m_best_bnb` (falling
back on the relaxation past its state budget), or by :func:`.assignment.m_best_sd`'s Lagrangian
relaxation and Murty partitioning (the paper's solver; a duality gap can hide cheaper events)."""


def candidate_marginals(tuples: np.ndarray, costs: np.ndarray, n_meas: list[int], n_targets: int, m: int,
                        iterations: int, search: str = "branch_and_bound") -> tuple[np.ndarray, float]:
    """Probabilities ``beta (L,)`` of the multi-sensor candidates ``tuples (L, 1 + N)`` (track,
    detection per sensor or -1) from the m-best (N+1)-D events ranked by ``search`` (one of
    :data:`M_BEST_SEARCHES`), and the largest duality gap met (0 for exactly ranked events)."""
    if search not in M_BEST_SEARCHES:
        raise ValueError(f"search must be one of {M_BEST_SEARCHES}, got {search!r}")
    events = m_best_bnb(tuples, costs, n_meas, n_targets, m) if search == "branch_and_bound" else None
    if events is None:
        events = m_best_sd(tuples, costs, n_meas, n_targets, m, iterations=iterations)
    p = event_probabilities(np.array([e.cost for e in events]))
    beta = np.zeros(len(costs))
    for w, e in zip(p, events):
        beta[e.picks] += w
    return beta, max(e.gap for e in events)


ENUMERATION_MAX_EVENTS = 4096
"""A cluster whose events (``prod(gated + 1)`` over its tracks, conflicts included) are at most
this many is solved by enumeration in :func:`batched_single_sensor_marginals`; larger ones by Murty."""


def batched_single_sensor_marginals(cost: np.ndarray, miss: float, m: int,
                                    max_events: int = ENUMERATION_MAX_EVENTS) -> np.ndarray:
    """:func:`single_sensor_marginals` of every cluster of every run at once.

    ``cost (B, T, M)`` detection costs, ``inf`` outside a track's gate; ``miss`` the cost of a
    miss. Returns ``alpha (B, T, M + 1)`` (last column the miss; 1 for a track that gates
    nothing). The clusters (:func:`.clustering.batched_track_labels`) of all runs whose event
    count is at most ``max_events`` are enumerated together in one flat array: event ``l`` of a
    cluster is the mixed-radix number whose digit ``j`` picks track ``j``'s option (0: miss,
    ``k``: its ``k``-th gated detection); events that give one detection to two tracks are
    dropped, and each cluster keeps its ``m`` cheapest. Those are the events Murty ranks (exact
    for 2-D), so the marginals are the same up to the order of floating-point sums (ties in cost
    at the m-th event aside, which continuous likelihoods make improbable). Larger clusters go
    through :func:`single_sensor_marginals` one by one.
    """
    B, T, M = cost.shape
    gated = np.isfinite(cost)
    alpha = np.zeros((B, T, M + 1))
    alpha[..., M] = 1.0  # a track that gates nothing missed
    labels = batched_track_labels(gated)
    member = labels >= 0
    if not member.any():
        return alpha
    # Clusters as (run, lowest member) keys; rows of ``tracks`` in ascending track order.
    b_idx, t_idx = np.nonzero(member)  # row-major: by run, then track
    key = b_idx * T + labels[b_idx, t_idx]
    uniq, cid = np.unique(key, return_inverse=True)
    by_cluster = np.argsort(cid, kind="stable")  # rows grouped by cluster, tracks ascending inside
    b_idx, t_idx, cid = b_idx[by_cluster], t_idx[by_cluster], cid[by_cluster]
    C = len(uniq)
    size = np.bincount(cid, minlength=C)
    n_opt = gated.sum(-1) + 1  # (B, T): options of each track, the miss included
    log_events = np.bincount(cid, weights=np.log(n_opt[b_idx, t_idx]), minlength=C)
    # counts compared in logs (a product could overflow); 1e-9 absorbs the rounding of the sum
    small = log_events <= math.log(max_events) + 1e-9 if max_events >= 1 else np.zeros(C, dtype=bool)
    alpha[member] = 0.0
    # Large clusters: one Murty problem each.
    for c in np.flatnonzero(~small):
        b, cl = uniq[c] // T, t_idx[cid == c]
        cols = np.flatnonzero(gated[b, cl].any(0))
        a = single_sensor_marginals(assignment_matrix(cost[b][np.ix_(cl, cols)], miss), m)
        alpha[b, cl, M] = a[:, -1]
        alpha[b][np.ix_(cl, cols)] = a[:, :-1]
    if not small.any():
        return alpha
    # Small clusters: the tracks of cluster c padded to (C, J) with a one-option pad.
    keep = small[cid]
    cid_s = np.cumsum(small) - 1  # cluster -> index among the small ones
    rows_c, rows_b, rows_t = cid_s[cid[keep]], b_idx[keep], t_idx[keep]
    Cs = int(small.sum())
    size_s = size[small]
    J = int(size_s.max())
    slot = np.arange(len(rows_c)) - np.concatenate(([0], np.cumsum(size_s)[:-1]))[rows_c]
    track = np.full((Cs, J), -1)
    track[rows_c, slot] = rows_t
    run = uniq[small] // T
    radix = np.ones((Cs, J), dtype=np.int64)
    radix[rows_c, slot] = n_opt[rows_b, rows_t]
    # Options of every track: column -1 (miss) then its gated detections in ascending order.
    G = int(n_opt.max()) - 1
    det_order = np.argsort(~gated, axis=-1, kind="stable")[..., :G]  # (B, T, G), gated first
    opt_col = np.concatenate([np.full((B, T, 1), -1), np.where(
        np.take_along_axis(gated, det_order, -1), det_order, -1)], -1)  # (B, T, G + 1)
    opt_cost = np.concatenate([np.full((B, T, 1), miss), np.take_along_axis(cost, det_order, -1)], -1)
    # Events built track by track: each partial event is extended by every option of the next
    # track (a pad has one, the miss of cost 0) and dropped as soon as two tracks share a
    # detection. ``ev`` stays sorted by cluster (np.repeat keeps the order).
    ev = np.arange(Cs)
    col = np.zeros((Cs, 0), dtype=np.int64)
    c_ev = np.zeros(Cs)
    for j in range(J):
        r = radix[ev, j]
        ev_new = np.repeat(ev, r)
        digit = np.arange(len(ev_new)) - np.repeat(np.cumsum(r) - r, r)
        t = track[ev_new, j]
        pad = t < 0
        bj, tj = run[ev_new], np.maximum(t, 0)
        cj = np.where(pad, -1, opt_col[bj, tj, digit])
        c_ev = np.repeat(c_ev, r) + np.where(pad, 0.0, opt_cost[bj, tj, digit])  # summed in track order, as Murty
        col = np.repeat(col, r, axis=0)
        ok = ~((col == cj[:, None]) & (cj[:, None] >= 0)).any(1)
        ev, col, c_ev = ev_new[ok], np.concatenate([col[ok], cj[ok, None]], 1), c_ev[ok]
    # The m cheapest feasible events of each cluster: only clusters with more than m are sorted.
    n_feasible = np.bincount(ev, minlength=Cs)
    if (n_feasible > m).any():
        cut = n_feasible[ev] > m
        idx = np.flatnonzero(cut)
        order = idx[np.lexsort((c_ev[idx], ev[idx]))]  # grouped by cluster, cheapest first
        sizes = n_feasible[n_feasible > m]
        rank = np.arange(len(order)) - np.repeat(np.cumsum(sizes) - sizes, sizes)
        kept = np.sort(np.concatenate([np.flatnonzero(~cut), order[rank < m]]))  # back in cluster order
        ev, col, c_ev = ev[kept], col[kept], c_ev[kept]
    group = np.concatenate(([0], np.cumsum(np.bincount(ev, minlength=Cs))[:-1]))
    c_min = np.minimum.reduceat(c_ev, group)  # every cluster keeps its all-miss event, none is empty
    w = np.exp(-(c_ev - c_min[ev]))
    p = w / np.bincount(ev, weights=w, minlength=Cs)[ev]
    tr = track[ev]
    # alpha[b, t, col or M] += p for every kept event and real track.
    real = tr >= 0
    flat = (run[ev][:, None] * T + tr) * (M + 1) + np.where(col >= 0, col, M)
    alpha += np.bincount(flat[real], weights=np.broadcast_to(p[:, None], flat.shape)[real],
                         minlength=B * T * (M + 1)).reshape(B, T, M + 1)
    return alpha
