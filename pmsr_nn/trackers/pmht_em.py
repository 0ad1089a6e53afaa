"""One EM iteration of PMHT (:mod:`.pmht`) on a window of scans: the E-step's association
weights, the M-step's synthetic measurements and unscented smoother, EM's objective, and the
evidence track management reads from a window.

Shapes: ``B`` runs (``b`` in a chunk), ``W`` scans of the window, ``L`` lists per scan, ``M``
detections per list, ``N`` tracks, ``S`` pairs, ``d`` values per pair, ``n`` state dimension,
``n_components`` components of the measurement mixture.
"""

from __future__ import annotations

import math

import torch

from ..filters.gaussian import Gaussian, safe_cholesky
from ..filters.smoothing import rts_from_predictions
from ..measurements import wrap_angle
from .gating import gaussian_log_likelihood
from .pmht_model import AssociationLists, PMHTProblem


def _log_terms(pr: PMHTProblem, X: torch.Tensor, lists: AssociationLists, inflate: float = 1.0,
               alive: torch.Tensor | None = None,
               P: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """For states ``X (B, W, N, n)`` and a window's lists: residuals ``nu (B, W, L, M, N, S, d)``,
    ``log(Pd c_p N(z_r; h_s(x_t), kappa_p R_s)) (B, W, L, M, N, S, n_components)`` (-inf where
    pair ``s`` is not a candidate or the slot is padding) and the clutter term
    ``log(lambda_A / V) (B, W, L, M)``;
    ``inflate`` scales every ``kappa`` (annealing); a track outside ``alive (B, W, N)`` (default:
    every track at every scan) explains no detection there (-inf). With the states' covariances
    ``P (B, W, N, n, n)`` the Gaussian is the marginal one, ``N(z_r; h_s(x_t), kappa_p R_s + H P H^T)``
    (``H`` the Jacobian of ``h_s`` at ``x_t``): see :func:`marginal_covariances`."""
    B, W, N, _ = X.shape
    S, d = pr.pairs, pr.R_inv_chol.shape[-1]
    h = pr.model.h(X).reshape(B, W, 1, 1, N, S, d)
    z = torch.nan_to_num(lists.z)[:, :, :, :, None, None, :]
    nu = z - h
    if bool(pr.angles.any()):
        nu = torch.where(pr.angles, wrap_angle(nu), nu)
    k = pr.kappa * inflate
    if P is None:
        e = torch.einsum("sij,bwlmtsj->bwlmtsi", pr.R_inv_chol, nu)
        maha = (e * e).sum(-1, keepdim=True)  # (B, W, L, M, N, S, 1)
        log_n = -0.5 * maha / k - 0.5 * (d * torch.log(2 * math.pi * k) + pr.log_det[:, None])
    else:
        C = marginal_covariances(pr, X, P, k)  # (B, W, N, S, n_components, d, d)
        Ci = torch.linalg.inv(C)
        maha = torch.einsum("bwlmtsi,bwtspij,bwlmtsj->bwlmtsp", nu, Ci, nu)
        log_n = -0.5 * maha - 0.5 * (d * math.log(2 * math.pi) + torch.logdet(C))[:, :, None, None]
    ok = lists.candidates & lists.valid.unsqueeze(-1)  # (B, W, L, M, S)
    log_t = torch.where(ok[:, :, :, :, None, :, None], math.log(pr.settings.pd) + pr.log_c + log_n,
                        torch.full((), -math.inf, dtype=X.dtype, device=X.device))
    if alive is not None:
        log_t = log_t.masked_fill(~alive[:, :, None, None, :, None, None], -math.inf)
    lam = (lists.candidates.to(X.dtype) * pr.rate).sum(-1)  # (B, W, L, M)
    log_clutter = torch.log(lam.clamp_min(1e-300)) - math.log(pr.settings.volume)
    return nu, log_t, log_clutter


def marginal_covariances(pr: PMHTProblem, X: torch.Tensor, P: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
    """``kappa_p R_s + H_s P H_s^T`` ``(B, W, N, S, n_components, d, d)`` for states ``X (B, W, N, n)``
    with covariances ``P (B, W, N, n, n)`` and scales ``k (n_components,)``: the covariance of a
    detection of track ``t`` through pair ``s`` when the track's state is only known to ``P``
    (linearised at ``X``), as a PDA filter gates with. Where ``P`` is wide (a loose initiation) a
    track weighs the detections its own uncertainty covers, and nothing beyond (a blanket
    inflation of ``R`` reaches other targets' detections too); as ``P`` shrinks it is plain PMHT."""
    B, W, N, n = X.shape
    S, d = pr.pairs, pr.R_inv_chol.shape[-1]
    H = pr.model.jacobian(X).reshape(B, W, N, S, d, n)
    HPH = H @ P[:, :, :, None] @ H.transpose(-1, -2)  # (B, W, N, S, d, d)
    HPH = 0.5 * (HPH + HPH.transpose(-1, -2))
    return k[:, None, None] * pr.R_blocks[:, None] + HPH[:, :, :, :, None]


def _log_density(log_t: torch.Tensor, log_clutter: torch.Tensor) -> torch.Tensor:
    """Log of each detection's mixture density ``(B, W, L, M)`` (up to a constant)."""
    return torch.logsumexp(torch.cat([log_clutter.unsqueeze(-1), log_t.flatten(-3)], -1), -1)


def association_weights(pr: PMHTProblem, X: torch.Tensor, lists: AssociationLists, inflate: float = 1.0,
                        alive: torch.Tensor | None = None, P: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """E-step: weights ``w (B, W, L, M, N, S, n_components)`` (0 on padding and where a track is not
    ``alive (B, W, N)``) and the residuals ``nu``; ``P (B, W, N, n, n)``: the marginal E-step
    (:func:`marginal_covariances`), None: plain PMHT's."""
    nu, log_t, log_clutter = _log_terms(pr, X, lists, inflate, alive, P)
    w = torch.exp(log_t - _log_density(log_t, log_clutter)[..., None, None, None])
    return torch.where(lists.valid[..., None, None, None], w, torch.zeros((), dtype=w.dtype, device=w.device)), nu


def synthetic_measurements(pr: PMHTProblem, X: torch.Tensor, w: torch.Tensor, nu: torch.Tensor, inflate: float = 1.0):
    """M-step's measurements: ``z~ (B, W, N, S d)`` (NaN rows where a pair's weight is below
    ``min_weight``) and the diagonal scale ``1 / sum(w / kappa)`` per row ``(B, W, N, S d)``."""
    B, W, N, _ = X.shape
    S, d = pr.pairs, pr.R_inv_chol.shape[-1]
    a = (w / (pr.kappa * inflate)).sum(-1)  # (B, W, L, M, N, S)
    total = a.sum((2, 3))  # (B, W, N, S)
    shift = torch.einsum("bwlmts,bwlmtsd->bwtsd", a, nu) / total.clamp_min(pr.settings.min_weight)[..., None]
    z = pr.model.h(X).reshape(B, W, N, S, d) + shift
    if bool(pr.angles.any()):
        z = torch.where(pr.angles, wrap_angle(z), z)
    missing = (total < pr.settings.min_weight)[..., None].expand(B, W, N, S, d)
    scale = torch.where(missing, torch.ones((), dtype=X.dtype, device=X.device), 1.0 / total.clamp_min(1e-300)[..., None])
    return z.masked_fill(missing, float("nan")).reshape(B, W, N, S * d), scale.reshape(B, W, N, S * d)


def _smooth(pr: PMHTProblem, prior: Gaussian, z: torch.Tensor, scale: torch.Tensor, hand_off: int,
            born: torch.Tensor | None = None, start: Gaussian | None = None):
    """Unscented Kalman smoother over synthetic measurements ``z (rows, W, m)``, one row per run
    and track (NaN entries missing; covariance ``D R D``, ``D = diag(sqrt(scale))``) from
    ``prior`` (predicted moments at the window's first scan, ``(rows, n)``): a UKF forward (the
    update of
    :func:`~pmsr_nn.filters.gaussian.kalman_update` with the moments of
    :func:`~pmsr_nn.filters.gaussian.unscented_moments`, written out once for the fixed shapes of
    this loop), then the RTS pass. Returns smoothed ``x (rows, W, n)``, ``P (rows, W, n, n)`` and the
    filter's prediction at scan ``hand_off`` of the window (the next window's prior).

    ``born (rows,)`` (optional, -1: none) and ``start`` ``(rows, n)``: a row born at scan ``born`` of
    the window is filtered as ``start`` there (the initiator's Gaussian, made from that scan's
    detections: they are not counted twice); before it, it only has ``prior`` and no measurement,
    and its smoothed states there mean nothing."""
    _, W, m = z.shape
    wm, wc, c = pr.sigma
    missing = torch.isnan(z)
    any_missing = missing.any((0, 2)).tolist()
    z = torch.nan_to_num(z)
    root = scale.sqrt()
    Rw = root[..., :, None] * pr.R * root[..., None, :]  # (rows, W, m, m)
    x, P = prior.x, prior.P
    xf, Pf, xp, Pp = [], [], [x], [P]
    for k in range(W):
        if k:
            x, P = x @ pr.F.T, pr.F @ P @ pr.F.T + pr.Q
            xp.append(x)
            Pp.append(P)
        L = safe_cholesky(c * P).transpose(-1, -2)
        X = torch.cat([x[:, None], x[:, None] + L, x[:, None] - L], 1)  # (rows, 2n+1, n)
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
        Kt = torch.cholesky_solve(C.transpose(-1, -2), safe_cholesky(S))  # (rows, m, n) = K^T
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
    """``log p(X)`` per run ``(B,)``: the window's first state under ``prior`` (``(B, N, n)``) and
    the CV transitions."""
    out = gaussian_log_likelihood((X[:, 0] - prior.x).unsqueeze(-2), prior.P)[1].sum((-2, -1))
    if X.shape[1] > 1:
        step = X[:, 1:] - X[:, :-1] @ pr.F.transpose(-1, -2)  # (B, W-1, N, n): N innovations against Q
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


def em_step(pr: PMHTProblem, X: torch.Tensor, prior: Gaussian, lists: AssociationLists, inflate: float = 1.0,
            hand_off: int | None = None, alive: torch.Tensor | None = None, born: torch.Tensor | None = None,
            start: Gaussian | None = None, P: torch.Tensor | None = None):
    """One EM iteration on a window: states ``X (b, W, N, n)``, ``prior`` the predicted moments at
    its first scan (one row per run and target, ``(b N, n)``). Returns the new states, their
    covariances ``(b, W, N, n, n)``, the forward filter's prediction at scan ``hand_off`` (default:
    after the window) and the E-step's weights. Tracks that start inside the window (track
    management): ``alive (b, W, N)`` where each explains detections, ``born (b, N)`` the scan of
    the window each starts at (-1: before it) as ``start`` ``(b N, n)`` (see :func:`_smooth`).
    ``P (b, W, N, n, n)``: covariances of ``X`` for the marginal E-step (None: plain PMHT's)."""
    b, W, N, n = X.shape
    w, nu = association_weights(pr, X, lists, inflate, alive, P)
    z, scale = synthetic_measurements(pr, X, w, nu, inflate)
    xs, Ps, handed = _smooth(pr, prior, _rows(z), _rows(scale), W if hand_off is None else hand_off,
                             None if born is None else born.reshape(b * N), start)
    return xs.reshape(b, N, W, n).transpose(1, 2), Ps.reshape(b, N, W, n, n).transpose(1, 2), handed, w


def _rows(t: torch.Tensor) -> torch.Tensor:
    """``(b, W, N, ...)`` -> one row per (run, target): ``(b N, W, ...)``."""
    b, W, N = t.shape[:3]
    return t.transpose(1, 2).reshape(b * N, W, *t.shape[3:])


def window_evidence(pr: PMHTProblem, X: torch.Tensor, lists: AssociationLists,
                    alive: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """What track management reads from a window's final states ``X (b, W, N, n)`` (tracks
    ``alive (b, W, N)``): each track's summed association weight per pair ``(b, W, N, S)``, its
    IPDA likelihood ratio per pair ``(b, W, N, S)`` (the sum over the pair's detections of
    ``sum_p c_p N(z_r; h_s(x_t), kappa_p R_s)`` over the clutter density ``lambda_A / V``: PMHT's
    own measurement density at the smoothed state) and each detection's total weight on a target
    ``(b, W, L, M)``."""
    _, log_t, log_clutter = _log_terms(pr, X, lists, 1.0, alive)
    w = torch.exp(log_t - _log_density(log_t, log_clutter)[..., None, None, None])  # 0 on padding: log_t = -inf
    ratio = torch.exp(log_t - log_clutter[..., None, None, None]).sum((2, 3, 6)) / pr.settings.pd
    return w.sum((2, 3, 6)), ratio, w.sum((4, 5, 6))
