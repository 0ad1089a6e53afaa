"""SI+KF: spherical-interpolation position fixes (:mod:`.spherical`), then a linear Kalman filter.

Each scan's bistatic ranges give one position fix and its first-order covariance
(:mod:`.fix_covariance`); a linear Kalman filter (:func:`~.kalman.kalman_filter`) runs over the
fixes as position measurements. Ground sensors in 3-D: by default only the horizontal part of
each fix is used (see :func:`si_kf` for why).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..errors import ConfigError
from ..measurements import LinearMeasurementModel, MeasurementModel
from ..motion import KinematicModel
from .fix_covariance import range_deviations, usable_covariance, working_covariances
from .gaussian import Gaussian, symmetrise
from .kalman import FilterResult, kalman_filter
from .spherical import WORK_DTYPE, WorkingFrame, or_identity, range_rows, working_fixes

NO_FIX_POSITION_STD_M = 1.0e5
"""Position deviation of the initial state of a run without a single valid fix (centred on the
sensors): effectively uninformative, and such a run's estimates stay there."""


@dataclass
class SIKFResult(FilterResult):
    """A :class:`FilterResult` plus the fixes the filter used.

    ``fixes (B, K, d)`` in m: the measurements given to the Kalman filter, NaN where missed (the
    fix that initialised a run without a prior is NaN at its step: it is the prior, not used
    twice); ``fix_R (B, K, d, d)`` their covariances (a unit placeholder on missed entries, never
    read); ``rejected (B, K)`` fixes that SI solved but whose covariance was non-finite or
    ill-conditioned (dropped whole; ground geometries drop only an unobservable altitude,
    counted in ``altitude_dropped``); ``init_step (B,)`` the step whose fix initialised each run
    (-1: a prior was given, or the run had no valid fix); ``prior`` the initial Gaussian used.
    """

    fixes: torch.Tensor
    fix_R: torch.Tensor
    rejected: torch.Tensor
    altitude_dropped: torch.Tensor
    init_step: torch.Tensor
    prior: Gaussian

    @property
    def n_rejected(self) -> int:
        return int(self.rejected.sum())


