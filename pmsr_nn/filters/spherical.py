"""SI+KF: spherical-interpolation position fixes from bistatic ranges, then a linear Kalman filter.

Spherical interpolation (SI) is the first of the two closed-form localisers of Malanowski and
Kulpa, "Two methods for target localization in multistatic passive radar", IEEE TAES 48(1),
2012 (after Smith and Abel's SI for range differences). The code below is our own derivation.

The linear equations
--------------------
Pair ``n`` = (transmitter ``t_j``, receiver ``r_n``) measures ``R_n = |p - t_j| + |p - r_n|``.
With ``D_j = |p - t_j|`` (one unknown per transmitter), ``|p - r_n| = R_n - D_j``; squaring it
and subtracting ``D_j^2 = |p - t_j|^2`` removes ``|p|^2``::

    (r_n - t_j) . p  -  R_n D_j  =  (|r_n|^2 - |t_j|^2 - R_n^2) / 2

(with the transmitter at the origin: ``s_n . p' - R_n R_t = (|s_n|^2 - R_n^2) / 2``). Stacked
over the pairs this is ``S p - Rm D = b``, linear in ``theta = (p, D_1..D_Nt)``: ``S (N, d)``
holds the receiver-transmitter vectors, ``Rm (N, Nt)`` has ``R_n`` in the column of pair ``n``'s
transmitter (a block structure with several transmitters). SI treats ``D`` as free unknowns
(dropping the constraint ``D_j = |p - t_j|``; keeping it is the spherical-intersection method):

1. for given ``D``, ``p = (S^T W S)^-1 S^T W (b + Rm D)`` (least squares);
2. substituting, ``D`` must make ``b + Rm D`` lie in the column space of ``S``: with the
   ``W``-orthogonal projector ``P = I - S (S^T W S)^-1 S^T W`` onto its complement,
   ``D = -(Rm^T W P Rm)^-1 Rm^T W P b``;
3. then ``p`` from step 1.

This is exactly the weighted least-squares solution of the joint system in ``theta``
(Frisch-Waugh-Lovell); the tests check it against ``torch.linalg.lstsq``.

Solvability: ``d_lin + N_t`` unknowns (``d_lin`` the dimension of the receiver-transmitter
vectors, see 3-D below; ``N_t`` transmitters with at least one detection) need at least that many
valid ranges in general position, and ``S`` must have rank ``d_lin``. With one transmitter: at
least ``d + 1`` receivers not all on a line (2-D) / in a plane (3-D) through the transmitter; the
default 1 Tx / 3 Rx geometry in 2-D is exactly determined. A pair's range only helps ``p`` when
its transmitter has another detected pair. The geometry is checked once (all pairs valid,
:class:`~pmsr_nn.errors.ConfigError` if unsolvable); each fix is checked again with its own
detections: fewer valid ranges than unknowns, or an ill-conditioned normal matrix, gives a NaN
fix (a missed fix, which the Kalman filter skips).

Weighting
---------
To first order a range error ``e_n`` enters equation ``n`` as ``|p - r_n| e_n``. ``"uniform"``
weights every valid equation alike (the plain SI); ``"distance"`` (default) solves once
uniformly, then again with ``W = diag(1 / |p_hat - r_n|^2)``, the inverse covariance of the
equation errors (the BLUE of the linear system for equal range deviations; a per-fix range
deviation cancels out, so the fix itself does not depend on it). When the system is exactly
determined (default geometry, all ranges present) weighting changes nothing.

SI is not efficient. To first order SI fits ``dR = J dp + c eps`` with an extra nuisance
direction ``c_n = -R_n / |p - r_n|`` (the dropped constraint), so its covariance exceeds the
Cramer-Rao bound ``(J^T R^-1 J)^-1``, ``J`` rows ``u_tx + u_rx``, unless ``J^T c = 0``. On the
default geometry (targets east of the transmitter, receivers 7.5-8.3 km west) the gap is large:
at (5, 3) km, SI's position variance is 46x the CRB (trace 255 vs 5.5 m^2 per 1 m^2 of
range variance), so :func:`fix_covariance` offers both: ``method="si"`` is the first-order
covariance of the SI estimator itself (what the Kalman filter must be told), ``method="crb"``
the bound, which is also the first-order covariance of the maximum-likelihood fix. A few
Gauss-Newton steps on the range equations (``refine_steps`` of :func:`spherical_interpolation`)
turn the SI fix into that ML fix at small noise; the fixes are then nearly efficient and the CRB is
the covariance to use.

3-D
---
When the sensors do not lie in one horizontal plane, the system is solved in 3-D as above.
When they all share one height ``z0`` (ground sensors, what :meth:`Geometry.lifted` makes), the
vertical column of ``S`` is zero: the system is solved for the horizontal position and ``D``,
and the altitude follows from ``(z - z0)^2 = D_j^2 - |p_h - t_j,h|^2`` (averaged over the
transmitters with detections). Its sign is ambiguous (a mirror target below the ground gives
the same ranges); we take the target **above** the sensors, ``z = z0 + sqrt(max(., 0))``
(negative estimates of the square, from noise, give ``z = z0``). The altitude is weakly observable
at low elevation: its first-order deviation grows like ``1 / (z - z0)`` and is infinite on the
ground. With 1 Tx / 3 Rx on the ground the 3-D problem is exactly determined (3 ranges, 3
coordinates), so there the SI fix is the exact intersection, i.e. the ML fix, and its covariance
is the CRB. :func:`si_kf` by default uses only the horizontal part of ground-sensor fixes (see
there for why). Gauss-Newton refinement on ground geometries iterates on ``(x, y, (z - z0)^2)``,
in which the ranges stay smooth on the ground.

Fixes are computed in float64 in a frame centred on the sensors and scaled to their spread (well
conditioned at any position), then returned in the dtype of the input.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import torch

from ..errors import ConfigError
from ..measurements import LinearMeasurementModel, MeasurementModel
from ..motion import KinematicModel
from .gaussian import Gaussian, symmetrise
from .kalman import FilterResult, kalman_filter

WEIGHTINGS = ("distance", "uniform")
COVARIANCE_METHODS = ("si", "crb")

RCOND = 1e-10
"""Smallest eigenvalue ratio of an equilibrated (unit-diagonal) normal or covariance matrix for a
fix to count as well conditioned; below it the fix is missed. In float64 a solve loses about
``log10(1 / RCOND)`` of its ~16 digits, so a kept fix keeps at least 6."""

NO_FIX_POSITION_STD_M = 1.0e5
"""Position deviation of the initial state of a run without a single valid fix (centred on the
sensors): effectively uninformative, and such a run's estimates stay there."""

