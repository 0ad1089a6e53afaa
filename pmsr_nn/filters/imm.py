"""Batched interacting multiple model (IMM) filter (Blom & Bar-Shalom 1988).

A manoeuvring target is modelled as switching between ``r`` motion modes (e.g. a quiet CA mode
with a small jerk PSD and a manoeuvring CA mode with a large one). The mode sequence is a Markov
chain with a row-stochastic ``transition`` (row ``i`` = from mode ``i``). The exact posterior is a
mixture whose number of terms grows as ``r^k``; the IMM keeps one Gaussian per mode and, before
each prediction, replaces the ``r^2`` mode-to-mode terms by ``r`` Gaussians (moment matching).
One cycle, for steps ``k >= 1``:

1. Mixing: ``c_j = sum_i mu_i T_ij`` (predicted mode probabilities) and mixing weights
   ``w_ij = mu_i T_ij / c_j``, the probability that the target was in mode ``i`` given that it is
   now in mode ``j``.
2. Mixed initial conditions per mode: ``x0_j = sum_i w_ij x_i`` and
   ``P0_j = sum_i w_ij (P_i + (x_i - x0_j)(x_i - x0_j)^T)`` (the spread term keeps the
   covariance honest when the modes disagree).
3. Per-mode prediction with the mode's own ``F`` and ``Q`` and per-mode Kalman update.
4. Mode likelihoods ``N(nu_j; 0, S_j)`` and posterior ``mu_j ~ c_j N(nu_j; 0, S_j)``, computed
   in log space from the Cholesky factor of ``S_j`` and normalised with log-sum-exp (the
   likelihoods of well-separated modes underflow).
5. Output: the moment-matched mixture ``x = sum_j mu_j x_j``, ``P = sum_j mu_j (P_j + spread)``.

Conventions are those of :mod:`.kalman`: the prior is the state at step 0 *before* ``z[:, 0]``;
step 0 is an update only, with every mode starting from the prior and ``mode_probs0`` as the
predicted mode probabilities; NaN entries of ``z`` are missing and skipped. Modes are a batch axis
(``(B, r, ...)``), so the only Python loop is over time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import torch

from ..errors import ConfigError
from ..measurements import MeasurementModel
from ..motion import KinematicModel
from .gaussian import FilterError, Gaussian, MeasurementMoments, kalman_update, linearised_moments, safe_cholesky
from .kalman import FilterResult, check_filter_inputs

_STOCHASTIC_TOL = 1e-9


@dataclass(frozen=True)
class IMMMode:
    """One motion mode: a kinematic model and its process-noise intensity ``q`` (as in
    :meth:`KinematicModel.Q`: m^2/s^5 jerk PSD for CA, m^2/s^4 acceleration variance for CV)."""

    motion: KinematicModel
    q: float


@dataclass
class IMMResult(FilterResult):
    """:class:`FilterResult` (moment-matched ``x``, ``P``; ``nu``, ``nis`` of the mode that was
    most probable before the update) plus the posterior mode probabilities ``mode_probs (B, K, r)``."""

    mode_probs: torch.Tensor


def markov_transition(r: int, stay: float, device: torch.device | str | None = None) -> torch.Tensor:
    """``(r, r)`` float64 Markov matrix on ``device`` with ``stay`` on the diagonal and
    ``(1 - stay) / (r - 1)`` elsewhere. With ``r = 1`` only ``stay = 1`` gives a Markov matrix."""
    if int(r) != r or r < 1:
        raise ConfigError(f"markov_transition needs at least one mode, got r={r}")
    if not (math.isfinite(stay) and 0.0 <= stay <= 1.0):
        raise ConfigError(f"markov_transition: stay must be a probability in [0, 1], got {stay}")
    if r == 1:
        if stay != 1.0:
            raise ConfigError(f"markov_transition: with one mode stay must be 1 (the only Markov matrix is [[1]]), got {stay}")
        return torch.ones(1, 1, dtype=torch.float64, device=device)
    T = torch.full((r, r), (1.0 - stay) / (r - 1), dtype=torch.float64, device=device)
    T.fill_diagonal_(stay)
    return T


def _check_modes(modes: Sequence[IMMMode]) -> None:
    if len(modes) < 1:
        raise ConfigError("imm needs at least one mode")
    if not all(isinstance(md, IMMMode) for md in modes):
        raise ConfigError("imm modes must be IMMMode(motion, q) instances")
    dims = [md.motion.dim_x for md in modes]
    if len(set(dims)) != 1:
        raise ConfigError(f"all IMM modes must share one state space; got state dimensions {dims}")
    # Equal dimension is not enough: a 3-D CV state [x, vx, y, vy, z, vz] cannot be mixed with a
    # 2-D CA state [x, vx, ax, y, vy, ay], although both have 6 entries.
    layouts = {(md.motion.pos_idx, md.motion.vel_idx) for md in modes}
    if len(layouts) != 1:
        raise ConfigError("all IMM modes must share one state layout (same position and velocity entries)")


def _check_transition(transition, r: int, dtype, device) -> torch.Tensor:
    T = torch.as_tensor(transition, dtype=dtype, device=device)
    if T.shape != (r, r):
        raise ConfigError(f"transition must be ({r}, {r}) for {r} modes, got {tuple(T.shape)}")
    if not bool(torch.isfinite(T).all()) or bool((T < 0).any()):
        raise ConfigError("transition must have finite, non-negative entries")
    rows = T.sum(-1)
    if bool(((rows - 1).abs() > _STOCHASTIC_TOL).any()):
        raise ConfigError(f"transition rows must sum to 1 (row i = from mode i); row sums are {rows.tolist()}")
    return T


def _check_mode_probs0(mode_probs0, B: int, r: int, dtype, device) -> torch.Tensor:
    if mode_probs0 is None:
        return torch.full((B, r), 1.0 / r, dtype=dtype, device=device)
    p = torch.as_tensor(mode_probs0, dtype=dtype, device=device)
    if p.shape not in ((r,), (B, r)):
        raise ConfigError(f"mode_probs0 must be ({r},) or (B={B}, {r}), got {tuple(p.shape)}")
    if not bool(torch.isfinite(p).all()) or bool((p < 0).any()):
        raise ConfigError("mode_probs0 must have finite, non-negative entries")
    if bool(((p.sum(-1) - 1).abs() > _STOCHASTIC_TOL).any()):
        raise ConfigError("mode_probs0 must sum to 1 (per run)")
    return p.expand(B, r)


def _mixture(w: torch.Tensor, x: torch.Tensor, P: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Moment-matched Gaussians ``sum_i w_ij N(x_i, P_i)`` for each ``j``.

    ``w (B, r_in, r_out)`` (columns sum to 1), ``x (B, r_in, n)``, ``P (B, r_in, n, n)`` ->
    ``(B, r_out, n)``, ``(B, r_out, n, n)``.
    """
    xm = torch.einsum("bij,bin->bjn", w, x)
    d = x.unsqueeze(2) - xm.unsqueeze(1)  # (B, r_in, r_out, n)
    Pm = torch.einsum("bij,bimn->bjmn", w, P) + torch.einsum("bij,bijm,bijn->bjmn", w, d, d)
    return xm, Pm


