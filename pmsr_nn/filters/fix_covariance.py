"""First-order covariance of spherical-interpolation fixes (:mod:`.spherical`), and the bound.

SI is not efficient. To first order SI fits ``d rho = J dp + c eps`` with an extra nuisance
direction ``c_s = -rho_s / |p - r_s|`` (the constraint SI drops), so its covariance exceeds the
Cramer-Rao bound ``(J^T R^-1 J)^-1``, ``J`` rows ``u_tx + u_rx``, unless ``J^T c = 0``. On the
default geometry (targets east of the transmitter, receivers 7.5-8.3 km west) the gap is large:
at (5, 3) km, SI's position variance is 46x the CRB (trace 255 vs 5.5 m^2 per 1 m^2 of
range variance), so :func:`fix_covariance` offers both: ``method="si"`` is the first-order
covariance of the SI estimator itself (what a Kalman filter of plain SI fixes must be told),
``method="crb"`` the bound, which is also the first-order covariance of the maximum-likelihood
fix. After a few Gauss-Newton steps (``refine_steps`` of
:func:`~.spherical.spherical_interpolation`) the fixes are nearly efficient and the CRB is the
covariance to use.

For ground sensors in 3-D the altitude's first-order deviation grows like ``1 / (z - z0)`` and is
infinite on the ground; :func:`working_covariances` then also gives the horizontal block of the
bound with the altitude unknown.
"""

from __future__ import annotations

import math

import torch

from ..errors import ConfigError
from .gaussian import symmetrise
from .spherical import (WEIGHTINGS, WORK_DTYPE, WorkingFrame, or_identity, range_jacobian, sensor_distances,
                        well_conditioned, working_frame)

COVARIANCE_METHODS = ("si", "crb")


def range_deviations(range_std, lead_shape, device) -> torch.Tensor:
    """``range_std`` (a scalar or anything that broadcasts to ``lead_shape``) as a float64 tensor
    of that shape; a one-line error unless every deviation is finite and positive."""
    s = torch.as_tensor(range_std, dtype=WORK_DTYPE, device=device)
    try:
        s = torch.broadcast_to(s, lead_shape)
    except RuntimeError:
        raise ConfigError(f"range_std must be a scalar or broadcast to the fixes' shape {tuple(lead_shape)}; "
                          f"got shape {tuple(s.shape)}") from None
    if not bool((torch.isfinite(s) & (s > 0)).all()):
        raise ConfigError("range_std must be finite and positive")
    return s


def working_covariances(pos: torch.Tensor, sigma: torch.Tensor, valid: torch.Tensor, fr: WorkingFrame, method: str,
                        weighting: str):
    """First-order covariance ``(..., dim, dim)`` of working-frame fixes ``pos (..., dim)`` and its
    horizontal block ``(..., 2, 2)`` when the altitude of a ground geometry is dropped (``None``
    otherwise), in working units, with range deviations ``sigma (...,)`` in working units and
    the pairs that had a range ``valid (..., S)``. Not yet checked for conditioning."""
    if method not in COVARIANCE_METHODS:
        raise ConfigError(f"covariance method must be one of {COVARIANCE_METHODS}, got {method!r}")
    if weighting not in WEIGHTINGS:
        raise ConfigError(f"weighting must be one of {WEIGHTINGS}, got {weighting!r}")
    finite = torch.isfinite(pos).all(-1)
    pos = torch.where(finite.unsqueeze(-1), pos, torch.zeros_like(pos))
    w = valid.to(WORK_DTYPE)
    var = (sigma * sigma).unsqueeze(-1)  # (..., 1)
    d_t, d_r, u_t, u_r = sensor_distances(pos, fr)
    eye = lambda n: torch.eye(n, dtype=WORK_DTYPE, device=pos.device)  # noqa: E731
    if method == "crb":
        J = u_t + u_r  # (..., S, dim)
        info = torch.einsum("...nd,...n,...ne->...de", J, w / var, J)
        ok = well_conditioned(info, 1e-300)
        cov = torch.where(ok[..., None, None], torch.linalg.inv(or_identity(info, ok)), torch.full_like(info, math.nan))
        horiz = None
        if fr.ground:
            # The horizontal block of the bound with the altitude unknown: invert the information
            # in (x, y, h = (z - z0)^2), which stays regular on the ground (in z it does not).
            _, Jq = range_jacobian(torch.cat([pos[..., :2], pos[..., 2:] ** 2], -1), fr)
            info_q = torch.einsum("...nd,...n,...ne->...de", Jq, w / var, Jq)
            ok_q = well_conditioned(info_q, 1e-300)
            horiz = torch.where(ok_q[..., None, None], torch.linalg.inv(or_identity(info_q, ok_q)),
                                torch.full_like(info_q, math.nan))
            horiz = symmetrise(horiz[..., :2, :2])
        return symmetrise(cov), horiz
    # SI: theta = (A^T W A)^-1 A^T W b with A = [E, -Rho]; at the noise-free ranges of the fix the
    # residual is zero and d theta = -(A^T W A)^-1 A^T W diag(|p - r_s|) d rho.
    rho = (d_t + d_r) * w
    d = fr.d_lin
    E = (fr.rx - fr.tx)[:, :d].expand(*rho.shape, d)
    A = torch.cat([E, -rho.unsqueeze(-1) * fr.onehot], dim=-1)  # (..., S, d + n_tx)
    wd = w / (d_r * d_r) if weighting == "distance" else w
    active = (valid.unsqueeze(-1) & (fr.onehot > 0)).any(-2)
    normal = torch.einsum("...na,...n,...nb->...ab", A, wd, A)
    pad = torch.cat([torch.zeros_like(active[..., :1]).expand(*active.shape[:-1], d), ~active], -1).to(WORK_DTYPE)
    normal = normal + torch.diag_embed(pad)
    ok_normal = well_conditioned(normal, 1e-300)
    normal_inv = torch.linalg.inv(or_identity(normal, ok_normal))
    L = -(normal_inv @ (A * (wd * d_r).unsqueeze(-1)).transpose(-1, -2))  # (..., d + n_tx, S)
    cov_theta = (L * var.unsqueeze(-1)) @ L.transpose(-1, -2)
    cov_theta = torch.where(ok_normal[..., None, None], cov_theta, torch.full_like(cov_theta, math.nan))
    if not fr.ground:
        return symmetrise(cov_theta[..., :d, :d]), None
    # Altitude h = sqrt(mean_j(D_j^2 - |p_h - t_j|^2)): dh = mean_j(D_j dD_j - (p_h - t_j) . dp_h) / h.
    a = active.to(WORK_DTYPE)
    a = a / a.sum(-1, keepdim=True).clamp_min(1.0)
    h = pos[..., 2]
    D = d_t.unsqueeze(-1).mul(fr.onehot).amax(-2)  # (..., n_tx): distance to each used transmitter
    gz = torch.cat([-(a.unsqueeze(-1) * (pos[..., :2].unsqueeze(-2) - fr.tx_used[:, :2])).sum(-2), a * D], -1)
    gz = gz / h.unsqueeze(-1)  # inf on the ground: the altitude is not observable there
    Gm = torch.cat([torch.cat([eye(d), torch.zeros(d, fr.n_tx, dtype=WORK_DTYPE, device=pos.device)], -1)
                    .expand(*gz.shape[:-1], d, d + fr.n_tx), gz.unsqueeze(-2)], -2)
    cov = Gm @ cov_theta @ Gm.transpose(-1, -2)
    return symmetrise(cov), symmetrise(cov_theta[..., :d, :d])