_WORK = torch.float64


# --------------------------------------------------------------------------------------------
# Geometry in the working frame
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Frame:
    """The geometry in a frame centred on the sensors and scaled by their spread (float64, CPU)."""

    dim: int  # spatial dimension of positions
    d_lin: int  # unknown position coordinates of the linear system (2 for ground sensors in 3-D)
    ground: bool  # 3-D geometry with every sensor at the same height
    centre: torch.Tensor  # (dim,) m
    scale: float  # m per working unit
    tx: torch.Tensor  # (N, dim) pair transmitter, working units
    rx: torch.Tensor  # (N, dim) pair receiver, working units
    onehot: torch.Tensor  # (N, Nt) pair -> used transmitter
    tx_used: torch.Tensor  # (Nt, dim) positions of the used transmitters, working units

    @property
    def n_pairs(self) -> int:
        return self.tx.shape[0]

    @property
    def n_tx(self) -> int:
        return self.onehot.shape[1]

    def to(self, device) -> "_Frame":
        move = {k: getattr(self, k).to(device) for k in ("centre", "tx", "rx", "onehot", "tx_used")}
        return _Frame(self.dim, self.d_lin, self.ground, scale=self.scale, **move)


@functools.lru_cache(maxsize=32)
def _frame(geometry) -> _Frame:
    """Working frame of a geometry; :class:`ConfigError` if SI cannot solve it."""
    tx = geometry.pair_tx_positions(_WORK)
    rx = geometry.pair_rx_positions(_WORK)
    sensors = torch.cat([tx, rx])
    centre = sensors.mean(0)
    scale = float(torch.linalg.vector_norm(sensors - centre, dim=-1).max())
    dim = geometry.dim
    heights = sensors[:, -1]
    ground = dim == 3 and float(heights.max() - heights.min()) <= 1e-9 * scale
    d_lin = 2 if ground else dim
    used = sorted({i for i, _ in geometry.pairs})
    col = {t: c for c, t in enumerate(used)}
    onehot = torch.zeros(geometry.n_pairs, len(used), dtype=_WORK)
    for n, (i, _) in enumerate(geometry.pairs):
        onehot[n, col[i]] = 1.0
    tx_used = torch.tensor([geometry.transmitters[i].position_m for i in used], dtype=_WORK)
    frame = _Frame(dim, d_lin, ground, centre, scale, (tx - centre) / scale, (rx - centre) / scale, onehot,
                   (tx_used - centre) / scale)
    need = d_lin + len(used)
    if geometry.n_pairs < need:
        raise ConfigError(
            f"spherical interpolation needs at least {need} bistatic pairs for {d_lin} position coordinates and "
            f"{len(used)} transmitter range(s) (e.g. one transmitter needs {d_lin + 1} receivers); this geometry has "
            f"{geometry.n_pairs}"
        )
    S = (frame.rx - frame.tx)[:, :d_lin]
    if int(torch.linalg.matrix_rank(S)) < d_lin:
        where = "on one line" if d_lin == 2 else "in one plane"
        raise ConfigError(
            f"spherical interpolation cannot solve this geometry: the receiver-transmitter baselines lie {where}, "
            f"so the {d_lin}-D position is not determined (rank {int(torch.linalg.matrix_rank(S))} < {d_lin})"
        )
    return frame


