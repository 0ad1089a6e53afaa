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
    h = pr.h(X).reshape(B, W, 1, 1, N, S, d)
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


EXP_FLOOR = -700.0
"""Exponents below this give weight 0 (``exp(-700) ~ 1e-304``, far below any weight's rounding):
``exp`` of an argument that under- or nearly underflows (and of ``-inf``) takes a slow path on x86
that cost 10-300x the ordinary one, and most detection-track terms are that far out."""


def candidate_pairs(lists: AssociationLists) -> tuple[torch.Tensor, torch.Tensor]:
    """The pairs each list's detections may come from, ``idx (L, Sc)`` (``Sc`` the most any list
    has: 1 per pair's own list, a receiver's pairs for pooled lists; a list with fewer is padded
    with pairs none of its detections may come from), and ``on (B, W, L, M, Sc)``: detection ``r``
    may come from pair ``idx[l, c]`` and is valid. The E-step weighs only these: a per-pair list
    would otherwise carry ``S - 1`` pairs of zeros per detection and track."""
    any_l = lists.candidates.any(3).any(1).any(0)  # (L, S)
    Sc = max(int(any_l.sum(-1).max()), 1)
    idx = torch.argsort((~any_l).to(torch.int8), dim=-1, stable=True)[:, :Sc]  # candidates first, in pair order
    B, W, L, M, _ = lists.candidates.shape
    on = lists.candidates.gather(-1, idx[None, None, :, None, :].expand(B, W, L, M, Sc)) & lists.valid[..., None]
    return idx, on


def _residual_components(pr: PMHTProblem, X: torch.Tensor, lists: AssociationLists,
                         idx: torch.Tensor) -> list[torch.Tensor]:
    """Residuals ``z_r - h_s(x_t)`` of each list's candidate pairs ``idx (L, Sc)``
    (:func:`candidate_pairs`) as ``d`` contiguous ``(B, W, L, M, N, Sc)`` tensors, one per value
    of a pair (angles wrapped): elementwise work on them avoids the tiny trailing ``d`` axis."""
    B, W, N, _ = X.shape
    S, d = pr.pairs, pr.R_inv_chol.shape[-1]
    h = pr.h(X).reshape(B, W, N, S, d)[:, :, :, idx].permute(0, 1, 3, 2, 4, 5)  # (B, W, L, N, Sc, d)
    z = torch.nan_to_num(lists.z)
    angles = pr.angles.tolist()
    out = []
    for i in range(d):
        nu = z[:, :, :, :, None, None, i] - h[:, :, :, None, :, :, i]
        out.append(wrap_angle(nu) if angles[i] else nu)
    return out


