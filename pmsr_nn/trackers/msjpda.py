"""Multi-sensor JPDA: sequential (S-MSJPDA) and parallel (P-MSJPDA), Lyu & Wang, IEEE Access 2019.

Both keep one Gaussian per track (``T`` tracks, maintained from a given initiation; no birth or
death) and run all Monte Carlo runs at once: the UKF moments, gates, likelihoods and the mixture
updates are batched over runs and tracks. S-MSJPDA's combinatorial part is batched too (the
clusters of all runs, and the m-best events of every cluster up to 4096 events enumerated in one
array; only larger clusters go through Murty one by one); P-MSJPDA's (N+1)-D events are ranked
cluster by cluster (exactly by a vectorised branch and bound; or by the paper's Lagrangian
relaxation).

* **S-MSJPDA** (Eqs. 15-21): sensor by sensor. Each sensor's detections update the tracks left by
  the previous sensor: UKF moments of that sensor's (range, Doppler), the m-best 2-D events (the
  m cheapest of a cluster's enumerated events, or Murty's ranked assignment), the marginals
  ``alpha`` and a Gaussian mixture collapse (Eq. 16).
* **P-MSJPDA** (Eqs. 9-14): all sensors at once. A track's candidate is one detection (or none)
  per sensor; its likelihood is the *joint* predicted density of the stacked measurements (one
  set of sigma points through all sensors, so the correlation between sensors that the state
  uncertainty creates is kept), the m-best (N+1)-D events come from an exact branch and bound
  (``m_best_search``; the paper's Lagrangian relaxation as an option, and past the search's
  state budget), and the update collapses the joint UKF updates of the candidates. Eq. 11 of
  the paper writes the candidate likelihood as a product over sensors; that is the special case
  of uncorrelated predicted measurements, under which the (N+1)-D problem would split into N
  2-D ones.

Missed detections at Pd = 1 keep a finite cost (``1 - Pd`` floored at 1e-300) so an event always
exists; with one track, one sensor, no clutter and Pd = 1 both trackers are the UKF.

Per scan and track the trackers also record what the paper's loss rule reads: whether the
dummy (no detection) is the most probable association at every sensor, and the predicted
bistatic-range deviation (the gate size).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch

from ..config import require
from ..errors import ConfigError
from ..filters.gaussian import Gaussian, kalman_update, predict, safe_cholesky, unscented_moments
from ..measurements import MeasurementModel, wrap_angle
from ..motion import KinematicModel
from ..simulation.detections import Scans, check_model_for_detections
from .clustering import track_clusters
from .gating import gate_threshold, gaussian_log_likelihood
from .mixture import collapse, expand_moments, pda_collapse
from .learned_gain import Association, GainCorrection, pda_marginals
from .jpda import M_BEST_SEARCHES, batched_single_sensor_marginals, candidate_marginals, detection_costs, miss_cost


@dataclass(frozen=True)
class JPDASettings:
    """``pd`` detection probability, ``clutter_density`` expected clutter per unit of measurement
    space (1 / (m Hz)), ``m_best`` events per cluster, ``gate_probability`` of the chi-square gate,
    and for P-MSJPDA's (N+1)-D events ``m_best_search`` (:data:`.jpda.M_BEST_SEARCHES`: exact
    branch and bound, or the paper's Lagrangian relaxation) and ``relaxation_iterations``."""

    pd: float
    clutter_density: float
    m_best: int = 10
    gate_probability: float = 0.999
    relaxation_iterations: int = 20
    m_best_search: str = "branch_and_bound"

    def __post_init__(self) -> None:
        require(0.0 < self.pd <= 1.0, f"pd must be in (0, 1], got {self.pd}")
        require(self.clutter_density > 0 and math.isfinite(self.clutter_density),
                f"clutter_density must be positive (a tracker needs a clutter model), got {self.clutter_density}")
        require(self.m_best >= 1, f"m_best must be at least 1, got {self.m_best}")
        require(self.relaxation_iterations >= 1, "relaxation_iterations must be at least 1")
        require(self.m_best_search in M_BEST_SEARCHES,
                f"m_best_search must be one of {', '.join(M_BEST_SEARCHES)}, got {self.m_best_search!r}")


