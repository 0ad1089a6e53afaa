"""The belief-propagation (BP) associator: the :class:`~.roles.Associator` of a TOMB/P-style
tracker (Williams, IEEE TAES 2015; Meyer et al., Proc. IEEE 2018) on the one tracker loop.

Pair by pair, as S-MSJPDA (:class:`~.jpda_associators.SequentialJPDA`): each pair's detections
update the tracks the previous pair left, with

* the sigma-point moments of that pair's measurement
  (:func:`~pmsr_nn.filters.gaussian.unscented_moments`) and its chi-square gate
  (:func:`~.gating.gate_threshold`);
* the association beliefs of :func:`~.bp_association.bp_associate` from each track's likelihood
  ratios ``N(z_m; z_hat, S) / lambda`` in the gate, its existence (the management's, updated pair
  by pair here) and a new potential target behind every detection;
* the moment-matched collapse (:func:`~.mixture.pda_collapse`) of each track's updated mixture
  with the BP weights given that the track is a target.

What the step hands the management: per pair the likelihood ratio ``sum_m L_m nu_m`` whose IPDA
update (:meth:`~.management.TrackTable.update_existence`, with the same detection probability)
is BP's existence update, so :class:`~.own_tracks.OwnTracks` keeps BP's existence unchanged; the
detections a track explains by its association probability; and, in :class:`BPStep`, BP's
existences and each detection's new potential target, for a management that starts tracks from
them.

Shapes: ``B`` runs, ``C`` track slots, ``S`` pairs, ``M`` detections per list, ``n`` state
dimension, ``d`` measurement components per pair.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch

from ..filters.gaussian import Gaussian
from ..measurements import MeasurementModel
from .bp_association import bp_associate
from .gating import gate_threshold, inside_gate
from .jpda_associators import pair_innovations
from .mixture import pda_collapse
from .roles import AssociationStep, Associator


@dataclass
class BPStep(AssociationStep):
    """An :class:`~.roles.AssociationStep` with BP's beliefs: ``existence (B, C)`` each track's
    existence after the last pair (the predicted one where a slot took no part),
    ``new_existence (B, S, M)`` the existence of each detection's new potential target,
    ``legacy (B, S, M)`` the probability that a detection is a track's and ``association
    (B, C, S, M + 1)`` each pair's association probabilities (last column the miss or no
    target). ``iterations`` the most message passes a pair took."""

    existence: torch.Tensor | None = None
    new_existence: torch.Tensor | None = None
    legacy: torch.Tensor | None = None
    association: torch.Tensor | None = None
    iterations: int = 0


class BPAssociator(Associator):
    """Pair-by-pair BP association and update (module docstring).

    ``model`` the detections' measurement model, ``R (S d, S d)`` block-diagonal over pairs;
    ``pd`` the detection probability BP gives a track (``Pd Pg`` with the gate, as
    :class:`~.own_tracks.OwnTracks` takes it, so the two existence updates agree);
    ``clutter_density`` ``lambda`` per unit of one pair's measurement space; ``existence`` a
    callable that gives the tracks' predicted existence ``(B, C)`` at each scan (the
    management's, e.g. ``lambda: tracks.table.existence``; None: every track is a target,
    existence 1); ``birth`` ``mu``, each detection's expected new targets relative to clutter
    (for undetected targets spread like the clutter: their expected number per scan times ``Pd``
    over the expected clutter count of a pair; 0: no births); ``explained`` the probability of
    being a track's from which a detection counts as explained (it starts no track);
    ``iterations`` and ``tolerance`` the message passing's (:func:`~.bp_association.bp_associate`)."""

    correction = None

    def __init__(self, model: MeasurementModel, R: torch.Tensor, pd: float, clutter_density: float,
                 existence: Callable[[], torch.Tensor] | None = None, birth: float = 0.0,
                 gate_probability: float = 0.999, explained: float = 0.5, iterations: int = 1000,
                 tolerance: float = 1e-10):
        self.pd, self.density, self.existence, self.birth = pd, clutter_density, existence, birth
        self.explained, self.iterations, self.tolerance = explained, iterations, tolerance
        self.gamma = gate_threshold(gate_probability, len(model.components))
        rows = [model.rows_for_pairs([s]) for s in range(model.n_pairs)]
        self.subs = [model.for_pairs([s]) for s in range(model.n_pairs)]
        self.R = [R[r][:, r] for r in rows]

    def associate(self, g: Gaussian, z: torch.Tensor, valid: torch.Tensor, associating: torch.Tensor | None,
                  learned: torch.Tensor | None = None) -> BPStep:
        B, C = g.x.shape[:2]
        active = torch.ones(B, C, dtype=torch.bool) if associating is None else associating
        r = torch.ones(B, C, dtype=g.x.dtype) if self.existence is None else self.existence().to(g.x.dtype).clone()
        ratios, explained, hits, sds, whitened, new, legacy, assoc, passes = [], [], [], [], [], [], [], [], 0
        for j, (sub, R) in enumerate(zip(self.subs, self.R)):
            zj, vj = z[:, j], valid[:, j]
            inn = pair_innovations(g, zj, vj, sub, R)
            mom, L, e = inn.moments, inn.L, inn.e
            gate = inside_gate(inn.d2, self.gamma) & vj.unsqueeze(1) & active.unsqueeze(-1)
            ratio = torch.where(gate, inn.log_lik.exp() / self.density, 0.0)
            birth = torch.full(vj.shape, float(self.birth), dtype=g.x.dtype)
            bp = bp_associate(ratio, torch.where(active, r, 0.0), self.pd, birth, vj, self.iterations, self.tolerance)
            g = pda_collapse(g, mom, L, e, gate, bp.weights)
            r = torch.where(active, bp.existence, r)
            M = zj.shape[1]
            w = bp.weights
            hits.append(active & (w[..., :M].amax(-1) > w[..., M]) if M else torch.zeros_like(active))
            ratios.append(bp.ratio)
            explained.append(bp.legacy >= self.explained)
            sds.append(mom.S[..., 0, 0].sqrt())
            whitened.append((w[..., :M, None] * torch.where(gate[..., None], e, 0.0)).sum(-2))
            new.append(bp.new_existence)
            legacy.append(bp.legacy)
            assoc.append(bp.association)
            passes = max(passes, bp.iterations)
        hit = torch.stack(hits, -1)
        return BPStep(g, hit.sum(-1), torch.stack(ratios, -1), torch.stack(explained, 1), ~hit.any(-1),
                      torch.stack(sds, -1).amax(-1), torch.stack(whitened, 2), existence=r,
                      new_existence=torch.stack(new, 1), legacy=torch.stack(legacy, 1),
                      association=torch.stack(assoc, 2), iterations=passes)
