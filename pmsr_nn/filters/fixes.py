"""Per-scan state fixes: position and velocity from one scan's bistatic ranges and range-rates.

A *state fix* is what a single scan says about the target on its own:

* position: the maximum-likelihood fix of the ranges (spherical interpolation followed by
  Gauss-Newton steps, :func:`~pmsr_nn.filters.spherical.spherical_interpolation`);
* velocity: given that position, every range-rate is linear in the velocity,
  ``rdot_n = (u_tx,n + u_rx,n) . v`` with ``u`` the unit vectors from the pair's sensors to the
  target (the same rows as the range Jacobian), so ``v`` is their least-squares solution
  (equal weights: one deviation is shared by a scan's pairs);
* acceleration: zero (a single scan carries no information about it).

The learned trackers use it as a window-local frame and as the base their residual output
corrects (:mod:`pmsr_nn.nets.representation`). Planar (2-D) geometries only.
"""

from __future__ import annotations

import torch

from ..errors import ConfigError, MeasurementError
from ..measurements import MeasurementModel
from .spherical import range_rows, spherical_interpolation


def _rows(model: MeasurementModel, component: str) -> list[int]:
    labels = model.labels
    return [labels.index(f"{component}_{n + 1}") for n in range(model.n_pairs)]


def state_fixes(z: torch.Tensor, model: MeasurementModel, dim_x: int, refine_steps: int = 2) -> torch.Tensor:
    """State fixes ``(..., dim_x)`` (m, m/s, m/s^2 = 0) of measurements ``z (..., dim_z)`` (SI units).

    ``model`` must have ``range`` and ``range_rate`` components and a 2-D geometry; the state
    layout is the model's (``pos_idx``, ``vel_idx``). A fix whose ranges cannot be solved
    (ill-conditioned, missing) is NaN in every component. Computed in float64.
    """
    if model.geometry.dim != 2:
        raise ConfigError("state fixes (inputs: local_fixes, output: residual) need a planar (2-D) geometry")
    if "range_rate" not in model.components:
        raise ConfigError(f"state fixes need range-rate measurements; the model has {model.components}")
    z = z.to(torch.float64)
    pos = spherical_interpolation(z[..., range_rows(model)], model.geometry, refine_steps=refine_steps)
    x = z.new_zeros(*z.shape[:-1], dim_x)
    x[..., list(model.pos_idx)] = pos
    H = model.jacobian(torch.nan_to_num(x))  # (..., dim_z, dim_x); velocity does not enter the range rows
    J = H[..., range_rows(model), :][..., list(model.pos_idx)]  # (..., N, 2): u_tx + u_rx per pair
    rdot = z[..., _rows(model, "range_rate")]
    # Normal equations of the 2 x 2 least-squares problem, solved in closed form (elementwise, fast).
    a, b, c = (J[..., 0] ** 2).sum(-1), (J[..., 0] * J[..., 1]).sum(-1), (J[..., 1] ** 2).sum(-1)
    r0, r1 = (J[..., 0] * rdot).sum(-1), (J[..., 1] * rdot).sum(-1)
    det = a * c - b * b
    ok = torch.isfinite(pos).all(-1) & torch.isfinite(rdot).all(-1) & (det > 1e-6 * (a + c) ** 2)
    det = torch.where(ok, det, torch.ones_like(det))
    x[..., model.vel_idx[0]] = (c * r0 - b * r1) / det
    x[..., model.vel_idx[1]] = (a * r1 - b * r0) / det
    return torch.where(ok[..., None], x, torch.full_like(x, float("nan")))


def hold_last_valid(x: torch.Tensor, bad: torch.Tensor) -> torch.Tensor:
    """``x (B, K, D)`` with each row where ``bad (B, K)`` replaced by the last row before it that is
    not bad (vectorised: a running maximum of valid indices). Row 0 must be valid."""
    K = x.shape[1]
    idx = torch.where(bad, torch.zeros((), dtype=torch.long), torch.arange(K, device=x.device).expand_as(bad)).cummax(1).values
    return x.gather(1, idx[..., None].expand_as(x))


def hold_missing_fixes(s: torch.Tensor) -> torch.Tensor:
    """Fixes ``(B, K, n)`` with NaN rows replaced by the last valid one (a sequence must start
    with a valid fix; :class:`MeasurementError` otherwise)."""
    bad = torch.isnan(s).any(-1)
    if not bool(bad.any()):
        return s
    if bool(bad[:, 0].any()):
        b = int(bad[:, 0].nonzero()[0])
        raise MeasurementError(f"sequence {b}: the first scan's ranges give no position fix "
                               "(too few valid ranges or a degenerate geometry)")
    return hold_last_valid(s, bad)