# --------------------------------------------------------------------------------------------
# Small batched linear algebra
# --------------------------------------------------------------------------------------------
def _well_conditioned(M: torch.Tensor, rcond: float = RCOND, scale: torch.Tensor | None = None) -> torch.Tensor:
    """``(...,)`` bool: symmetric ``M (..., n, n)`` is finite and positive definite with an
    equilibrated eigenvalue ratio above ``rcond``.

    Equilibration divides by ``sqrt(diag(M))`` on both sides (unit diagonal), or by
    ``sqrt(scale (..., n))`` when given; then the smallest eigenvalue must exceed ``rcond`` times
    the largest (own diagonal) or ``rcond`` itself (given scale)."""
    finite = torch.isfinite(M).all(-1).all(-1)
    M = torch.where(finite[..., None, None], M, torch.eye(M.shape[-1], dtype=M.dtype, device=M.device))
    diag = torch.diagonal(M, dim1=-2, dim2=-1)
    pos = (diag > 0).all(-1)
    s = (diag if scale is None else scale).clamp_min(1e-300).rsqrt()
    eig = torch.linalg.eigvalsh(symmetrise(M * s[..., :, None] * s[..., None, :]))
    floor = rcond * eig[..., -1] if scale is None else torch.full_like(eig[..., 0], rcond)
    return finite & pos & (eig[..., 0] > floor)


def _safe(M: torch.Tensor, ok: torch.Tensor) -> torch.Tensor:
    """``M`` where ``ok``, the identity elsewhere (so that a batched solve never fails)."""
    eye = torch.eye(M.shape[-1], dtype=M.dtype, device=M.device)
    return torch.where(ok[..., None, None], M, eye)


def _solve_spd(M: torch.Tensor, rhs: torch.Tensor, ok: torch.Tensor) -> torch.Tensor:
    return torch.linalg.solve(_safe(M, ok), rhs)


# --------------------------------------------------------------------------------------------
# Spherical interpolation
# --------------------------------------------------------------------------------------------
def _check_ranges(ranges: torch.Tensor, n_pairs: int) -> None:
    if not isinstance(ranges, torch.Tensor) or ranges.dim() < 1 or ranges.shape[-1] != n_pairs:
        shape = tuple(ranges.shape) if isinstance(ranges, torch.Tensor) else type(ranges).__name__
        raise ConfigError(f"ranges must be a tensor (..., {n_pairs}) with one bistatic range per pair; got {shape}")
    if not ranges.is_floating_point():
        raise ConfigError(f"ranges must be floating point, got {ranges.dtype}")
    inf = torch.isinf(ranges)
    if bool(inf.any()):
        idx = tuple(inf.nonzero()[0].tolist())
        raise ConfigError(f"range at index {idx} is infinite (use NaN for a missed detection)")


