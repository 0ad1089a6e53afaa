"""Probabilistic multi-hypothesis tracking (PMHT, Streit & Luginbuhl 1995) and its 3-D
(target-detection-illuminator) association variant of Li et al., JEIT 2021, over a sliding batch
of scans, all Monte Carlo runs at once.

Model
-----
``T`` targets, each present at every scan (:func:`pmht`: tracks start from a prior at scan 0;
no birth or death; :func:`managed_pmht` starts and ends its own, below).
Detections arrive in *lists*: one per transmitter-receiver pair when each detection's illuminator
is known, one per receiver in a single-frequency network (SFN), where it is not. Detection ``r``
was caused by clutter (uniform over the measurement box of volume ``V``) or by target ``t`` through
one of the pairs ``A_r`` that can have produced it (every pair of its receiver in an SFN, its own
pair otherwise), independently of the other detections: PMHT's assumption, which lets a target
cause several detections of a list and makes the association posterior factor over detections.
With fixed association priors written as rates (Pd per target and pair, clutter rate
``lambda_s`` per pair), each detection's density is the mixture

    p(z_r | X) = [lambda_A / V + sum_{t, s in A_r, p} Pd c_p N(z_r; h_s(x_t), kappa_p R_s)] / const,

``lambda_A = sum_{s in A_r} lambda_s``. The Gaussian scale mixture (``kappa_p`` with weights
``c_p``) is the paper's "equal means, different covariances" (Section 3.2); one component with
``kappa = 1`` is plain PMHT. The priors are fixed (from Pd and the clutter rate), not estimated.

EM over a window of scans (MAP estimate of the states ``X`` of every target at every scan)
-------------------------------------------------------------------------------------------
* E-step (Eq. 20): the posterior weight of every (detection, target, pair, component), with runs,
  scans, lists, detections, targets, pairs and components as tensor axes.
* M-step (Eqs. 21-25): per target and pair one synthetic measurement, the weighted mean of the
  detections with weights ``w / kappa`` (taken as residuals about the current prediction, so an
  angle would average correctly), with covariance ``R_s / sum(w / kappa)``. The paper's Eq. 25
  divides by ``sum(w)``; the maximiser of its Eq. 21 has the ``1 / kappa`` (they agree for one
  component). Then an unscented Kalman smoother per target: a UKF over the synthetic
  measurements and the RTS backward pass (the CV transition is linear, where the unscented RTS
  pass of :mod:`~pmsr_nn.filters.smoothing` equals the linear one). A pair whose summed weight is
  below ``min_weight`` gives no synthetic measurement.
* Annealing (optional, ``anneal``): the first iterations of a batch use an inflated measurement
  covariance, shrinking to ``R`` by the middle (:meth:`PMHTSettings.inflation`), so that EM
  started several deviations from the detections (a loose initiation) still finds them.
* With a linear measurement model the M-step is exact and the objective (:func:`window_objective`:
  the log prior of the window's first state, the transitions and every detection's mixture
  density) never decreases over iterations; with the bistatic model the UKF's linearisation makes
  the M-step approximate.

Sliding window: ``window`` scans, advancing by ``window - overlap`` (the last window ends at the
last scan). The scans leaving a window keep its smoothed estimates (a fixed-lag smoother, not
causal); the next window's prior is the last iteration's forward filter predicted to its first
scan, so no detection counts twice; EM starts from the previous smoothed states on the overlap
and their CV prediction beyond.

Track management (:func:`managed_pmht`)
---------------------------------------
The tracks of :mod:`.management` (a table of slots, an initiator, M-of-N confirmation, a
deleter, IPDA existence) in the sliding window: EM runs on every slot, a free one explaining no
detection; after EM, each scan the window commits reads the association weights (a hit where a
track's summed weight at a pair is >= 0.5, a start from the detections whose weight on all
tracks is < 0.5), and a track started at a scan of the window joins EM from that scan on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch

from ..config import require
from ..errors import ConfigError
from ..filters.gaussian import Gaussian, SigmaPoints, predict, safe_cholesky
from ..filters.smoothing import rts_from_predictions
from ..measurements import wrap_angle
from ..motion import KinematicModel
from ..simulation.detections import PooledScans, Scans
from .gating import gaussian_log_likelihood
from .management import Management, TrackReport, TrackTable, parked_state


@dataclass(frozen=True)
class PMHTSettings:
    """``pd``: detection probability per target and pair; ``clutter_rate (S,)``: expected clutter
    detections per scan attributed to each pair (> 0); ``volume``: the measurement box's volume in
    SI units (m Hz for range-Doppler); ``window`` scans per batch, ``overlap`` scans shared by
    consecutive batches; ``em_iterations`` per batch (at most: EM stops earlier once no position
    moves more than ``tolerance_m``, 0 = never); ``kappa`` covariance scales of the measurement
    mixture with ``kappa_weights`` (default equal); ``anneal``: the measurement covariance of the
    first EM iteration of a batch is ``anneal`` times ``R`` (:meth:`inflation`); ``chunk_runs``:
    runs per pass (bounds memory)."""

    pd: float
    clutter_rate: tuple[float, ...]
    volume: float
    window: int = 10
    overlap: int = 3
    em_iterations: int = 6
    tolerance_m: float = 0.0
    kappa: tuple[float, ...] = (1.0,)
    kappa_weights: tuple[float, ...] | None = None
    anneal: float = 1.0
    min_weight: float = 1e-9
    chunk_runs: int = 64

    def __post_init__(self) -> None:
        require(0.0 < self.pd <= 1.0, f"pd must be in (0, 1], got {self.pd}")
        require(all(r > 0 and math.isfinite(r) for r in self.clutter_rate) and len(self.clutter_rate) > 0,
                f"clutter rates must be positive (a tracker needs a clutter model), got {self.clutter_rate}")
        require(self.volume > 0 and math.isfinite(self.volume), f"volume must be positive, got {self.volume}")
        require(self.window >= 1, f"window must be at least 1 scan, got {self.window}")
        require(0 <= self.overlap < self.window, f"overlap must be in [0, window - 1], got {self.overlap}")
        require(self.em_iterations >= 1, f"em_iterations must be at least 1, got {self.em_iterations}")
        require(self.tolerance_m >= 0, f"tolerance_m must be >= 0, got {self.tolerance_m}")
        require(len(self.kappa) >= 1 and all(k > 0 and math.isfinite(k) for k in self.kappa),
                f"kappa must be positive covariance scales, got {self.kappa}")
        w = self.kappa_weights
        require(w is None or (len(w) == len(self.kappa) and all(v > 0 for v in w)),
                f"kappa_weights must be one positive weight per kappa, got {w}")
        require(self.min_weight > 0 and self.chunk_runs >= 1, "min_weight must be positive and chunk_runs >= 1")
        require(self.anneal >= 1 and math.isfinite(self.anneal), f"anneal must be >= 1, got {self.anneal}")

    def inflation(self, iteration: int) -> float:
        """Annealing (homotopy) of the measurement covariance: iteration ``i`` (0-based) of a batch
        uses ``a_i R``, ``a_i = anneal^(1 - i / h)`` for ``i < h = em_iterations // 2``, then 1. EM
        from a start far from the detections (several deviations: a loose initiation prior) sees
        them through the wider covariance first; the last iterations are plain EM."""
        h = self.em_iterations // 2
        return self.anneal ** (1 - iteration / h) if iteration < h and self.anneal > 1 else 1.0

    @property
    def step(self) -> int:
        return self.window - self.overlap

    def mixture(self, dtype, device) -> tuple[torch.Tensor, torch.Tensor]:
        """``kappa (P,)`` and the log of the normalised weights ``(P,)``."""
        kappa = torch.tensor(self.kappa, dtype=dtype, device=device)
        w = torch.tensor(self.kappa_weights or [1.0] * len(self.kappa), dtype=dtype, device=device)
        return kappa, (w / w.sum()).log()


@dataclass
class AssociationLists:
    """Detections as PMHT reads them: ``z (B, K, L, M, d)``, ``valid (B, K, L, M)`` and
    ``candidates (B, K, L, M, S)`` bool, the pairs that may have produced each detection."""

    z: torch.Tensor
    valid: torch.Tensor
    candidates: torch.Tensor

    @classmethod
    def per_pair(cls, scans: Scans) -> "AssociationLists":
        """Illuminator known: one list per pair, each detection from its list's pair."""
        B, K, S, M = scans.shape
        eye = torch.eye(S, dtype=torch.bool, device=scans.z.device)
        return cls(scans.z, scans.valid, eye[:, None, :].expand(B, K, S, M, S))

    @classmethod
    def pooled(cls, pooled: PooledScans, labels_known: bool = False) -> "AssociationLists":
        """One list per receiver; the candidates are the receiver's pairs, or (``labels_known``,
        for checks) each detection's true pair."""
        s = pooled.scans
        B, K, L, M = s.shape
        S = pooled.routes.shape[1]
        if labels_known:
            cand = pooled.pair.unsqueeze(-1) == torch.arange(S, device=s.z.device)
        else:
            cand = pooled.routes.to(s.z.device)[:, None, :].expand(B, K, L, M, S)
        return cls(s.z, s.valid, cand)

    def take(self, runs: slice, scans: slice = slice(None)) -> "AssociationLists":
        return AssociationLists(self.z[runs, scans], self.valid[runs, scans], self.candidates[runs, scans])


