"""Batched EKF and UKF over whole measurement sequences (the only Python loop is over time).

Convention: the prior ``(x0, P0)`` is the state at step 0 *before* ``z[:, 0]``; step 0 is an
update only, every later step a prediction over ``dt`` followed by an update. A run whose state
becomes non-finite raises :class:`~pmsr_nn.filters.gaussian.FilterError` naming the run and step.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch

from ..errors import ConfigError
from ..measurements import LinearMeasurementModel, MeasurementModel
from ..motion import KinematicModel
from .gaussian import (
    FilterError,
    Gaussian,
    MeasurementMoments,
    SigmaPoints,
    kalman_update,
    linearised_moments,
    predict,
    unscented_moments,
)


@dataclass
class FilterResult:
    """Filtered means ``x (B, K, n)``, covariances ``P (B, K, n, n)``, innovations ``nu (B, K, m)``
    and normalised innovations squared ``nis (B, K)``."""

    x: torch.Tensor
    P: torch.Tensor
    nu: torch.Tensor
    nis: torch.Tensor


def check_filter_inputs(prior: Gaussian, z: torch.Tensor, model: MeasurementModel, motion: KinematicModel, R: torch.Tensor) -> None:
    """Shapes, finiteness and positive definiteness of a filter's inputs; :class:`ConfigError`
    naming the run (and step) otherwise. Shared by every whole-sequence filter."""
    n, m = motion.dim_x, model.dim_z
    if prior.x.dim() != 2 or prior.x.shape[-1] != n or prior.P.shape[-2:] != (n, n) or prior.P.shape[:-2] not in ((), prior.x.shape[:1]):
        raise ConfigError(f"prior must be x (B, {n}) and P (B, {n}, {n}); got {tuple(prior.x.shape)}, {tuple(prior.P.shape)}")
    if z.dim() != 3 or z.shape[-1] != m or z.shape[0] != prior.x.shape[0]:
        raise ConfigError(f"measurements must be (B={prior.x.shape[0]}, K, {m}); got {tuple(z.shape)}")
    if R.shape[-2:] != (m, m) or R.dim() > 4 or (R.dim() == 4 and R.shape[:2] != z.shape[:2]):
        raise ConfigError(f"R must be ({m}, {m}), (B, {m}, {m}) or per step (B, K, {m}, {m}); got {tuple(R.shape)}")
    bad_x = ~torch.isfinite(prior.x).all(-1)
    if bool(bad_x.any()):
        raise ConfigError(f"prior mean of run {int(bad_x.nonzero()[0])} is not finite")
    inf = torch.isinf(z)
    if bool(inf.any()):
        b, k, _ = inf.nonzero()[0].tolist()
        raise ConfigError(f"measurement of run {b} at step {k} is infinite (use NaN for a missing value)")
    for name, M in (("P0", prior.P), ("R", R)):
        if not torch.allclose(M, M.transpose(-1, -2), rtol=1e-10, atol=0):
            raise ConfigError(f"{name} is not symmetric")
        if bool((torch.linalg.cholesky_ex(M)[1] != 0).any()):
            raise ConfigError(f"{name} is not positive definite")


def run_gaussian_filter(prior: Gaussian, z: torch.Tensor, motion: KinematicModel, dt: float, q, model: MeasurementModel,
                        R: torch.Tensor, moments: Callable[[Gaussian, MeasurementModel, torch.Tensor], MeasurementMoments]) -> FilterResult:
    """Filter ``z (B, K, m)`` (NaN = missing) with motion ``F(dt), Q(dt, q)`` and the given moments.

    ``R`` is ``(m, m)``, per run ``(B, m, m)`` or per run and step ``(B, K, m, m)`` (position
    fixes whose accuracy changes along the track, as in SI+KF).
    """
    check_filter_inputs(prior, z, model, motion, R)
    F = motion.F(dt, z.dtype, z.device)
    Q = motion.Q(dt, q, z.dtype, z.device)
    g = prior
    B, K, m = z.shape
    n = prior.x.shape[-1]
    out = FilterResult(z.new_empty(B, K, n), z.new_empty(B, K, n, n), z.new_empty(B, K, m), z.new_empty(B, K))
    for k in range(K):
        if k > 0:
            g = predict(g, F, Q)
        try:
            R_k = R[:, k] if R.dim() == 4 else R
            g, out.nu[:, k], out.nis[:, k] = kalman_update(g, z[:, k], moments(g, model, R_k), model)
        except FilterError as exc:
            raise FilterError(f"step {k}: {exc}") from None
        bad = ~torch.isfinite(g.x).all(-1)
        if bool(bad.any()):
            raise FilterError(f"state of run {int(bad.nonzero()[0])} became non-finite at step {k}")
        out.x[:, k], out.P[:, k] = g.x, g.P
    return out


def ekf(prior: Gaussian, z: torch.Tensor, motion: KinematicModel, dt: float, q, model: MeasurementModel, R: torch.Tensor) -> FilterResult:
    """Extended Kalman filter (analytic Jacobians) for a batch of runs."""
    return run_gaussian_filter(prior, z, motion, dt, q, model, R, linearised_moments)


def ukf(prior: Gaussian, z: torch.Tensor, motion: KinematicModel, dt: float, q, model: MeasurementModel, R: torch.Tensor,
        sigma: SigmaPoints = SigmaPoints()) -> FilterResult:
    """Unscented Kalman filter (scaled sigma points, redrawn after each prediction) for a batch of runs."""
    return run_gaussian_filter(prior, z, motion, dt, q, model, R, lambda g, mm, RR: unscented_moments(g, mm, RR, sigma))


def kalman_filter(prior: Gaussian, z: torch.Tensor, motion: KinematicModel, dt: float, q, model: LinearMeasurementModel,
                  R: torch.Tensor) -> FilterResult:
    """Linear Kalman filter for a :class:`~pmsr_nn.measurements.LinearMeasurementModel`."""
    if not isinstance(model, LinearMeasurementModel):
        raise ConfigError("kalman_filter needs a LinearMeasurementModel; use ekf or ukf for bistatic measurements")
    return run_gaussian_filter(prior, z, motion, dt, q, model, R, linearised_moments)
