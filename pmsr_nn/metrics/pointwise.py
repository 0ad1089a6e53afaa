"""Accuracy metrics over Monte Carlo runs / tracks.

``est`` and ``truth`` are ``(B, K, dim_x)`` in SI units; ``idx`` picks the components (the
position or velocity columns). The error at a sample is the Euclidean norm over ``idx``.
"""

from __future__ import annotations

from typing import Sequence

import torch


def position_columns(dim_x: int) -> list[int]:
    """Position columns of a CA state ``[x, vx, ax, y, vy, ay(, z, vz, az)]``."""
    return list(range(0, dim_x, 3))


def velocity_columns(dim_x: int) -> list[int]:
    return list(range(1, dim_x, 3))


def squared_error(est: torch.Tensor, truth: torch.Tensor, idx: Sequence[int]) -> torch.Tensor:
    """``(B, K)`` squared Euclidean error on the ``idx`` components."""
    return ((est - truth)[..., list(idx)] ** 2).sum(-1)


def rmse_over_time(est: torch.Tensor, truth: torch.Tensor, idx: Sequence[int]) -> torch.Tensor:
    """``(K,)`` RMSE at each step over the runs (Eq. 31 of the MDFNN paper)."""
    return squared_error(est, truth, idx).mean(0).sqrt()


def pooled_rmse(est: torch.Tensor, truth: torch.Tensor, idx: Sequence[int], start: int = 0) -> float:
    """Root of the mean squared error over runs and the steps from ``start`` on (one pooled number)."""
    return float(squared_error(est[:, start:], truth[:, start:], idx).mean().sqrt())


def normalised_nees(x: torch.Tensor, P: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """NEES over the full state divided by its dimension (1 for a consistent filter): ``x, truth (..., n)``,
    ``P (..., n, n)`` -> ``(...)``. NaN where the error or the covariance is not finite; a singular
    covariance is solved with its pseudo-inverse (LAPACK's least squares must not see a NaN: it
    stops the process with an internal error instead of raising)."""
    e = (x - truth).unsqueeze(-1)
    ok = torch.isfinite(e).all(-1).all(-1) & torch.isfinite(P).all(-1).all(-1)
    eye = torch.eye(P.shape[-1], dtype=P.dtype, device=P.device)
    Pf = torch.where(ok[..., None, None], P, eye)
    ef = torch.where(ok[..., None, None], e, torch.zeros((), dtype=e.dtype, device=e.device))
    sol, info = torch.linalg.solve_ex(Pf, ef)
    singular = info != 0
    if bool(singular.any()):
        sol = sol.clone()
        sol[singular] = torch.linalg.pinv(Pf[singular]) @ ef[singular]
    value = (ef * sol).sum((-2, -1)) / x.shape[-1]
    return torch.where(ok, value, torch.full_like(value, float("nan")))


def track_loss(dummy_most_probable: torch.Tensor, gate_sd: torch.Tensor, successive: int, gate_limit: float) -> torch.Tensor:
    """The loss rule of the S-MSJPDA paper (after Ref. [38] there): a track is lost once the dummy
    (no detection) has been its most probable association for ``successive`` scans in a row, or
    once its gate grows past ``gate_limit`` (here: the predicted bistatic-range deviation, m).

    ``dummy_most_probable`` and ``gate_sd`` are ``(B, K, M)`` (``M`` tracks); returns the scan at which each
    track was declared lost, ``(B, M)`` int64, -1 for a track never lost.
    """
    B, K, M = dummy_most_probable.shape
    run = torch.zeros(B, M, dtype=torch.int64)
    lost_at = torch.full((B, M), -1, dtype=torch.int64)
    for k in range(K):  # K is small (scans); runs and tracks are vectorised
        run = torch.where(dummy_most_probable[:, k], run + 1, torch.zeros_like(run))
        hit = ((run >= successive) | (gate_sd[:, k] > gate_limit)) & (lost_at < 0)
        lost_at = torch.where(hit, torch.full_like(lost_at, k), lost_at)
    return lost_at