@dataclass
class MultiTargetResult:
    """Per scan and track: means ``x (B, K, T, n)``, covariances ``P (B, K, T, n, n)``,
    ``dummy_most_probable (B, K, T)`` (no detection was the likeliest association at every
    sensor), ``gate_range_sd_m (B, K, T)`` (largest predicted bistatic-range deviation over the
    sensors, R included) and, for P-MSJPDA, the largest relaxation duality gap met (nats)."""

    x: torch.Tensor
    P: torch.Tensor
    dummy_most_probable: torch.Tensor
    gate_range_sd_m: torch.Tensor
    max_duality_gap: float = 0.0


def check_scans(scans: Scans, model: MeasurementModel) -> None:
    """One-line errors for detections ``model`` can not read (sensor count, values, NaN)."""
    check_model_for_detections(model)
    B, K, N, M = scans.shape
    if N != model.n_pairs or scans.z.shape[-1] != len(model.components):
        raise ConfigError(f"detections are from {N} sensors with {scans.z.shape[-1]} values each; the model has "
                          f"{model.n_pairs} sensors with {len(model.components)}")
    if bool(torch.isnan(scans.z[scans.valid]).any()) or bool(torch.isinf(scans.z).any()):
        raise ConfigError("a valid detection is NaN or infinite")


def check_tracker_inputs(scans: Scans, prior: Gaussian, motion: KinematicModel, model: MeasurementModel) -> None:
    check_scans(scans, model)
    B = scans.shape[0]
    n = motion.dim_x
    if prior.x.dim() != 3 or prior.x.shape[0] != B or prior.x.shape[-1] != n or prior.P.shape != (*prior.x.shape, n):
        raise ConfigError(f"prior must be x (B={B}, T, {n}) and P (B, T, {n}, {n}); got {tuple(prior.x.shape)}, "
                          f"{tuple(prior.P.shape)}")
    if not bool(torch.isfinite(prior.x).all()):
        raise ConfigError("the prior mean is not finite")


def _jpda_marginals(gated: np.ndarray, log_lik: np.ndarray, s: JPDASettings) -> np.ndarray:
    """``alpha (B, T, M + 1)`` of one sensor: the tracks' clusters of all runs and the m-best
    events of each (:func:`~.jpda.batched_single_sensor_marginals`); column ``M`` the miss."""
    cost = np.where(gated, detection_costs(log_lik, s.pd, s.clutter_density), np.inf)
    return batched_single_sensor_marginals(cost, miss_cost(s.pd), s.m_best)