@dataclass
class PMHTResult:
    """Smoothed means ``x (B, K, T, n)`` and covariances ``P (B, K, T, n, n)``; ``objective``: per
    window, ``(iterations + 1, B)`` values of :func:`window_objective` (only when asked for)."""

    x: torch.Tensor
    P: torch.Tensor
    objective: list[torch.Tensor] | None = None


@dataclass
class PMHTProblem:
    """What every window shares: models, per-pair noise factors and the settings."""

    model: object
    F: torch.Tensor
    Q: torch.Tensor
    R: torch.Tensor  # (S d, S d) block-diagonal
    R_inv_chol: torch.Tensor  # (S, d, d): L_s^-1 with L_s L_s^T = R_s
    log_det: torch.Tensor  # (S,): log det R_s
    angles: torch.Tensor  # (d,) bool
    rate: torch.Tensor  # (S,)
    kappa: torch.Tensor  # (P,)
    log_c: torch.Tensor  # (P,)
    sigma: tuple  # (wm, wc, scale) of the UKF's sigma points
    settings: PMHTSettings

    @property
    def pairs(self) -> int:
        return self.R_inv_chol.shape[0]


def problem(model, motion: KinematicModel, dt: float, q, R: torch.Tensor, s: PMHTSettings, dtype=torch.float64,
            device=None) -> PMHTProblem:
    """Everything the windows share (one-line errors for a model or ``R`` PMHT can not use)."""
    S = getattr(model, "n_pairs", 1)
    if getattr(model, "layout", "pair") != "pair":
        raise ConfigError("PMHT reads detections per pair: the measurement model needs layout 'pair'")
    if len(s.clutter_rate) != S:
        raise ConfigError(f"{len(s.clutter_rate)} clutter rates for {S} pairs")
    d = model.dim_z // S
    R = R.to(dtype=dtype, device=device)
    blocks = torch.stack([R[i * d:(i + 1) * d, i * d:(i + 1) * d] for i in range(S)])
    off = R.clone()
    for i in range(S):
        off[i * d:(i + 1) * d, i * d:(i + 1) * d] = 0
    if bool((off != 0).any()):
        raise ConfigError("PMHT needs R block-diagonal across pairs (independent sensors)")
    L = safe_cholesky(blocks)
    eye = torch.eye(d, dtype=dtype, device=device).expand_as(L)
    kappa, log_c = s.mixture(dtype, device)
    return PMHTProblem(model, motion.F(dt, dtype, device), motion.Q(dt, q, dtype, device), R,
                    torch.linalg.solve_triangular(L, eye, upper=False),
                    2 * torch.log(torch.diagonal(L, dim1=-2, dim2=-1)).sum(-1), model.angle_mask[:d].to(device),
                    torch.tensor(s.clutter_rate, dtype=dtype, device=device), kappa, log_c,
                    SigmaPoints().weights(motion.dim_x, dtype, device), s)


