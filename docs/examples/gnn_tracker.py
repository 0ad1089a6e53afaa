"""A global-nearest-neighbour (GNN) tracker assembled from pmsr_nn's roles: the worked example of
docs/design.md "A tracker from the roles".

The only new part is the associator; the loop (:func:`pmsr_nn.trackers.loop.run_tracker`), the
track management (:class:`pmsr_nn.trackers.own_tracks.OwnTracks`) and its options
(:mod:`pmsr_nn.methods.track_management`) are shared. Pair by pair, each run's tracks take at most
one gated detection each, by the cheapest 2-D assignment of ``-log(Pd N(z; z_hat, S) / lambda)``
against a miss at ``-log(1 - Pd)`` (scipy's solver), and a Kalman update with it. Importing this
module registers the method kind ``gnn_example``.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment

from pmsr_nn.filters.gaussian import kalman_update, unscented_moments
from pmsr_nn.methods import MethodKind, Option, register
from pmsr_nn.methods.track_management import OWN_TRACK_OPTIONS, check_initiation, clutter_density, management
from pmsr_nn.trackers.base import Estimates
from pmsr_nn.trackers.gating import gate_threshold, gaussian_log_likelihood, inside_gate
from pmsr_nn.trackers.jpda import miss_cost
from pmsr_nn.trackers.loop import run_tracker
from pmsr_nn.trackers.own_tracks import OwnTracks
from pmsr_nn.trackers.roles import Associator, AssociationStep


class GNNAssociator(Associator):
    """The :class:`~pmsr_nn.trackers.roles.Associator` of a GNN tracker (module docstring)."""

    def __init__(self, model, R: torch.Tensor, pd: float, density: float, gate_probability: float = 0.999):
        rows = [model.rows_for_pairs([s]) for s in range(model.n_pairs)]
        self.subs, self.R = [model.for_pairs([s]) for s in range(model.n_pairs)], [R[r][:, r] for r in rows]
        self.pd, self.density, self.gamma = pd, density, gate_threshold(gate_probability, len(model.components))

    def assign(self, cost: np.ndarray) -> np.ndarray:
        """Each track's detection ``(C,)`` (-1: a miss) of the cheapest assignment of ``cost (C, M)``."""
        C, M = cost.shape
        miss = np.where(np.eye(C, dtype=bool), miss_cost(self.pd), np.inf)
        rows, cols = linear_sum_assignment(np.concatenate([cost, miss], 1))
        return np.where(cols[np.argsort(rows)] < M, cols[np.argsort(rows)], -1)

    def associate(self, g, z, valid, associating, learned=None) -> AssociationStep:
        hits, gates, ratios, sds = [], [], [], []
        for s, (sub, R) in enumerate(zip(self.subs, self.R)):
            mom = unscented_moments(g, sub, R)
            d2, log_lik = gaussian_log_likelihood(sub.residual(z[:, s].unsqueeze(1), mom.z.unsqueeze(2)), mom.S)
            gate = inside_gate(d2, self.gamma) & valid[:, s].unsqueeze(1)
            gate = gate if associating is None else gate & associating.unsqueeze(-1)
            cost = torch.where(gate, math.log(self.density / self.pd) - log_lik, math.inf).numpy()
            pick = torch.from_numpy(np.stack([self.assign(c) for c in cost]))  # (B, C), a loop over runs
            chosen = z[:, s].gather(1, pick.clamp(min=0).unsqueeze(-1).expand(*pick.shape, z.shape[-1]))
            g, _, _ = kalman_update(g, torch.where((pick >= 0).unsqueeze(-1), chosen, math.nan), mom, sub)
            hits.append(pick >= 0)
            gates.append(gate)
            ratios.append(torch.where(gate, log_lik.exp(), 0.0).sum(-1) / self.density)
            sds.append(mom.S[..., 0, 0].sqrt())
        hit = torch.stack(hits, -1)
        return AssociationStep(g, hit.sum(-1), torch.stack(ratios, -1), torch.stack(gates, 2).any(1), ~hit.any(-1),
                               torch.stack(sds, -1).amax(-1))


def run_gnn(call) -> Estimates:
    m, s, p_gate = call.models, call.sensing, float(call.spec.option("gate_probability"))
    gnn = GNNAssociator(s.detection_model, s.detection_model.R(), s.pd, clutter_density(s), p_gate)
    tracks = OwnTracks(management(call.spec, s), s.detection_model, m.motion.dim_x, s.pd * p_gate)
    rep = run_tracker(call.product.scans, m.motion, m.dt, m.q, gnn, tracks)
    return Estimates(rep.x, rep.exists, rep.P, paired=False, existence=rep.existence)


register(MethodKind("gnn_example", "detections", run_gnn,
                    {"gate_probability": Option(0.999, float, 0.5, 1.0 - 1e-12), **OWN_TRACK_OPTIONS},
                    check_sensing=check_initiation,
                    description="global nearest neighbour, pair by pair (docs/examples/gnn_tracker.py)"))