def _sensor_step(g: Gaussian, z: torch.Tensor, valid: torch.Tensor, sub: MeasurementModel, R: torch.Tensor,
                 s: JPDASettings, gamma: float, active: torch.Tensor | None = None,
                 association: Association = "jpda", correction: GainCorrection | None = None, pair: int = 0,
                 learned: torch.Tensor | None = None
                 ) -> tuple[Gaussian, np.ndarray, torch.Tensor, np.ndarray, torch.Tensor, torch.Tensor]:
    """One sensor's detections ``z (B, M, d)`` update tracks ``g`` ``(B, T, n)`` (Eqs. 15-21);
    a track outside ``active (B, T)`` gates nothing (it is only predicted). Returns the
    posterior, whether no detection was the likeliest association ``(B, T)``, the predicted
    range deviation ``(B, T)``, the gates ``(B, T, M)``, the summed likelihood ratio of the
    gated detections to clutter ``(B, T)`` (what a track's existence is updated with) and the
    whitened combined innovation ``L^-1 sum_i alpha_i nu_i`` ``(B, T, d)`` (the innovation bias
    test's, :mod:`.innovation_bias`).

    ``association``: ``jpda`` (the paper's m-best joint events) or ``pda`` (each track on its
    own, :func:`~.learned_gain.pda_marginals`). ``correction`` (the hybrid tracker of
    :mod:`.learned_gain`) adds its learned gain correction times the combined innovation of
    sensor ``pair`` to the posterior mean, on the tracks ``learned (B, T)`` (default: ``active``);
    the association weights are constants to it (no gradient)."""
    mom = unscented_moments(g, sub, R)
    nu = sub.residual(z.unsqueeze(1), mom.z.unsqueeze(2))  # (B, T, M, d), NaN for padding
    # gaussian_log_likelihood's algebra with one triangular solve per track for all M detections
    # (M right-hand sides, not M broadcast solves); L and e = L^-1 nu serve the update too.
    L = safe_cholesky(mom.S)  # (B, T, d, d)
    pad = ~valid.unsqueeze(1)  # (B, 1, M)
    e = torch.linalg.solve_triangular(L, nu.masked_fill(pad.unsqueeze(-1), 0.0).transpose(-1, -2),
                                      upper=False).transpose(-1, -2)  # (B, T, M, d)
    d2 = (e * e).sum(-1)
    half_logdet = torch.log(torch.diagonal(L, dim1=-2, dim2=-1)).sum(-1)
    log_lik = (-0.5 * d2 - half_logdet.unsqueeze(-1) - 0.5 * nu.shape[-1] * math.log(2 * math.pi)).masked_fill(
        pad, math.nan)
    gate = (d2 <= gamma) & valid.unsqueeze(1)
    gate = gate if active is None else gate & active.unsqueeze(-1)
    gated = gate.numpy()
    M = gated.shape[-1]
    if association == "pda":
        w = pda_marginals(log_lik.detach(), gate, s.pd, s.clutter_density)
    else:
        w = torch.from_numpy(_jpda_marginals(gated, log_lik.detach().numpy(), s))
    alpha = w.numpy()
    dummy = alpha[..., M] >= alpha[..., :M].max(-1, initial=0.0)
    ratio = torch.where(gate, log_lik.exp(), torch.zeros((), dtype=log_lik.dtype)).sum(-1)
    out = pda_collapse(g, mom, L, e, gate, w)
    if correction is not None:
        out = Gaussian(out.x + correction.step(pair, w, nu, gate, mom, active if learned is None else learned), out.P)
    e_c = (w[..., :M, None] * torch.where(gate[..., None], e, torch.zeros((), dtype=e.dtype))).sum(-2)
    return out, dummy, mom.S[..., 0, 0].sqrt(), gated, ratio.detach() / s.clutter_density, e_c


def _wrap(nu: torch.Tensor, model: MeasurementModel) -> torch.Tensor:
    """Angle components of per-sensor residuals ``(..., d)`` wrapped to (-pi, pi]."""
    if "azimuth" not in model.components:
        return nu
    angles = torch.tensor([c == "azimuth" for c in model.components])
    return torch.where(angles, wrap_angle(nu), nu)


def _wrap_np(nu: np.ndarray, model: MeasurementModel) -> np.ndarray:
    return _wrap(torch.from_numpy(nu), model).numpy() if "azimuth" in model.components else nu


def _pattern_inverses(S: torch.Tensor, N: int, d: int) -> tuple[np.ndarray, np.ndarray]:
    """For every detection pattern (bit s set: sensor s detected) the inverse of the joint
    innovation covariance restricted to those sensors, embedded in zeros, ``(B, T, 2^N, Nd, Nd)``,
    and half its log-determinant ``(B, T, 2^N)`` (pattern 0: zeros)."""
    inv = S.new_zeros(*S.shape[:-2], 2**N, N * d, N * d)
    half_logdet = S.new_zeros(*S.shape[:-2], 2**N)
    for p in range(1, 2**N):
        rows = [s * d + j for s in range(N) if p >> s & 1 for j in range(d)]
        L = safe_cholesky(S[..., rows, :][..., rows])
        eye = torch.eye(len(rows), dtype=S.dtype).expand_as(L)
        Linv = torch.linalg.solve_triangular(L, eye, upper=False)
        idx = torch.tensor(rows)
        inv[..., p, idx[:, None], idx] = Linv.transpose(-1, -2) @ Linv
        half_logdet[..., p] = torch.log(torch.diagonal(L, dim1=-2, dim2=-1)).sum(-1)
    return inv.numpy(), half_logdet.numpy()


