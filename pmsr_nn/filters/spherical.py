"""Spherical interpolation (SI): position fixes from the bistatic ranges of one scan.

Spherical interpolation is the first of the two closed-form localisers of Malanowski and
Kulpa, "Two methods for target localization in multistatic passive radar", IEEE TAES 48(1),
2012 (after Smith and Abel's SI for range differences). The code below is our own derivation.
The fixes' first-order covariance is :mod:`.fix_covariance`; the Kalman filter over them,
SI+KF, is :mod:`.si_kf`.

The linear equations
--------------------
Pair ``s`` = (transmitter ``t_j``, receiver ``r_s``) measures the bistatic range
``rho_s = |p - t_j| + |p - r_s|``. With ``D_j = |p - t_j|`` (one unknown per transmitter),
``|p - r_s| = rho_s - D_j``; squaring it and subtracting ``D_j^2 = |p - t_j|^2`` removes
``|p|^2``::

    (r_s - t_j) . p  -  rho_s D_j  =  (|r_s|^2 - |t_j|^2 - rho_s^2) / 2

(with the transmitter at the origin: ``e_s . p' - rho_s D = (|e_s|^2 - rho_s^2) / 2``). Stacked
over the ``S`` pairs this is ``E p - Rho D = b``, linear in ``theta = (p, D_1..D_n_tx)``:
``E (S, d)`` holds the receiver-transmitter vectors, ``Rho (S, n_tx)`` has ``rho_s`` in the
column of pair ``s``'s transmitter (a block structure with several transmitters). SI treats
``D`` as free unknowns (dropping the constraint ``D_j = |p - t_j|``; keeping it is the
spherical-intersection method):

1. for given ``D``, ``p = (E^T W E)^-1 E^T W (b + Rho D)`` (least squares);
2. substituting, ``D`` must make ``b + Rho D`` lie in the column space of ``E``: with the
   ``W``-orthogonal projector ``Pi = I - E (E^T W E)^-1 E^T W`` onto its complement,
   ``D = -(Rho^T W Pi Rho)^-1 Rho^T W Pi b``;
3. then ``p`` from step 1.

This is exactly the weighted least-squares solution of the joint system in ``theta``
(Frisch-Waugh-Lovell); the tests check it against ``torch.linalg.lstsq``.

Solvability: ``d_lin + n_tx`` unknowns (``d_lin`` the dimension of the receiver-transmitter
vectors, see 3-D below; ``n_tx`` transmitters with at least one detection) need at least that
many valid ranges in general position, and ``E`` must have rank ``d_lin``. With one transmitter:
at least ``d + 1`` receivers not all on a line (2-D) / in a plane (3-D) through the transmitter;
the default 1 Tx / 3 Rx geometry in 2-D is exactly determined. A pair's range only helps ``p``
when its transmitter has another detected pair. The geometry is checked once (all pairs valid,
:class:`~pmsr_nn.errors.ConfigError` if unsolvable); each fix is checked again with its own
detections: fewer valid ranges than unknowns, or an ill-conditioned normal matrix, gives a NaN
fix (a missed fix, which a Kalman filter skips).

Weighting
---------
To first order a range error ``e_s`` enters equation ``s`` as ``|p - r_s| e_s``. ``"uniform"``
weights every valid equation alike (the plain SI); ``"distance"`` (default) solves once
uniformly, then again with ``W = diag(1 / |p_hat - r_s|^2)``, the inverse covariance of the
equation errors (the BLUE of the linear system for equal range deviations; a per-fix range
deviation cancels out, so the fix itself does not depend on it). When the system is exactly
determined (default geometry, all ranges present) weighting changes nothing.

SI is not efficient (:mod:`.fix_covariance`). A few Gauss-Newton steps on the range equations
(``refine_steps`` of :func:`spherical_interpolation`) turn the SI fix into the maximum-likelihood
fix at small noise.

3-D
---
When the sensors do not lie in one horizontal plane, the system is solved in 3-D as above.
When they all share one height ``z0`` (ground sensors, what :meth:`Geometry.lifted` makes), the
vertical column of ``E`` is zero: the system is solved for the horizontal position and ``D``,
and the altitude follows from ``(z - z0)^2 = D_j^2 - |p_h - t_j,h|^2`` (averaged over the
transmitters with detections). Its sign is ambiguous (a mirror target below the ground gives
the same ranges); we take the target **above** the sensors, ``z = z0 + sqrt(max(., 0))``
(negative estimates of the square, from noise, give ``z = z0``). The altitude is weakly observable
at low elevation: its first-order deviation grows like ``1 / (z - z0)`` and is infinite on the
ground. With 1 Tx / 3 Rx on the ground the 3-D problem is exactly determined (3 ranges, 3
coordinates), so there the SI fix is the exact intersection, i.e. the ML fix, and its covariance
is the CRB. Gauss-Newton refinement on ground geometries iterates on ``(x, y, (z - z0)^2)``,
in which the ranges stay smooth on the ground.

Fixes are computed in float64 in a frame centred on the sensors and scaled to their spread (well
conditioned at any position), then returned in the dtype of the input. The working frame and the
small batched linear algebra here are shared with :mod:`.fix_covariance` and :mod:`.si_kf`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import torch

from ..errors import ConfigError
from ..measurements import MeasurementModel
from .gaussian import symmetrise

WEIGHTINGS = ("distance", "uniform")

RCOND = 1e-10
"""Smallest eigenvalue ratio of an equilibrated (unit-diagonal) normal or covariance matrix for a
fix to count as well conditioned; below it the fix is missed. In float64 a solve loses about
``log10(1 / RCOND)`` of its ~16 digits, so a kept fix keeps at least 6."""

WORK_DTYPE = torch.float64
"""The dtype every fix and covariance is computed in."""

FRAME_DEVICE = torch.device("cpu")  # device: a geometry's frame is made once, here, and moved (WorkingFrame.to)
"""Where :func:`working_frame` makes (and caches) a geometry's frame; callers move it to their
device (:meth:`WorkingFrame.to`)."""


# --------------------------------------------------------------------------------------------
# Geometry in the working frame
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class WorkingFrame:
    """The geometry in a frame centred on the sensors and scaled by their spread (float64, CPU)."""

    dim: int  # spatial dimension of positions
    d_lin: int  # unknown position coordinates of the linear system (2 for ground sensors in 3-D)
    ground: bool  # 3-D geometry with every sensor at the same height
    centre: torch.Tensor  # (dim,) m
    scale: float  # m per working unit
    tx: torch.Tensor  # (S, dim) pair transmitter, working units
    rx: torch.Tensor  # (S, dim) pair receiver, working units
    onehot: torch.Tensor  # (S, n_tx) pair -> used transmitter
    tx_used: torch.Tensor  # (n_tx, dim) positions of the used transmitters, working units

    @property
    def n_pairs(self) -> int:
        return self.tx.shape[0]

    @property
    def n_tx(self) -> int:
        return self.onehot.shape[1]

    def to(self, device) -> "WorkingFrame":
        move = {k: getattr(self, k).to(device) for k in ("centre", "tx", "rx", "onehot", "tx_used")}
        return WorkingFrame(self.dim, self.d_lin, self.ground, scale=self.scale, **move)


@functools.lru_cache(maxsize=32)
def working_frame(geometry) -> WorkingFrame:
    """Working frame of a geometry, on :data:`FRAME_DEVICE`; :class:`ConfigError` if SI cannot solve it."""
    tx = geometry.pair_tx_positions(WORK_DTYPE, FRAME_DEVICE)
    rx = geometry.pair_rx_positions(WORK_DTYPE, FRAME_DEVICE)
    sensors = torch.cat([tx, rx])
    centre = sensors.mean(0)
    scale = float(torch.linalg.vector_norm(sensors - centre, dim=-1).max())
    dim = geometry.dim
    heights = sensors[:, -1]
    ground = dim == 3 and float(heights.max() - heights.min()) <= 1e-9 * scale
    d_lin = 2 if ground else dim
    used = sorted({i for i, _ in geometry.pairs})
    col = {t: c for c, t in enumerate(used)}
    onehot = torch.zeros(geometry.n_pairs, len(used), dtype=WORK_DTYPE, device=FRAME_DEVICE)
    for s, (i, _) in enumerate(geometry.pairs):
        onehot[s, col[i]] = 1.0
    tx_used = torch.tensor([geometry.transmitters[i].position_m for i in used], dtype=WORK_DTYPE, device=FRAME_DEVICE)
    frame = WorkingFrame(dim, d_lin, ground, centre, scale, (tx - centre) / scale, (rx - centre) / scale, onehot,
                         (tx_used - centre) / scale)
    need = d_lin + len(used)
    if geometry.n_pairs < need:
        raise ConfigError(
            f"spherical interpolation needs at least {need} bistatic pairs for {d_lin} position coordinates and "
            f"{len(used)} transmitter range(s) (e.g. one transmitter needs {d_lin + 1} receivers); this geometry has "
            f"{geometry.n_pairs}"
        )
    E = (frame.rx - frame.tx)[:, :d_lin]
    if int(torch.linalg.matrix_rank(E)) < d_lin:
        where = "on one line" if d_lin == 2 else "in one plane"
        raise ConfigError(
            f"spherical interpolation cannot solve this geometry: the receiver-transmitter baselines lie {where}, "
            f"so the {d_lin}-D position is not determined (rank {int(torch.linalg.matrix_rank(E))} < {d_lin})"
        )
    return frame


# --------------------------------------------------------------------------------------------
# Small batched linear algebra
# --------------------------------------------------------------------------------------------
def well_conditioned(M: torch.Tensor, rcond: float = RCOND, scale: torch.Tensor | None = None) -> torch.Tensor:
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


def or_identity(M: torch.Tensor, ok: torch.Tensor) -> torch.Tensor:
    """``M`` where ``ok``, the identity elsewhere (so that a batched solve never fails)."""
    eye = torch.eye(M.shape[-1], dtype=M.dtype, device=M.device)
    return torch.where(ok[..., None, None], M, eye)


def _solve_spd(M: torch.Tensor, rhs: torch.Tensor, ok: torch.Tensor) -> torch.Tensor:
    return torch.linalg.solve(or_identity(M, ok), rhs)


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


def _linear_solve(rho: torch.Tensor, valid: torch.Tensor, w: torch.Tensor, fr: WorkingFrame):
    """One weighted SI solve in working units.

    Bistatic ranges ``rho (..., S)`` and weights ``w (..., S)`` (invalid rows: 0 and 0),
    ``valid (..., S)``. Returns the linear-system position ``p_lin (..., d_lin)``, transmitter
    distances ``D (..., n_tx)``, the active transmitters ``(..., n_tx)`` and ``ok (...,)``.
    """
    d = fr.d_lin
    E = (fr.rx - fr.tx)[:, :d]  # (S, d)
    c = (fr.rx * fr.rx).sum(-1) - (fr.tx * fr.tx).sum(-1)  # (S,)
    b = 0.5 * (c - rho * rho)  # (..., S)
    Rho = rho.unsqueeze(-1) * fr.onehot  # (..., S, n_tx)
    Y0 = torch.cat([Rho, b.unsqueeze(-1)], dim=-1)  # (..., S, n_tx + 1)
    # Step 1: least squares in p for the columns [Rho, b]; G = E^T W E.
    G = torch.einsum("nd,...n,ne->...de", E, w, E)
    okG = well_conditioned(G)
    X = _solve_spd(G, torch.einsum("nd,...n,...nk->...dk", E, w, Y0), okG)  # (..., d, n_tx + 1)
    # Step 2: the W-orthogonal complement of E: Pi Y0 = Y0 - E X.
    PiY = Y0 - torch.einsum("nd,...dk->...nk", E, X)
    active = (valid.unsqueeze(-1) & (fr.onehot > 0)).any(-2)  # (..., n_tx)
    inactive = (~active).to(rho.dtype)
    G_D = torch.einsum("...nj,...n,...nk->...jk", Rho, w, PiY[..., :-1]) + torch.diag_embed(inactive)
    y = torch.einsum("...nj,...n,...n->...j", Rho, w, PiY[..., -1])
    G_D = symmetrise(G_D)
    # Condition of G_D relative to Rho^T W Rho (before projection): how much of each
    # transmitter's range column lies outside the span of E. Its own diagonal would hide a 1x1
    # G_D near zero.
    ref = torch.einsum("...nj,...n,...nj->...j", Rho, w, Rho) + inactive
    okD = well_conditioned(G_D, scale=ref)
    D = -_solve_spd(G_D, y.unsqueeze(-1), okD).squeeze(-1)
    # Step 3: p = X_b + X_Rho D.
    p = X[..., -1] + (X[..., :-1] @ D.unsqueeze(-1)).squeeze(-1)
    enough = valid.sum(-1) >= d + active.sum(-1)
    ok = okG & okD & enough & torch.isfinite(p).all(-1) & torch.isfinite(D).all(-1)
    return p, D, active, ok


def _squared_height(p_h: torch.Tensor, D: torch.Tensor, active: torch.Tensor, fr: WorkingFrame) -> torch.Tensor:
    """Ground geometries: ``h = (z - z0)^2`` (working units, may be negative from noise) from the
    linear-system solution, averaged over the transmitters with detections, ``(...,)``."""
    rho2 = ((p_h.unsqueeze(-2) - fr.tx_used[:, :2]) ** 2).sum(-1)  # (..., n_tx)
    a = active.to(D.dtype)
    return ((D * D - rho2) * a).sum(-1) / a.sum(-1).clamp_min(1.0)


def _solution(p_lin, D, active, fr: WorkingFrame) -> torch.Tensor:
    """The solved parameters ``s``: the position, or ``(x, y, h)`` for ground geometries."""
    if not fr.ground:
        return p_lin
    return torch.cat([p_lin, _squared_height(p_lin, D, active, fr).unsqueeze(-1)], dim=-1)


def _to_position(s: torch.Tensor, fr: WorkingFrame) -> torch.Tensor:
    """Working-frame position ``(..., dim)``: ground geometries take the root ``z - z0 >= 0``."""
    if not fr.ground:
        return s
    return torch.cat([s[..., :2], s[..., 2:].clamp_min(0.0).sqrt()], dim=-1)


def sensor_distances(pos: torch.Tensor, fr: WorkingFrame):
    """Distances of working-frame positions ``pos (..., dim)`` to each pair's transmitter and
    receiver ``(..., S)``, and the unit vectors from them ``(..., S, dim)``."""
    dt_vec = pos.unsqueeze(-2) - fr.tx
    dr_vec = pos.unsqueeze(-2) - fr.rx
    d_t = torch.linalg.vector_norm(dt_vec, dim=-1).clamp_min(1e-12)
    d_r = torch.linalg.vector_norm(dr_vec, dim=-1).clamp_min(1e-12)
    return d_t, d_r, dt_vec / d_t.unsqueeze(-1), dr_vec / d_r.unsqueeze(-1)


def range_jacobian(s: torch.Tensor, fr: WorkingFrame):
    """Model ranges ``(..., S)`` and their Jacobian ``(..., S, dim)`` in the solved parameters ``s``
    (position, or ``(x, y, h)`` for ground geometries, where the ranges are smooth in ``h``:
    ``d |p - q| / dh = 1 / (2 |p - q|)``, defined for ``h < 0`` too)."""
    if not fr.ground:
        d_t, d_r, u_t, u_r = sensor_distances(s, fr)
        return d_t + d_r, u_t + u_r
    # Ground sensors sit at height 0 of the working frame.
    off_t = s[..., :2].unsqueeze(-2) - fr.tx[:, :2]
    off_r = s[..., :2].unsqueeze(-2) - fr.rx[:, :2]
    h = s[..., 2:]
    d_t = ((off_t * off_t).sum(-1) + h).clamp_min(1e-24).sqrt()
    d_r = ((off_r * off_r).sum(-1) + h).clamp_min(1e-24).sqrt()
    J = torch.cat([off_t / d_t.unsqueeze(-1) + off_r / d_r.unsqueeze(-1), (0.5 / d_t + 0.5 / d_r).unsqueeze(-1)], -1)
    return d_t + d_r, J


def _gauss_newton(s: torch.Tensor, rho: torch.Tensor, valid: torch.Tensor, ok: torch.Tensor, fr: WorkingFrame,
                  steps: int):
    """``steps`` Gauss-Newton iterations of the (equally weighted) least squares of the ranges
    ``rho (..., S)`` from the solved parameters ``s``."""
    w = valid.to(rho.dtype)
    for _ in range(steps):
        model_rho, J = range_jacobian(s, fr)
        normal = torch.einsum("...nd,...n,...ne->...de", J, w, J)
        ok_normal = ok & well_conditioned(normal)
        step = _solve_spd(normal, torch.einsum("...nd,...n->...d", J, (rho - model_rho) * w).unsqueeze(-1),
                          ok_normal).squeeze(-1)
        s = s + torch.where(ok_normal.unsqueeze(-1), step, torch.zeros_like(step))
    return s


def working_fixes(ranges: torch.Tensor, geometry, weighting: str, refine_steps: int):
    """SI in the working frame of ``geometry`` (see :func:`spherical_interpolation`): positions
    ``(..., dim)`` (NaN where missed), the valid ranges ``(..., S)``, ``ok (...,)`` and the
    frame."""
    if weighting not in WEIGHTINGS:
        raise ConfigError(f"weighting must be one of {WEIGHTINGS}, got {weighting!r}")
    if not (isinstance(refine_steps, int) and refine_steps >= 0):
        raise ConfigError(f"refine_steps must be a non-negative integer, got {refine_steps!r}")
    fr = working_frame(geometry).to(ranges.device)
    _check_ranges(ranges, fr.n_pairs)
    valid = ~torch.isnan(ranges)
    rho = torch.where(valid, ranges.to(WORK_DTYPE) / fr.scale, torch.zeros((), dtype=WORK_DTYPE, device=ranges.device))
    w = valid.to(WORK_DTYPE)
    p_lin, D, active, ok = _linear_solve(rho, valid, w, fr)
    sol = _solution(p_lin, D, active, fr)
    if weighting == "distance":
        pos = _to_position(sol, fr)
        _, d_r, _, _ = sensor_distances(torch.where(ok.unsqueeze(-1), pos, torch.zeros_like(pos)), fr)
        p_lin, D, active, ok2 = _linear_solve(rho, valid, w / (d_r * d_r), fr)
        sol = _solution(p_lin, D, active, fr)
        ok = ok & ok2
    if refine_steps:
        sol = _gauss_newton(sol, rho, valid, ok, fr, refine_steps)
        ok = ok & torch.isfinite(sol).all(-1)
    pos = _to_position(sol, fr)
    pos = torch.where(ok.unsqueeze(-1), pos, torch.full_like(pos, math.nan))
    return pos, valid, ok, fr


def spherical_interpolation(ranges: torch.Tensor, geometry, *, weighting: str = "distance",
                            refine_steps: int = 0) -> torch.Tensor:
    """Position fixes ``(..., d)`` in m from bistatic ranges ``(..., S)`` in m (pair order of ``geometry``).

    Any leading axes (runs, steps) are batched. NaN ranges are missed detections: their rows get
    zero weight, and a fix with fewer valid ranges than unknowns (``d_lin`` + transmitters with a
    detection) or an ill-conditioned system is NaN. ``weighting`` is ``"distance"`` (two-pass,
    default) or ``"uniform"`` (module docstring). ``refine_steps`` Gauss-Newton steps on the range
    equations turn the SI fix into the maximum-likelihood fix at small noise (0: plain SI; 2 is
    plenty at the default noise). 3-D ground geometries give the altitude above the sensors.
    Computed in float64, returned in the dtype and on the device of ``ranges``.
    """
    pos, _, _, fr = working_fixes(ranges, geometry, weighting, refine_steps)
    return (fr.centre + fr.scale * pos).to(ranges.dtype)


def range_rows(model: MeasurementModel) -> list[int]:
    """Indices of the bistatic-range rows of ``model``'s measurement vector, in pair order."""
    if not isinstance(model, MeasurementModel) or "range" not in model.components:
        comps = getattr(model, "components", None)
        raise ConfigError(f"SI+KF needs a measurement model with a 'range' component; got components {comps}")
    labels = model.labels
    return [labels.index(f"range_{s + 1}") for s in range(model.n_pairs)]
