"""Learned corrections of BP's association inputs: neural-enhanced belief propagation (NEBP; Liang &
Meyer, IEEE TSP 2024, 72:15-30) on the BP tracker of :mod:`.bp_tracker`.

At each pair's list, before the message passing of :func:`~.bp_association.bp_associate`, a graph
network (:class:`~pmsr_nn.nets.nebp.NEBPNet`) reads the association graph: the ``C`` track nodes
(existence ``r_i > 0``), the list's ``M`` detections and the gated edges between them (likelihood
ratio ``L_im > 0``), and returns

* per gated edge a log-correction ``delta_im`` of the association likelihood: ``L_im <- L_im
  exp(delta_im) sum_m' L_im' / sum_m' L_im' exp(delta_im')``, which moves track ``i``'s likelihood
  among its gated detections and keeps its sum (the evidence that the track was detected, which
  BP's existence update reads, stays the model's);
* per detection a log-correction ``epsilon_m`` of target against false alarm: every target
  hypothesis of the detection, a track's and a new target's, is multiplied by ``exp(epsilon_m)``
  (``L_im <- L_im exp(epsilon_m)`` for every track ``i``, ``mu_m <- mu_m exp(epsilon_m)``), so the
  split between a track and a new target stays BP's. (Acting on ``mu_m`` alone, the first form
  tried, taught the network to raise the new-target weight of every detection that looked like a
  target's: the new targets then competed with the tracks for their own detections, and on the
  trial scenes the tracks lost localisation and targets.)

Both are bounded (``bound tanh(. / bound)`` nats) and start at zero, so the untrained NEBP is BP
exactly. Everything else (gates, the message passing, the update, the management) is BP's.

What the network reads (:func:`graph_features`), all scale-free: per edge the whitened innovation
and ``log L_im``; per track node its existence, predicted range deviation (in units of the range
noise), how many detections it gates and their summed ratio; per detection its measurement (each
component over a scale, an angle as its cosine and sine), how many tracks gate it, their summed
ratio, its new-target weight ``log mu_m``, the list's length and the pair (one-hot).

Shapes: ``B`` runs, ``C`` track nodes, ``M`` detections of the list, ``d`` measurement components,
``E`` gated edges, ``D`` valid detections, ``T`` live track nodes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch

from .bp_association import bp_associate

ANGLES = ("azimuth",)
"""Measurement components that are angles (read as cosine and sine)."""

TRACK_FEATURES = 4
EDGE_EXTRA = 1
"""An edge's features: its ``d`` whitened innovation entries and :data:`EDGE_EXTRA` more (``log L``)."""


def detection_feature_count(components, n_pairs: int) -> int:
    """Features per detection: the measurement (an angle as two), four graph figures, the pair one-hot."""
    return sum(2 if c in ANGLES else 1 for c in components) + 4 + n_pairs


@dataclass
class Graph:
    """One list's association graph in sparse form: ``edges (E, 3)`` (run, track node, detection)
    of the gated edges, ``dets (D, 2)`` (run, detection) of the valid detections, ``tracks (T, 2)``
    (run, node) of the live nodes; ``edge_det (E,)`` / ``edge_track (E,)`` each edge's row in
    ``dets`` / ``tracks``; the features ``edge_x (E, d + 1)``, ``det_x (D, F_d)``, ``track_x (T,
    4)`` (the detections' dtype; the network reads them in its own)."""

    edges: torch.Tensor
    dets: torch.Tensor
    tracks: torch.Tensor
    edge_det: torch.Tensor
    edge_track: torch.Tensor
    edge_x: torch.Tensor
    det_x: torch.Tensor
    track_x: torch.Tensor


def graph_features(pair: int, n_pairs: int, components, scales: torch.Tensor, range_sd_unit: float,
                   whitened: torch.Tensor, range_sd: torch.Tensor, ratio: torch.Tensor, birth: torch.Tensor,
                   prior: torch.Tensor, z: torch.Tensor, valid: torch.Tensor) -> Graph:
    """The :class:`Graph` of pair ``pair``'s list (module docstring): ``whitened (B, C, M, d)`` the
    whitened innovations, ``range_sd (B, C)`` each node's predicted range deviation (m; its unit
    ``range_sd_unit``), ``ratio (B, C, M)`` the gated likelihood ratios (0 off the gate),
    ``birth (B, M)`` ``mu_m``, ``prior (B, C)`` the existences (0: not a node), ``z (B, M, d)``
    and ``valid (B, M)`` the detections; ``scales (d,)`` each non-angle component's scale."""
    B, C, M = ratio.shape
    dev = ratio.device
    live = prior > 0
    gated = (ratio > 0) & live.unsqueeze(-1) & valid.unsqueeze(1)
    edges = gated.nonzero()  # (E, 3)
    dets = valid.nonzero()  # (D, 2)
    tracks = live.nonzero()  # (T, 2)
    det_row = torch.full((B, M), -1, dtype=torch.long, device=dev)
    det_row[dets[:, 0], dets[:, 1]] = torch.arange(len(dets), device=dev)
    track_row = torch.full((B, C), -1, dtype=torch.long, device=dev)
    track_row[tracks[:, 0], tracks[:, 1]] = torch.arange(len(tracks), device=dev)
    b, i, m = edges.unbind(-1)
    L = ratio[b, i, m]
    logL = L.log()
    edge_x = torch.cat([whitened[b, i, m], (logL / 10.0).unsqueeze(-1)], -1)
    g = gated.to(ratio.dtype)
    per_track_count, per_track_sum = g.sum(-1), ratio.sum(-1)  # (B, C)
    per_det_count, per_det_sum = g.sum(1), (ratio * g).sum(1)  # (B, M)
    tb, ti = tracks.unbind(-1)
    track_x = torch.stack([prior[tb, ti], (range_sd[tb, ti] / range_sd_unit).clamp(min=1e-3).log() / 5.0,
                           per_track_count[tb, ti].log1p() / 2.0, per_track_sum[tb, ti].log1p() / 10.0], -1)
    db, dm = dets.unbind(-1)
    zd = z[db, dm]  # (D, d)
    cols = []
    for c, name in enumerate(components):
        if name in ANGLES:
            cols += [zd[:, c].cos(), zd[:, c].sin()]
        else:
            cols.append(zd[:, c] / scales[c])
    count = valid.sum(-1).to(ratio.dtype)  # (B,)
    cols += [per_det_count[db, dm].log1p() / 2.0, per_det_sum[db, dm].log1p() / 10.0,
             birth[db, dm].clamp(min=1e-30).log() / 10.0, count[db] / 50.0]
    det_x = torch.cat([torch.stack(cols, -1), torch.nn.functional.one_hot(
        torch.full((len(dets),), pair, dtype=torch.long, device=dev), n_pairs).to(ratio.dtype)], -1)
    return Graph(edges, dets, tracks, det_row[b, m], track_row[b, i], edge_x, det_x, track_x)


