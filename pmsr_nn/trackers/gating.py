"""Gating in measurement space: which detections could a track have caused.

A track's predicted measurement ``z_hat (d,)`` with innovation covariance ``S (d, d)`` (R
included) gates a detection ``z`` when the squared Mahalanobis distance
``(z - z_hat)^T S^-1 (z - z_hat)`` is at most ``gamma``, the chi-square quantile with ``d``
degrees of freedom for the gate probability ``P_G``: a detection of the track falls inside with
probability ``P_G`` when the filter is consistent.
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
