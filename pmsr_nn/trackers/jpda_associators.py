"""The JPDA associators of S-MSJPDA and P-MSJPDA (Lyu & Wang, IEEE Access 2019), batched over runs
and tracks: the :class:`~.roles.Associator` role of :func:`~.loop.run_tracker`.

* :class:`SequentialJPDA` (Eqs. 15-21): pair by pair. Each pair's detections update the tracks
  left by the previous pair: sigma-point moments of that pair's measurement, the chi-square gate,
  the association weights (the m-best 2-D events, or each track on its own with ``pda``), and the
  moment-matched collapse (Eq. 16).
* :class:`ParallelJPDA` (Eqs. 9-14): all pairs at once. A track's candidate is one detection (or
  none) per pair; its likelihood is the joint predicted density of the stacked measurements (one
  set of sigma points through all pairs, so the correlation the state uncertainty creates between
  pairs is kept), the m-best (S+1)-D events come from :func:`~.jpda.candidate_marginals` and the
  update collapses the joint updates of the candidates. Eq. 11 of the paper writes the candidate
  likelihood as a product over pairs: the special case of uncorrelated predicted measurements.

Shapes: ``B`` runs, ``C`` track slots, ``S`` pairs, ``M`` detections per list, ``n`` state
dimension, ``d`` measurement components per pair.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch

from ..filters.gaussian import Gaussian, MeasurementMoments, kalman_update, safe_cholesky, unscented_moments
from ..measurements import MeasurementModel, wrap_angle
from .clustering import track_clusters
from .gating import gate_threshold, gaussian_log_likelihood, inside_gate
from .jpda import batched_single_sensor_marginals, candidate_marginals, detection_costs, miss_cost
from .mixture import collapse, expand_moments, pda_collapse
from .roles import Associator, AssociationStep

Association = Literal["jpda", "pda"]


def pda_marginals(log_lik: torch.Tensor, gated: torch.Tensor, pd: float, density: float) -> torch.Tensor:
    """Association probabilities of each track on its own (PDA, no competition between tracks).

    ``log_lik (..., M)`` ``log N(z_i; z_hat, S)``, ``gated (..., M)`` bool. A gated detection
    weighs ``Pd N_i / lambda``, the miss ``1 - Pd`` (the costs of :mod:`.jpda`, so with one track
    and fewer gated detections than the JPDA's ``m_best`` both agree). Returns ``alpha (..., M + 1)``,
    the last column the miss. Batched over every axis.
    """
    det = torch.where(gated, log_lik + math.log(pd) - math.log(density),
                      torch.tensor(-math.inf, dtype=log_lik.dtype, device=log_lik.device))
    miss = torch.full((*log_lik.shape[:-1], 1), -miss_cost(pd), dtype=log_lik.dtype, device=log_lik.device)
    return torch.softmax(torch.cat([det, miss], -1), -1)


@dataclass
class PairInnovations:
    """Tracks ``(B, C, n)`` against one pair's detections ``(B, M, d)``: the sigma-point
    ``moments``, the innovations ``nu (B, C, M, d)`` (NaN for padding), the Cholesky factor ``L
    (B, C, d, d)`` of ``S``, the whitened innovations ``e = L^-1 nu`` (0 for padding), the squared
    Mahalanobis distances ``d2 (B, C, M)`` and ``log_lik (B, C, M)`` ``log N(nu; 0, S)``."""

    moments: MeasurementMoments
    nu: torch.Tensor
    L: torch.Tensor
    e: torch.Tensor
    d2: torch.Tensor
    log_lik: torch.Tensor


def pair_innovations(g: Gaussian, z: torch.Tensor, valid: torch.Tensor, sub: MeasurementModel,
                     R: torch.Tensor) -> PairInnovations:
    """:class:`PairInnovations` of tracks ``g`` and detections ``z (B, M, d)`` (``valid (B, M)``)
    of the one-pair model ``sub`` with noise ``R (d, d)``: gaussian_log_likelihood's algebra with
    one triangular solve per track for all ``M`` detections (``M`` right-hand sides, not ``M``
    broadcast solves); ``L`` and ``e`` serve the update too."""
    mom = unscented_moments(g, sub, R)
    nu = sub.residual(z.unsqueeze(1), mom.z.unsqueeze(2))
    L = safe_cholesky(mom.S)
    pad = ~valid.unsqueeze(1)  # (B, 1, M)
    e = torch.linalg.solve_triangular(L, nu.masked_fill(pad.unsqueeze(-1), 0.0).transpose(-1, -2),
                                      upper=False).transpose(-1, -2)
    d2 = (e * e).sum(-1)
    half_logdet = torch.log(torch.diagonal(L, dim1=-2, dim2=-1)).sum(-1)
    log_lik = -0.5 * d2 - half_logdet.unsqueeze(-1) - 0.5 * nu.shape[-1] * math.log(2 * math.pi)
    return PairInnovations(mom, nu, L, e, d2, log_lik)


@dataclass
class PairUpdate:
    """One pair's association and update (:meth:`SequentialJPDA.pair_step`): the ``posterior``
    ``(B, C, n)``, whether no detection was the likeliest association ``miss_likeliest (B, C)``
    (numpy), the predicted range deviation ``range_sd_m (B, C)``, the gates ``gated (B, C, M)``
    (numpy), the summed likelihood ratio of the gated detections to clutter ``ratio (B, C)``, the
    whitened combined innovation ``whitened (B, C, d)``, each detection's association probability
    summed over the tracks ``taken (B, M)`` and the JIPDA-style ratio ``shared_ratio (B, C)``
    (:func:`shared_ratio`)."""

    posterior: Gaussian
    miss_likeliest: np.ndarray
    range_sd_m: torch.Tensor
    gated: np.ndarray
    ratio: torch.Tensor
    whitened: torch.Tensor
    taken: torch.Tensor
    shared_ratio: torch.Tensor


UNDERFLOW = 1e-200
"""Below this, a probability of no detection has lost its digits (``Pd`` 1: a miss weight of
:data:`~.jpda.MIN_MISS_PROBABILITY`)."""


def shared_ratio(alpha: torch.Tensor, pd: float, ratio: torch.Tensor) -> torch.Tensor:
    """The JIPDA-style likelihood ratio of a track at one pair from its association probabilities
    ``alpha (..., M + 1)`` (the last column no detection, computed with the miss weight
    ``1 - Pd`` of :func:`~.jpda.miss_cost`): ``(1 - Pd) / Pd * sum_i alpha_i / alpha_0``, ``(...)``.

    For a track on its own (PDA, or JPDA without a competing track) ``alpha_i / alpha_0 = Pd
    l_i / (lambda (1 - Pd))``, so this is the IPDA's ``sum_i l_i / lambda`` over the gated
    detections; where another track takes a detection, ``alpha_0`` grows and the ratio falls (the
    existence of a track that only shares another's detections fades). 0 for a track that gates
    nothing. Where ``alpha_0`` is below :data:`UNDERFLOW` (the track surely took a detection) the
    IPDA ``ratio (...)`` stands in."""
    q = math.exp(-miss_cost(pd))
    beta0 = alpha[..., -1]
    odds = (q / pd) * alpha[..., :-1].sum(-1) / beta0.clamp(min=UNDERFLOW)
    return torch.where(beta0 < UNDERFLOW, ratio, odds)


def pair_update(g: Gaussian, z: torch.Tensor, valid: torch.Tensor, sub: MeasurementModel, R: torch.Tensor,
                pd: float, clutter_density: float, m_best: int, gamma: float, active: torch.Tensor | None = None,
                association: Association = "jpda") -> PairUpdate:
    """One pair's detections ``z (B, M, d)`` update tracks ``g`` ``(B, C, n)`` (Eqs. 15-21); a
    track outside ``active (B, C)`` gates nothing (it is only predicted). ``association``:
    ``jpda`` (the paper's m-best joint events) or ``pda`` (:func:`pda_marginals`)."""
    inn = pair_innovations(g, z, valid, sub, R)
    mom, L, e, d2 = inn.moments, inn.L, inn.e, inn.d2
    log_lik = inn.log_lik.masked_fill(~valid.unsqueeze(1), math.nan)
    gate = inside_gate(d2, gamma) & valid.unsqueeze(1)
    gate = gate if active is None else gate & active.unsqueeze(-1)
    gated = gate.cpu().numpy()
    M = gated.shape[-1]
    if association == "pda":
        w = pda_marginals(log_lik.detach(), gate, pd, clutter_density)
    else:
        cost = np.where(gated, detection_costs(log_lik.detach().cpu().numpy(), pd, clutter_density), np.inf)
        w = torch.from_numpy(batched_single_sensor_marginals(cost, miss_cost(pd), m_best)).to(z.device)
    alpha = w.cpu().numpy()
    miss = alpha[..., M] >= alpha[..., :M].max(-1, initial=0.0)
    ratio = torch.where(gate, log_lik.exp(), torch.zeros((), dtype=log_lik.dtype, device=log_lik.device)).sum(-1)
    out = pda_collapse(g, mom, L, e, gate, w)
    e_c = (w[..., :M, None] * torch.where(gate[..., None], e, torch.zeros((), dtype=e.dtype, device=e.device))).sum(-2)
    ratio = ratio.detach() / clutter_density
    return PairUpdate(out, miss, mom.S[..., 0, 0].sqrt(), gated, ratio, e_c, w[..., :M].sum(1), shared_ratio(w, pd, ratio))


class SequentialJPDA(Associator):
    """S-MSJPDA's associator: :func:`pair_update` pair by pair (module docstring).

    ``model`` the detections' measurement model, ``R (S d, S d)`` block-diagonal over pairs,
    ``settings`` a :class:`~.msjpda.JPDASettings`, ``association`` ``jpda`` or ``pda``."""

    def __init__(self, model: MeasurementModel, R: torch.Tensor, settings, association: Association = "jpda"):
        self.settings, self.association = settings, association
        self.gamma = gate_threshold(settings.gate_probability, len(model.components))
        self.subs = [model.for_pairs([s]) for s in range(model.n_pairs)]
        self.R = [R[model.rows_for_pairs([s])][:, model.rows_for_pairs([s])] for s in range(model.n_pairs)]

    def associate(self, g: Gaussian, z: torch.Tensor, valid: torch.Tensor,
                  associating: torch.Tensor | None) -> AssociationStep:
        s = self.settings
        steps = []
        for j in range(len(self.subs)):
            step = pair_update(g, z[:, j], valid[:, j], self.subs[j], self.R[j], s.pd, s.clutter_density, s.m_best,
                               self.gamma, associating, self.association)
            g = step.posterior
            steps.append(step)
        dev = g.x.device
        detected = torch.zeros(g.x.shape[:2], dtype=torch.int64, device=dev)
        for step in steps:
            hit = torch.from_numpy(~step.miss_likeliest).to(dev)
            detected += hit if associating is None else hit & associating
        return AssociationStep(
            g, detected, torch.stack([st.ratio for st in steps], -1),
            torch.from_numpy(np.stack([st.gated.any(1) for st in steps], 1)).to(dev),
            torch.from_numpy(np.logical_and.reduce([st.miss_likeliest for st in steps])).to(dev),
            torch.stack([st.range_sd_m for st in steps], -1).amax(-1), torch.stack([st.whitened for st in steps], 2),
            taken=torch.stack([st.taken for st in steps], 1), shared_ratio=torch.stack([st.shared_ratio for st in steps], -1))


def _wrap(nu: torch.Tensor, model: MeasurementModel) -> torch.Tensor:
    """Angle components of per-pair residuals ``(..., d)`` wrapped to (-pi, pi]."""
    if "azimuth" not in model.components:
        return nu
    angles = torch.tensor([c == "azimuth" for c in model.components], device=nu.device)
    return torch.where(angles, wrap_angle(nu), nu)


def _pattern_inverses(S: torch.Tensor, n_pairs: int, d: int) -> tuple[np.ndarray, np.ndarray]:
    """For every detection pattern (bit s set: pair s detected) the inverse of the joint
    innovation covariance restricted to those pairs, embedded in zeros, ``(B, C, 2^S, S d, S d)``,
    and half its log-determinant ``(B, C, 2^S)`` (pattern 0: zeros)."""
    inv = S.new_zeros(*S.shape[:-2], 2**n_pairs, n_pairs * d, n_pairs * d)
    half_logdet = S.new_zeros(*S.shape[:-2], 2**n_pairs)
    for p in range(1, 2**n_pairs):
        rows = [s * d + j for s in range(n_pairs) if p >> s & 1 for j in range(d)]
        L = safe_cholesky(S[..., rows, :][..., rows])
        eye = torch.eye(len(rows), dtype=S.dtype, device=S.device).expand_as(L)
        Linv = torch.linalg.solve_triangular(L, eye, upper=False)
        idx = torch.tensor(rows, device=S.device)
        inv[..., p, idx[:, None], idx] = Linv.transpose(-1, -2) @ Linv
        half_logdet[..., p] = torch.log(torch.diagonal(L, dim1=-2, dim2=-1)).sum(-1)
    return inv.cpu().numpy(), half_logdet.cpu().numpy()


class ParallelJPDA(Associator):
    """P-MSJPDA's associator: every pair's detections update the tracks jointly (module docstring).
    ``model``, ``R`` and ``settings`` as :class:`SequentialJPDA`'s."""

    def __init__(self, model: MeasurementModel, R: torch.Tensor, settings):
        self.model, self.R, self.settings = model, R, settings
        self.gamma = gate_threshold(settings.gate_probability, len(model.components))

    def associate(self, g: Gaussian, z: torch.Tensor, valid: torch.Tensor,
                  associating: torch.Tensor | None) -> AssociationStep:
        """The joint update of tracks ``g`` from ``z (B, S, M, d)``. ``detected`` counts the pairs
        where some detection was more probable than none; each pair's ``ratio`` is taken under
        that pair's own block of the joint moments."""
        model, s = self.model, self.settings
        B, S, M, d = z.shape
        C = g.x.shape[1]
        mom = unscented_moments(g, model, self.R)  # pair layout: pair s owns rows s*d .. s*d+d-1
        zhat = mom.z.reshape(B, C, S, d)
        # each pair's diagonal block of the joint S, (B, C, S, d, d), gates that pair's detections
        S_blocks = mom.S.reshape(B, C, S, d, S, d).diagonal(dim1=2, dim2=4).permute(0, 1, 4, 2, 3)
        nu = _wrap(z.unsqueeze(1) - zhat.unsqueeze(3), model)  # (B, C, S, M, d)
        d2, block_log_lik = gaussian_log_likelihood(nu, S_blocks)
        gate = inside_gate(d2, self.gamma) & valid.unsqueeze(1)
        gated = (gate if associating is None else gate & associating[:, :, None, None]).cpu().numpy()  # (B, C, S, M)
        cand_z, cand_w, miss, detected, gap, taken, p_miss = self._candidates(gated, z.cpu().numpy(), zhat.cpu().numpy(),
                                                                               mom.S)
        Lmax = max(len(w) for row in cand_w for w in row)
        Zc = np.full((B, C, Lmax, S * d), np.nan)
        Wc = np.zeros((B, C, Lmax))
        for b in range(B):
            for t in range(C):
                L = len(cand_w[b][t])
                Zc[b, t, :L], Wc[b, t, :L] = cand_z[b][t], cand_w[b][t]
        dev = g.x.device
        post, _, _ = kalman_update(Gaussian(g.x.unsqueeze(-2), g.P.unsqueeze(-3)), torch.from_numpy(Zc).to(dev),
                                   expand_moments(mom), model)
        range_sd = mom.S.diagonal(dim1=-2, dim2=-1)[..., 0::d].sqrt().amax(-1)
        ratio = torch.where(torch.from_numpy(gated).to(dev), block_log_lik.exp(),
                            torch.zeros((), dtype=d2.dtype, device=dev)).sum(-1)
        ratio = ratio / s.clutter_density
        return AssociationStep(collapse(torch.from_numpy(Wc).to(dev), post.x, post.P), torch.from_numpy(detected).to(dev),
                               ratio, torch.from_numpy(gated.any(1)).to(dev), torch.from_numpy(miss).to(dev),
                               range_sd, None, gap, taken=torch.from_numpy(taken).to(dev),
                               shared_ratio=shared_ratio(torch.from_numpy(np.stack([1.0 - p_miss, p_miss], -1)).to(dev),
                                                         s.pd, ratio))

    def _candidates(self, gated: np.ndarray, zn: np.ndarray, zhat_n: np.ndarray, S_joint: torch.Tensor):
        """Per run and track, the candidate measurements ``(L, S d)`` and their marginal weights
        (cluster by cluster, :func:`~.jpda.candidate_marginals`); the loss-rule flag, the detected
        pair count ``(B, C)``, the largest duality gap, each detection's probability of being some
        track's ``(B, S, M)`` and each track's probability of no detection per pair ``(B, C, S)``."""
        model, s = self.model, self.settings
        B, C, S, M = gated.shape
        d = zn.shape[-1]
        inv, half_logdet = _pattern_inverses(S_joint, S, d)
        det_offset = math.log(2 * math.pi) * d / 2 - math.log(s.pd) + math.log(s.clutter_density)  # per detection
        miss = miss_cost(s.pd)
        wrap = "azimuth" in model.components
        cand_z = [[np.full((1, S * d), np.nan)] * C for _ in range(B)]
        cand_w = [[np.ones(1)] * C for _ in range(B)]
        dummy = np.ones((B, C), dtype=bool)
        detected = np.zeros((B, C), dtype=np.int64)
        taken = np.zeros((B, S, M))
        p_miss_all = np.ones((B, C, S))
        worst_gap = 0.0
        for b in range(B):
            for cl in track_clusters(gated[b].reshape(C, S * M)):
                used = gated[b, cl].any(0)  # (S, M): detections some track of the cluster gates
                local = [np.cumsum(used[k]) - 1 for k in range(S)]  # global -> local detection index
                n_meas = [int(used[k].sum()) for k in range(S)]
                tuples, costs, zs, owners = [], [], [], []
                for j, t in enumerate(cl):
                    options = [np.concatenate([[-1], np.flatnonzero(gated[b, t, k])]) for k in range(S)]
                    idx = np.array(list(itertools.product(*options)), dtype=np.int64)  # (L, S)
                    hit = idx >= 0
                    meas = np.where(hit[..., None], zn[b, np.arange(S), np.maximum(idx, 0)], np.nan)  # (L, S, d)
                    r = meas - zhat_n[b, t]
                    if wrap:
                        r = _wrap(torch.from_numpy(r), model).numpy()  # cpu: numpy in, numpy out
                    r = np.where(hit[..., None], r, 0.0).reshape(len(idx), S * d)
                    pattern = (hit * (1 << np.arange(S))).sum(1)
                    quad = np.einsum("li,lij,lj->l", r, inv[b, t, pattern], r)
                    D = hit.sum(1)
                    costs.append(0.5 * quad + half_logdet[b, t, pattern] + D * det_offset + (S - D) * miss)
                    loc = np.where(hit, np.stack([local[k][np.maximum(idx[:, k], 0)] for k in range(S)], 1), -1)
                    tuples.append(np.concatenate([np.full((len(idx), 1), j), loc], 1))
                    zs.append(meas.reshape(len(idx), S * d))
                    owners.append(idx)
                beta, gap = candidate_marginals(np.concatenate(tuples), np.concatenate(costs), n_meas, len(cl),
                                                s.m_best, s.relaxation_iterations, s.m_best_search)
                worst_gap = max(worst_gap, gap)
                start = 0
                for j, t in enumerate(cl):
                    L = len(costs[j])
                    w = beta[start:start + L]
                    start += L
                    keep = w > 0
                    cand_z[b][t], cand_w[b][t] = zs[j][keep], w[keep]
                    idx = owners[j][keep]
                    # loss-rule flag: at every pair, "no detection" at least as probable as any one detection
                    flags = []
                    for k in range(S):
                        p_miss = w[keep][idx[:, k] < 0].sum()
                        p_det = np.bincount(idx[:, k][idx[:, k] >= 0], weights=w[keep][idx[:, k] >= 0], minlength=1)
                        flags.append(p_miss >= p_det.max(initial=0.0))
                        taken[b, k, :len(p_det)] += p_det
                        p_miss_all[b, t, k] = p_miss
                    dummy[b, t] = all(flags)
                    detected[b, t] = S - sum(flags)
        return cand_z, cand_w, dummy, detected, worst_gap, taken, p_miss_all