def _joint_step(g: Gaussian, z: torch.Tensor, valid: torch.Tensor, model: MeasurementModel, R: torch.Tensor,
                s: JPDASettings, gamma: float, active: torch.Tensor | None = None
                ) -> tuple[Gaussian, np.ndarray, torch.Tensor, float, np.ndarray, np.ndarray, torch.Tensor]:
    """All sensors' detections ``z (B, N, M, d)`` update tracks ``g`` jointly (Eqs. 9-14); a
    track outside ``active (B, T)`` gates nothing. Returns the posterior, the loss-rule flag
    ``(B, T)``, the predicted range deviation ``(B, T)``, the largest duality gap, the gates
    ``(B, T, N, M)``, at how many sensors each track was detected ``(B, T)`` (a detection more
    probable than none) and each sensor's summed likelihood ratio of its gated detections to
    clutter ``(B, T, N)`` (under that sensor's own block of the joint moments)."""
    B, N, M, d = z.shape
    T = g.x.shape[1]
    mom = unscented_moments(g, model, R)  # pair layout: sensor s owns rows s*d .. s*d+d-1
    zhat = mom.z.reshape(B, T, N, d)
    # each sensor's diagonal block of the joint S, (B, T, N, d, d), gates that sensor's detections
    S_blocks = mom.S.reshape(B, T, N, d, N, d).diagonal(dim1=2, dim2=4).permute(0, 1, 4, 2, 3)
    nu = _wrap(z.unsqueeze(1) - zhat.unsqueeze(3), model)  # (B, T, N, M, d)
    d2, block_log_lik = gaussian_log_likelihood(nu, S_blocks)
    gate = (d2 <= gamma) & valid.unsqueeze(1)
    gated = (gate if active is None else gate & active[:, :, None, None]).numpy()  # (B, T, N, M)
    inv, half_logdet = _pattern_inverses(mom.S, N, d)
    zn, zhat_n = z.numpy(), zhat.numpy()
    det_offset = math.log(2 * math.pi) * d / 2 - math.log(s.pd) + math.log(s.clutter_density)  # per detection
    miss = miss_cost(s.pd)
    cand_z = [[np.full((1, N * d), np.nan)] * T for _ in range(B)]  # per run and track: candidate measurements
    cand_w = [[np.ones(1)] * T for _ in range(B)]
    dummy = np.ones((B, T), dtype=bool)
    detected = np.zeros((B, T), dtype=np.int64)
    worst_gap = 0.0
    for b in range(B):
        for cl in track_clusters(gated[b].reshape(T, N * M)):
            used = gated[b, cl].any(0)  # (N, M): detections some track of the cluster gates
            local = [np.cumsum(used[k]) - 1 for k in range(N)]  # global -> local detection index
            n_meas = [int(used[k].sum()) for k in range(N)]
            tuples, costs, zs, owners = [], [], [], []
            for j, t in enumerate(cl):
                options = [np.concatenate([[-1], np.flatnonzero(gated[b, t, k])]) for k in range(N)]
                idx = np.array(list(itertools.product(*options)), dtype=np.int64)  # (L, N)
                hit = idx >= 0
                meas = np.where(hit[..., None], zn[b, np.arange(N), np.maximum(idx, 0)], np.nan)  # (L, N, d)
                r = np.where(hit[..., None], _wrap_np(meas - zhat_n[b, t], model), 0.0).reshape(len(idx), N * d)
                pattern = (hit * (1 << np.arange(N))).sum(1)
                quad = np.einsum("li,lij,lj->l", r, inv[b, t, pattern], r)
                D = hit.sum(1)
                costs.append(0.5 * quad + half_logdet[b, t, pattern] + D * det_offset + (N - D) * miss)
                loc = np.where(hit, np.stack([local[k][np.maximum(idx[:, k], 0)] for k in range(N)], 1), -1)
                tuples.append(np.concatenate([np.full((len(idx), 1), j), loc], 1))
                zs.append(meas.reshape(len(idx), N * d))
                owners.append(idx)
            beta, gap = candidate_marginals(np.concatenate(tuples), np.concatenate(costs), n_meas, len(cl), s.m_best,
                                            s.relaxation_iterations, s.m_best_search)
            worst_gap = max(worst_gap, gap)
            start = 0
            for j, t in enumerate(cl):
                L = len(costs[j])
                w = beta[start:start + L]
                start += L
                keep = w > 0
                cand_z[b][t], cand_w[b][t] = zs[j][keep], w[keep]
                idx = owners[j][keep]
                # loss-rule flag: at every sensor, "no detection" at least as probable as any one detection
                flags = []
                for k in range(N):
                    p_miss = w[keep][idx[:, k] < 0].sum()
                    p_det = np.bincount(idx[:, k][idx[:, k] >= 0], weights=w[keep][idx[:, k] >= 0], minlength=1)
                    flags.append(p_miss >= p_det.max(initial=0.0))
                dummy[b, t] = all(flags)
                detected[b, t] = N - sum(flags)
    Lmax = max(len(w) for row in cand_w for w in row)
    Zc = np.full((B, T, Lmax, N * d), np.nan)
    Wc = np.zeros((B, T, Lmax))
    for b in range(B):
        for t in range(T):
            L = len(cand_w[b][t])
            Zc[b, t, :L], Wc[b, t, :L] = cand_z[b][t], cand_w[b][t]
    post, _, _ = kalman_update(Gaussian(g.x.unsqueeze(-2), g.P.unsqueeze(-3)), torch.from_numpy(Zc), expand_moments(mom), model)
    range_sd = mom.S.diagonal(dim1=-2, dim2=-1)[..., 0::d].sqrt().amax(-1)
    ratio = torch.where(torch.from_numpy(gated), block_log_lik.exp(), torch.zeros((), dtype=d2.dtype)).sum(-1)
    return (collapse(torch.from_numpy(Wc), post.x, post.P), dummy, range_sd, worst_gap, gated, detected,
            ratio / s.clutter_density)


