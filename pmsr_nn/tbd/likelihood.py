"""The likelihood ratio of range-Doppler maps given a target state (the seed's Eqs. 12-16, 30), and
the maximum-likelihood map amplitude behind the online SNR estimate (Eqs. 18-20, 25).

Cell ``(d, u)`` of map ``i`` holds ``z = g + v`` with ``v`` circular complex Gaussian of power
``sigma^2``; its magnitude is Rician given a target of response magnitude ``|g|`` and Rayleigh
without one, so each cell contributes the log ratio

    ``l(z | g) = -|g|^2 / sigma^2 + log I0(2 |z| |g| / sigma^2)``

and a map's log likelihood ratio is the sum over cells (independent noise). Only a *sub-area*
around the state's own cell is summed (Eq. 30): ``half = h`` gives ``(2h+1) x (2h+1)`` cells, and
``half = None`` the whole map (every Doppler row, and every range column the triangle reaches:
the others have ``g = 0`` exactly and add nothing). ``log I0(x)`` is evaluated as
``x + log i0e(x)`` (overflow-free), ``log i0e`` by the polynomial approximations of Abramowitz &
Stegun 9.8.1-9.8.2 (:func:`log_i0e`: within 1e-6 of the exact value in float32, at a fraction of
the cost of ``torch.special.i0e``), over chunks of states whose temporaries stay in cache.

The amplitude ``A`` of ``g = A G`` (``G`` the unit response) that maximises a state's likelihood
solves ``A = sum |z| G rho(2 A |z| G / sigma^2) / sum G^2`` with ``rho = I1 / I0``; we solve it by
Newton's method on the exact Rician density (:func:`ml_amplitude`; the seed's Eq. 19 uses the
asymptotic expansion of ``I0``). Shapes: ``B`` runs, ``M`` particles, ``S`` maps (one per pair),
``C`` cells of a sub-area.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .maps import MapGrid, triangle


@dataclass
class CellValues:
    """The cells a batch of states reads: ``absz`` (map magnitudes) and ``G`` (unit response
    magnitudes), each ``(B, M, S, C)`` float32; cells outside the map have ``G = 0``."""

    absz: torch.Tensor
    G: torch.Tensor


def _offsets(half: int, n: int, device) -> torch.Tensor:
    return torch.arange(-min(half, n), min(half, n) + 1, device=device)


def gather_cells(maps_abs: torch.Tensor, d: torch.Tensor, u: torch.Tensor, lobe_cells: float,
                 half: int | None) -> CellValues:
    """Magnitudes and unit responses of the sub-area cells of states at fractional cells
    ``d, u (B, M, S)`` (Doppler row, range column) in maps ``maps_abs (B, S, D, U)``, gathered in
    chunks of states of about :data:`LIKELIHOOD_CHUNK_CELLS` cells (cache-sized temporaries)."""
    B, S, D, U = maps_abs.shape
    M = d.shape[1]
    n_rows = D if half is None else 2 * min(half, D) + 1
    n_cols = 2 * math.ceil(lobe_cells) + 1 if half is None else 2 * min(half, U) + 1
    absz = maps_abs.new_empty(B, M, S, n_rows * n_cols)
    G = maps_abs.new_empty(B, M, S, n_rows * n_cols)
    step = max(1, LIKELIHOOD_CHUNK_CELLS // max(1, B * S * n_rows * n_cols))
    flat_maps = maps_abs.reshape(B, -1)
    for m in range(0, M, step):
        sl = slice(m, m + step)
        a, g = _gather_chunk(flat_maps, (S, D, U), d[:, sl], u[:, sl], lobe_cells, half)
        absz[:, sl], G[:, sl] = a, g
    return CellValues(absz, G)


def _gather_chunk(flat_maps: torch.Tensor, shape: tuple[int, int, int], d: torch.Tensor, u: torch.Tensor,
                  lobe_cells: float, half: int | None) -> tuple[torch.Tensor, torch.Tensor]:
    B, M = d.shape[:2]
    G, flat = sub_area(shape, d, u, lobe_cells, half)
    absz = flat_maps.gather(1, flat.reshape(B, -1)).view(B, M, shape[0], -1)
    return absz, G.to(absz.dtype)


def sub_area(shape: tuple[int, int, int], d: torch.Tensor, u: torch.Tensor, lobe_cells: float,
             half: int | None) -> tuple[torch.Tensor, torch.Tensor]:
    """The unit responses ``G`` and the flat indices into maps of ``shape = (S, D, U)`` (map ``p``'s
    cell ``(row, col)`` at ``(p D + row) U + col``; cells outside the map clamped to its edge, with
    ``G = 0``) of the sub-area cells of states at fractional cells ``d, u (B, M, S)``: each
    ``(B, M, S, C)``."""
    S, D, U = shape
    B, M = d.shape[:2]
    dev = d.device
    if half is None:  # every row; the columns the triangle reaches
        rows = torch.arange(D, device=dev).view(1, 1, 1, D).expand(B, M, S, D)
        cw = math.ceil(lobe_cells)
        cols = torch.round(u).to(torch.int64)[..., None] + torch.arange(-cw, cw + 1, device=dev)
    else:
        rows = torch.round(d).to(torch.int64)[..., None] + _offsets(half, D, dev)
        cols = torch.round(u).to(torch.int64)[..., None] + _offsets(half, U, dev)
    # the response is separable: a factor per row and per column, zero outside the map
    row_f = torch.sinc(rows - d[..., None]).abs() * ((rows >= 0) & (rows < D))
    col_f = triangle((cols - u[..., None]) / lobe_cells) * ((cols >= 0) & (cols < U))
    G = (row_f[..., :, None] * col_f[..., None, :]).reshape(B, M, S, -1)
    flat = ((torch.arange(S, device=dev).view(1, 1, S, 1) * D + rows.clamp(0, D - 1))[..., :, None] * U
            + cols.clamp(0, U - 1)[..., None, :])
    return G, flat.reshape(B, M, S, -1)


# Abramowitz & Stegun 9.8.1 (t = (x / 3.75)^2, x <= 3.75; stated error 1.6e-7 relative) and 9.8.2
# (s = 3.75 / x, x >= 3.75; 1.9e-7 absolute on x^1/2 e^-x I0(x) >= 0.39): at most 5e-7 in the log.
_I0_SMALL = (1.0, 3.5156229, 3.0899424, 1.2067492, 0.2659732, 0.0360768, 0.0045813)
_I0E_LARGE = (0.39894228, 0.01328592, 0.00225319, -0.00157565, 0.00916281, -0.02057706, 0.02635537,
              -0.01647633, 0.00392377)
# 9.8.3 (x^-1 I1(x), x <= 3.75; error below 8e-9) and 9.8.4 (x^1/2 e^-x I1(x), x >= 3.75; 2.2e-7).
_I1_SMALL = (0.5, 0.87890594, 0.51498869, 0.15084934, 0.02658733, 0.00301532, 0.00032411)
_I1E_LARGE = (0.39894228, -0.03988024, -0.00362018, 0.00163801, -0.01031555, 0.02282967, -0.02895312,
              0.01787654, -0.00420059)
LIKELIHOOD_CHUNK_CELLS = 1 << 16
"""Cells of one chunk of :func:`log_likelihood_ratio`: its float32 temporaries (256 KiB each) stay
in cache, where whole-batch temporaries (millions of cells) would be fresh memory each time."""


def _horner(coefficients: tuple[float, ...], t: torch.Tensor) -> torch.Tensor:
    p = torch.full_like(t, coefficients[-1])
    for c in coefficients[-2::-1]:
        p.mul_(t).add_(c)
    return p


def log_i0e(x: torch.Tensor) -> torch.Tensor:
    """``log(exp(-x) I0(x))`` for ``x >= 0`` (``log I0(x) = x + log_i0e(x)``), within 1e-6 of the
    exact value in float32 (tested against scipy's ``i0e`` in float64)."""
    small = _horner(_I0_SMALL, (x * (1 / 3.75)).square_()).log_().sub_(x)
    xl = x.clamp(min=3.75)
    large = _horner(_I0E_LARGE, xl.reciprocal().mul_(3.75)).div_(xl.sqrt_()).log_()  # (x^1/2 i0e(x)) / x^1/2
    return small.where(x <= 3.75, large)


def bessel_ratio(x: torch.Tensor) -> torch.Tensor:
    """``I1(x) / I0(x)`` for ``x >= 0`` (A&S 9.8.1-9.8.4), within 2e-6 of the exact ratio."""
    t = (x * (1 / 3.75)).square_()
    small = _horner(_I1_SMALL, t).mul_(x).div_(_horner(_I0_SMALL, t))  # x (x^-1 I1) / I0
    s = x.clamp(min=3.75).reciprocal_().mul_(3.75)
    large = _horner(_I1E_LARGE, s).div_(_horner(_I0E_LARGE, s))  # the factors x^-1/2 e^x cancel
    return small.where(x <= 3.75, large)


def log_i0(x: torch.Tensor) -> torch.Tensor:
    """``log I0(x)`` for ``x >= 0`` without overflow."""
    return log_i0e(x).add_(x)


def _chunk_log_likelihood_ratio(absz: torch.Tensor, G: torch.Tensor, amplitude: torch.Tensor,
                                noise_power: float) -> torch.Tensor:
    g = G * (amplitude[..., None] / noise_power)  # g / sigma^2
    x = absz * g
    x.add_(x)  # 2 |z| g / sigma^2
    # log I0(x) - |g|^2 / sigma^2 = log i0e(x) + x - g^2 sigma^2 (g here is g / sigma^2)
    return log_i0e(x).add_(x).sub_(g.mul_(g).mul_(noise_power)).sum(-1)


def log_likelihood_ratio(cells: CellValues, amplitude: torch.Tensor, noise_power: float) -> torch.Tensor:
    """Per state and map ``(B, M, S)``: the summed cell log ratios for amplitude ``amplitude``
    (broadcast against ``(B, M, S)``, e.g. ``(B, 1, S)``), in chunks of states of about
    :data:`LIKELIHOOD_CHUNK_CELLS` cells."""
    B, M, S, n_cells = cells.absz.shape
    amp = amplitude.to(cells.G.dtype).expand(B, M, S)
    step = max(1, LIKELIHOOD_CHUNK_CELLS // max(1, B * S * n_cells))  # states per chunk
    out = cells.absz.new_empty(B, M, S)
    for m in range(0, M, step):
        sl = slice(m, m + step)
        out[:, sl] = _chunk_log_likelihood_ratio(cells.absz[:, sl], cells.G[:, sl], amp[:, sl], noise_power)
    return out


def ml_amplitude(cells: CellValues, noise_power: float, iterations: int = 30, tol: float = 1e-6) -> torch.Tensor:
    """The amplitude maximising each state's likelihood on its cells ``(B, M, S)`` (0 where the
    state reads no cell).

    The score is ``f(A) = sum |z| G rho(2 A |z| G / sigma^2) - A sum G^2``, concave in ``A`` (``rho``
    is concave on ``x >= 0``) with ``f(0) = 0``: a positive maximum exists iff ``f'(0) > 0``, i.e.
    ``sum (|z| G)^2 > sigma^2 sum G^2``, and then Newton's method from ``A0 = sum |z| G / sum G^2``
    (where ``f <= 0``, right of the root) descends to it monotonically. Stops when every step is
    below ``tol`` relative, or after ``iterations``."""
    zG = cells.absz.to(torch.float64) * cells.G.to(torch.float64)
    G2 = (cells.G.to(torch.float64) ** 2).sum(-1)
    safe = torch.where(G2 > 0, G2, G2.new_ones(()))
    a = zG.sum(-1) / safe
    positive = (zG * zG).sum(-1) > noise_power * G2
    c = 2.0 * zG / noise_power
    for _ in range(iterations):
        x = a[..., None] * c
        rho = bessel_ratio(x)
        drho = torch.where(x > 1e-6, 1.0 - rho / x.clamp(min=1e-6) - rho * rho, torch.full_like(x, 0.5))
        f = (zG * rho).sum(-1) - a * G2
        df = (zG * drho * c).sum(-1) - G2
        step = torch.where(df < 0, f / df, f.new_zeros(()))
        a = (a - step).clamp(min=0.0)
        if bool((step.abs() <= tol * a.clamp(min=1e-12)).all()):
            break
    return torch.where((G2 > 0) & positive, a, a.new_zeros(())).to(cells.absz.dtype)


def max_ml_amplitude(cells: CellValues, valid: torch.Tensor, noise_power: float, iterations: int = 30,
                     candidates: int | None = 256) -> torch.Tensor:
    """The largest maximum-likelihood amplitude over the valid states ``valid (B, M)`` of each run
    and map ``(B, S)`` (the seed's estimate below Eq. 24), over the states
    :func:`candidate_ml_amplitudes` iterates."""
    return candidate_ml_amplitudes(cells, valid, noise_power, iterations, candidates)[0].amax(1)


def candidate_ml_amplitudes(cells: CellValues, valid: torch.Tensor, noise_power: float, iterations: int = 30,
                            candidates: int | None = 256) -> tuple[torch.Tensor, torch.Tensor]:
    """The maximum-likelihood amplitudes ``(B, k, S)`` of the ``k = candidates`` valid states
    (``valid (B, M)``) with the largest starting values per run and map, and those states' indices
    ``(B, k, S)`` into ``M``. Every state's ML amplitude is at most its starting value
    ``sum |z| G / sum G^2`` (``rho < 1``), so only those are iterated (``None``: all states, exact).
    The pre-selection can miss the maximum where noise inflates a starting value more than the
    iteration deflates it; the cost of iterating every particle (the special functions on
    ``B x M x S x C`` cells, 30 times) is what it saves."""
    zG = (cells.absz * cells.G).sum(-1)
    G2 = (cells.G * cells.G).sum(-1)
    a0 = torch.where(valid[..., None] & (G2 > 0), zG / torch.where(G2 > 0, G2, G2.new_ones(())),
                     zG.new_zeros(()))  # (B, M, S)
    M = a0.shape[1]
    k = M if candidates is None else min(candidates, M)
    _, idx = a0.topk(k, dim=1)  # (B, k, S)
    n_cells = cells.absz.shape[-1]
    sub = CellValues(cells.absz.gather(1, idx[..., None].expand(-1, -1, -1, n_cells)),
                     cells.G.gather(1, idx[..., None].expand(-1, -1, -1, n_cells)))
    return ml_amplitude(sub, noise_power, iterations), idx


def cells_of_states(grid: MapGrid, rng: torch.Tensor, dop: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Fractional cells ``(d, u)`` float32 of ranges / Dopplers ``(B, M, S)``."""
    d, u = grid.cell_coordinates(rng, dop)
    return d.to(torch.float32), u.to(torch.float32)
