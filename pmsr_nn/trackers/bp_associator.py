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

With :class:`Births` (the tracker of :mod:`.bp_tracker`), undetected targets are a Poisson
intensity of mass ``mu_u`` spread like the clutter (Meyer et al., Sec. VIII): at each pair every
detection's new potential target has ``mu_m = mu_u Pd / Lambda_c`` (``Lambda_c`` the pair's
expected clutter count), the pair's undetected mass becomes ``mu_u (1 - Pd)``, and each new
potential target (its Gaussian from the one detection that seeds it, :attr:`Births.seed`) is a
track for the later pairs of the same scan: a target seen at the first pair is a track by the
second, so its other detections confirm it instead of seeding duplicates. New potential targets
whose existence is below :attr:`Births.keep` are dropped.

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
from typing import TYPE_CHECKING, Callable

import torch

from ..errors import ConfigError
from ..filters.gaussian import Gaussian
from ..measurements import MeasurementModel
from .bp_association import bp_associate
from .gating import gate_threshold, inside_gate
from .jpda_associators import pair_innovations
from .mixture import pda_collapse
from .roles import AssociationStep, Associator

if TYPE_CHECKING:
    from .message_refiner import MessageRefiner


@dataclass(frozen=True)
class Births:
    """New targets born inside the association (module docstring): ``undetected`` a callable that
    gives the undetected targets' expected number ``mu_u (B,)`` at this scan (after its
    prediction), ``pd`` the detection probability of an undetected target (no gate: it has no
    prediction), ``clutter_count`` ``Lambda_c``, the expected clutter detections of one pair per
    scan, ``seed(z (B, S, M, d), valid (B, S, M)) -> (Gaussian (B, S, M, n), real (B, S, M))`` the
    state of the new potential target behind each detection given that detection alone, for
    every pair ``s`` from its view ``z[:, s]`` of its list (called once per scan), and ``keep`` the
    existence below which a new potential target is dropped."""

    undetected: Callable[[], torch.Tensor]
    pd: float
    clutter_count: float
    seed: Callable[[int, torch.Tensor, torch.Tensor], tuple[Gaussian, torch.Tensor]]
    keep: float


@dataclass
class BPStep(AssociationStep):
    """An :class:`~.roles.AssociationStep` with BP's beliefs: ``existence (B, C')`` each track's
    existence after the last pair (the predicted one where a slot took no part),
    ``new_existence (B, S, M)`` the existence of each detection's new potential target,
    ``legacy (B, S, M)`` the probability that a detection is a track's and ``association
    (B, C', S, M + 1)`` each pair's association probabilities (last column the miss or no
    target). ``iterations`` the most message passes a pair took.

    With :class:`Births`: ``C' = C + G``, the last ``G`` slots the new potential targets kept
    (``born (B, C')`` marks them; a slot of them not kept has existence 0), and ``undetected
    (B,)`` ``mu_u`` after the last pair. The per-pair fields are 0 for a new potential target at
    the pairs before its birth."""

    existence: torch.Tensor | None = None
    new_existence: torch.Tensor | None = None
    legacy: torch.Tensor | None = None
    association: torch.Tensor | None = None
    iterations: int = 0
    born: torch.Tensor | None = None
    undetected: torch.Tensor | None = None