def _check_variant(architecture: str, association: str, correction) -> None:
    if architecture not in ("sequential", "parallel"):
        raise ConfigError(f"architecture must be 'sequential' or 'parallel', got {architecture!r}")
    if association not in ("jpda", "pda"):
        raise ConfigError(f"association must be 'jpda' or 'pda', got {association!r}")
    if architecture == "parallel" and (association != "jpda" or correction is not None):
        raise ConfigError("P-MSJPDA associates jointly over the sensors: no pda association or learned gain")


def _births(active: torch.Tensor | None, B: int, K: int, T: int) -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """``active`` as ``(B, K, T)`` and each track's first active scan ``(B, T)`` (K if never)."""
    if active is None:
        return None, None
    if active.shape not in ((K, T), (B, K, T)):
        raise ConfigError(f"active must be (K={K}, T={T}) or (B={B}, K, T), got {tuple(active.shape)}")
    active = active.expand(B, K, T)
    first = torch.where(active.any(1), active.to(torch.int64).argmax(1), torch.full((B, T), K))
    return active, first


def msjpda(scans: Scans, prior: Gaussian, motion: KinematicModel, dt: float, q: float, model: MeasurementModel,
           R: torch.Tensor, settings: JPDASettings, architecture: Literal["sequential", "parallel"],
           active: torch.Tensor | None = None, association: Association = "jpda",
           correction: GainCorrection | None = None) -> MultiTargetResult:
    """Track ``T`` targets through ``scans`` (``B`` runs, ``K`` scans) from ``prior`` ``x (B, T, n)``.

    Step 0 is an update of the prior only (the convention of :mod:`pmsr_nn.filters.kalman`); every
    later scan a CV/CA prediction over ``dt`` with process noise ``q``, then the update of the
    chosen architecture. ``R (N d, N d)`` is block-diagonal over sensors (pair layout).

    ``active (K, T)`` or ``(B, K, T)`` (default: every track at every scan) gives each track's
    life: a track is started from its ``prior`` at its first active scan (the prior is then the
    state at that scan), takes part in the association only while active, and is only predicted
    otherwise (its estimates there mean nothing).

    ``association`` and ``correction`` (sequential only): see :func:`_sensor_step`.
    """
    check_tracker_inputs(scans, prior, motion, model)
    _check_variant(architecture, association, correction)
    B, K, N, M = scans.shape
    T, n = prior.x.shape[1:]
    if correction is not None:
        correction.start(B, T)
    active, first = _births(active, B, K, T)
    d = len(model.components)
    gamma = gate_threshold(settings.gate_probability, d)
    F, Q = motion.F(dt, prior.x.dtype), motion.Q(dt, q, prior.x.dtype)
    subs = [model.for_pairs([k]) for k in range(N)]
    rows = [model.rows_for_pairs([k]) for k in range(N)]
    x = prior.x.new_empty(B, K, T, n)
    P = prior.x.new_empty(B, K, T, n, n)
    dummy = np.zeros((B, K, T), dtype=bool)
    gate_sd = prior.x.new_empty(B, K, T)
    worst_gap = 0.0
    g = prior
    for k in range(K):
        if k > 0:
            g = predict(g, F, Q)
            if first is not None and bool((first == k).any()):
                born = (first == k)
                g = Gaussian(torch.where(born[..., None], prior.x, g.x), torch.where(born[..., None, None], prior.P, g.P))
        act = None if active is None else active[:, k]
        if architecture == "sequential":
            flags, sds = [], []
            for j in range(N):
                g, f, sd, _, _, _ = _sensor_step(g, scans.z[:, k, j], scans.valid[:, k, j], subs[j], R[rows[j]][:, rows[j]],
                                              settings, gamma, act, association, correction, j)
                flags.append(f)
                sds.append(sd)
            dummy[:, k] = np.logical_and.reduce(flags)
            gate_sd[:, k] = torch.stack(sds, -1).amax(-1)
        else:
            g, dummy[:, k], gate_sd[:, k], gap, _, _, _ = _joint_step(g, scans.z[:, k], scans.valid[:, k], model, R, settings,
                                                                   gamma, act)
            worst_gap = max(worst_gap, gap)
        x[:, k], P[:, k] = g.x, g.P
    return MultiTargetResult(x, P, torch.from_numpy(dummy), gate_sd, worst_gap)


def true_assignment_ukf(scans: Scans, prior: Gaussian, motion: KinematicModel, dt: float, q: float,
                        model: MeasurementModel, R: torch.Tensor) -> MultiTargetResult:
    """The reference of Fig. 3: each track is updated by a UKF with exactly the detections its
    target caused (the truth origin), none when missed, and never with clutter."""
    from ..filters import ukf

    check_tracker_inputs(scans, prior, motion, model)
    B, K, N, M = scans.shape
    T, n = prior.x.shape[1:]
    z = scans.target_measurements(T).permute(0, 2, 1, 3, 4).reshape(B * T, K, -1)  # pair layout
    r = ukf(Gaussian(prior.x.reshape(B * T, n), prior.P.reshape(B * T, n, n)), z, motion, dt, q, model, R)
    x = r.x.reshape(B, T, K, n).transpose(1, 2)
    P = r.P.reshape(B, T, K, n, n).transpose(1, 2)
    d = len(model.components)
    missed = torch.isnan(z.reshape(B, T, K, N, d)[..., 0]).all(-1).transpose(1, 2)
    no_gate = torch.zeros(B, K, T, dtype=x.dtype)  # the reference has no gate, so the gate rule never fires
    return MultiTargetResult(x, P, missed, no_gate)
