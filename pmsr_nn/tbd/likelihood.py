"""The likelihood ratio of range-Doppler maps given a target state (the seed's Eqs. 12-16, 30), and
the maximum-likelihood map amplitude behind the online SNR estimate (Eqs. 18-20, 25).

Cell ``(d, u)`` of map ``i`` holds ``z = g + v`` with ``v`` circular complex Gaussian of power
``sigma^2``; its magnitude is Rician given a target of response magnitude ``|g|`` and Rayleigh
without one, so each cell contributes the log ratio

    ``l(z | g) = -|g|^2 / sigma^2 + log I0(2 |z| |g| / sigma^2)``

and a map's log likelihood ratio is the sum over cells (independent noise). Only a *sub-area*
around the state's own cell is summed (Eq. 30): ``half = h`` gives ``(2h+1) x (2h+1)`` cells, and
``half = None`` the whole map (every Doppler row, and every range column the triangle reaches:
the others have ``g = 0`` exactly and add nothing). ``log I0`` is evaluated as ``log(i0e(x)) + x``,
exact and overflow-free.

The amplitude ``A`` of ``g = A G`` (``G`` the unit response) that maximises a state's likelihood
solves ``A = sum |z| G rho(2 A |z| G / sigma^2) / sum G^2`` with ``rho = I1 / I0``; we solve it by
Newton's method on the exact Rician density (:func:`ml_amplitude`; the seed's Eq. 19 uses the
asymptotic expansion of ``I0``). Shapes: ``B`` runs, ``M`` particles, ``P`` maps,
``S`` cells of a sub-area.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .maps import MapGrid, triangle


@dataclass
class CellValues:
    """The cells a batch of states reads: ``absz`` (map magnitudes) and ``G`` (unit response
    magnitudes), each ``(B, M, P, S)`` float32; cells outside the map have ``G = 0``."""

    absz: torch.Tensor
    G: torch.Tensor


def _offsets(half: int, n: int) -> torch.Tensor:
    return torch.arange(-min(half, n), min(half, n) + 1)


def gather_cells(maps_abs: torch.Tensor, d: torch.Tensor, u: torch.Tensor, lobe_cells: float,
                 half: int | None) -> CellValues:
    """Magnitudes and unit responses of the sub-area cells of states at fractional cells
    ``d, u (B, M, P)`` (Doppler row, range column) in maps ``maps_abs (B, P, D, U)``."""
    B, P, D, U = maps_abs.shape
    M = d.shape[1]
    if half is None:  # every row; the columns the triangle reaches
        rows = torch.arange(D).view(1, 1, 1, D).expand(B, M, P, D)
        cw = math.ceil(lobe_cells)
        cols = torch.round(u).to(torch.int64)[..., None] + torch.arange(-cw, cw + 1)
    else:
        rows = torch.round(d).to(torch.int64)[..., None] + _offsets(half, D)
        cols = torch.round(u).to(torch.int64)[..., None] + _offsets(half, U)
    # the response is separable: a factor per row and per column, zero outside the map
    row_f = torch.sinc(rows - d[..., None]).abs() * ((rows >= 0) & (rows < D))
    col_f = triangle((cols - u[..., None]) / lobe_cells) * ((cols >= 0) & (cols < U))
    G = (row_f[..., :, None] * col_f[..., None, :]).reshape(B, M, P, -1)
    flat = (torch.arange(P).view(1, 1, P, 1) * D + rows.clamp(0, D - 1))[..., :, None] * U + cols.clamp(0, U - 1)[..., None, :]
    absz = maps_abs.reshape(B, -1).gather(1, flat.reshape(B, -1)).view(B, M, P, -1)
    return CellValues(absz, G.to(absz.dtype))


def log_i0(x: torch.Tensor) -> torch.Tensor:
    """``log I0(x)`` for ``x >= 0`` without overflow."""
    return torch.log(torch.special.i0e(x)) + x


def log_likelihood_ratio(cells: CellValues, amplitude: torch.Tensor, noise_power: float) -> torch.Tensor:
    """Per state and map ``(B, M, P)``: the summed cell log ratios for amplitude ``amplitude``
    (broadcast against ``(B, M, P)``, e.g. ``(B, 1, P)``)."""
    g = cells.G * (amplitude.to(cells.G.dtype)[..., None] / noise_power)  # g / sigma^2
    x = cells.absz * g
    x = x + x  # 2 |z| g / sigma^2
    # log I0(x) - |g|^2 / sigma^2 = log i0e(x) + g (2|z| - g) / sigma^2, in place where it can be
    return torch.log_(torch.special.i0e(x)).add_(x).sub_(g.mul_(g).mul_(noise_power)).sum(-1)


def ml_amplitude(cells: CellValues, noise_power: float, iterations: int = 30, tol: float = 1e-6) -> torch.Tensor:
    """The amplitude maximising each state's likelihood on its cells ``(B, M, P)`` (0 where the
    state reads no cell).

    The score is ``f(A) = sum |z| G rho(2 A |z| G / sigma^2) - A sum G^2``, concave in ``A`` (``rho``
    is concave on ``x >= 0``) with ``f(0) = 0``: a positive maximum exists iff ``f'(0) > 0``, i.e.
    ``sum (|z| G)^2 > sigma^2 sum G^2``, and then Newton's method from ``A0 = sum |z| G / sum G^2``
    (where ``f <= 0``, right of the root) descends to it monotonically. Stops when every step is
    below ``tol`` relative, or after ``iterations``."""
    zG = cells.absz.to(torch.float64) * cells.G.to(torch.float64)
    G2 = (cells.G.to(torch.float64) ** 2).sum(-1)
    safe = torch.where(G2 > 0, G2, torch.ones((), dtype=G2.dtype))
    a = zG.sum(-1) / safe
    positive = (zG * zG).sum(-1) > noise_power * G2
    c = 2.0 * zG / noise_power
    for _ in range(iterations):
        x = a[..., None] * c
        rho = torch.special.i1e(x) / torch.special.i0e(x)
        drho = torch.where(x > 1e-6, 1.0 - rho / x.clamp(min=1e-6) - rho * rho, torch.full_like(x, 0.5))
        f = (zG * rho).sum(-1) - a * G2
        df = (zG * drho * c).sum(-1) - G2
        step = torch.where(df < 0, f / df, torch.zeros((), dtype=f.dtype))
        a = (a - step).clamp(min=0.0)
        if bool((step.abs() <= tol * a.clamp(min=1e-12)).all()):
            break
    return torch.where((G2 > 0) & positive, a, torch.zeros((), dtype=a.dtype)).to(cells.absz.dtype)


def max_ml_amplitude(cells: CellValues, valid: torch.Tensor, noise_power: float, iterations: int = 30,
                     candidates: int | None = 256) -> torch.Tensor:
    """The largest maximum-likelihood amplitude over the valid states ``valid (B, M)`` of each run
    and map ``(B, P)`` (the seed's estimate below Eq. 24). Every state's ML amplitude is at most its
    starting value ``sum |z| G / sum G^2`` (``rho < 1``), so only the ``candidates`` states with the
    largest starting values are iterated (``None``: all, exact). The pre-selection can miss the
    maximum where noise inflates a starting value more than the iteration deflates it; the cost
    of iterating every particle (the special functions on ``B x M x P x S`` cells, 30 times) is
    what it saves."""
    zG = (cells.absz * cells.G).sum(-1)
    G2 = (cells.G * cells.G).sum(-1)
    a0 = torch.where(valid[..., None] & (G2 > 0), zG / torch.where(G2 > 0, G2, torch.ones((), dtype=G2.dtype)),
                     torch.zeros((), dtype=zG.dtype))  # (B, M, P)
    M = a0.shape[1]
    k = M if candidates is None else min(candidates, M)
    _, idx = a0.topk(k, dim=1)  # (B, k, P)
    S = cells.absz.shape[-1]
    sub = CellValues(cells.absz.gather(1, idx[..., None].expand(-1, -1, -1, S)),
                     cells.G.gather(1, idx[..., None].expand(-1, -1, -1, S)))
    return ml_amplitude(sub, noise_power, iterations).amax(1)


def cells_of_states(grid: MapGrid, rng: torch.Tensor, dop: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Fractional cells ``(d, u)`` float32 of ranges / Dopplers ``(B, M, P)``."""
    d, u = grid.cell_coordinates(rng, dop)
    return d.to(torch.float32), u.to(torch.float32)