def si_kf(z: torch.Tensor, model: MeasurementModel, motion: KinematicModel, dt: float, q,
          noise_std: torch.Tensor | None = None, prior: Gaussian | None = None, *,
          weighting: str = "distance", refine_steps: int = 0, covariance: str | None = None,
          init_velocity_std_mps: float = 50.0, init_acceleration_std_mps2: float = 1.0,
          init_altitude_std_m: float = 1000.0, max_fix_std_m: float | None = None,
          use_altitude: bool = False, min_altitude_snr: float = 3.0) -> SIKFResult:
    """SI+KF: SI position fixes from the range rows of ``z (B, K, m)``, then a linear Kalman filter.

    ``model`` says where the ranges are (its ``"range"`` rows; other rows are ignored);
    ``noise_std (B, n_components)`` are per-run deviations per component of ``model`` (``None``:
    the model's own); the range deviation sets each fix's covariance
    (:func:`~.fix_covariance.fix_covariance`, method
    ``covariance``: default ``"si"`` for plain SI fixes, ``"crb"`` when ``refine_steps > 0``),
    which is the per-step ``R`` of :func:`~pmsr_nn.filters.kalman.kalman_filter` with
    :meth:`LinearMeasurementModel.position`. Motion ``motion``, interval ``dt`` and process
    noise ``q`` as in the other filters.

    Missed fixes (too few ranges, ill-conditioned geometry, a covariance that is non-finite,
    ill-conditioned, or has a deviation above ``max_fix_std_m``) are NaN and the filter only
    predicts there.

    Ground sensors in 3-D: by default (``use_altitude=False``) only the horizontal part of each
    fix is used, with the horizontal block of its covariance (the altitude is marked missed and
    counted in ``altitude_dropped``); the vertical state then follows the prior and the motion
    model. The SI altitude is too fragile to feed a linear filter: it is the root of a noisy
    square, its first-order deviation grows like ``1 / (z - z0)``, and evaluated at a noisy
    altitude that deviation is itself unreliable. On the default 1 Tx / 3 Rx geometry with
    16-30 m range noise (200 tracks, 100 steps, seed 0) the altitude of targets on the ground
    comes out with an RMSE of about 1.4 km, and feeding the altitudes that looked accurate
    (deviation below a third of the altitude) raised the horizontal RMSE after 10 steps from
    133 m to 299 m. ``use_altitude=True`` uses a fix's altitude where its first-order deviation
    is below ``1 / min_altitude_snr`` of the height above the sensors (with sensors at several
    heights the full 3-D fix is always used).

    ``prior=None``: each run starts from its first valid fix (position = fix, position covariance =
    fix covariance; velocity and acceleration zero with deviations ``init_velocity_std_mps`` and
    ``init_acceleration_std_mps2`` per axis; an unobservable altitude gets
    ``init_altitude_std_m``). That Gaussian is moved back to step 0 through ``F(-k0 dt)`` (so the
    filter, which predicts without updates up to ``k0``, holds it at ``k0`` with the process noise of
    ``k0`` steps added), and the fix at ``k0`` is not used a second time. A run without any valid fix
    starts at the sensors' centre with deviation ``NO_FIX_POSITION_STD_M``.
    """
    if not isinstance(z, torch.Tensor) or z.dim() != 3 or not isinstance(model, MeasurementModel) or z.shape[-1] != model.dim_z:
        shape = tuple(z.shape) if isinstance(z, torch.Tensor) else type(z).__name__
        m = model.dim_z if isinstance(model, MeasurementModel) else "m"
        raise ConfigError(f"measurements must be (B, K, {m}); got {shape}")
    rows = range_rows(model)
    g = model.geometry
    if motion.spatial_dim != g.dim:
        raise ConfigError(f"motion model is {motion.spatial_dim}-D but the geometry is {g.dim}-D")
    inf = torch.isinf(z)
    if bool(inf.any()):
        b, k, _ = inf.nonzero()[0].tolist()
        raise ConfigError(f"measurement of run {b} at step {k} is infinite (use NaN for a missing value)")
    for name, v in (("init_velocity_std_mps", init_velocity_std_mps), ("init_acceleration_std_mps2", init_acceleration_std_mps2),
                    ("init_altitude_std_m", init_altitude_std_m), ("min_altitude_snr", min_altitude_snr)):
        if not (math.isfinite(v) and v > 0):
            raise ConfigError(f"{name} must be finite and positive, got {v}")
    if max_fix_std_m is not None and not max_fix_std_m > 0:
        raise ConfigError(f"max_fix_std_m must be positive or None, got {max_fix_std_m}")
    covariance = covariance or ("crb" if refine_steps else "si")
    B, K, _ = z.shape
    dev, dtype = z.device, z.dtype
    comp = model.components.index("range")
    if noise_std is None:
        sigma = torch.full((B,), model.noise_std[comp], dtype=WORK_DTYPE, device=dev)
    else:
        ns = torch.as_tensor(noise_std, dtype=WORK_DTYPE, device=dev)
        if ns.shape != (B, len(model.components)):
            raise ConfigError(f"noise_std must be per run (B={B}, {len(model.components)}) in the order {model.components}; "
                              f"got {tuple(ns.shape)}")
        sigma = ns[:, comp]
    sigma = range_deviations(sigma, (B,), dev)

    # Fixes and their covariances, all runs and steps at once (working frame).
    pos, valid, ok, fr = working_fixes(z[..., rows], g, weighting, refine_steps)
    s_w = (sigma / fr.scale).unsqueeze(-1).expand(B, K)
    cov, horiz = working_covariances(pos, s_w, valid, fr, covariance, weighting)
    full_ok = ok & usable_covariance(cov, None if max_fix_std_m is None else max_fix_std_m / fr.scale)
    if fr.ground:  # the altitude only on request, and where its deviation is small against it
        var_z = torch.diagonal(cov, dim1=-2, dim2=-1)[..., 2]
        full_ok = full_ok & (min_altitude_snr**2 * var_z < pos[..., 2] ** 2) & use_altitude
    d = fr.dim
    keep = full_ok.unsqueeze(-1).expand(B, K, d).clone()  # per coordinate
    R = or_identity(cov, full_ok)
    alt_dropped = torch.zeros(B, K, dtype=torch.bool, device=dev)
    if fr.ground:
        h_ok = ok & ~full_ok & usable_covariance(horiz, None if max_fix_std_m is None else max_fix_std_m / fr.scale)
        keep[..., :2] |= h_ok.unsqueeze(-1)
        R_h = torch.zeros_like(R)
        R_h[..., :2, :2] = or_identity(horiz, h_ok)
        R_h[..., 2, 2] = 1.0
        R = torch.where(h_ok[..., None, None], R_h, R)
        alt_dropped = h_ok
    rejected = ok & ~keep.any(-1)
    fixes_w = torch.where(keep, pos, torch.full_like(pos, math.nan))
    fixes = fr.centre + fr.scale * fixes_w
    # A unit placeholder (m^2) where a fix is missed: never read, must only be a valid covariance.
    R = torch.where(keep.any(-1)[..., None, None], R * fr.scale**2, torch.eye(d, dtype=WORK_DTYPE, device=dev))
    R = symmetrise(R)

    init_step = torch.full((B,), -1, dtype=torch.long, device=dev)
    if prior is None:
        prior, init_step, fixes = _initial_prior(fixes, R, keep, alt_dropped, pos, fr, motion, dt, init_velocity_std_mps,
                                                 init_acceleration_std_mps2, init_altitude_std_m)
    fixes, R = fixes.to(dtype), R.to(dtype)
    prior = Gaussian(prior.x.to(dtype), prior.P.to(dtype))
    lin = LinearMeasurementModel.position(motion.dim_x, motion.pos_idx, 1.0, dev)
    res = kalman_filter(prior, fixes, motion, dt, q, lin, R)
    return SIKFResult(res.x, res.P, res.nu, res.nis, fixes, R, rejected, alt_dropped, init_step, prior)


