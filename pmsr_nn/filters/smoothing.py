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
    """Smoothed means ``x (B, K, n)`` and covariances ``P (B, K, n, n)``."""

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
                         F: torch.Tensor) -> SmootherResult:
    """Linear RTS pass from filtered moments ``x (B, K, n)``, ``P (B, K, n, n)`` and the
    predictions the filter made from them, ``x_pred[k], P_pred[k]`` for scan ``k + 1``
    (``(B, K-1, ...)``): what a filter that kept its predictions passes without recomputing them."""
    _check(x, P)
    xs = None if x is None else x.clone()
    Ps = P.clone()
    if P.shape[1] < 2:
        return SmootherResult(xs, Ps)
    # Every gain at once (they depend on the filter's moments only): G_k = P_k F^T P_pred_k^-1,
    # i.e. G_k^T = P_pred_k^-1 F P_k (P_pred symmetric positive definite).
    Gt = torch.cholesky_solve(F @ P[:, :-1], safe_cholesky(P_pred))
    G = Gt.transpose(-1, -2)
    for k in range(P.shape[1] - 2, -1, -1):
        Ps[:, k] = symmetrise(P[:, k] + G[:, k] @ (Ps[:, k + 1] - P_pred[:, k]) @ Gt[:, k])
        if xs is not None:
            xs[:, k] = x[:, k] + ((xs[:, k + 1] - x_pred[:, k]).unsqueeze(-2) @ Gt[:, k]).squeeze(-2)
    return SmootherResult(xs, Ps)


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
