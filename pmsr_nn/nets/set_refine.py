"""The set tracker's model-based refinement: a few Gauss-Newton steps on the detections a query
chose (:class:`~.set_tracker.SetTracker`).

The network says which detections of the window belong to a query (an association weight per
token) and where to start; the measurement model does the geometry. Per query, the state at the
window's last scan ``s = (p, v)`` (planar position m, velocity m/s; constant velocity across the
window, so the state at a detection ``a`` scans earlier is ``(p - a dt v, v)``) minimises

    sum_t  w_t rho_i(|r_t|^2) |r_t|^2  +  |s - s0|^2 over the prior deviations,

``r_t`` the detection's residual whitened by the measurement deviations (angles wrapped),
``w_t`` the network's association weight, and ``rho_i`` a redescending kernel
``exp(-|r|^2 / (2 c_i^2))`` that tightens over the iterations (``c_i`` in :data:`KERNEL_SCALES`;
none at the first): clutter the network half-chose drops out once the state is near. Every step
is differentiable, so training reaches the association weights through the refined state.
"""

from __future__ import annotations

import torch

from ..measurements import MeasurementModel, wrap_angle

KERNEL_SCALES = (None, 10.0, 5.0, 3.0)
"""Whitened residual norms ``c_i`` of the kernel at iterations 0, 1, 2, 3 (later ones reuse the last)."""


def state_vector(model: MeasurementModel, pos: torch.Tensor, vel: torch.Tensor, dim_x: int) -> torch.Tensor:
    """The model's state ``(..., dim_x)`` with position ``pos (..., 2)`` and velocity ``vel (..., 2)``, 0 elsewhere."""
    x = pos.new_zeros(*pos.shape[:-1], dim_x)
    x[..., list(model.pos_idx)] = pos
    x[..., list(model.vel_idx)] = vel
    return x


def _select_pair(t: torch.Tensor, pair: torch.Tensor, S: int, d: int) -> torch.Tensor:
    """Rows of ``t (..., S*d, *rest)`` (pair layout) for each token's ``pair (...)``: ``(..., d, *rest)``."""
    rest = t.shape[pair.dim() + 1:]
    t = t.reshape(*pair.shape, S, d, *rest)
    idx = pair.reshape(*pair.shape, 1, 1, *(1 for _ in rest)).expand(*pair.shape, 1, d, *rest)
    return t.gather(pair.dim(), idx).squeeze(pair.dim())


def _whitened(p: torch.Tensor, v: torch.Tensor, z: torch.Tensor, pair: torch.Tensor, age: torch.Tensor,
              model: MeasurementModel, dt: float, dim_x: int, jacobian: bool = False):
    """Whitened residuals ``(..., k, d)`` (angles wrapped) of detections ``z (..., k, d)`` with their
    ``pair`` and ``age (..., k)`` under states ``p, v (..., 2)`` carried back to each detection's scan
    (leading dimensions broadcast), and with ``jacobian`` their derivatives ``(..., k, d, 4)`` by
    ``(p, v)`` at the last scan (else None). Float64."""
    S, d = model.n_pairs, len(model.components)
    std = torch.tensor(model.noise_std, dtype=torch.float64, device=z.device)
    angle = torch.tensor([c == "azimuth" for c in model.components], device=z.device)
    lag = (age.double() * dt).unsqueeze(-1)  # (..., k, 1) seconds before the last scan
    p, v = p.double().unsqueeze(-2), v.double().unsqueeze(-2)
    at = p - lag * v  # (..., k, 2): the position at each detection's scan
    x = state_vector(model, at, v.expand_as(at), dim_x)
    pair = pair.expand(at.shape[:-1])
    r = z.double() - _select_pair(model.h(x), pair, S, d)
    r = torch.where(angle, wrap_angle(r), r) / std
    if not jacobian:
        return r, None
    J = _select_pair(model.jacobian(x), pair, S, d)  # (..., k, d, dim_x)
    Jp, Jv = J[..., list(model.pos_idx)], J[..., list(model.vel_idx)]
    return r, torch.cat([Jp, Jv - lag.unsqueeze(-1) * Jp], -1) / std[:, None]


def token_residuals(pos: torch.Tensor, vel: torch.Tensor, z: torch.Tensor, pair: torch.Tensor, age: torch.Tensor,
                    model: MeasurementModel, dt: float, dim_x: int) -> torch.Tensor:
    """Squared whitened residual ``(W, Q, T)`` of every token ``z (W, T, d)`` (its ``pair``, ``age``
    ``(W, T)``) under every query's state ``pos, vel (W, Q, 2)`` carried back to the token's scan."""
    r, _ = _whitened(pos, vel, z[:, None], pair[:, None], age[:, None], model, dt, dim_x)
    return (r * r).sum(-1)


def gauss_newton(pos0: torch.Tensor, vel0: torch.Tensor, z: torch.Tensor, pair: torch.Tensor, age: torch.Tensor,
                 weight: torch.Tensor, model: MeasurementModel, dt: float, dim_x: int, iterations: int,
                 prior_sd: tuple[float, float], kernel_scales: tuple = KERNEL_SCALES) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Refine states (module docstring).

    ``pos0, vel0 (..., 2)`` the starting (and prior) states; per state ``k`` chosen detections:
    ``z (..., k, d)`` in the model's components, ``pair (..., k)``, ``age (..., k)`` (scans before
    the last), ``weight (..., k)`` in [0, 1] (0: ignored). ``prior_sd``: (position m, velocity m/s);
    ``kernel_scales``: ``c_i`` per iteration (``None``: no kernel; the last repeats).
    Returns the refined ``pos, vel (..., 2)`` and ``support (...)``: the summed final weights
    ``w_t rho(|r_t|^2)``, a soft count of the detections consistent with the refined state.
    All in float64.
    """
    w = weight.double()
    p, v = pos0.double(), vel0.double()
    p0, v0 = p, v
    lam = torch.tensor([prior_sd[0] ** -2] * 2 + [prior_sd[1] ** -2] * 2, dtype=torch.float64, device=z.device)
    omega = w
    for i in range(iterations):
        r, Jx = _whitened(p, v, z, pair, age, model, dt, dim_x, jacobian=True)  # (..., k, d), (..., k, d, 4)
        e2 = (r * r).sum(-1)
        scale = kernel_scales[min(i, len(kernel_scales) - 1)]
        omega = w if scale is None else w * torch.exp(-e2.clamp(max=400.0) / (2 * scale**2))
        A = torch.einsum("...k,...kdi,...kdj->...ij", omega, Jx, Jx) + torch.diag(lam)
        s, s0 = torch.cat([p, v], -1), torch.cat([p0, v0], -1)
        b = torch.einsum("...k,...kdi,...kd->...i", omega, Jx, r) + lam * (s0 - s)
        step = torch.linalg.solve(A, b.unsqueeze(-1)).squeeze(-1)
        s = s + step
        p, v = s[..., :2], s[..., 2:]
    return p, v, omega.sum(-1)

