"""Batched Gaussian filtering steps shared by the EKF, the UKF and the multi-target trackers.

A Gaussian is ``x (..., n)`` and ``P (..., n, n)``; the leading axes are runs, tracks or
hypotheses. The EKF and the UKF share one update (:func:`kalman_update`) and differ only in how
they compute the predicted measurement moments (:func:`linearised_moments` or
:func:`unscented_moments`), as in Stone Soup's Kalman updaters.

Missing measurements: a NaN entry of ``z`` (per run, per component) is skipped exactly: its
innovation, cross-covariance and innovation-covariance rows are zeroed (with a unit diagonal),
so the gain column is zero and that entry changes nothing.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import torch

from ..errors import ConfigError, PmsrError
from ..measurements import MeasurementModel, wrap_angle


class FilterError(PmsrError):
    """A filter met a non-finite state or a covariance that is not positive definite."""


@dataclass
class Gaussian:
    """Mean ``x (..., n)`` and covariance ``P (..., n, n)``."""

    x: torch.Tensor
    P: torch.Tensor

    def to(self, device: torch.device | str) -> "Gaussian":
        """The same Gaussian on ``device`` (itself where it is there already)."""
        return Gaussian(self.x.to(device), self.P.to(device))


@dataclass
class MeasurementMoments:
    """Predicted measurement ``z (..., m)``, its covariance ``S (..., m, m)`` (R included) and the
    state-measurement cross-covariance ``C (..., n, m)``."""

    z: torch.Tensor
    S: torch.Tensor
    C: torch.Tensor


def symmetrise(P: torch.Tensor) -> torch.Tensor:
    return 0.5 * (P + P.transpose(-1, -2))


def predict(g: Gaussian, F: torch.Tensor, Q: torch.Tensor) -> Gaussian:
    """Linear prediction ``x = F x``, ``P = F P F^T + Q``; ``F (n, n)``, ``Q (..., n, n)``."""
    x = g.x @ F.transpose(-1, -2)
    P = F @ g.P @ F.transpose(-1, -2) + Q  # symmetrised by the update that follows
    return Gaussian(x, P)


def linearised_moments(g: Gaussian, model: MeasurementModel, R: torch.Tensor) -> MeasurementMoments:
    """EKF moments with the analytic Jacobian ``H`` at the mean: ``S = H P H^T + R``, ``C = P H^T``."""
    H = model.jacobian(g.x)
    C = g.P @ H.transpose(-1, -2)
    # S is only read through its lower triangle (Cholesky), so it is not symmetrised here.
    return MeasurementMoments(model.h(g.x), H @ C + R, C)


@dataclass(frozen=True)
class SigmaPoints:
    """Scaled sigma points (van der Merwe): ``2n + 1`` points, weights from ``alpha, beta, kappa``.

    ``lambda = alpha^2 (n + kappa) - n``; points ``x`` and ``x +- columns of chol((n + lambda) P)``.
    Defaults ``alpha = 1, beta = 2, kappa = 3 - n`` (the classic choice that matches the fourth
    moment of a Gaussian); ``kappa=None`` means ``3 - n``.
    """

    alpha: float = 1.0
    beta: float = 2.0
    kappa: float | None = None

    def weights(self, n: int, dtype=torch.float64, device=None) -> tuple[torch.Tensor, torch.Tensor, float]:
        kappa = 3.0 - n if self.kappa is None else self.kappa
        lam = self.alpha**2 * (n + kappa) - n
        wm = torch.full((2 * n + 1,), 0.5 / (n + lam), dtype=dtype, device=device)
        wc = wm.clone()
        wm[0] = lam / (n + lam)
        wc[0] = lam / (n + lam) + (1 - self.alpha**2 + self.beta)
        return wm, wc, n + lam

    def points(self, g: Gaussian) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Sigma points ``(..., 2n+1, n)`` and the mean and covariance weights ``(2n+1,)``."""
        n = g.x.shape[-1]
        wm, wc, scale = self.weights(n, g.x.dtype, g.x.device)
        L = safe_cholesky(scale * g.P)  # (..., n, n); columns are the offsets
        offsets = L.transpose(-1, -2)  # rows
        x = g.x.unsqueeze(-2)
        return torch.cat([x, x + offsets, x - offsets], dim=-2), wm, wc


def safe_cholesky(P: torch.Tensor) -> torch.Tensor:
    """Cholesky factor of a batch of covariances.

    Fallback for matrices that round-off has made slightly indefinite: add a jitter of
    ``1e-12 * mean diagonal``, growing 100x per attempt up to ``1e-6``; beyond that the matrix is
    not a covariance and :class:`FilterError` is raised naming the first bad batch index.
    """
    L, info = torch.linalg.cholesky_ex(P)
    if not bool((info != 0).any()):
        return L
    scale = torch.diagonal(P, dim1=-2, dim2=-1).mean(-1).abs().clamp_min(1e-300)[..., None, None]
    eye = torch.eye(P.shape[-1], dtype=P.dtype, device=P.device)
    for rel in (1e-12, 1e-10, 1e-8, 1e-6):
        L, info = torch.linalg.cholesky_ex(P + rel * scale * eye)
        if not bool((info != 0).any()):
            return L
    bad = torch.nonzero(info != 0)[0].tolist()
    raise FilterError(f"covariance at batch index {bad} is not positive definite (even with jitter 1e-6)")


