"""The one tracker loop: every multi-target tracker that keeps tracks scan by scan runs here.

A tracker is an assembly of an :class:`~.roles.Associator` (the association and update, its
updater inside) and a :class:`~.roles.TrackManagement` (the tracks, their existence,
confirmation, deletion, initiation and report); this loop runs them over the scans, batched over
runs and track slots::

    for each scan k:
        predict the tracks (k > 0) -> the management's births, parking and existence prediction
        associate and update       -> AssociationStep
        the management: existence update, confirm, delete, report, initiate
        the associator hears of the tracks started

Step 0 has no prediction (the convention of :mod:`pmsr_nn.filters.kalman`). Shapes: ``B`` runs,
``K`` scans, ``S`` pairs, ``M`` detections per list.
"""

from __future__ import annotations

from ..motion import KinematicModel
from ..simulation.detections import Scans
from .pmht_model import AssociationLists
from .roles import Associator, TrackManagement


def run_tracker(scans: Scans | AssociationLists, motion: KinematicModel, dt: float, q, associator: Associator,
                management: TrackManagement):
    """Run ``associator`` and ``management`` over ``scans`` (``z (B, K, L, M, d)`` and ``valid
    (B, K, L, M)``: per-pair lists, or PMHT's association lists) with the CV/CA prediction of
    ``motion`` over ``dt`` and process noise ``q``; returns ``management.result()``."""
    B, K = scans.z.shape[:2]
    dtype = scans.z.dtype
    F, Q = motion.F(dt, dtype, scans.z.device), motion.Q(dt, q, dtype, scans.z.device)
    management.begin(B, K, F, Q)
    for k in range(K):
        if k > 0:
            management.g = associator.predict(management.g, k, F, Q)
            management.predicted(k)
        z, valid = scans.z[:, k], scans.valid[:, k]
        step = associator.associate(management.g, z, valid, management.associating(k))
        management.updated(k, step, z, valid)
        associator.tracks_started(management.started, management.g)
    return management.result()
