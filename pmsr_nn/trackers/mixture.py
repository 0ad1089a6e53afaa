"""Moment-matched collapse of Gaussian mixtures: what a (J)PDA update leaves of a track's
per-detection posteriors, one Gaussian per track (Bar-Shalom's PDA update)."""

from __future__ import annotations

import torch

from ..filters.gaussian import Gaussian, MeasurementMoments


def collapse(weights: torch.Tensor, x: torch.Tensor, P: torch.Tensor) -> Gaussian:
    """Moment-matched Gaussian of the mixture ``weights (..., L)``, ``x (..., L, n)``, ``P (..., L, n, n)``."""
    mean = (weights.unsqueeze(-1) * x).sum(-2)
    d = x - mean.unsqueeze(-2)
    cov = (weights[..., None, None] * (P + d.unsqueeze(-1) * d.unsqueeze(-2))).sum(-3)
    return Gaussian(mean, 0.5 * (cov + cov.transpose(-1, -2)))


def pda_collapse(g: Gaussian, mom: MeasurementMoments, L: torch.Tensor, e: torch.Tensor, gate: torch.Tensor,
                 w: torch.Tensor) -> Gaussian:
    """Moment-matched Gaussian of the PDA mixture of tracks ``g`` ``(B, T, n)``: weight
    ``w[..., i]`` on the Kalman update with detection ``i``, whose whitened innovation is
    ``e (B, T, M, d)`` (``L^-1 nu``, ``L L^T = S (B, T, d, d)``; used only where ``gate (B, T, M)``,
    ``w`` is 0 elsewhere), ``w[..., M]`` on the prediction.

    The mixture :func:`collapse` of :func:`~pmsr_nn.filters.gaussian.kalman_update`'s
    per-detection posteriors, written with what they share: one gain ``K = W^T L^-1`` and one
    ``P - W^T W`` per track (``W = L^-1 C^T``), so the ``M`` detections cost no posteriors
    ``(n, n)`` of their own. The spread of the means is taken about the prediction
    (``dx_i = K nu_i``), which also avoids the cancellation of subtracting positions of tens of km."""
    Wc = torch.linalg.solve_triangular(L, mom.C.transpose(-1, -2), upper=False)  # (B, T, d, n)
    e = e.masked_fill(~gate.unsqueeze(-1), 0.0)
    dx = e @ Wc  # (B, T, M, n): K nu_i
    wd, wm = w[..., :-1], w[..., -1]
    wdx = (wd.unsqueeze(-1) * dx).transpose(-1, -2)  # (B, T, n, M)
    dbar = wdx.sum(-1)  # (B, T, n)
    # sum_i w_i (dx_i - dbar)(..)^T + w_M dbar dbar^T, with the weights summing to 1
    spread = wdx @ dx - dbar.unsqueeze(-1) * dbar.unsqueeze(-2)
    P_post = g.P - Wc.transpose(-1, -2) @ Wc
    cov = wd.sum(-1)[..., None, None] * P_post + wm[..., None, None] * g.P + spread
    return Gaussian(g.x + dbar, 0.5 * (cov + cov.transpose(-1, -2)))


def expand_moments(m: MeasurementMoments) -> MeasurementMoments:
    """Moments ``(..., d)`` with a detection axis before the last: ``(..., 1, d)``."""
    return MeasurementMoments(m.z.unsqueeze(-2), m.S.unsqueeze(-3), m.C.unsqueeze(-3))