def _linear_solve(R: torch.Tensor, valid: torch.Tensor, w: torch.Tensor, fr: _Frame):
    """One weighted SI solve in working units.

    ``R, w (..., N)`` (invalid rows: R = 0, w = 0), ``valid (..., N)``. Returns the linear-system
    position ``p_lin (..., d_lin)``, transmitter distances ``D (..., Nt)``, the active
    transmitters ``(..., Nt)`` and ``ok (...,)``.
    """
    d = fr.d_lin
    S = (fr.rx - fr.tx)[:, :d]  # (N, d)
    c = (fr.rx * fr.rx).sum(-1) - (fr.tx * fr.tx).sum(-1)  # (N,)
    b = 0.5 * (c - R * R)  # (..., N)
    Rm = R.unsqueeze(-1) * fr.onehot  # (..., N, Nt)
    Y0 = torch.cat([Rm, b.unsqueeze(-1)], dim=-1)  # (..., N, Nt + 1)
    # Step 1: least squares in p for the columns [Rm, b]; G = S^T W S.
    G = torch.einsum("nd,...n,ne->...de", S, w, S)
    okG = _well_conditioned(G)
    X = _solve_spd(G, torch.einsum("nd,...n,...nk->...dk", S, w, Y0), okG)  # (..., d, Nt + 1)
    # Step 2: the W-orthogonal complement of S: P Y0 = Y0 - S X.
    PY = Y0 - torch.einsum("nd,...dk->...nk", S, X)
    active = (valid.unsqueeze(-1) & (fr.onehot > 0)).any(-2)  # (..., Nt)
    inactive = (~active).to(R.dtype)
    M = torch.einsum("...nj,...n,...nk->...jk", Rm, w, PY[..., :-1]) + torch.diag_embed(inactive)
    y = torch.einsum("...nj,...n,...n->...j", Rm, w, PY[..., -1])
    M = symmetrise(M)
    # Condition of M relative to Rm^T W Rm (before projection): how much of each transmitter's
    # range column lies outside the span of S. Its own diagonal would hide a 1x1 M near zero.
    ref = torch.einsum("...nj,...n,...nj->...j", Rm, w, Rm) + inactive
    okM = _well_conditioned(M, scale=ref)
    D = -_solve_spd(M, y.unsqueeze(-1), okM).squeeze(-1)
    # Step 3: p = X_b + X_Rm D.
    p = X[..., -1] + (X[..., :-1] @ D.unsqueeze(-1)).squeeze(-1)
    enough = valid.sum(-1) >= d + active.sum(-1)
    ok = okG & okM & enough & torch.isfinite(p).all(-1) & torch.isfinite(D).all(-1)
    return p, D, active, ok


def _squared_height(p_h: torch.Tensor, D: torch.Tensor, active: torch.Tensor, fr: _Frame) -> torch.Tensor:
    """Ground geometries: ``h = (z - z0)^2`` (working units, may be negative from noise) from the
    linear-system solution, averaged over the transmitters with detections, ``(...,)``."""
    rho2 = ((p_h.unsqueeze(-2) - fr.tx_used[:, :2]) ** 2).sum(-1)  # (..., Nt)
    a = active.to(D.dtype)
    return ((D * D - rho2) * a).sum(-1) / a.sum(-1).clamp_min(1.0)


def _solution(p_lin, D, active, fr: _Frame) -> torch.Tensor:
    """The solved parameters ``s``: the position, or ``(x, y, h)`` for ground geometries."""
    if not fr.ground:
        return p_lin
    return torch.cat([p_lin, _squared_height(p_lin, D, active, fr).unsqueeze(-1)], dim=-1)


def _to_position(s: torch.Tensor, fr: _Frame) -> torch.Tensor:
    """Working-frame position ``(..., dim)``: ground geometries take the root ``z - z0 >= 0``."""
    if not fr.ground:
        return s
    return torch.cat([s[..., :2], s[..., 2:].clamp_min(0.0).sqrt()], dim=-1)


def _distances(pos: torch.Tensor, fr: _Frame):
    """Distances to each pair's transmitter and receiver ``(..., N)`` and the unit vectors ``(..., N, dim)``."""
    dt_vec = pos.unsqueeze(-2) - fr.tx
    dr_vec = pos.unsqueeze(-2) - fr.rx
    d_t = torch.linalg.vector_norm(dt_vec, dim=-1).clamp_min(1e-12)
    d_r = torch.linalg.vector_norm(dr_vec, dim=-1).clamp_min(1e-12)
    return d_t, d_r, dt_vec / d_t.unsqueeze(-1), dr_vec / d_r.unsqueeze(-1)


def _range_jacobian(s: torch.Tensor, fr: _Frame):
    """Model ranges ``(..., N)`` and their Jacobian ``(..., N, dim)`` in the solved parameters
    (position, or ``(x, y, h)`` for ground geometries, where the ranges are smooth in ``h``:
    ``d |p - q| / dh = 1 / (2 |p - q|)``, defined for ``h < 0`` too)."""
    if not fr.ground:
        d_t, d_r, u_t, u_r = _distances(s, fr)
        return d_t + d_r, u_t + u_r
    # Ground sensors sit at height 0 of the working frame.
    off_t = s[..., :2].unsqueeze(-2) - fr.tx[:, :2]
    off_r = s[..., :2].unsqueeze(-2) - fr.rx[:, :2]
    h = s[..., 2:]
    d_t = ((off_t * off_t).sum(-1) + h).clamp_min(1e-24).sqrt()
    d_r = ((off_r * off_r).sum(-1) + h).clamp_min(1e-24).sqrt()
    J = torch.cat([off_t / d_t.unsqueeze(-1) + off_r / d_r.unsqueeze(-1), (0.5 / d_t + 0.5 / d_r).unsqueeze(-1)], -1)
    return d_t + d_r, J


