"""Posterior Cramer-Rao bounds (Tichavsky, Muravchik and Nehorai 1998) for the tracking models.

For linear motion ``x_{k+1} = F x_k + w`` (``w ~ N(0, Q)``) and measurements
``z_k = h(x_k) + v`` (``v ~ N(0, R)``), the Bayesian information of ``x_k`` obeys

    J_0 = P_0^-1 + I_0,    J_{k+1} = (F J_k^-1 F^T + Q)^-1 + I_{k+1},

with the measurement information ``I_k = p_d E[H_k^T R^-1 H_k]`` (``H_k`` the Jacobian at the
true state; ``p_d`` the information-reduction factor of missed detections without clutter). This
is the Kalman covariance recursion with ``I_k`` in place of ``H^T R^-1 H``, so the
**fixed-interval smoothing** bound (Simandl, Kralovec and Tichavsky 2001) is the RTS covariance
pass over it: the inverse of the trajectory's block-tridiagonal information matrix, diagonal
blocks (a test checks both against that matrix inverted by brute force).

Two forms, which a report must name:

* ``"information_averaged"`` (Tichavsky's Bayesian bound): ``I_k`` averaged over the true
  trajectories, then one recursion. Well-placed tracks dominate the averaged information, so on
  multistatic geometry this can be far below what any estimator reaches on a typical track.
* ``"per_trajectory"``: the recursion on each track's own ``H_k``, the resulting covariances
  averaged over tracks. By Jensen's inequality (the Riccati map is concave in the information
  and the inverse is convex) it is never below the averaged form; it is the fair yardstick for
  errors averaged over a fixed set of trajectories.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .errors import ConfigError
from .filters.smoothing import rts_backward
from .measurements import LinearMeasurementModel, MeasurementModel
from .motion import KinematicModel

FORMS = ("information_averaged", "per_trajectory")
_SENSOR_RADIUS_M = 1.0


@dataclass
class BoundResult:
    """Bounds on the state-error covariance ``(K, n, n)``, averaged over trajectories.

    ``per_track_position`` / ``per_track_position_smoothing`` ``(B, K)`` hold each track's own
    position RMSE bound (m) for the per-trajectory form (None for the averaged form).
    """

    form: str
    filtering: torch.Tensor
    smoothing: torch.Tensor | None
    pos_idx: tuple[int, ...]
    vel_idx: tuple[int, ...]
    per_track_position: torch.Tensor | None = None
    per_track_position_smoothing: torch.Tensor | None = None

    def _rmse(self, which: str, idx: tuple[int, ...]) -> torch.Tensor:
        if which not in ("filtering", "smoothing"):
            raise ConfigError(f"which must be 'filtering' or 'smoothing', got {which!r}")
        P = getattr(self, which)
        if P is None:
            raise ConfigError("this bound was computed without the smoothing pass")
        return torch.diagonal(P, dim1=-2, dim2=-1)[..., list(idx)].sum(-1).sqrt()

    def position_rmse(self, which: str = "filtering") -> torch.Tensor:
        """Position RMSE bound per step ``(K,)`` in m: ``sqrt(trace)`` of the position block."""
        return self._rmse(which, self.pos_idx)

    def velocity_rmse(self, which: str = "filtering") -> torch.Tensor:
        """Velocity RMSE bound per step ``(K,)`` in m/s."""
        return self._rmse(which, self.vel_idx)

    @property
    def label(self) -> str:
        return f"PCRB ({self.form.replace('_', '-')})"


def _inverse_spd(M: torch.Tensor) -> torch.Tensor:
    L, info = torch.linalg.cholesky_ex(M)
    if bool((info != 0).any()):
        raise ConfigError("an information matrix of the bound is not positive definite (is P0 or Q singular?)")
    return torch.cholesky_inverse(L)


def measurement_information(truth: torch.Tensor, model: MeasurementModel | LinearMeasurementModel, R: torch.Tensor,
                            detection_probability: float = 1.0) -> torch.Tensor:
    """``p_d H^T R^-1 H`` at the true states: ``truth (B, K, n)``, ``R`` ``(m, m)``, ``(B, m, m)``
    or ``(B, K, m, m)`` -> ``(B, K, n, n)``."""
    H = model.jacobian(truth)  # (B, K, m, n)
    R_inv = _inverse_spd(R)
    if R_inv.dim() == 3:
        R_inv = R_inv.unsqueeze(1)
    return detection_probability * (H.transpose(-1, -2) @ R_inv @ H)


def _filtering_pass(info: torch.Tensor, J0: torch.Tensor, F: torch.Tensor, Q: torch.Tensor) -> torch.Tensor:
    """Covariance bounds ``(B, K, n, n)`` from measurement information ``(B, K, n, n)``."""
    P = torch.empty_like(info)
    P[:, 0] = _inverse_spd(J0 + info[:, 0])
    for k in range(1, info.shape[1]):
        P_pred = F @ P[:, k - 1] @ F.transpose(-1, -2) + Q
        P_pred = 0.5 * (P_pred + P_pred.transpose(-1, -2))
        P[:, k] = _inverse_spd(_inverse_spd(P_pred) + info[:, k])
    return P


def _check(truth: torch.Tensor, motion: KinematicModel, model: MeasurementModel | LinearMeasurementModel, P0: torch.Tensor, R: torch.Tensor, form: str) -> None:
    n, m = motion.dim_x, model.dim_z
    if form not in FORMS:
        raise ConfigError(f"form must be one of {FORMS}, got {form!r}")
    if truth.dim() != 3 or truth.shape[-1] != n:
        raise ConfigError(f"truth must be (B, K, {n}); got {tuple(truth.shape)}")
    if P0.shape[-2:] != (n, n) or P0.dim() > 3:
        raise ConfigError(f"P0 must be ({n}, {n}) or (B, {n}, {n}); got {tuple(P0.shape)}")
    if R.shape[-2:] != (m, m) or R.dim() > 4:
        raise ConfigError(f"R must be ({m}, {m}), (B, {m}, {m}) or (B, K, {m}, {m}); got {tuple(R.shape)}")
    bad = ~torch.isfinite(truth).all(-1)
    if bool(bad.any()):
        b, k = bad.nonzero()[0].tolist()
        raise ConfigError(f"true state of run {b} at step {k} is not finite")
    on_sensor = model.near_sensor(truth, _SENSOR_RADIUS_M) if isinstance(model, MeasurementModel) else None
    if on_sensor is not None and bool(on_sensor.any()):
        b, k = on_sensor.nonzero()[0].tolist()
        raise ConfigError(f"true state of run {b} at step {k} is within {_SENSOR_RADIUS_M} m of a sensor: "
                          "the bistatic information is unbounded there")
    if bool((torch.linalg.cholesky_ex(P0)[1] != 0).any()):
        raise ConfigError("P0 is not positive definite")


def pcrb(truth: torch.Tensor, motion: KinematicModel, dt: float, q, model: MeasurementModel | LinearMeasurementModel, R: torch.Tensor,
         P0: torch.Tensor, form: str = "per_trajectory", smoothing: bool = True,
         detection_probability: float = 1.0, chunk_tracks: int | None = None) -> BoundResult:
    """Filtering (and fixed-interval smoothing) PCRB over the true trajectories ``truth (B, K, n)``.

    ``q`` as in :meth:`KinematicModel.Q` (per-run ``q`` only with the per-trajectory form),
    ``R`` ``(m, m)``, per run ``(B, m, m)`` or per step ``(B, K, m, m)``, ``P0`` the prior covariance
    at step 0 ``(n, n)`` or ``(B, n, n)``. The first step is a measurement of the prior, as in the
    filters. Tracks are processed ``chunk_tracks`` at a time (default: about 2e5 track-steps) to
    bound memory.
    """
    _check(truth, motion, model, P0, R, form)
    if not 0 < detection_probability <= 1:
        raise ConfigError(f"detection_probability must be in (0, 1], got {detection_probability}")
    B, K, n = truth.shape
    dtype, device = truth.dtype, truth.device
    F = motion.F(dt, dtype, device)
    Q = motion.Q(dt, q, dtype, device)
    P0 = P0.to(dtype)
    chunk = chunk_tracks or max(1, 200_000 // K)
    if form == "information_averaged":
        if Q.dim() > 2:
            raise ConfigError("the information-averaged bound needs one q for all runs")
        info = torch.zeros(1, K, n, n, dtype=dtype, device=device)
        for s in range(0, B, chunk):
            R_c = R if R.dim() == 2 else R[s : s + chunk]
            info += measurement_information(truth[s : s + chunk], model, R_c, detection_probability).sum(0, keepdim=True)
        J0 = _inverse_spd(P0).mean(0) if P0.dim() == 3 else _inverse_spd(P0)
        P = _filtering_pass(info / B, J0, F, Q)
        Ps = rts_backward(None, P, F, Q).P if smoothing else None
        return BoundResult(form, P[0], None if Ps is None else Ps[0], motion.pos_idx, motion.vel_idx)

    sum_f = torch.zeros(K, n, n, dtype=dtype, device=device)
    sum_s = torch.zeros(K, n, n, dtype=dtype, device=device) if smoothing else None
    pos_f = truth.new_empty(B, K)
    pos_s = truth.new_empty(B, K) if smoothing else None
    for s in range(0, B, chunk):
        e = min(B, s + chunk)
        R_c = R if R.dim() == 2 else R[s:e]
        r = _per_trajectory(measurement_information(truth[s:e], model, R_c, detection_probability), F,
                            Q if Q.dim() == 2 else Q[s:e], P0 if P0.dim() == 2 else P0[s:e], motion, smoothing)
        sum_f += r.filtering * (e - s)
        pos_f[s:e] = r.per_track_position
        if smoothing:
            sum_s += r.smoothing * (e - s)
            pos_s[s:e] = r.per_track_position_smoothing
    return BoundResult(form, sum_f / B, None if sum_s is None else sum_s / B, motion.pos_idx, motion.vel_idx, pos_f, pos_s)


def _per_trajectory(info: torch.Tensor, F: torch.Tensor, Q: torch.Tensor, P0: torch.Tensor, motion: KinematicModel,
                    smoothing: bool) -> BoundResult:
    """The per-trajectory bound of measurement information ``info (B, K, n, n)`` (module docstring)."""
    B, K, n = info.shape[:3]
    J0 = _inverse_spd(P0.to(info.dtype)).expand(B, n, n)
    P = _filtering_pass(info, J0, F, Q)
    Ps = rts_backward(None, P, F, Q).P if smoothing else None
    pos = list(motion.pos_idx)
    track = lambda C: torch.diagonal(C, dim1=-2, dim2=-1)[..., pos].sum(-1).sqrt()
    return BoundResult("per_trajectory", P.mean(0), None if Ps is None else Ps.mean(0), motion.pos_idx,
                       motion.vel_idx, track(P), None if Ps is None else track(Ps))


def information_bound(info: torch.Tensor, motion: KinematicModel, dt: float, q, P0: torch.Tensor,
                      smoothing: bool = True) -> BoundResult:
    """The per-trajectory PCRB of :func:`pcrb` from measurement information already formed:
    ``info (B, K, n, n)`` per trajectory and step (another sensor's, e.g. range-Doppler maps':
    :mod:`pmsr_nn.tbd.bound`), ``q`` and ``P0 (n, n)`` or ``(B, n, n)`` as for :func:`pcrb`."""
    n = motion.dim_x
    if info.dim() != 4 or info.shape[-2:] != (n, n):
        raise ConfigError(f"info must be (B, K, {n}, {n}); got {tuple(info.shape)}")
    if bool((torch.linalg.cholesky_ex(P0)[1] != 0).any()):
        raise ConfigError("P0 is not positive definite")
    F = motion.F(dt, info.dtype, info.device)
    Q = motion.Q(dt, q, info.dtype, info.device)
    return _per_trajectory(info, F, Q, P0, motion, smoothing)


def finite_memory_pcrb(truth: torch.Tensor, motion: KinematicModel, dt: float, q, model: MeasurementModel | LinearMeasurementModel,
                       R: torch.Tensor, P0: torch.Tensor, memory: int, chunk_windows: int = 4096) -> BoundResult:
    """Filtering PCRB for an estimator that reads only the last ``memory`` scans.

    The bound at step ``k`` is the filtering bound of scans ``max(0, k - memory + 1) .. k`` alone,
    with prior covariance ``P0`` on the state at the first of them (for a learned tracker: the
    spread of the states it was trained on). A network whose estimate at ``k`` reads a finite
    window (an MDFNN reads ``2 (M - 1) + 1`` scans) cannot beat this bound, which sits above the
    ordinary filtering bound that uses every past scan. Per-trajectory form, filtering only;
    ``truth (B, K, n)``, ``R`` ``(m, m)`` or per run ``(B, m, m)``.
    """
    _check(truth, motion, model, P0, R, "per_trajectory")
    if memory < 1:
        raise ConfigError(f"memory must be at least 1 scan, got {memory}")
    B, K, n = truth.shape
    L = min(memory, K)
    F = motion.F(dt, truth.dtype, truth.device)
    Q = motion.Q(dt, q, truth.dtype, truth.device)
    if Q.dim() > 2:
        raise ConfigError("finite_memory_pcrb needs one q for all runs")
    J0 = _inverse_spd(P0.to(truth.dtype))
    info = measurement_information(truth, model, R)  # (B, K, n, n)
    J0_b = J0.expand(B, n, n) if J0.dim() == 2 else J0
    sum_P = torch.empty(K, n, n, dtype=truth.dtype, device=truth.device)
    pos = list(motion.pos_idx)
    per_track = truth.new_empty(B, K)
    head = _filtering_pass(info[:, :L], J0_b, F, Q)  # steps k < L read every scan so far
    sum_P[:L] = head.mean(0)
    per_track[:, :L] = torch.diagonal(head, dim1=-2, dim2=-1)[..., pos].sum(-1).sqrt()
    # Steps k >= L: a window of L scans ending at k. Windows of all runs are one batch.
    starts = torch.arange(1, K - L + 1, device=truth.device)
    per_chunk = max(1, chunk_windows // B)
    for c in range(0, len(starts), per_chunk):
        s = starts[c : c + per_chunk]
        idx = s[:, None] + torch.arange(L, device=truth.device)  # (S, L)
        win = info[:, idx].reshape(B * len(s), L, n, n)
        J = J0_b.repeat_interleave(len(s), 0) if J0_b.shape[0] == B else J0_b.expand(B * len(s), n, n)
        P_last = _filtering_pass(win, J, F, Q)[:, -1].reshape(B, len(s), n, n)
        k = s + L - 1
        sum_P[k] = P_last.mean(0)
        per_track[:, k] = torch.diagonal(P_last, dim1=-2, dim2=-1)[..., pos].sum(-1).sqrt()
    return BoundResult(f"finite memory ({L} scans)", sum_P, None, motion.pos_idx, motion.vel_idx, per_track, None)
