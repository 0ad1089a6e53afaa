"""Fixed-interval Rauch-Tung-Striebel smoothers over batched filter output.

Both smoothers run backwards over the filtered moments ``x (B, K, n)``, ``P (B, K, n, n)`` of
:mod:`~pmsr_nn.filters.kalman` (any filter: KF, EKF, UKF, SI+KF). With ``P_pred = Cov(x_{k+1} | z_1..k)``
and the cross-covariance ``C = Cov(x_k, x_{k+1} | z_1..k)``, the smoother gain is
``G = C P_pred^-1`` and

    x_s[k] = x[k] + G (x_s[k+1] - x_pred),    P_s[k] = P[k] + G (P_s[k+1] - P_pred) G^T.

The linear RTS smoother takes ``x_pred = F x``, ``C = P F^T``; the unscented RTS smoother (Sarkka
2008) takes them from sigma points through a transition function, which for the linear CA / CV
models gives the same numbers up to round-off (a test checks this), and lets a nonlinear
transition use the same code.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch

from ..errors import ConfigError
from ..motion import KinematicModel
from .gaussian import Gaussian, SigmaPoints, safe_cholesky, symmetrise

Transition = Callable[[torch.Tensor], torch.Tensor]
"""A state transition over one interval: states ``(..., n)`` -> ``(..., n)``."""


@dataclass
class SmootherResult:
    """Smoothed means ``x (B, K, n)`` and covariances ``P (B, K, n, n)`` (either None where not asked for)."""

    x: torch.Tensor
    P: torch.Tensor


def _check(x: torch.Tensor | None, P: torch.Tensor) -> None:
    if P.dim() != 4 or P.shape[-1] != P.shape[-2] or (x is not None and x.shape != P.shape[:-1]):
        raise ConfigError(f"smoother needs x (B, K, n) and P (B, K, n, n); got {None if x is None else tuple(x.shape)}, "
                          f"{tuple(P.shape)}")


def rts_backward(x: torch.Tensor | None, P: torch.Tensor, F: torch.Tensor, Q: torch.Tensor) -> SmootherResult:
    """Linear RTS pass: ``x (B, K, n)`` (or None for covariances only), ``P (B, K, n, n)``,
    ``F (n, n)``, ``Q (n, n)`` or ``(B, n, n)``. Also used by the smoothing PCRB, which has no means."""
    _check(x, P)
    P_pred = symmetrise(F @ P[:, :-1] @ F.transpose(-1, -2) + (Q if Q.dim() == 2 else Q[:, None]))
    x_pred = None if x is None else x[:, :-1] @ F.transpose(-1, -2)
    return rts_from_predictions(x, P, x_pred, P_pred, F)


def rts_from_predictions(x: torch.Tensor | None, P: torch.Tensor, x_pred: torch.Tensor | None, P_pred: torch.Tensor,
                         F: torch.Tensor, covariances: bool = True) -> SmootherResult:
    """Linear RTS pass from filtered moments ``x (B, K, n)``, ``P (B, K, n, n)`` and the
    predictions the filter made from them, ``x_pred[k], P_pred[k]`` for scan ``k + 1``
    (``(B, K-1, ...)``): what a filter that kept its predictions passes without recomputing them.
    ``x`` None: covariances only; ``covariances`` False: means only (``P`` of the result None).

    What does not depend on the smoothed moments is done for every scan at once (the gains
    ``G_k^T = P_pred_k^-1 F P_k``, by Cholesky), leaving two fused multiply-adds per scan:
    ``x_s[k] = (x[k] - G_k x_pred[k]) + G_k x_s[k+1]`` and ``P_s[k] = (P[k] - G_k P_pred[k] G_k^T)
    + G_k P_s[k+1] G_k^T`` (symmetrised at the end)."""
    _check(x, P)
    if P.shape[1] < 2:
        return SmootherResult(x, P if covariances else None)
    Gt = torch.cholesky_solve(F @ P[:, :-1], safe_cholesky(P_pred))
    G = Gt.transpose(-1, -2)
    K = P.shape[1]
    xs = None
    if x is not None:
        cx = x[:, :-1] - (x_pred[:, :, None] @ Gt)[:, :, 0]
        out = [x[:, -1]]
        for k in range(K - 2, -1, -1):
            out.append(torch.baddbmm(cx[:, k, None], out[-1][:, None], Gt[:, k])[:, 0])
        xs = torch.stack(out[::-1], 1)
    if not covariances:
        return SmootherResult(xs, None)
    cP = P[:, :-1] - G @ P_pred @ Gt
    out = [P[:, -1]]
    for k in range(K - 2, -1, -1):
        out.append(torch.baddbmm(cP[:, k], G[:, k] @ out[-1], Gt[:, k]))
    Ps = torch.stack(out[::-1], 1)
    return SmootherResult(xs, 0.5 * (Ps + Ps.transpose(-1, -2)))


def rts_smoother(x: torch.Tensor, P: torch.Tensor, motion: KinematicModel, dt: float, q) -> SmootherResult:
    """Linear RTS smoother of filtered moments under ``motion`` (``F(dt)``, ``Q(dt, q)``, ``q`` per run allowed)."""
    return rts_backward(x, P, motion.F(dt, P.dtype, P.device), motion.Q(dt, q, P.dtype, P.device))


def unscented_rts_smoother(x: torch.Tensor, P: torch.Tensor, transition: Transition, Q: torch.Tensor,
                           sigma: SigmaPoints = SigmaPoints()) -> SmootherResult:
    """Unscented RTS smoother: ``transition`` maps states ``(..., n)`` over one step, ``Q (n, n)``
    or ``(B, n, n)`` is added to the predicted covariance. For a linear motion model pass
    ``lambda s: s @ motion.F(dt).T``."""
    _check(x, P)
    xs, Ps = x.clone(), P.clone()
    for k in range(P.shape[1] - 2, -1, -1):
        X, wm, wc = sigma.points(Gaussian(x[:, k], P[:, k]))  # (B, 2n+1, n)
        Y = transition(X)
        x_pred = (wm[:, None] * Y).sum(-2)
        dX, dY = X - x[:, k].unsqueeze(-2), Y - x_pred.unsqueeze(-2)
        P_pred = symmetrise((dY.transpose(-1, -2) * wc) @ dY + Q)
        C = (dX.transpose(-1, -2) * wc) @ dY
        G = torch.cholesky_solve(C.transpose(-1, -2), safe_cholesky(P_pred)).transpose(-1, -2)
        xs[:, k] = x[:, k] + ((xs[:, k + 1] - x_pred).unsqueeze(-2) @ G.transpose(-1, -2)).squeeze(-2)
        Ps[:, k] = symmetrise(P[:, k] + G @ (Ps[:, k + 1] - P_pred) @ G.transpose(-1, -2))
    return SmootherResult(xs, Ps)