def _gauss_newton(s: torch.Tensor, R: torch.Tensor, valid: torch.Tensor, ok: torch.Tensor, fr: _Frame, steps: int):
    """``steps`` Gauss-Newton iterations of the (equally weighted) range least squares from ``s``."""
    w = valid.to(R.dtype)
    for _ in range(steps):
        rng, J = _range_jacobian(s, fr)
        F = torch.einsum("...nd,...n,...ne->...de", J, w, J)
        okF = ok & _well_conditioned(F)
        step = _solve_spd(F, torch.einsum("...nd,...n->...d", J, (R - rng) * w).unsqueeze(-1), okF).squeeze(-1)
        s = s + torch.where(okF.unsqueeze(-1), step, torch.zeros_like(step))
    return s


def _si(ranges: torch.Tensor, geometry, weighting: str, refine_steps: int):
    """Working-frame SI: position ``(..., dim)`` (NaN where missed), valid rows, ok, frame."""
    if weighting not in WEIGHTINGS:
        raise ConfigError(f"weighting must be one of {WEIGHTINGS}, got {weighting!r}")
    if not (isinstance(refine_steps, int) and refine_steps >= 0):
        raise ConfigError(f"refine_steps must be a non-negative integer, got {refine_steps!r}")
    fr = _frame(geometry).to(ranges.device)
    _check_ranges(ranges, fr.n_pairs)
    valid = ~torch.isnan(ranges)
    R = torch.where(valid, ranges.to(_WORK) / fr.scale, torch.zeros((), dtype=_WORK, device=ranges.device))
    w = valid.to(_WORK)
    p_lin, D, active, ok = _linear_solve(R, valid, w, fr)
    sol = _solution(p_lin, D, active, fr)
    if weighting == "distance":
        pos = _to_position(sol, fr)
        _, d_r, _, _ = _distances(torch.where(ok.unsqueeze(-1), pos, torch.zeros_like(pos)), fr)
        p_lin, D, active, ok2 = _linear_solve(R, valid, w / (d_r * d_r), fr)
        sol = _solution(p_lin, D, active, fr)
        ok = ok & ok2
    if refine_steps:
        sol = _gauss_newton(sol, R, valid, ok, fr, refine_steps)
        ok = ok & torch.isfinite(sol).all(-1)
    pos = _to_position(sol, fr)
    pos = torch.where(ok.unsqueeze(-1), pos, torch.full_like(pos, math.nan))
    return pos, valid, ok, fr


def spherical_interpolation(ranges: torch.Tensor, geometry, *, weighting: str = "distance",
                            refine_steps: int = 0) -> torch.Tensor:
    """Position fixes ``(..., d)`` in m from bistatic ranges ``(..., N)`` in m (pair order of ``geometry``).

    Any leading axes (runs, steps) are batched. NaN ranges are missed detections: their rows get
    zero weight, and a fix with fewer valid ranges than unknowns (``d_lin`` + transmitters with a
    detection) or an ill-conditioned system is NaN. ``weighting`` is ``"distance"`` (two-pass,
    default) or ``"uniform"`` (module docstring). ``refine_steps`` Gauss-Newton steps on the range
    equations turn the SI fix into the maximum-likelihood fix at small noise (0: plain SI; 2 is
    plenty at the default noise). 3-D ground geometries give the altitude above the sensors.
    Computed in float64, returned in the dtype and on the device of ``ranges``.
    """
    pos, _, _, fr = _si(ranges, geometry, weighting, refine_steps)
    return (fr.centre + fr.scale * pos).to(ranges.dtype)


# --------------------------------------------------------------------------------------------
# Fix covariance
# --------------------------------------------------------------------------------------------
def _range_std(range_std, lead_shape, device) -> torch.Tensor:
    s = torch.as_tensor(range_std, dtype=_WORK, device=device)
    try:
        s = torch.broadcast_to(s, lead_shape)
    except RuntimeError:
        raise ConfigError(f"range_std must be a scalar or broadcast to the fixes' shape {tuple(lead_shape)}; "
                          f"got shape {tuple(s.shape)}") from None
    if not bool((torch.isfinite(s) & (s > 0)).all()):
        raise ConfigError("range_std must be finite and positive")
    return s