def apply_corrections(graph: Graph, edge_log: torch.Tensor, det_log: torch.Tensor, ratio: torch.Tensor,
                      birth: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``ratio (B, C, M)`` and ``birth (B, M)`` with the gated edges' ratios times
    ``exp(edge_log (E,))``, rescaled per track node to keep its summed ratio, then every ratio and
    ``mu_m`` of each valid detection times ``exp(det_log (D,))`` (the gradients flow to the
    corrections)."""
    e, dts = graph.edges, graph.dets
    edge_full = torch.zeros(ratio.shape, dtype=ratio.dtype, device=ratio.device).index_put(
        (e[:, 0], e[:, 1], e[:, 2]), edge_log.to(ratio.dtype))
    det_full = torch.zeros(birth.shape, dtype=birth.dtype, device=birth.device).index_put(
        (dts[:, 0], dts[:, 1]), det_log.to(birth.dtype))
    scaled = ratio * edge_full.exp()
    # each node's summed ratio kept: the corrections move a node's likelihood among its detections, not its
    # evidence of being detected (the existence update's; a shift common to its edges changes nothing)
    total, new_total = ratio.sum(-1, keepdim=True), scaled.sum(-1, keepdim=True)
    keep = torch.where(new_total > 0, total / torch.where(new_total > 0, new_total, 1.0), 1.0)
    # a detection's weight multiplies every target hypothesis it has (a track's or a new one) against clutter
    weight = det_full.exp()
    return scaled * keep * weight.unsqueeze(1), birth * weight


class MessageRefiner:
    """The :class:`~.bp_associator.BPAssociator`'s ``refiner`` for NEBP (module docstring).

    ``net`` the graph network (``(Graph) -> (edge_log (E,), det_log (D,))``), ``components`` and
    ``n_pairs`` the detections', ``scales (d,)`` the measurement scales the network was trained
    with, ``range_sd_unit`` the range noise (m). ``supervisor``: in training, a callable
    ``(k, pair, g, graph inputs, beliefs) -> loss`` summed into :attr:`loss` (``grad_passes``
    differentiable message passes from BP's fixed point, whose beliefs the loss reads); None at
    inference."""

    def __init__(self, net, components, n_pairs: int, scales: torch.Tensor, range_sd_unit: float,
                 supervisor: Callable | None = None, grad_passes: int = 3):
        self.net, self.components, self.n_pairs = net, tuple(components), n_pairs
        self.scales, self.range_sd_unit = scales, float(range_sd_unit)
        self.supervisor, self.grad_passes = supervisor, grad_passes
        self.k = -1
        self.loss = None
        self._last = None

    def begin_scan(self) -> None:
        self.k += 1

    def refine(self, pair: int, g, inn, ratio: torch.Tensor, birth: torch.Tensor, prior: torch.Tensor,
               z: torch.Tensor, valid: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(ratio, birth)`` corrected (module docstring) for pair ``pair``'s list: ``inn`` its
        :class:`~.jpda_associators.PairInnovations`, the rest as :func:`graph_features`."""
        range_sd = inn.moments.S[..., 0, 0].clamp(min=0.0).sqrt()
        graph = graph_features(pair, self.n_pairs, self.components, self.scales.to(ratio.device), self.range_sd_unit,
                               inn.e, range_sd, ratio, birth, prior, z, valid)
        edge_log, det_log = self.net(graph)
        new_ratio, new_birth = apply_corrections(graph, edge_log, det_log, ratio, birth)
        if self.supervisor is not None:
            self._last = (pair, g, new_ratio, new_birth, prior, valid)
        return new_ratio, new_birth

    def observe(self, bp, pd) -> None:
        """In training and validation, the supervisor's loss of this list's beliefs: ``grad_passes``
        message passes (with gradients where the corrections carry them) from BP's converged
        messages ``bp.messages``."""
        if self.supervisor is None or self._last is None:
            return
        pair, g, ratio, birth, prior, valid = self._last
        self._last = None
        beliefs = bp_associate(ratio, prior, pd, birth, valid, self.grad_passes, 0.0, start=bp.messages.detach())
        term = self.supervisor(self.k, pair, g, prior, ratio, valid, beliefs)
        if term is not None:
            self.loss = term if self.loss is None else self.loss + term


def bounded(raw: torch.Tensor, bound: float) -> torch.Tensor:
    """``bound tanh(raw / bound)``: a correction of at most ``bound`` nats either way, ``raw`` near 0 kept."""
    return bound * torch.tanh(raw / bound)