def usable_covariance(cov: torch.Tensor, max_std: float | None) -> torch.Tensor:
    """``(...,)`` bool: ``cov (..., d, d)`` is well conditioned (:func:`~.spherical.well_conditioned`)
    and, given ``max_std``, no deviation exceeds it (same units as ``cov``'s roots)."""
    ok = well_conditioned(cov)
    if max_std is not None:
        ok = ok & (torch.diagonal(cov, dim1=-2, dim2=-1).max(-1).values <= max_std**2)
    return ok


def fix_covariance(positions: torch.Tensor, geometry, range_std, *, method: str = "si", weighting: str = "distance",
                   valid: torch.Tensor | None = None) -> torch.Tensor:
    """First-order covariance ``(..., d, d)`` in m^2 of fixes ``positions (..., d)``.

    ``range_std`` (m) is a scalar or broadcasts to ``positions.shape[:-1]`` (one deviation per
    fix, shared by its pairs). ``method="si"`` (default) propagates the range noise through the
    SI estimator with ``weighting`` (the covariance of :func:`~.spherical.spherical_interpolation` fixes made
    with the same weighting and ``refine_steps=0``); ``method="crb"`` is ``(J^T W J)^-1`` with
    ``J`` rows ``u_tx + u_rx`` and ``W = 1 / range_std^2``: the Cramer-Rao bound, and the
    covariance of refined (maximum-likelihood) fixes. Both are evaluated at the fix (its
    noise-free ranges). ``valid (..., S)`` marks the pairs that had a range (default all).

    A NaN fix, or one whose covariance is non-finite or ill-conditioned (e.g. the altitude of a
    fix on the ground plane of ground sensors), gets a NaN matrix.
    """
    fr = working_frame(geometry).to(positions.device)
    if not isinstance(positions, torch.Tensor) or positions.dim() < 1 or positions.shape[-1] != fr.dim:
        shape = tuple(positions.shape) if isinstance(positions, torch.Tensor) else type(positions).__name__
        raise ConfigError(f"positions must be a tensor (..., {fr.dim}); got {shape}")
    if bool(torch.isinf(positions).any()):
        raise ConfigError("positions must be finite (NaN marks a missed fix)")
    lead = positions.shape[:-1]
    sigma = range_deviations(range_std, lead, positions.device) / fr.scale
    if valid is None:
        valid = torch.ones(*lead, fr.n_pairs, dtype=torch.bool, device=positions.device)
    elif tuple(valid.shape) != (*lead, fr.n_pairs):
        raise ConfigError(f"valid must be a boolean ({', '.join(map(str, lead))}, {fr.n_pairs}); got {tuple(valid.shape)}")
    pos = (positions.to(WORK_DTYPE) - fr.centre) / fr.scale
    cov, _ = working_covariances(pos, sigma, valid.bool(), fr, method, weighting)
    ok = usable_covariance(cov, None) & torch.isfinite(pos).all(-1)
    cov = torch.where(ok[..., None, None], cov * fr.scale**2, torch.full_like(cov, math.nan))
    return cov.to(positions.dtype)