def _covariances(pos: torch.Tensor, sigma: torch.Tensor, valid: torch.Tensor, fr: _Frame, method: str, weighting: str):
    """First-order fix covariance ``(..., dim, dim)`` and its horizontal block ``(..., 2, 2)`` when
    the altitude of a ground geometry is dropped (``None`` otherwise), in working units, with
    ``sigma (...,)`` in working units. Not yet checked for conditioning."""
    if method not in COVARIANCE_METHODS:
        raise ConfigError(f"covariance method must be one of {COVARIANCE_METHODS}, got {method!r}")
    if weighting not in WEIGHTINGS:
        raise ConfigError(f"weighting must be one of {WEIGHTINGS}, got {weighting!r}")
    finite = torch.isfinite(pos).all(-1)
    pos = torch.where(finite.unsqueeze(-1), pos, torch.zeros_like(pos))
    w = valid.to(_WORK)
    var = (sigma * sigma).unsqueeze(-1)  # (..., 1)
    d_t, d_r, u_t, u_r = _distances(pos, fr)
    eye = lambda n: torch.eye(n, dtype=_WORK, device=pos.device)  # noqa: E731
    if method == "crb":
        J = u_t + u_r  # (..., N, dim)
        info = torch.einsum("...nd,...n,...ne->...de", J, w / var, J)
        ok = _well_conditioned(info, 1e-300)
        cov = torch.where(ok[..., None, None], torch.linalg.inv(_safe(info, ok)), torch.full_like(info, math.nan))
        horiz = None
        if fr.ground:
            # The horizontal block of the bound with the altitude unknown: invert the information
            # in (x, y, h = (z - z0)^2), which stays regular on the ground (in z it does not).
            _, Jq = _range_jacobian(torch.cat([pos[..., :2], pos[..., 2:] ** 2], -1), fr)
            info_q = torch.einsum("...nd,...n,...ne->...de", Jq, w / var, Jq)
            ok_q = _well_conditioned(info_q, 1e-300)
            horiz = torch.where(ok_q[..., None, None], torch.linalg.inv(_safe(info_q, ok_q)), torch.full_like(info_q, math.nan))
            horiz = symmetrise(horiz[..., :2, :2])
        return symmetrise(cov), horiz
    # SI: theta = (A^T W A)^-1 A^T W b with A = [S, -Rm]; at the noise-free ranges of the fix the
    # residual is zero and d theta = -(A^T W A)^-1 A^T W diag(|p - r_n|) dR.
    R = (d_t + d_r) * w
    d = fr.d_lin
    S = (fr.rx - fr.tx)[:, :d].expand(*R.shape, d)
    A = torch.cat([S, -R.unsqueeze(-1) * fr.onehot], dim=-1)  # (..., N, d + Nt)
    wd = w / (d_r * d_r) if weighting == "distance" else w
    active = (valid.unsqueeze(-1) & (fr.onehot > 0)).any(-2)
    N_ = torch.einsum("...na,...n,...nb->...ab", A, wd, A)
    pad = torch.cat([torch.zeros_like(active[..., :1]).expand(*active.shape[:-1], d), ~active], -1).to(_WORK)
    N_ = N_ + torch.diag_embed(pad)
    okN = _well_conditioned(N_, 1e-300)
    Ninv = torch.linalg.inv(_safe(N_, okN))
    L = -(Ninv @ (A * (wd * d_r).unsqueeze(-1)).transpose(-1, -2))  # (..., d + Nt, N)
    cov_theta = (L * var.unsqueeze(-1)) @ L.transpose(-1, -2)
    cov_theta = torch.where(okN[..., None, None], cov_theta, torch.full_like(cov_theta, math.nan))
    if not fr.ground:
        return symmetrise(cov_theta[..., :d, :d]), None
    # Altitude h = sqrt(mean_j(D_j^2 - |p_h - t_j|^2)): dh = mean_j(D_j dD_j - (p_h - t_j) . dp_h) / h.
    a = active.to(_WORK)
    a = a / a.sum(-1, keepdim=True).clamp_min(1.0)
    h = pos[..., 2]
    D = d_t.unsqueeze(-1).mul(fr.onehot).amax(-2)  # (..., Nt): distance to each used transmitter
    gz = torch.cat([-(a.unsqueeze(-1) * (pos[..., :2].unsqueeze(-2) - fr.tx_used[:, :2])).sum(-2), a * D], -1)
    gz = gz / h.unsqueeze(-1)  # inf on the ground: the altitude is not observable there
    Gm = torch.cat([torch.cat([eye(d), torch.zeros(d, fr.n_tx, dtype=_WORK, device=pos.device)], -1)
                    .expand(*gz.shape[:-1], d, d + fr.n_tx), gz.unsqueeze(-2)], -2)
    cov = Gm @ cov_theta @ Gm.transpose(-1, -2)
    return symmetrise(cov), symmetrise(cov_theta[..., :d, :d])