def _padded(parts: list[torch.Tensor], C: int) -> torch.Tensor:
    """Per-pair ``(B, C_j, ...)`` zero-padded to ``C`` slots and stacked on dim 2."""
    return torch.stack([torch.cat([t, t.new_zeros(t.shape[0], C - t.shape[1], *t.shape[2:])], 1) for t in parts], 2)


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
    over the expected clutter count of a pair; 0: no births) where ``births`` is None, else
    :class:`Births` gives it and starts new potential targets; ``explained`` the probability of
    being a track's from which a detection counts as explained (it starts no track);
    ``iterations`` and ``tolerance`` the message passing's (:func:`~.bp_association.bp_associate`);
    ``lists (S,)`` the detection list each pair reads (None: list ``s`` for pair ``s``): where a
    receiver pools its pairs' detections (the illuminator unknown), each of its pairs reads the
    pooled list in turn, so the illuminator is a third dimension of the association, resolved by
    which pair's prediction a detection fits (``clutter_density`` then the pooled list's);
    ``refiner`` a :class:`~.message_refiner.MessageRefiner` (neural-enhanced BP) that corrects each
    list's likelihood ratios and detection weights before the message passing (per-pair lists only)."""

    def __init__(self, model: MeasurementModel, R: torch.Tensor, pd: float, clutter_density: float,
                 existence: Callable[[], torch.Tensor] | None = None, birth: float = 0.0,
                 gate_probability: float = 0.999, explained: float = 0.5, iterations: int = 1000,
                 tolerance: float = 1e-10, births: Births | None = None, lists: list[int] | None = None,
                 refiner: "MessageRefiner | None" = None):
        self.lists = list(range(model.n_pairs)) if lists is None else [int(v) for v in lists]
        # the pairs that read each list, in the order of its first pair
        self.groups = [[j for j, v in enumerate(self.lists) if v == l] for l in dict.fromkeys(self.lists)]
        self.pd, self.density, self.existence, self.birth = pd, clutter_density, existence, birth
        self.explained, self.iterations, self.tolerance, self.births = explained, iterations, tolerance, births
        self.gamma = gate_threshold(gate_probability, len(model.components))
        rows = [model.rows_for_pairs([s]) for s in range(model.n_pairs)]
        self.subs = [model.for_pairs([s]) for s in range(model.n_pairs)]
        self.R = [R[r][:, r] for r in rows]
        self.refiner = refiner
        if refiner is not None and any(len(pairs) > 1 for pairs in self.groups):
            raise ConfigError("learned message corrections read per-pair lists; these lists are pooled per receiver")

    def associate(self, g: Gaussian, z: torch.Tensor, valid: torch.Tensor,
                  associating: torch.Tensor | None) -> BPStep:
        B, C = g.x.shape[:2]
        dtype = g.x.dtype
        dev = g.x.device
        active = torch.ones(B, C, dtype=torch.bool, device=dev) if associating is None else associating
        r = torch.ones(B, C, dtype=dtype, device=dev) if self.existence is None else self.existence().to(dtype).clone()
        born = torch.zeros(B, C, dtype=torch.bool, device=dev)
        births = self.births
        mu_u = births.undetected().to(dtype).clone() if births is not None else None
        per_pair, explained, passes = {}, torch.zeros(valid.shape, dtype=torch.bool, device=dev), 0
        if self.refiner is not None:
            self.refiner.begin_scan()
        if births is not None:  # every pair's seeds at once: they read the detections alone
            seeds, seedable = births.seed(z[:, self.lists], valid[:, self.lists])
        for pairs in self.groups:
            l = self.lists[pairs[0]]
            zl, vl = z[:, l], valid[:, l]
            C, M, J = g.x.shape[1], zl.shape[1], len(pairs)
            inns = [pair_innovations(g, zl, vl, self.subs[j], self.R[j]) for j in pairs]
            gates = [inside_gate(inn.d2, self.gamma) & vl.unsqueeze(1) & active.unsqueeze(-1) for inn in inns]
            # one node per (track, pair) of the list: a detection is at most one of them
            ratio = torch.cat([torch.where(gate, inn.log_lik.exp() / self.density, 0.0) for inn, gate in zip(inns, gates)], 1)
            if births is None:
                birth = torch.full(vl.shape, float(self.birth), dtype=dtype, device=dev)
            else:  # a new target under any of the list's illuminators
                birth = (mu_u * births.pd / births.clutter_count * J).unsqueeze(-1).expand(B, M)
            prior = torch.where(active, r, 0.0)
            if self.refiner is not None:  # learned corrections (J == 1); in training they carry gradients
                ratio, birth = self.refiner.refine(l, g, inns[0], ratio, birth, prior, zl, vl)
            bp = bp_associate(ratio.detach(), prior.repeat(1, J), self.pd, birth.detach(), vl, self.iterations,
                              self.tolerance)
            if self.refiner is not None:
                self.refiner.observe(bp, self.pd)
            passes = max(passes, bp.iterations)
            explained[:, l] |= bp.legacy >= self.explained
            for k, j in enumerate(pairs):
                nodes = slice(k * C, (k + 1) * C)
                # the weights are the joint association's; the moments the state's after the list's earlier pairs
                inn = inns[k] if k == 0 else pair_innovations(g, zl, vl, self.subs[j], self.R[j])
                w = bp.weights[:, nodes]
                g = pda_collapse(g, inn.moments, inn.L, inn.e, gates[k], w)
                if J == 1:
                    r = torch.where(active, bp.existence, r)
                else:  # each pair's IPDA-form update with its BP likelihood ratio, in turn
                    pd_eff = self.pd * bp.ratio[:, nodes]
                    r = torch.where(active, r * (1.0 - self.pd + pd_eff) / (1.0 - r * self.pd + r * pd_eff), r)
                per_pair[j] = (active & (w[..., :M].amax(-1) > w[..., M]) if M else torch.zeros_like(active),
                               bp.ratio[:, nodes], inn.moments.S[..., 0, 0].sqrt(),
                               (w[..., :M, None] * torch.where(gates[k][..., None], inn.e, 0.0)).sum(-2),
                               bp.new_existence / J, bp.legacy, bp.association[:, nodes])
            if births is not None:
                for j in pairs:
                    mu_u = mu_u * (1.0 - births.pd)
                for j in pairs:  # a new potential target behind each detection, under each illuminator
                    new_existence = bp.new_existence / J
                    kept = vl & (new_existence >= births.keep)
                    if bool(kept.any()):
                        seeded = Gaussian(seeds.x[:, j], seeds.P[:, j])
                        kept = kept & seedable[:, j]
                        g = Gaussian(torch.cat([g.x, seeded.x], 1), torch.cat([g.P, seeded.P], 1))
                        r = torch.cat([r, torch.where(kept, new_existence, 0.0)], 1)
                        active = torch.cat([active, kept], 1)
                        born = torch.cat([born, kept], 1)
        Cn = g.x.shape[1]
        hits, ratios, sds, whitened, new, legacy, assoc = zip(*(per_pair[j] for j in range(len(self.subs))))
        hit = _padded(list(hits), Cn)
        return BPStep(g, hit.sum(-1), _padded(list(ratios), Cn), explained, ~hit.any(-1),
                      _padded(list(sds), Cn).amax(-1), _padded(list(whitened), Cn), existence=r,
                      new_existence=torch.stack(new, 1), legacy=torch.stack(legacy, 1),
                      association=_padded(list(assoc), Cn), iterations=passes,
                      born=born if births is not None else None, undetected=mu_u)