def unscented_moments(g: Gaussian, model: MeasurementModel, R: torch.Tensor, sigma: SigmaPoints = SigmaPoints()) -> MeasurementMoments:
    """UKF moments from sigma points through ``h``; angle rows use circular means and wrapped residuals."""
    X, wm, wc = sigma.points(g)
    Z = model.h(X)  # (..., 2n+1, m)
    angles = model.angle_rows(Z.device)
    z_lin = (wm[:, None] * Z).sum(-2)
    z_circ = torch.atan2((wm[:, None] * torch.sin(Z)).sum(-2), (wm[:, None] * torch.cos(Z)).sum(-2))
    z_mean = torch.where(angles, z_circ, z_lin)
    dZ = Z - z_mean.unsqueeze(-2)
    dZ = torch.where(angles, wrap_angle(dZ), dZ)
    dX = X - g.x.unsqueeze(-2)
    S = (dZ.transpose(-1, -2) * wc) @ dZ + R
    C = (dX.transpose(-1, -2) * wc) @ dZ
    return MeasurementMoments(z_mean, symmetrise(S), C)


def kalman_update(g: Gaussian, z: torch.Tensor, m: MeasurementMoments,
                  model: MeasurementModel | None) -> tuple[Gaussian, torch.Tensor, torch.Tensor]:
    """Kalman update from predicted moments; NaN entries of ``z (..., m)`` are skipped. ``model``
    wraps the angle rows of the innovation (None: no angle rows, ``nu = z - m.z``).

    The batch axes of ``g``/``m`` and ``z`` broadcast, so one call updates a track with each of
    several candidate measurements (one posterior per association hypothesis).

    Returns the posterior, the innovation ``nu (..., m)`` (wrapped on angle rows, 0 where missing)
    and the normalised innovation squared ``nu^T S^-1 nu (...,)`` (chi-square with as many
    degrees of freedom as entries present, when the filter is consistent).
    """
    missing = torch.isnan(z)
    filled = torch.where(missing, m.z, z)
    nu = filled - m.z if model is None else model.residual(filled, m.z)
    S, C = m.S, m.C
    if bool(missing.any()):
        keep = (~missing).to(S.dtype)
        S = S * keep.unsqueeze(-1) * keep.unsqueeze(-2) + torch.diag_embed(1.0 - keep)
        C = C * keep.unsqueeze(-2)
        nu = nu * keep
    L = safe_cholesky(S)
    # Per-hypothesis use: one predicted track against several measurements broadcasts the batch
    # axes of (g, m) against those of z, e.g. x (B, T, 1, n) with z (B, T, M, m).
    batch = torch.broadcast_shapes(C.shape[:-2], nu.shape[:-1])
    Ct = C.transpose(-1, -2).expand(*batch, *C.shape[-1:], C.shape[-2])
    # With W = L^-1 C^T: K = C S^-1 = W^T L^-1, K S K^T = W^T W and NIS = |L^-1 nu|^2.
    W = torch.linalg.solve_triangular(L, torch.cat([Ct, nu.expand(*batch, nu.shape[-1]).unsqueeze(-1)], -1), upper=False)
    Wc, e = W[..., :-1], W[..., -1]
    x = g.x + (Wc.transpose(-1, -2) @ e.unsqueeze(-1)).squeeze(-1)
    P = symmetrise(g.P - Wc.transpose(-1, -2) @ Wc)
    return Gaussian(x, P), nu, (e * e).sum(-1)


def kalman_gain(m: MeasurementMoments) -> torch.Tensor:
    """The gain ``K = C S^-1 (..., n, m)`` of :func:`kalman_update` (Cholesky of ``S``), for a
    filter that applies it itself (``x + K nu``, ``P - K C^T``)."""
    return torch.cholesky_solve(m.C.transpose(-1, -2), safe_cholesky(m.S)).transpose(-1, -2)


def sequential_update(g: Gaussian, z: torch.Tensor, model: MeasurementModel, R: torch.Tensor,
                      moments: Callable[[Gaussian, MeasurementModel, torch.Tensor], MeasurementMoments],
                      order: Sequence[int] | None = None) -> tuple[Gaussian, torch.Tensor]:
    """Update with one sensor (bistatic pair) at a time, recomputing the moments after each.

    This is the sequential multi-sensor update of the S-MSJPDA and SMC-PHD papers: each pair's
    rows of ``z (..., m)`` (NaN = missing) update the posterior of the previous pair, so an EKF
    re-linearises at every sensor. Needs ``R`` (``(m, m)`` or ``(..., m, m)``) block-diagonal
    across pairs (independent sensors). With moments linear in the state the result equals the
    joint update (information adds up); the EKF's re-linearisation is what makes them differ.
    Returns the posterior and the summed NIS ``(...,)``.
    """
    order = range(model.n_pairs) if order is None else order
    blocks = [model.rows_for_pairs([p]) for p in order]
    mask = torch.zeros(model.dim_z, model.dim_z, dtype=torch.bool, device=R.device)
    for rows in blocks:
        idx = torch.tensor(rows, device=R.device)
        mask[idx[:, None], idx] = True
    if bool((R.masked_fill(mask, 0) != 0).any()):
        raise ConfigError("sequential_update needs R block-diagonal across pairs (independent sensors)")
    nis = z.new_zeros(torch.broadcast_shapes(g.x.shape[:-1], z.shape[:-1]))
    for p, rows in zip(order, blocks):
        sub = model.for_pairs([p])
        R_p = R[..., rows, :][..., rows]
        g, _, nis_p = kalman_update(g, z[..., rows], moments(g, sub, R_p), sub)
        nis = nis + nis_p
    return g, nis