def _usable(cov: torch.Tensor, max_std: float | None) -> torch.Tensor:
    ok = _well_conditioned(cov)
    if max_std is not None:
        ok = ok & (torch.diagonal(cov, dim1=-2, dim2=-1).max(-1).values <= max_std**2)
    return ok


def fix_covariance(positions: torch.Tensor, geometry, range_std, *, method: str = "si", weighting: str = "distance",
                   valid: torch.Tensor | None = None) -> torch.Tensor:
    """First-order covariance ``(..., d, d)`` in m^2 of fixes ``positions (..., d)``.

    ``range_std`` (m) is a scalar or broadcasts to ``positions.shape[:-1]`` (one deviation per
    fix, shared by its pairs). ``method="si"`` (default) propagates the range noise through the
    SI estimator with ``weighting`` (the covariance of :func:`spherical_interpolation` fixes made
    with the same weighting and ``refine_steps=0``); ``method="crb"`` is ``(J^T W J)^-1`` with
    ``J`` rows ``u_tx + u_rx`` and ``W = 1 / range_std^2``: the Cramer-Rao bound, and the
    covariance of refined (maximum-likelihood) fixes. Both are evaluated at the fix (its
    noise-free ranges). ``valid (..., N)`` marks the pairs that had a range (default all).

    A NaN fix, or one whose covariance is non-finite or ill-conditioned (e.g. the altitude of a
    fix on the ground plane of ground sensors), gets a NaN matrix.
    """
    fr = _frame(geometry).to(positions.device)
    if not isinstance(positions, torch.Tensor) or positions.dim() < 1 or positions.shape[-1] != fr.dim:
        shape = tuple(positions.shape) if isinstance(positions, torch.Tensor) else type(positions).__name__
        raise ConfigError(f"positions must be a tensor (..., {fr.dim}); got {shape}")
    if bool(torch.isinf(positions).any()):
        raise ConfigError("positions must be finite (NaN marks a missed fix)")
    lead = positions.shape[:-1]
    sigma = _range_std(range_std, lead, positions.device) / fr.scale
    if valid is None:
        valid = torch.ones(*lead, fr.n_pairs, dtype=torch.bool, device=positions.device)
    elif tuple(valid.shape) != (*lead, fr.n_pairs):
        raise ConfigError(f"valid must be a boolean ({', '.join(map(str, lead))}, {fr.n_pairs}); got {tuple(valid.shape)}")
    pos = (positions.to(_WORK) - fr.centre) / fr.scale
    cov, _ = _covariances(pos, sigma, valid.bool(), fr, method, weighting)
    ok = _usable(cov, None) & torch.isfinite(pos).all(-1)
    cov = torch.where(ok[..., None, None], cov * fr.scale**2, torch.full_like(cov, math.nan))
    return cov.to(positions.dtype)


# --------------------------------------------------------------------------------------------
# SI + KF
# --------------------------------------------------------------------------------------------
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


def range_rows(model: MeasurementModel) -> list[int]:
    """Indices of the bistatic-range rows of ``model``'s measurement vector, in pair order."""
    if not isinstance(model, MeasurementModel) or "range" not in model.components:
        comps = getattr(model, "components", None)
        raise ConfigError(f"SI+KF needs a measurement model with a 'range' component; got components {comps}")
    labels = model.labels
    return [labels.index(f"range_{n + 1}") for n in range(model.n_pairs)]