def _per_list(t: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """``t (B, W, N, S, ...)`` at each list's candidate pairs: ``(B, W, L, 1, N, Sc, ...)``."""
    return t[:, :, :, idx].transpose(2, 3).unsqueeze(3)


def to_pairs(t: torch.Tensor, idx: torch.Tensor, S: int) -> torch.Tensor:
    """Sums over each list's candidates ``t (B, W, L, N, Sc)`` gathered per pair: ``(B, W, N, S)``
    (a padded candidate carries 0)."""
    B, W, L, N, Sc = t.shape
    out = t.new_zeros(B, W, N, S)
    return out.index_add_(3, idx.flatten(), t.permute(0, 1, 3, 2, 4).reshape(B, W, N, L * Sc))


def _marginal_terms(pr: PMHTProblem, X: torch.Tensor, P: torch.Tensor,
                    k: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The marginal E-step's Gaussians (:func:`marginal_covariances`, ``C (B, W, N, S,
    n_components, d, d)``): their inverses ``C^-1`` and ``log(Pd c_p) - log det(2 pi C) / 2``
    ``(B, W, N, S, n_components)``; ``k (n_components,)`` the annealed scales. 2 x 2 covariances
    (range-Doppler) are inverted in closed form (a batched LU of 2 x 2 matrices costs more)."""
    d = pr.R_inv_chol.shape[-1]
    base = math.log(pr.settings.pd) + pr.log_c - 0.5 * d * math.log(2 * math.pi)
    C = marginal_covariances(pr, X, P, k)
    if d == 2:
        a, b, c = C[..., 0, 0], C[..., 0, 1], C[..., 1, 1]
        det = a * c - b * b
        J = torch.stack([torch.stack([c, -b], -1), torch.stack([-b, a], -1)], -2) / det[..., None, None]
        return J, base - 0.5 * torch.log(det)
    return torch.linalg.inv(C), base - 0.5 * torch.logdet(C)


def association_weights(pr: PMHTProblem, X: torch.Tensor, lists: AssociationLists, inflate: float = 1.0,
                        alive: torch.Tensor | None = None,
                        P: torch.Tensor | None = None) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """E-step: weights ``w (B, W, L, M, N, S, n_components)`` (0 on padding, where a pair is no
    candidate and where a track is not ``alive (B, W, N)``) and the residuals of the candidate pairs
    (:func:`compact_weights`, whose weights these are, set out over every pair)."""
    w, nu, idx, _ = compact_weights(pr, X, lists, inflate, alive, P)
    return over_pairs(w, idx, pr.pairs), nu


def over_pairs(w: torch.Tensor, idx: torch.Tensor, S: int) -> torch.Tensor:
    """Weights over the lists' candidate pairs ``w (B, W, L, M, N, Sc, n_components)`` set out over
    every pair: ``(B, W, L, M, N, S, n_components)``, 0 where a pair is no candidate."""
    B, W, L, M, N, Sc, n_c = w.shape
    full = w.new_zeros(B, W, L, M, N, S, n_c)
    return full.scatter_(5, idx[:, None, None, :, None].expand(B, W, L, M, N, Sc, n_c), w)


def compact_weights(pr: PMHTProblem, X: torch.Tensor, lists: AssociationLists, inflate: float = 1.0,
                    alive: torch.Tensor | None = None,
                    P: torch.Tensor | None = None):
    """E-step over each list's candidate pairs ``idx (L, Sc)`` (:func:`candidate_pairs`): weights
    ``w (B, W, L, M, N, Sc, n_components)`` (0 on padding, on a padded candidate and where a track
    is not ``alive (B, W, N)``), the residuals (:func:`_residual_components`), ``idx`` and each
    detection's log density over its clutter term, ``log(p(z_r) / (lambda_A / V)) (B, W, L, M)``;
    ``P (B, W, N, n, n)``: the marginal E-step (:func:`marginal_covariances`), None: plain PMHT's.

    The same weights as ``exp(log_t - log p(z_r))`` from :func:`_log_terms` (to rounding; terms
    below ``exp(EXP_FLOOR)`` of a detection's largest are 0), computed in fewer passes over the
    large tensors: the quadratic form from the ``d (d + 1) / 2`` products of residual values, the
    log-sum-exp's shift by each detection's largest term (clutter included), so every term is
    ``<= 1`` and the density ``>= 1``."""
    idx, on = candidate_pairs(lists)
    nu = _residual_components(pr, X, lists, idx)
    d = len(nu)
    k = pr.kappa * inflate
    # products nu_i nu_j (B, W, L, M, N, Sc, 1); a pair that is no candidate for a detection (or
    # padding, or a track not alive) gets nu_0^2 = inf: its term is exp(-inf) = 0
    prods = {(i, j): (nu[i] * nu[j]).unsqueeze(-1) for i in range(d) for j in range(i, d)}
    off = ~on[:, :, :, :, None, :, None]  # (B, W, L, M, 1, Sc, 1)
    if alive is not None:
        off = off | ~alive[:, :, None, None, :, None, None]
    prods[0, 0] = prods[0, 0].masked_fill(off, math.inf)
    L, Sc = idx.shape
    if P is None:  # N(z; h, kappa_p R_s): one quadratic form per pair, scaled by 1 / kappa_p
        Ri = (pr.R_inv_chol.transpose(-1, -2) @ pr.R_inv_chol)[idx]  # (L, Sc, d, d) = R_s^-1
        log_norm = (math.log(pr.settings.pd) + pr.log_c
                    - 0.5 * (d * torch.log(2 * math.pi * k) + pr.log_det[:, None]))[idx]  # (L, Sc, n_components)
        maha = None
        for (i, j), q in prods.items():
            c = (Ri[:, :, i, j] * (1.0 if i == j else 2.0)).reshape(L, 1, 1, Sc, 1)
            maha = q * c if maha is None else torch.addcmul(maha, q, c)
        arg = torch.addcmul(log_norm.reshape(L, 1, 1, Sc, -1), maha, -0.5 / k)  # (B, W, L, M, N, Sc, n_components)
    else:  # N(z; h, C): log_norm - sum_ij (C^-1)_ij nu_i nu_j / 2
        J, log_norm = _marginal_terms(pr, X, P, k)
        J, arg = _per_list(J, idx), _per_list(log_norm, idx)
        for (i, j), q in prods.items():
            arg = torch.addcmul(arg, q, J[..., i, j], value=-0.5 if i == j else -1.0)
    lam = (lists.candidates.to(X.dtype) * pr.rate).sum(-1)  # (B, W, L, M)
    log_clutter = torch.log(lam.clamp_min(1e-300)) - math.log(pr.settings.volume)
    top = torch.maximum(arg.amax((-3, -2, -1)), log_clutter)  # (B, W, L, M)
    e = (arg - top[..., None, None, None]).clamp_min_(EXP_FLOOR).exp_()
    e = torch.nn.functional.threshold_(e, 1.5 * math.exp(EXP_FLOOR), 0.0)  # the floor's exp(EXP_FLOOR) -> 0
    dens = e.sum((-3, -2, -1)) + torch.exp(log_clutter - top)  # >= 1: the largest term is exp(0)
    return e / dens[..., None, None, None], nu, idx, top - log_clutter + torch.log(dens)


def synthetic_measurements(pr: PMHTProblem, X: torch.Tensor, w: torch.Tensor, nu: list[torch.Tensor],
                           idx: torch.Tensor, inflate: float = 1.0):
    """M-step's measurements from the E-step's weights ``w`` and residual values ``nu`` over the
    lists' candidate pairs ``idx`` (:func:`compact_weights`): ``z~ (B, W, N, S d)`` (NaN rows where
    a pair's weight is below ``min_weight``) and the diagonal scale ``1 / sum(w / kappa)`` per row
    ``(B, W, N, S d)``."""
    B, W, N, _ = X.shape
    S, d = pr.pairs, pr.R_inv_chol.shape[-1]
    a = w @ (1.0 / (pr.kappa * inflate))  # (B, W, L, M, N, Sc): sum_p w_p / kappa_p
    total = to_pairs(a.sum(3), idx, S)  # (B, W, N, S)
    shift = (torch.stack([to_pairs((a * v).sum(3), idx, S) for v in nu], -1)
             / total.clamp_min(pr.settings.min_weight)[..., None])
    z = pr.h(X).reshape(B, W, N, S, d) + shift
    if bool(pr.angles.any()):
        z = torch.where(pr.angles, wrap_angle(z), z)
    missing = (total < pr.settings.min_weight)[..., None].expand(B, W, N, S, d)
    scale = torch.where(missing, torch.ones((), dtype=X.dtype, device=X.device), 1.0 / total.clamp_min(1e-300)[..., None])
    return z.masked_fill(missing, float("nan")).reshape(B, W, N, S * d), scale.reshape(B, W, N, S * d)


def _smooth(pr: PMHTProblem, prior: Gaussian, z: torch.Tensor, scale: torch.Tensor, hand_off: int,
            born: torch.Tensor | None = None, start: Gaussian | None = None, covariances: bool = True,
            safe: bool = False):
    """Unscented Kalman smoother over synthetic measurements ``z (rows, W, m)``, one row per run
    and track (NaN entries missing; covariance ``D R D``, ``D = diag(sqrt(scale))``) from
    ``prior`` (predicted moments at the window's first scan, ``(rows, n)``): a UKF forward (the
    update of
    :func:`~pmsr_nn.filters.gaussian.kalman_update` with the moments of
    :func:`~pmsr_nn.filters.gaussian.unscented_moments`, written out once for the fixed shapes of
    this loop), then the RTS pass (:func:`~pmsr_nn.filters.smoothing.rts_from_predictions`).
    Returns smoothed ``x (rows, W, n)``, ``P (rows, W, n, n)`` (None unless ``covariances``) and the filter's prediction at scan ``hand_off`` of
    the window (the next window's prior).

    ``born (rows,)`` (optional, -1: none) and ``start`` ``(rows, n)``: a row born at scan ``born`` of
    the window is filtered as ``start`` there (the initiator's Gaussian, made from that scan's
    detections: they are not counted twice); before it, it only has ``prior`` and no measurement,
    and its smoothed states there mean nothing.

    The loop is bound by the count of small tensor operations (a window has ``W`` steps of a few
    rows each), so it keeps them few: the Cholesky factors are checked once per window (``safe``:
    through :func:`~pmsr_nn.filters.gaussian.safe_cholesky` at every step, what a window whose
    check failed is redone with), the sigma points' offsets serve as ``X - x``, the updates are
    fused multiply-adds."""
    _, W, m = z.shape
    wm, wc, c = pr.sigma
    missing = torch.isnan(z)
    any_missing = missing.any((0, 2)).tolist()
    keep = (~missing).to(z.dtype)
    born_at = set() if born is None else set(born.tolist())
    z = torch.nan_to_num(z)
    root = scale.sqrt()
    Rw = root[..., :, None] * pr.R * root[..., None, :]  # (rows, W, m, m)
    Ft = pr.F.T
    infos = []

    def factor(A: torch.Tensor) -> torch.Tensor:
        if safe:
            return safe_cholesky(A)
        L, info = torch.linalg.cholesky_ex(A)
        infos.append(info)
        return L

    x, P = prior.x, prior.P
    xf, Pf, xp, Pp = [], [], [x], [P]
    for k in range(W):
        if k:
            x, P = x @ Ft, pr.F @ P @ Ft + pr.Q
            xp.append(x)
            Pp.append(P)
        L = factor(c * P).transpose(-1, -2)
        D = torch.cat([torch.zeros_like(L[:, :1]), L, -L], 1)  # (rows, 2n+1, n): sigma points - x
        Z = pr.h(x[:, None] + D)
        zm = wm @ Z
        dZw = (Z - zm[:, None]) * wc[:, None]
        S = torch.baddbmm(Rw[:, k], dZw.transpose(-1, -2), Z - zm[:, None])
        C = D.transpose(-1, -2) @ dZw
        nu = z[:, k] - zm
        if any_missing[k]:
            kp = keep[:, k]
            S = S * kp[:, :, None] * kp[:, None, :] + torch.diag_embed(1.0 - kp)
            C, nu = C * kp[:, None, :], nu * kp
        Kt = torch.cholesky_solve(C.transpose(-1, -2), factor(S))  # (rows, m, n) = K^T
        x = torch.baddbmm(x[:, None], nu[:, None], Kt)[:, 0]
        P = torch.baddbmm(P, C, Kt, alpha=-1.0)
        P = (P + P.transpose(-1, -2)).mul_(0.5)
        if k in born_at:
            here = born == k
            x, P = torch.where(here[:, None], start.x, x), torch.where(here[:, None, None], start.P, P)
        xf.append(x)
        Pf.append(P)
    if infos and bool(torch.stack(infos).any()):  # a factor failed: redo with the jitter fallback
        return _smooth(pr, prior, z.masked_fill(missing, math.nan), scale, hand_off, born, start, covariances, True)
    xp.append(x @ Ft)
    Pp.append(pr.F @ P @ Ft + pr.Q)
    sm = rts_from_predictions(torch.stack(xf, 1), torch.stack(Pf, 1), torch.stack(xp[1:W], 1), torch.stack(Pp[1:W], 1),
                              pr.F, covariances)
    return sm.x, sm.P, Gaussian(xp[hand_off], Pp[hand_off])


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
            start: Gaussian | None = None, P: torch.Tensor | None = None, covariances: bool = True,
            weights: bool = False):
    """One EM iteration on a window: states ``X (b, W, N, n)``, ``prior`` the predicted moments at
    its first scan (one row per run and target, ``(b N, n)``). Returns the new states, their
    covariances ``(b, W, N, n, n)``, the forward filter's prediction at scan ``hand_off`` (default:
    after the window) and, with ``weights``, the E-step's weights over every pair
    (:func:`association_weights`; None otherwise: most callers need none). Tracks that start inside the window (track
    management): ``alive (b, W, N)`` where each explains detections, ``born (b, N)`` the scan of
    the window each starts at (-1: before it) as ``start`` ``(b N, n)`` (see :func:`_smooth`).
    ``P (b, W, N, n, n)``: covariances of ``X`` for the marginal E-step (None: plain PMHT's);
    ``covariances`` False: the smoothed covariances are not computed (None is returned)."""
    b, W, N, n = X.shape
    w, nu, idx, _ = compact_weights(pr, X, lists, inflate, alive, P)
    z, scale = synthetic_measurements(pr, X, w, nu, idx, inflate)
    xs, Ps, handed = _smooth(pr, prior, _rows(z), _rows(scale), W if hand_off is None else hand_off,
                             None if born is None else born.reshape(b * N), start, covariances)
    Ps = None if Ps is None else Ps.reshape(b, N, W, n, n).transpose(1, 2)
    return xs.reshape(b, N, W, n).transpose(1, 2), Ps, handed, over_pairs(w, idx, pr.pairs) if weights else None


def _rows(t: torch.Tensor) -> torch.Tensor:
    """``(b, W, N, ...)`` -> one row per (run, target): ``(b N, W, ...)``."""
    b, W, N = t.shape[:3]
    return t.transpose(1, 2).reshape(b * N, W, *t.shape[3:])


def window_evidence(pr: PMHTProblem, X: torch.Tensor, lists: AssociationLists,
                    alive: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """What track management reads from a window's final states ``X (b, W, N, n)`` (tracks
    ``alive (b, W, N)``): each track's summed association weight per pair ``(b, W, N, S)``, its
    IPDA likelihood ratio per pair ``(b, W, N, S)`` (the sum over the pair's detections of
    ``sum_p c_p N(z_r; h_s(x_t), kappa_p R_s)`` over the clutter density ``lambda_A / V``: PMHT's
    own measurement density at the smoothed state), each detection's total weight on a target
    ``(b, W, L, M)`` and the shared ratio ``(b, W, N, S)``: the same sum with every other track's
    density added to the clutter's (the modified clutter density of LM-IPDA, Musicki & La Scala
    2008), ``sum_r w_rt / (1 - W_rt) / Pd`` (``W_rt`` the detection's total weight on track
    ``t``): the IPDA ratio for a track alone, smaller where other tracks explain its detections."""
    w, _, idx, log_over_clutter = compact_weights(pr, X, lists, 1.0, alive)  # 0 on padding and non-candidates
    S = pr.pairs
    per_pair = lambda t: to_pairs(t.sum(-1).sum(3), idx, S)  # noqa: E731 - (b, W, L, M, N, Sc, P) -> (b, W, N, S)
    # exp(log_t - log_clutter) = w p(z_r) / (lambda_A / V)
    ratio = per_pair(w * log_over_clutter.exp()[..., None, None, None]) / pr.settings.pd
    on_track = w.sum((5, 6), keepdim=True)  # (b, W, L, M, N, 1, 1)
    shared = per_pair(w / (1.0 - on_track).clamp(min=1e-300)) / pr.settings.pd
    return per_pair(w), ratio, w.sum((4, 5, 6)), shared
