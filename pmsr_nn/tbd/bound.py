"""The information bound of a target seen through range-Doppler maps (issue 58).

A target of map SNR ``A^2 / sigma^2`` at fractional cell ``(d, u)`` adds ``A e^{j phi} h(d, u)``
to the map, ``h`` the real, separable response of :mod:`.maps`:
``h_{r,c} = sinc(r - d) tri((c - u) / L)``, in circular complex Gaussian noise of power
``sigma^2`` per cell. The Fisher information of ``theta`` (here ``(d, u)``, then the state) in
a complex Gaussian mean ``mu(theta)`` is ``(2 / sigma^2) Re(dmu^H dmu)``. The phase ``phi`` is
a nuisance (uniform per frame and map); its cross term ``(2 A^2 / sigma^2) Re(j dh^T h)`` is 0
because ``h`` is real, so the information on ``(d, u)`` is the same whether or not the phase is
known:

    J_cells = 2 SNR sum_cells grad h grad h^T,

and, the response being separable, each entry is a product of one sum over rows and one over
columns (:func:`cell_information`). On a map without edges, ``sum_r sinc'(r - d)^2 = pi^2 / 3``
and ``sum_r sinc(r - d)^2 = 1`` for any ``d`` (band-limited functions, their squares' samples
sum to their integrals) and ``sum_r sinc sinc' = 0``, so the Doppler information is
``2 SNR (pi^2 / 3) sum_c tri^2`` and the range information ``2 SNR sum_c tri'^2`` (``1 / L^2``
per column inside the triangle). The amplitude is taken as known (the bound of a filter told the
SNR); its cross terms with ``(d, u)``, ``sum h dh``, vanish on average over the sub-cell offset.

The state's information per frame is ``sum_p H_p^T J_p H_p`` over the maps, ``H_p`` the Jacobian
of map ``p``'s fractional cells in the planar CV state ``[x, vx, y, vy]`` (autograd through
:meth:`~.scene.MapScene` geometry, in float64). :func:`map_bound` runs the PCRB's recursion
(:func:`pmsr_nn.bounds.information_bound`) on it, in the scenario's motion model.
"""

from __future__ import annotations

import math

import torch

from ..bounds import BoundResult, information_bound
from ..motion import KinematicModel
from .maps import range_doppler, triangle
from .scene import MapScene


def sinc_derivative(x: torch.Tensor) -> torch.Tensor:
    """``d/dx sinc(x)`` of the normalised sinc ``sin(pi x) / (pi x)``: ``(cos(pi x) - sinc(x)) / x``,
    its Taylor form ``-pi^2 x / 3`` near 0 (where the quotient cancels)."""
    small = x.abs() < 1e-4
    safe = torch.where(small, torch.ones_like(x), x)
    return torch.where(small, -(math.pi ** 2) * x / 3, (torch.cos(math.pi * safe) - torch.sinc(safe)) / safe)


def cell_information(d: torch.Tensor, u: torch.Tensor, D: int, U: int, lobe_cells: float) -> torch.Tensor:
    """Fisher information per unit SNR ``(..., 2, 2)`` of a target's fractional cell ``(d, u)``
    (each ``(...)``) in a map of ``D`` Doppler rows and ``U`` range columns whose range triangle has
    half-width ``lobe_cells``: ``2 sum_cells grad h grad h^T`` over the map's cells, order
    ``(d, u)``. Multiply by the linear SNR ``A^2 / sigma^2``."""
    rows = torch.arange(D, dtype=torch.float64, device=d.device)
    cols = torch.arange(U, dtype=torch.float64, device=d.device)
    x = rows - d[..., None]  # (..., D)
    s, ds = torch.sinc(x), -sinc_derivative(x)  # d/dd sinc(r - d) = -sinc'(r - d)
    c = cols - u[..., None]  # (..., U)
    t = triangle(c / lobe_cells)
    dt = torch.where(t > 0, torch.sign(c) / lobe_cells, torch.zeros_like(c))  # d/du tri((c - u) / L) inside the lobe
    j_dd = (ds * ds).sum(-1) * (t * t).sum(-1)
    j_uu = (s * s).sum(-1) * (dt * dt).sum(-1)
    j_du = (ds * s).sum(-1) * (t * dt).sum(-1)
    return 2 * torch.stack([torch.stack([j_dd, j_du], -1), torch.stack([j_du, j_uu], -1)], -2)


def cell_jacobian(scene: MapScene, x: torch.Tensor, frames: torch.Tensor) -> torch.Tensor:
    """Jacobian ``(L, P, 2, 4)`` of every map's fractional cell ``(d, u)`` in the planar CV states
    ``x (L, 4)`` at frames ``frames (L,)`` (0-based), float64, by autograd."""
    x = x.detach().to(torch.float64).requires_grad_(True)
    d, u = _cells(scene, x, frames)
    # each output depends on its own state only: the gradient of a column's sum is the per-state row
    grad = lambda v: torch.autograd.grad(v.sum(), x, retain_graph=True)[0]
    return torch.stack([torch.stack([grad(d[:, p]), grad(u[:, p])], -2) for p in range(scene.P)], 1)


def map_information(scene: MapScene, x: torch.Tensor, frames: torch.Tensor) -> torch.Tensor:
    """Information ``(L, 4, 4)`` on the planar CV states ``x (L, 4)`` from every map of frames
    ``frames (L,)``: ``sum_p SNR_p H_p^T J_p H_p`` (module docstring)."""
    grid = scene.grid
    d, u = _cells(scene, x.detach(), frames)
    J = cell_information(d, u, grid.D, grid.U, scene.maps.lobe_cells)  # (L, P, 2, 2)
    snr = 10.0 ** (torch.tensor(scene.snr_db, dtype=torch.float64) / 10)  # (P,)
    H = cell_jacobian(scene, x, frames)  # (L, P, 2, 4)
    return (snr[:, None, None] * (H.transpose(-1, -2) @ J @ H)).sum(1)


def _cells(scene: MapScene, x: torch.Tensor, frames: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Fractional cells ``(d, u)``, each ``(L, P)`` float64, of states ``x (L, 4)`` at ``frames (L,)``."""
    rng, dop = range_doppler(x.to(torch.float64), scene.tx[frames], scene.maps, scene.rx, scene.wavelength)
    return scene.grid.cell_coordinates(rng, dop)


def map_bound(scene: MapScene, truth: torch.Tensor, first_frame: int, motion: KinematicModel, dt: float, q,
              P0: torch.Tensor, smoothing: bool = False) -> BoundResult:
    """The PCRB of one target seen through the maps from frame ``first_frame`` (0-based) on:
    ``truth (L, n)`` its states in the scenario's state space (its CV columns
    ``scene.state_index``), ``motion``, ``dt``, ``q`` and the prior ``P0 (n, n)`` as for
    :func:`pmsr_nn.bounds.pcrb`."""
    L, n = truth.shape
    frames = torch.arange(first_frame, first_frame + L)
    cv = scene.cv_states(truth.to(torch.float64))
    idx = torch.tensor(scene.state_index)
    info = torch.zeros(1, L, n, n, dtype=torch.float64)
    info[0, :, idx[:, None], idx[None, :]] = map_information(scene, cv, frames)
    return information_bound(info, motion, dt, q, P0, smoothing)