def imm(prior: Gaussian, z: torch.Tensor, modes: Sequence[IMMMode], transition: torch.Tensor, dt: float,
        model: MeasurementModel, R: torch.Tensor, *, mode_probs0: torch.Tensor | None = None,
        moments: Callable[[Gaussian, MeasurementModel, torch.Tensor], MeasurementMoments] = linearised_moments) -> IMMResult:
    """IMM filter of ``z (B, K, m)`` (NaN = missing) with ``r = len(modes)`` motion modes.

    ``prior``: ``x (B, n)``, ``P (n, n)`` or ``(B, n, n)`` at step 0 before ``z[:, 0]``.
    ``transition (r, r)``: row-stochastic, ``T[i, j] = P(mode j at k | mode i at k-1)``.
    ``dt``: sampling interval (s). ``R``: ``(m, m)``, ``(B, m, m)`` or ``(B, K, m, m)``.
    ``mode_probs0``: ``(r,)`` or ``(B, r)`` mode probabilities at step 0 before ``z[:, 0]``
    (default uniform). ``moments``: :func:`linearised_moments` (EKF, default) or
    :func:`unscented_moments` (UKF) per mode.

    Returns the moment-matched ``x (B, K, n)``, ``P (B, K, n, n)``, the posterior
    ``mode_probs (B, K, r)`` and ``nu (B, K, m)``, ``nis (B, K)`` of the mode with the highest
    *predicted* probability ``c`` at that step (chosen before the measurement is seen, so the
    choice does not bias the NIS towards small values; ties go to the lower mode index).
    """
    _check_modes(modes)
    check_filter_inputs(prior, z, model, modes[0].motion, R)
    dtype, device = z.dtype, z.device
    B, K, m = z.shape
    r, n = len(modes), modes[0].motion.dim_x
    T = _check_transition(transition, r, dtype, device)
    mu = _check_mode_probs0(mode_probs0, B, r, dtype, device)
    F = torch.stack([md.motion.F(dt, dtype, device) for md in modes])  # (r, n, n)
    # Q per mode, (r, n, n), or (B, r, n, n) when some q is given per run.
    Q = torch.stack(torch.broadcast_tensors(*[md.motion.Q(dt, md.q, dtype, device) for md in modes]), dim=-3)
    Ft = F.transpose(-1, -2)

    x = prior.x.to(dtype).unsqueeze(1).expand(B, r, n)
    P = prior.P.to(dtype).expand(B, n, n).unsqueeze(1).expand(B, r, n, n)
    out = IMMResult(z.new_empty(B, K, n), z.new_empty(B, K, n, n), z.new_empty(B, K, m), z.new_empty(B, K),
                    z.new_empty(B, K, r))
    for k in range(K):
        if k == 0:
            c = mu  # every mode starts from the prior: nothing to mix
        else:
            c = mu @ T  # (B, r): predicted mode probabilities
            w = T * mu.unsqueeze(-1) / c.unsqueeze(-2)
            # A mode nobody can switch into (c_j = 0) is mixed from the current mixture instead of
            # 0/0: its probability is 0, so it only needs a finite state.
            w = torch.where(c.unsqueeze(-2) > 0, w, mu.unsqueeze(-1))
            x, P = _mixture(w, x, P)
            x = (F @ x.unsqueeze(-1)).squeeze(-1)
            P = F @ P @ Ft + Q
        try:
            R_k = R[:, k] if R.dim() == 4 else R
            R_k = R_k.unsqueeze(-3) if R_k.dim() == 3 else R_k  # (B, 1, m, m) against the mode axis
            z_k = z[:, k].unsqueeze(1)  # (B, 1, m)
            mom = moments(Gaussian(x, P), model, R_k)
            g, nu, nis = kalman_update(Gaussian(x, P), z_k, mom, model)  # nu (B, r, m), nis (B, r)
            # log N(nu; 0, S) needs log det S, which kalman_update does not return. Missing rows are
            # replaced as there (unit diagonal, zero innovation): they add nothing to log det S or
            # to the NIS, only their -log(2 pi)/2, which like the whole -m log(2 pi)/2 is the same
            # for every mode and cancels in the normalisation, so it is left out.
            S = mom.S
            keep = (~torch.isnan(z_k)).to(dtype)
            if bool((keep == 0).any()):
                S = S * keep.unsqueeze(-1) * keep.unsqueeze(-2) + torch.diag_embed(1.0 - keep)
            logdet = 2.0 * torch.log(torch.diagonal(safe_cholesky(S), dim1=-2, dim2=-1)).sum(-1)
        except FilterError as exc:
            raise FilterError(f"step {k}: {exc}") from None
        loglik = -0.5 * (nis + logdet)  # (B, r), up to a per-run constant
        # Shift the best mode to 0: the common part cancels anyway, and adding it to log c would
        # only cost precision. log c_j = -inf for a mode nobody can be in; softmax is the
        # log-sum-exp normalisation (no underflow however far apart the modes' likelihoods are).
        loglik = loglik - loglik.amax(-1, keepdim=True)
        mu = torch.softmax(torch.log(c) + loglik, dim=-1)
        x, P = g.x, g.P
        bad = ~(torch.isfinite(x).all(-1).all(-1) & torch.isfinite(mu).all(-1))
        if bool(bad.any()):
            raise FilterError(f"state of run {int(bad.nonzero()[0])} became non-finite at step {k}")
        best = c.argmax(-1)  # (B,)
        out.nu[:, k] = nu.gather(1, best[:, None, None].expand(B, 1, m)).squeeze(1)
        out.nis[:, k] = nis.gather(1, best[:, None]).squeeze(1)
        out.mode_probs[:, k] = mu
        xc, Pc = _mixture(mu.unsqueeze(-1), x, P)
        out.x[:, k], out.P[:, k] = xc.squeeze(1), Pc.squeeze(1)
    return out
