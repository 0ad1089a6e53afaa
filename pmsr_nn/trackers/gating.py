"""Gating in measurement space: which detections could a track have caused.

A track's predicted measurement ``z_hat (d,)`` with innovation covariance ``S (d, d)`` (R
included) gates a detection ``z`` when the squared Mahalanobis distance
``d2 = (z - z_hat)^T S^-1 (z - z_hat)`` is at most ``gamma`` (``d2 <= gamma``: :func:`inside_gate`),
the chi-square quantile with ``d`` degrees of freedom for the gate probability ``P_G``: a
detection of the track falls inside with probability ``P_G`` when the filter is consistent.

This module is the one place that computes ``d2`` and decides the gate: every tracker, initiator,
labeller and PHD clustering reads it from here. ``d2`` is ``|L^-1 nu|^2`` with ``L`` the
Cholesky factor of ``S`` (:func:`mahalanobis`, :func:`gaussian_log_likelihood`); where one ``S``
serves many innovations its inverse factor is formed once (:func:`whitening`,
:func:`whitened_d2`); points already whitened (divided by diagonal deviations) have plain
squared distances (:func:`pairwise_d2`). A NaN innovation gives a NaN ``d2``, which no gate admits.
"""

from __future__ import annotations

import math

import torch
from scipy.stats import chi2

from ..config import require


def gate_threshold(probability: float, dof: int) -> float:
    """``gamma`` with ``P(chi2_dof <= gamma) = probability``."""
    require(0.0 < probability < 1.0, f"gate probability must be in (0, 1), got {probability}")
    return float(chi2.ppf(probability, dof))


def inside_gate(d2: torch.Tensor, gamma: float) -> torch.Tensor:
    """The gate: ``d2 <= gamma`` (bool, same shape); NaN is outside."""
    return d2 <= gamma


def mahalanobis(nu: torch.Tensor, S: torch.Tensor) -> torch.Tensor:
    """Squared Mahalanobis distance ``nu^T S^-1 nu (...)`` of innovations ``nu (..., d)`` against
    covariances ``S (..., d, d)`` (batch axes broadcast). Where ``S`` is not positive definite
    (its Cholesky factorisation fails), ``inf``: nothing is inside such a gate."""
    L, info = torch.linalg.cholesky_ex(S)
    shape = torch.broadcast_shapes(L.shape[:-2], nu.shape[:-1])
    L = torch.where((info == 0)[..., None, None], L, torch.eye(S.shape[-1], dtype=S.dtype, device=S.device))
    e = torch.linalg.solve_triangular(L.expand(*shape, *L.shape[-2:]), nu.expand(*shape, nu.shape[-1]).unsqueeze(-1),
                                      upper=False).squeeze(-1)
    d2 = (e * e).sum(-1)
    return torch.where((info == 0).expand(shape), d2, torch.full((), math.inf, dtype=d2.dtype, device=d2.device))


def whitening(S: torch.Tensor) -> torch.Tensor:
    """``W = L^-1 (..., d, d)`` of covariances ``S (..., d, d)`` (``L L^T = S``, Cholesky), so
    that ``|W nu|^2`` is ``nu^T S^-1 nu``: one factorisation for many innovations."""
    L = torch.linalg.cholesky(S)
    eye = torch.eye(S.shape[-1], dtype=S.dtype, device=S.device).expand_as(L)
    return torch.linalg.solve_triangular(L, eye, upper=False)


def whitened_d2(nu: torch.Tensor, W: torch.Tensor) -> torch.Tensor:
    """``|W nu|^2 (...)`` of innovations ``nu (..., d)`` with whitenings ``W (..., d, d)`` of
    :func:`whitening` (lower triangular; batch axes broadcast), row by row: no ``(..., d, d)``
    temporary of the broadcast shape."""
    d2 = None
    for i in range(nu.shape[-1]):
        e = W[..., i, 0] * nu[..., 0]
        for j in range(1, i + 1):
            e = e + W[..., i, j] * nu[..., j]
        d2 = e * e if d2 is None else d2 + e * e
    return d2


def pairwise_d2(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Squared distances ``(B, P, C)`` between whitened points ``a (B, P, d)`` and ``b (B, C, d)``
    (each already divided by its deviations: ``d2`` under a diagonal covariance), as
    ``|a|^2 + |b|^2 - 2 a.b``: one batched product, no ``(B, P, C, d)`` temporary; the
    cancellation costs ``|a|^2 x eps`` (below 1e-9 for ranges of 100 km in units of 30 m)."""
    d2 = torch.baddbmm((a * a).sum(-1)[:, :, None] + (b * b).sum(-1)[:, None, :], a, b.transpose(1, 2), alpha=-2.0)
    return d2.clamp_(min=0.0)


def gaussian_log_likelihood(nu: torch.Tensor, S: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Squared Mahalanobis distance and ``log N(nu; 0, S)`` of innovations.

    ``nu (..., M, d)`` innovations of ``M`` detections against tracks whose covariances are
    ``S (..., d, d)`` (batch axes broadcast). Returns ``(d2, log_lik)``, both ``(..., M)``; a NaN
    innovation (padding) gives NaN.
    """
    L = torch.linalg.cholesky(S)
    e = torch.linalg.solve_triangular(L.unsqueeze(-3), nu.unsqueeze(-1), upper=False).squeeze(-1)
    d2 = (e * e).sum(-1)
    half_logdet = torch.log(torch.diagonal(L, dim1=-2, dim2=-1)).sum(-1)
    d = nu.shape[-1]
    return d2, -0.5 * d2 - half_logdet.unsqueeze(-1) - 0.5 * d * math.log(2 * math.pi)