def _log_terms(pr: PMHTProblem, X: torch.Tensor, lists: AssociationLists, inflate: float = 1.0,
               alive: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """For states ``X (B, W, T, n)`` and a window's lists: residuals ``nu (B, W, L, M, T, S, d)``,
    ``log(Pd c_p N(z_r; h_s(x_t), kappa_p R_s)) (B, W, L, M, T, S, P)`` (-inf where pair ``s`` is
    not a candidate or the slot is padding) and the clutter term ``log(lambda_A / V) (B, W, L, M)``;
    ``inflate`` scales every ``kappa`` (annealing); a track outside ``alive (B, W, T)`` (default:
    every track at every scan) explains no detection there (-inf)."""
    B, W, T, _ = X.shape
    S, d = pr.pairs, pr.R_inv_chol.shape[-1]
    h = pr.model.h(X).reshape(B, W, 1, 1, T, S, d)
    z = torch.nan_to_num(lists.z)[:, :, :, :, None, None, :]
    nu = z - h
    if bool(pr.angles.any()):
        nu = torch.where(pr.angles, wrap_angle(nu), nu)
    e = torch.einsum("sij,bwlmtsj->bwlmtsi", pr.R_inv_chol, nu)
    maha = (e * e).sum(-1, keepdim=True)  # (B, W, L, M, T, S, 1)
    k = pr.kappa * inflate
    log_n = -0.5 * maha / k - 0.5 * (d * torch.log(2 * math.pi * k) + pr.log_det[:, None])
    ok = lists.candidates & lists.valid.unsqueeze(-1)  # (B, W, L, M, S)
    log_t = torch.where(ok[:, :, :, :, None, :, None], math.log(pr.settings.pd) + pr.log_c + log_n,
                        torch.full((), -math.inf, dtype=X.dtype, device=X.device))
    if alive is not None:
        log_t = log_t.masked_fill(~alive[:, :, None, None, :, None, None], -math.inf)
    lam = (lists.candidates.to(X.dtype) * pr.rate).sum(-1)  # (B, W, L, M)
    log_clutter = torch.log(lam.clamp_min(1e-300)) - math.log(pr.settings.volume)
    return nu, log_t, log_clutter


def _log_density(log_t: torch.Tensor, log_clutter: torch.Tensor) -> torch.Tensor:
    """Log of each detection's mixture density ``(B, W, L, M)`` (up to a constant)."""
    return torch.logsumexp(torch.cat([log_clutter.unsqueeze(-1), log_t.flatten(-3)], -1), -1)


def association_weights(pr: PMHTProblem, X: torch.Tensor, lists: AssociationLists, inflate: float = 1.0,
                        alive: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """E-step: weights ``w (B, W, L, M, T, S, P)`` (0 on padding and where a track is not
    ``alive (B, W, T)``) and the residuals ``nu``."""
    nu, log_t, log_clutter = _log_terms(pr, X, lists, inflate, alive)
    w = torch.exp(log_t - _log_density(log_t, log_clutter)[..., None, None, None])
    return torch.where(lists.valid[..., None, None, None], w, torch.zeros((), dtype=w.dtype, device=w.device)), nu


def synthetic_measurements(pr: PMHTProblem, X: torch.Tensor, w: torch.Tensor, nu: torch.Tensor, inflate: float = 1.0):
    """M-step's measurements: ``z~ (B, W, T, S d)`` (NaN rows where a pair's weight is below
    ``min_weight``) and the diagonal scale ``1 / sum(w / kappa)`` per row ``(B, W, T, S d)``."""
    B, W, T, _ = X.shape
    S, d = pr.pairs, pr.R_inv_chol.shape[-1]
    a = (w / (pr.kappa * inflate)).sum(-1)  # (B, W, L, M, T, S)
    total = a.sum((2, 3))  # (B, W, T, S)
    shift = torch.einsum("bwlmts,bwlmtsd->bwtsd", a, nu) / total.clamp_min(pr.settings.min_weight)[..., None]
    z = pr.model.h(X).reshape(B, W, T, S, d) + shift
    if bool(pr.angles.any()):
        z = torch.where(pr.angles, wrap_angle(z), z)
    missing = (total < pr.settings.min_weight)[..., None].expand(B, W, T, S, d)
    scale = torch.where(missing, torch.ones((), dtype=X.dtype, device=X.device), 1.0 / total.clamp_min(1e-300)[..., None])
    return z.masked_fill(missing, float("nan")).reshape(B, W, T, S * d), scale.reshape(B, W, T, S * d)


def _smooth(pr: PMHTProblem, prior: Gaussian, z: torch.Tensor, scale: torch.Tensor, hand_off: int,
            born: torch.Tensor | None = None, start: Gaussian | None = None):
    """Unscented Kalman smoother over synthetic measurements ``z (R, W, m)`` (NaN rows missing;
    covariance ``D R D``, ``D = diag(sqrt(scale))``) from ``prior`` (predicted moments at the
    window's first scan, ``(R, n)``): a UKF forward (the update of
    :func:`~pmsr_nn.filters.gaussian.kalman_update` with the moments of
    :func:`~pmsr_nn.filters.gaussian.unscented_moments`, written out once for the fixed shapes of
    this loop), then the RTS pass. Returns smoothed ``x (R, W, n)``, ``P (R, W, n, n)`` and the
    filter's prediction at scan ``hand_off`` of the window (the next window's prior).

    ``born (R,)`` (optional, -1: none) and ``start`` ``(R, n)``: a row born at scan ``born`` of
    the window is filtered as ``start`` there (the initiator's Gaussian, made from that scan's
    detections: they are not counted twice); before it, it only has ``prior`` and no measurement,
    and its smoothed states there mean nothing."""
    Rn, W, m = z.shape
    wm, wc, c = pr.sigma
    missing = torch.isnan(z)
    any_missing = missing.any((0, 2)).tolist()
    z = torch.nan_to_num(z)
    root = scale.sqrt()
    Rw = root[..., :, None] * pr.R * root[..., None, :]  # (R, W, m, m)
    x, P = prior.x, prior.P
    xf, Pf, xp, Pp = [], [], [x], [P]
    for k in range(W):
        if k:
            x, P = x @ pr.F.T, pr.F @ P @ pr.F.T + pr.Q
            xp.append(x)
            Pp.append(P)
        L = safe_cholesky(c * P).transpose(-1, -2)
        X = torch.cat([x[:, None], x[:, None] + L, x[:, None] - L], 1)  # (R, 2n+1, n)
        Z = pr.model.h(X)
        zm = wm @ Z
        dZ, dX = Z - zm[:, None], X - x[:, None]
        dZw = dZ * wc[:, None]
        S = dZw.transpose(-1, -2) @ dZ + Rw[:, k]
        C = dX.transpose(-1, -2) @ dZw
        nu = z[:, k] - zm
        if any_missing[k]:
            keep = (~missing[:, k]).to(S.dtype)
            S = S * keep[:, :, None] * keep[:, None, :] + torch.diag_embed(1.0 - keep)
            C, nu = C * keep[:, None, :], nu * keep
        Kt = torch.cholesky_solve(C.transpose(-1, -2), safe_cholesky(S))  # (R, m, n) = K^T
        x = x + (nu[:, None, :] @ Kt)[:, 0]
        P = P - C @ Kt
        P = 0.5 * (P + P.transpose(-1, -2))
        if born is not None and bool((born == k).any()):
            here = born == k
            x, P = torch.where(here[:, None], start.x, x), torch.where(here[:, None, None], start.P, P)
        xf.append(x)
        Pf.append(P)
    xp.append(x @ pr.F.T)
    Pp.append(pr.F @ P @ pr.F.T + pr.Q)
    sm = rts_from_predictions(torch.stack(xf, 1), torch.stack(Pf, 1), torch.stack(xp[1:], 1)[:, :W - 1],
                              torch.stack(Pp[1:], 1)[:, :W - 1], pr.F)
    handed = Gaussian(xp[hand_off], Pp[hand_off])
    return sm.x, sm.P, handed


def state_log_prior(pr: PMHTProblem, X: torch.Tensor, prior: Gaussian) -> torch.Tensor:
    """``log p(X)`` per run ``(B,)``: the window's first state under ``prior`` (``(B, T, n)``) and
    the CV transitions."""
    out = gaussian_log_likelihood((X[:, 0] - prior.x).unsqueeze(-2), prior.P)[1].sum((-2, -1))
    if X.shape[1] > 1:
        step = X[:, 1:] - X[:, :-1] @ pr.F.transpose(-1, -2)  # (B, W-1, T, n): T innovations against Q
        out = out + gaussian_log_likelihood(step, pr.Q)[1].sum((1, 2))
    return out


def window_objective(pr: PMHTProblem, X: torch.Tensor, prior: Gaussian, lists: AssociationLists) -> torch.Tensor:
    """EM's objective per run ``(B,)``: ``log p(X) + sum_r log p(z_r | X)`` (up to a constant)."""
    _, log_t, log_clutter = _log_terms(pr, X, lists)
    dens = torch.where(lists.valid, _log_density(log_t, log_clutter), torch.zeros((), dtype=X.dtype, device=X.device))
    return state_log_prior(pr, X, prior) + dens.sum((1, 2, 3))


def expected_complete_log_likelihood(pr: PMHTProblem, X: torch.Tensor, prior: Gaussian, lists: AssociationLists,
                                     w: torch.Tensor) -> torch.Tensor:
    """EM's auxiliary function ``Q(X; X_old)`` per run ``(B,)`` (Eq. 21), the weights ``w`` from
    the E-step at ``X_old``: ``log p(X) + sum w log(Pd c_p N(z_r; h_s(x_t), kappa_p R_s))`` plus
    the clutter weights' term (constant in ``X``)."""
    _, log_t, log_clutter = _log_terms(pr, X, lists)
    wt = torch.where(w > 0, w * log_t, torch.zeros((), dtype=X.dtype, device=X.device)).sum((1, 2, 3, 4, 5, 6))
    w0 = (1 - w.sum((-3, -2, -1))) * lists.valid
    return state_log_prior(pr, X, prior) + wt + (w0 * log_clutter).sum((1, 2, 3))


def check_lists(lists: AssociationLists, prior: Gaussian | None, n_pairs: int, n: int) -> None:
    """One-line errors for detections and priors (``None``: none, the tracker starts its own
    tracks) that do not fit."""
    B, K, L, M, _ = lists.z.shape
    if lists.candidates.shape[-1] != n_pairs:
        raise ConfigError(f"the detections name {lists.candidates.shape[-1]} illuminator pair(s); the measurement "
                          f"model has {n_pairs}")
    if bool(torch.isnan(lists.z[lists.valid]).any()) or bool(torch.isinf(lists.z).any()):
        raise ConfigError("a valid detection is NaN or infinite")
    if prior is None:
        return
    if prior.x.dim() != 3 or prior.x.shape[0] != B or prior.x.shape[-1] != n:
        raise ConfigError(f"prior must be x (B={B}, T, {n}); got {tuple(prior.x.shape)}")
    if not bool(torch.isfinite(prior.x).all()):
        raise ConfigError("the prior mean is not finite")


def window_starts(K: int, s: PMHTSettings) -> list[int]:
    """First scan of each window: every ``step`` scans; the last window ends at the last scan."""
    if s.window > K:
        raise ConfigError(f"PMHT window of {s.window} scans is longer than the {K} scans of the scenario")
    starts = [0]
    while starts[-1] + s.window < K:
        starts.append(min(starts[-1] + s.step, K - s.window))
    return starts


def pmht(lists: AssociationLists, prior: Gaussian, motion: KinematicModel, dt: float, q, model, R: torch.Tensor,
         settings: PMHTSettings, record_objective: bool = False) -> PMHTResult:
    """PMHT on ``lists`` (``K`` scans), tracks from ``prior`` (``x (B, T, n)`` at scan 0).

    ``model``: the pair-layout measurement model (``h`` of a state gives every pair's ``d``
    values) or any model with ``h``, ``angle_mask``, ``residual`` and ``dim_z`` (one pair);
    ``R (S d, S d)`` block-diagonal. ``record_objective`` keeps :func:`window_objective` after
    every iteration (for checks; it costs one more E-step each).
    """
    n = motion.dim_x
    S = getattr(model, "n_pairs", 1)
    check_lists(lists, prior, S, n)
    B, K = lists.z.shape[:2]
    T = prior.x.shape[1]
    dtype, device = prior.x.dtype, prior.x.device
    pr = problem(model, motion, dt, q, R, settings, dtype, device)
    starts = window_starts(K, settings)
    x_out = torch.empty(B, K, T, n, dtype=dtype, device=device)
    P_out = torch.empty(B, K, T, n, n, dtype=dtype, device=device)
    history = [] if record_objective else None
    for c0 in range(0, B, settings.chunk_runs):
        runs = slice(c0, min(B, c0 + settings.chunk_runs))
        b = runs.stop - runs.start
        g = Gaussian(prior.x[runs].reshape(b * T, n), prior.P[runs].reshape(b * T, n, n))
        X_prev = None
        for i, a in enumerate(starts):
            W = min(settings.window, K - a)
            nxt = starts[i + 1] if i + 1 < len(starts) else K
            win = lists.take(runs, slice(a, a + W))
            X = _initial_states(pr, g, X_prev, a - starts[i - 1] if i else 0, W, b, T)
            win_prior = Gaussian(g.x.reshape(b, T, n), g.P.reshape(b, T, n, n))
            record = [window_objective(pr, X, win_prior, win)] if record_objective else None
            for it in range(settings.em_iterations):
                X_new, P, handed, _ = em_step(pr, X, g, win, settings.inflation(it), nxt - a)
                moved = (X_new - X)[..., list(motion.pos_idx)].norm(dim=-1).max()
                X = X_new
                if record is not None:
                    record.append(window_objective(pr, X, win_prior, win))
                if settings.tolerance_m > 0 and float(moved) < settings.tolerance_m:
                    break
            done = nxt - a
            x_out[runs, a:a + done] = X[:, :done]
            P_out[runs, a:a + done] = P[:, :done]
            g, X_prev = handed, X
            if record is not None:
                history.append(torch.stack(record))
    return PMHTResult(x_out, P_out, history)


def em_step(pr: PMHTProblem, X: torch.Tensor, prior: Gaussian, lists: AssociationLists, inflate: float = 1.0,
            hand_off: int | None = None, alive: torch.Tensor | None = None, born: torch.Tensor | None = None,
            start: Gaussian | None = None):
    """One EM iteration on a window: states ``X (b, W, T, n)``, ``prior`` the predicted moments at
    its first scan (one row per run and target, ``(b T, n)``). Returns the new states, their
    covariances ``(b, W, T, n, n)``, the forward filter's prediction at scan ``hand_off`` (default:
    after the window) and the E-step's weights. Tracks that start inside the window (track
    management): ``alive (b, W, T)`` where each explains detections, ``born (b, T)`` the scan of
    the window each starts at (-1: before it) as ``start`` ``(b T, n)`` (see :func:`_smooth`)."""
    b, W, T, n = X.shape
    w, nu = association_weights(pr, X, lists, inflate, alive)
    z, scale = synthetic_measurements(pr, X, w, nu, inflate)
    xs, Ps, handed = _smooth(pr, prior, _rows(z), _rows(scale), W if hand_off is None else hand_off,
                             None if born is None else born.reshape(b * T), start)
    return xs.reshape(b, T, W, n).transpose(1, 2), Ps.reshape(b, T, W, n, n).transpose(1, 2), handed, w


def _rows(t: torch.Tensor) -> torch.Tensor:
    """``(b, W, T, ...)`` -> one row per (run, target): ``(b T, W, ...)``."""
    b, W, T = t.shape[:3]
    return t.transpose(1, 2).reshape(b * T, W, *t.shape[3:])


def _initial_states(pr: PMHTProblem, g: Gaussian, X_prev: torch.Tensor | None, shift: int, W: int, b: int, T: int) -> torch.Tensor:
    """EM's starting states ``(b, W, T, n)``: the previous window's smoothed states on the overlap,
    CV predictions beyond (the prior's mean predicted through the first window)."""
    n = pr.F.shape[0]
    if X_prev is None:
        cur, out = g.x.reshape(b, T, n), []
    else:
        keep = X_prev[:, shift:]
        out = list(keep.unbind(1))[:W]
        cur = keep[:, -1] @ pr.F.transpose(-1, -2)
    while len(out) < W:
        out.append(cur)
        cur = cur @ pr.F.transpose(-1, -2)
    return torch.stack(out, 1)


# ------------------------------------------------------------------------------ track management

def window_evidence(pr: PMHTProblem, X: torch.Tensor, lists: AssociationLists,
                    alive: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """What track management reads from a window's final states ``X (b, W, T, n)`` (tracks
    ``alive (b, W, T)``): each track's summed association weight per pair ``(b, W, T, S)``, its
    IPDA likelihood ratio per pair ``(b, W, T, S)`` (the sum over the pair's detections of
    ``sum_p c_p N(z_r; h_s(x_t), kappa_p R_s)`` over the clutter density ``lambda_A / V``: PMHT's
    own measurement density at the smoothed state) and each detection's total weight on a target
    ``(b, W, L, M)``."""
    _, log_t, log_clutter = _log_terms(pr, X, lists, 1.0, alive)
    w = torch.exp(log_t - _log_density(log_t, log_clutter)[..., None, None, None])  # 0 on padding: log_t = -inf
    ratio = torch.exp(log_t - log_clutter[..., None, None, None]).sum((2, 3, 6)) / pr.settings.pd
    return w.sum((2, 3, 6)), ratio, w.sum((4, 5, 6))


def _pad_slots(t: torch.Tensor, C: int, fill, dim: int = 2) -> torch.Tensor:
    """``t`` with its slot axis ``dim`` padded to ``C`` with ``fill``."""
    extra = C - t.shape[dim]
    if extra <= 0:
        return t
    shape = list(t.shape)
    shape[dim] = extra
    return torch.cat([t, t.new_full(shape, fill)], dim)


def _started_rows(pr: PMHTProblem, X: torch.Tensor, rows: torch.Tensor, born: torch.Tensor,
                  x0: torch.Tensor) -> torch.Tensor:
    """EM's starting states ``X (b, W, C, n)`` with the tracks ``rows (b, C)`` started inside the
    window at scan ``born (b, C)`` set to their initiator mean ``x0 (b, C, n)`` there, its CV
    predictions after and the same mean before (where they explain nothing)."""
    W = X.shape[1]
    powers = torch.stack([torch.linalg.matrix_power(pr.F, k) for k in range(W)])  # (W, n, n)
    steps = (torch.arange(W)[None, :, None] - born[:, None, :]).clamp(0, W - 1)  # (b, W, C)
    xk = (powers[steps] @ x0[:, None, :, :, None]).squeeze(-1)
    return torch.where(rows[:, None, :, None], xk, X)


def managed_pmht(scans: Scans, motion: KinematicModel, dt: float, q, model, R: torch.Tensor, settings: PMHTSettings,
                 management: Management) -> TrackReport:
    """PMHT that starts, confirms and deletes its own tracks (:mod:`.management`), on per-pair
    lists (each detection's illuminator known: the initiators need them).

    The tracks live in a :class:`~.management.TrackTable` whose Gaussians are the priors at the
    current window's first scan; EM runs on every slot (a free slot explains no detection). After
    EM on a window, each scan the window commits (hands on: the scans before the next window's
    first), in order:

    1. existence: predicted by ``survival``, then each pair's IPDA update with the ratio of
       :func:`window_evidence` (no gate: ``Pd Pg = Pd``);
    2. a track whose summed association weight at a pair is >= 0.5 was detected there; hit and
       miss, M-of-N confirmation and deletion as the table does;
    3. the confirmed tracks whose existence is >= ``report_existence`` are reported with their
       smoothed states at that scan;
    4. the detections whose total weight on the tracks is < 0.5 (explained mostly by clutter)
       start tentative tracks (the management's initiator, :mod:`.initiators`).

    A track started at scan ``k`` of the window takes part in it from ``k`` on: it explains no
    detection before ``k`` and its filter is the initiator's Gaussian at ``k`` (see
    :func:`_smooth`). So that it explains its own later detections in the window (and starts no
    second track from them, and can be confirmed at ``k + 1``), EM is run again on the window
    with the new tracks and the committed scans go on from ``k + 1``; a track started at the last
    committed scan is only predicted into the next window. Returns the reported confirmed tracks
    (:class:`~.management.TrackReport`, ``(B, K, T, n)``), smoothed: not causal.
    """
    S = getattr(model, "n_pairs", 1)
    lists = AssociationLists.per_pair(scans)
    check_lists(lists, None, S, motion.dim_x)
    management.check(model, "PMHT")
    B, K = scans.shape[:2]
    pr = problem(model, motion, dt, q, R, settings, scans.z.dtype, scans.z.device)
    starts = window_starts(K, settings)
    parts = [_managed_runs(pr, lists.take(slice(c0, min(B, c0 + settings.chunk_runs))), starts, management,
                           list(motion.pos_idx)) for c0 in range(0, B, settings.chunk_runs)]
    T = max(p.x.shape[2] for p in parts)
    cat = lambda name, fill: torch.cat([_pad_slots(getattr(p, name), T, fill) for p in parts], 0)
    return TrackReport(cat("x", math.nan), cat("P", 0.0), cat("exists", False), cat("existence", 0.0)).trimmed()


def _managed_runs(pr: PMHTProblem, lists: AssociationLists, starts: list[int], mg: Management,
                  pos: list[int]) -> TrackReport:
    """:func:`managed_pmht` on one chunk of ``b`` runs. Each run's EM is re-run only when that run
    started tracks, and stops on that run's own movement: a run's tracks do not depend on which
    other runs share its chunk."""
    b, K, S = lists.z.shape[:3]
    s, model, n, dtype = pr.settings, pr.model, pr.F.shape[0], lists.z.dtype
    table = TrackTable.empty(b, n, parked_state(model, n, dtype))
    report = TrackReport.empty(b, K, n, dtype)
    X = None
    for i, a in enumerate(starts):
        W = min(s.window, K - a)
        h = (starts[i + 1] if i + 1 < len(starts) else K) - a  # scans this window commits
        win = lists.take(slice(None), slice(a, a + W))
        C = table.g.x.shape[1]
        X = _initial_states(pr, table.g, X, a - starts[i - 1] if i else 0, W, b, C)
        born = torch.full((b, C), -1, dtype=torch.int64)  # scan of the window a track started at (-1: before)
        fit = _WindowFit.empty(X, lists.z.shape[3], S)
        redo = torch.ones(b, dtype=torch.bool)  # runs whose EM must run (again) before scan k
        late = torch.zeros(b, C, dtype=torch.bool)  # tracks started at the last committed scan
        for k in range(h):
            if bool(redo.any()):
                C = table.g.x.shape[1]
                born = torch.where(table.active, born, -1)
                alive = table.active[:, None, :] & (born[:, None, :] <= torch.arange(W)[None, :, None])
                # table.g: the prior at the window's first scan of a track that was there, the
                # initiator's Gaussian of one started inside it (the smoother's start at its scan)
                rows = redo.nonzero()[:, 0]
                fit = fit.padded(C).put(rows, _window_em(pr, X[rows], Gaussian(table.g.x[rows], table.g.P[rows]),
                                                         win.take(rows), h, alive[rows], born[rows], pos))
                X = fit.X
            if a + k > 0:
                table.predict_existence(mg.survival)
            for j in range(S):
                table.update_existence(fit.ratio[:, k, :, j], s.pd)
            table.record((fit.pair_w[:, k] >= 0.5).sum(-1), mg.hit_pairs)
            table.manage(mg.confirmer, mg.deleter, pos)
            shown = replace(table, g=Gaussian(X[:, k], fit.P[:, k]))  # the smoothed states at this scan
            report.write(a + k, shown, mg.report_existence)
            unused = win.valid[:, k] & (fit.target_w[:, k] < 0.5)  # (b, S, M): per-pair lists
            before = table.active
            if bool(unused.any()):
                table.add(*mg.initiator.initiate(win.z[:, k], unused, model, n, mg.other_sd), mg.initial_existence)
            C = table.g.x.shape[1]
            late = table.active & ~_pad_slots(before, C, False, 1)
            redo = late.any(-1)
            if bool(redo.any()):
                born = torch.where(late, k, _pad_slots(born, C, -1, 1))
                X = _started_rows(pr, _pad_slots(X, C, 0.0), late, born, table.g.x)
        # hand on: the last EM's forward prediction at the next window's first scan; a track
        # started at the last committed scan (after that EM) predicted from its initiator
        fit = fit.padded(table.g.x.shape[1])
        step = predict(table.g, pr.F, pr.Q)
        table.g = Gaussian(torch.where(late[..., None], step.x, fit.handed.x),
                           torch.where(late[..., None, None], step.P, fit.handed.P))
        table.free(~table.active)  # keep free slots parked
    return report


@dataclass
class _WindowFit:
    """What EM on a window gives each run: states ``X (b, W, C, n)``, covariances ``P``, the
    forward prediction handed to the next window ``(b, C, n)`` and :func:`window_evidence`."""

    X: torch.Tensor
    P: torch.Tensor
    handed: Gaussian
    pair_w: torch.Tensor
    ratio: torch.Tensor
    target_w: torch.Tensor

    @classmethod
    def empty(cls, X: torch.Tensor, M: int, S: int) -> "_WindowFit":
        b, W, C, n = X.shape
        z = X.new_zeros
        return cls(X, z(b, W, C, n, n), Gaussian(z(b, C, n), z(b, C, n, n)), z(b, W, C, S), z(b, W, C, S),
                   z(b, W, S, M))

    def padded(self, C: int) -> "_WindowFit":
        """Slots up to ``C``; the new slots are free (no weight, no evidence)."""
        return _WindowFit(_pad_slots(self.X, C, 0.0), _pad_slots(self.P, C, 0.0),
                          Gaussian(_pad_slots(self.handed.x, C, 0.0, 1), _pad_slots(self.handed.P, C, 0.0, 1)),
                          _pad_slots(self.pair_w, C, 0.0), _pad_slots(self.ratio, C, 0.0), self.target_w)

    def put(self, rows: torch.Tensor, part: "_WindowFit") -> "_WindowFit":
        """A copy with the runs ``rows`` replaced by ``part``."""
        def put(full, new):
            out = full.clone()
            out[rows] = new
            return out
        return _WindowFit(put(self.X, part.X), put(self.P, part.P),
                          Gaussian(put(self.handed.x, part.handed.x), put(self.handed.P, part.handed.P)),
                          put(self.pair_w, part.pair_w), put(self.ratio, part.ratio), put(self.target_w, part.target_w))


def _window_em(pr: PMHTProblem, X: torch.Tensor, prior: Gaussian, win: AssociationLists, h: int,
               alive: torch.Tensor, born: torch.Tensor, pos: list[int]) -> _WindowFit:
    """EM of :func:`managed_pmht` on a window for ``b`` runs from states ``X (b, W, C, n)`` and
    ``prior`` ``(b, C, n)``: ``em_iterations`` per run, fewer for a run whose positions all move
    less than ``tolerance_m``."""
    b, W, C, n = X.shape
    s = pr.settings
    X, P = X.clone(), X.new_zeros(b, W, C, n, n)
    hx, hP = X.new_zeros(b, C, n), X.new_zeros(b, C, n, n)
    todo = torch.arange(b)
    for it in range(s.em_iterations):
        g = Gaussian(prior.x[todo].reshape(-1, n), prior.P[todo].reshape(-1, n, n))
        X_new, P_new, handed, _ = em_step(pr, X[todo], g, win.take(todo), s.inflation(it), h, alive[todo],
                                          born[todo], g)
        moved = (X_new - X[todo])[..., pos].norm(dim=-1).flatten(1).amax(1)
        X[todo], P[todo] = X_new, P_new
        hx[todo], hP[todo] = handed.x.reshape(-1, C, n), handed.P.reshape(-1, C, n, n)
        if s.tolerance_m > 0:
            todo = todo[moved >= s.tolerance_m]
            if len(todo) == 0:
                break
    return _WindowFit(X, P, Gaussian(hx, hP), *window_evidence(pr, X, win, alive))
