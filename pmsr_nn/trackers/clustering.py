"""Clusters of tracks that compete for detections.

Two tracks are in one cluster when some detection (of any sensor) falls in both gates, directly or
through a chain of such tracks. Association events of different clusters are independent, so each
cluster is solved on its own (a smaller assignment problem, and no events wasted on combinations
of unrelated tracks).
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components


SMALL = 32
"""Up to this many gated tracks the clusters come from a dense transitive closure."""


def track_clusters(gated: np.ndarray) -> list[np.ndarray]:
    """Clusters of tracks from a gate matrix ``gated (T, M)`` bool (detections of all sensors as
    columns). Returns the track indices of each cluster that has at least one gated detection;
    a track without any is left out (it can only have missed)."""
    active = np.flatnonzero(gated.any(1))
    if len(active) <= 1:
        return [active] if len(active) else []
    g = gated[active].astype(np.float64)
    share = (g @ g.T) > 0  # (A, A): tracks with a common detection
    if len(active) <= SMALL:  # transitive closure by repeated squaring: cheaper than a sparse graph here
        reach = share
        for _ in range(int(np.ceil(np.log2(len(active)))) + 1):
            reach = (reach.astype(np.float64) @ reach) > 0
        first = reach.argmax(1)  # each track's cluster is named by its lowest member
        return [active[first == c] for c in np.unique(first)]
    n, labels = connected_components(csr_matrix(share), directed=False)
    return [active[labels == c] for c in range(n)]


def batched_track_labels(gated: np.ndarray) -> np.ndarray:
    """Clusters of every run at once from ``gated (B, T, M)`` bool: ``labels (B, T)``, each
    track's cluster named by its lowest member, -1 for a track that gates nothing. The same
    clusters as :func:`track_clusters` per run (transitive closure by repeated squaring of the
    batched ``(B, T, T)`` sharing matrix; ``ceil(log2 T)`` products reach every chain)."""
    B, T, _ = gated.shape
    g = gated.astype(np.float64)
    reach = (g @ g.transpose(0, 2, 1)) > 0  # (B, T, T), the diagonal set for every track with a gate
    for _ in range(max(int(np.ceil(np.log2(max(T, 1)))), 0)):
        f = reach.astype(np.float64)
        reach = (f @ f) > 0
    return np.where(gated.any(-1), reach.argmax(-1), -1)