def si_kf(z: torch.Tensor, model: MeasurementModel, motion: KinematicModel, dt: float, q,
          noise_std: torch.Tensor | None = None, prior: Gaussian | None = None, *,
          weighting: str = "distance", refine_steps: int = 0, covariance: str | None = None,
          init_velocity_std_mps: float = 50.0, init_acceleration_std_mps2: float = 1.0,
          init_altitude_std_m: float = 1000.0, max_fix_std_m: float | None = None,
          use_altitude: bool = False, min_altitude_snr: float = 3.0) -> SIKFResult:
    """SI+KF: SI position fixes from the range rows of ``z (B, K, m)``, then a linear Kalman filter.

    ``model`` says where the ranges are (its ``"range"`` rows; other rows are ignored);
    ``noise_std (B, C)`` are per-run deviations per component of ``model`` (``None``: the model's
    own); the range deviation sets each fix's covariance (:func:`fix_covariance`, method
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
        sigma = torch.full((B,), model.noise_std[comp], dtype=_WORK, device=dev)
    else:
        ns = torch.as_tensor(noise_std, dtype=_WORK, device=dev)
        if ns.shape != (B, len(model.components)):
            raise ConfigError(f"noise_std must be per run (B={B}, {len(model.components)}) in the order {model.components}; "
                              f"got {tuple(ns.shape)}")
        sigma = ns[:, comp]
    sigma = _range_std(sigma, (B,), dev)

    # Fixes and their covariances, all runs and steps at once (working frame).
    pos, valid, ok, fr = _si(z[..., rows], g, weighting, refine_steps)
    s_w = (sigma / fr.scale).unsqueeze(-1).expand(B, K)
    cov, horiz = _covariances(pos, s_w, valid, fr, covariance, weighting)
    full_ok = ok & _usable(cov, None if max_fix_std_m is None else max_fix_std_m / fr.scale)
    if fr.ground:  # the altitude only on request, and where its deviation is small against it
        var_z = torch.diagonal(cov, dim1=-2, dim2=-1)[..., 2]
        full_ok = full_ok & (min_altitude_snr**2 * var_z < pos[..., 2] ** 2) & use_altitude
    d = fr.dim
    keep = full_ok.unsqueeze(-1).expand(B, K, d).clone()  # per coordinate
    R = _safe(cov, full_ok)
    alt_dropped = torch.zeros(B, K, dtype=torch.bool, device=dev)
    if fr.ground:
        h_ok = ok & ~full_ok & _usable(horiz, None if max_fix_std_m is None else max_fix_std_m / fr.scale)
        keep[..., :2] |= h_ok.unsqueeze(-1)
        R_h = torch.zeros_like(R)
        R_h[..., :2, :2] = _safe(horiz, h_ok)
        R_h[..., 2, 2] = 1.0
        R = torch.where(h_ok[..., None, None], R_h, R)
        alt_dropped = h_ok
    rejected = ok & ~keep.any(-1)
    fixes_w = torch.where(keep, pos, torch.full_like(pos, math.nan))
    fixes = fr.centre + fr.scale * fixes_w
    # A unit placeholder (m^2) where a fix is missed: never read, must only be a valid covariance.
    R = torch.where(keep.any(-1)[..., None, None], R * fr.scale**2, torch.eye(d, dtype=_WORK, device=dev))
    R = symmetrise(R)

    init_step = torch.full((B,), -1, dtype=torch.long, device=dev)
    if prior is None:
        prior, init_step, fixes = _initial_prior(fixes, R, keep, alt_dropped, pos, fr, motion, dt, init_velocity_std_mps,
                                                 init_acceleration_std_mps2, init_altitude_std_m)
    fixes, R = fixes.to(dtype), R.to(dtype)
    prior = Gaussian(prior.x.to(dtype), prior.P.to(dtype))
    lin = LinearMeasurementModel.position(motion.dim_x, motion.pos_idx, 1.0)
    res = kalman_filter(prior, fixes, motion, dt, q, lin, R)
    return SIKFResult(res.x, res.P, res.nu, res.nis, fixes, R, rejected, alt_dropped, init_step, prior)


def _initial_prior(fixes, R, keep, alt_dropped, pos_w, fr: _Frame, motion: KinematicModel, dt: float,
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
    P0 = torch.where(has[..., None, None], P0, NO_FIX_POSITION_STD_M**2 * torch.eye(d, dtype=_WORK, device=dev))
    n = motion.dim_x
    x = torch.zeros(B, n, dtype=_WORK, device=dev)
    P = torch.zeros(B, n, n, dtype=_WORK, device=dev)
    pi = torch.tensor(motion.pos_idx, device=dev)
    x[:, pi] = p0
    P[:, pi[:, None], pi[None, :]] = P0
    P[:, list(motion.vel_idx), list(motion.vel_idx)] = sd_v**2
    if motion.order >= 3:
        P[:, list(motion.acc_idx), list(motion.acc_idx)] = sd_a**2
    # Back to step 0: x_0 = F(-k0 dt) x_k0 (so that K predictions later it is x_k0 again).
    k_used = torch.where(has, k0, torch.zeros_like(k0))
    Fb = motion.F(-dt * k_used.to(_WORK), _WORK, dev)  # (B, n, n)
    x = (Fb @ x.unsqueeze(-1)).squeeze(-1)
    P = symmetrise(Fb @ P @ Fb.transpose(-1, -2))
    fixes = fixes.clone()
    fixes[runs[has], k0[has]] = math.nan
    init_step = torch.where(has, k0, torch.full_like(k0, -1))
    return Gaussian(x.to(fixes.dtype), P.to(fixes.dtype)), init_step, fixes