def _initial_prior(fixes, R, keep, alt_dropped, pos_w, fr: WorkingFrame, motion: KinematicModel, dt: float,
                   sd_v: float, sd_a: float, sd_alt: float):
    """Prior at step 0 from each run's first usable fix (see :func:`si_kf`); that fix is then NaN."""
    B, K, d = fixes.shape
    dev = fixes.device
    usable = keep.any(-1)  # (B, K)
    has = usable.any(-1)
    steps = torch.arange(K, device=dev)
    k0 = torch.where(usable, steps, K).amin(-1).clamp_max(K - 1)  # first usable step (K-1 if none)
    runs = torch.arange(B, device=dev)
    p0 = fr.centre + fr.scale * pos_w[runs, k0]  # the fix, altitude included even when dropped
    P0 = R[runs, k0].clone()
    alt = alt_dropped[runs, k0]
    if fr.ground and bool(alt.any()):
        P0[alt, 2, :] = 0.0
        P0[alt, :, 2] = 0.0
        P0[alt, 2, 2] = sd_alt**2
    p0 = torch.where(has.unsqueeze(-1), p0, fr.centre.expand(B, d))
    P0 = torch.where(has[..., None, None], P0, NO_FIX_POSITION_STD_M**2 * torch.eye(d, dtype=WORK_DTYPE, device=dev))
    n = motion.dim_x
    x = torch.zeros(B, n, dtype=WORK_DTYPE, device=dev)
    P = torch.zeros(B, n, n, dtype=WORK_DTYPE, device=dev)
    pi = torch.tensor(motion.pos_idx, device=dev)
    x[:, pi] = p0
    P[:, pi[:, None], pi[None, :]] = P0
    P[:, list(motion.vel_idx), list(motion.vel_idx)] = sd_v**2
    if motion.order >= 3:
        P[:, list(motion.acc_idx), list(motion.acc_idx)] = sd_a**2
    # Back to step 0: x_0 = F(-k0 dt) x_k0 (so that K predictions later it is x_k0 again).
    k_used = torch.where(has, k0, torch.zeros_like(k0))
    Fb = motion.F(-dt * k_used.to(WORK_DTYPE), WORK_DTYPE, dev)  # (B, n, n)
    x = (Fb @ x.unsqueeze(-1)).squeeze(-1)
    P = symmetrise(Fb @ P @ Fb.transpose(-1, -2))
    fixes = fixes.clone()
    fixes[runs[has], k0[has]] = math.nan
    init_step = torch.where(has, k0, torch.full_like(k0, -1))
    return Gaussian(x.to(fixes.dtype), P.to(fixes.dtype)), init_step, fixes
