"""The online SNR estimate of the modified ICMB (the seed's Section 3.3.1, Eq. 25), and a
parametric-bootstrap correction of its bias.

The seed estimates map ``i``'s target amplitude as the largest maximum-likelihood amplitude over
the predicted particles (``max``: :func:`~.likelihood.max_ml_amplitude`). A maximum over positions
is biased high: near the target it picks the positions where the noise adds to the target's lobe,
and without a target it picks the strongest noise peak. An amplitude modelled too high makes the
``-A^2 G^2`` term outweigh ``log I0`` on the target's own cells, so the filter detects less than it
would with the true SNRs (``evaluate/RESULTS.md`` has the measured figures).

``bootstrap`` estimates that bias by the filter's own map model (Efron & Tibshirani 1993, Ch. 10,
the bootstrap estimate of bias) and removes it. Keep the ``kept`` states with the largest ML
amplitudes, ``A`` the best one's; draw ``replicas`` replica maps, each with one target of amplitude
``A`` at the best state's cells (the response of :func:`~.maps.response`, a uniform random phase)
in fresh complex Gaussian noise; in each, take the largest ML amplitude over the same kept states,
``A_r``. The maximum's bias in power is ``mean A_r^2 - A^2``, so the corrected power is
``2 A^2 - mean A_r^2`` (the first-order bootstrap correction), clipped at 0: a map whose replicas
find more than twice the power it shows is taken to show none, and the update then reads nothing
from it (its likelihood ratio is 1). Two approximations keep the cost at ``replicas x kept``
states per map: a replica is drawn only on the cells the kept states read (one noise value per
distinct cell, so states that share a cell see the same noise, as on a whole map; tested against
whole-map replicas), and the replicas re-run the maximum over the kept states only, not over
every particle. A maximum over fewer states is less biased, so the correction removes only a part
of the bias (``tests/test_tbd_snr.py``, static maps with 800 states: +1.0 dB before, +0.5 dB
after at 8 dB; +0.7 and +0.3 dB at 10 dB); on the seed's scene, where the particles crowd the
target, -0.3 to +0.45 dB is left (``evaluate/RESULTS.md``).

What neither estimate can do is tell that no target is there: both are the amplitude of a target
assumed present, so with none they report the strongest noise peak's (corrected: a little lower).

Shapes: ``B`` runs, ``M`` states, ``P`` maps, ``D x U`` cells per map.
"""

from __future__ import annotations

import math
from typing import Literal

import torch

from .likelihood import CellValues, candidate_ml_amplitudes, ml_amplitude, sub_area
from .maps import response

SnrEstimator = Literal["max", "bootstrap"]
SNR_ESTIMATORS = ("max", "bootstrap")


def bootstrap_ml_amplitude(shape: tuple[int, int, int], d: torch.Tensor, u: torch.Tensor, cells: CellValues,
                           valid: torch.Tensor, lobe_cells: float, half: int | None, noise_power: float,
                           iterations: int, candidates: int | None, replicas: int, kept: int,
                           g: torch.Generator) -> torch.Tensor:
    """The bias-corrected largest ML amplitude ``(B, P)`` float64 (module docstring) of the valid
    states ``valid (B, M)`` at fractional cells ``d, u (B, M, P)`` of maps of ``shape = (P, D, U)``,
    whose sub-area cells are ``cells``; ``half``: the sub-area (``None``: the whole map)."""
    a, idx = candidate_ml_amplitudes(cells, valid, noise_power, iterations, candidates)  # (B, k, P)
    top_a, top = a.topk(min(kept, a.shape[1]), dim=1)  # best first
    states = idx.gather(1, top)  # (B, kept, P)
    a_hat = top_a[:, 0].to(torch.float64)  # (B, P)
    a_r = replica_maxima(shape, d.gather(1, states), u.gather(1, states), a_hat, lobe_cells, half, noise_power,
                         iterations, replicas, g)
    power = 2 * a_hat ** 2 - (a_r ** 2).mean(0)  # the observed power minus the estimated bias
    return power.clamp(min=0.0).sqrt()


def replica_maxima(shape: tuple[int, int, int], d: torch.Tensor, u: torch.Tensor, amplitude: torch.Tensor,
                   lobe_cells: float, half: int | None, noise_power: float, iterations: int, replicas: int,
                   g: torch.Generator) -> torch.Tensor:
    """The largest ML amplitude ``(R, B, P)`` over states at fractional cells ``d, u (B, n, P)`` in
    each of ``R = replicas`` replica maps of ``shape = (P, D, U)``: one target of ``amplitude (B, P)``
    at the first state's cells, a uniform random phase, and complex Gaussian noise of power
    ``noise_power`` drawn on the cells the states read (one value per distinct cell)."""
    P, D, U = shape
    B, n = d.shape[:2]
    G, flat = sub_area(shape, d, u, lobe_cells, half)  # (B, n, P, S)
    S = G.shape[-1]
    cell = flat.permute(0, 2, 1, 3).reshape(B, P, n * S)  # per run and map, the cells the states read
    ordered, perm = cell.sort(-1)
    new = torch.ones_like(ordered, dtype=torch.bool)
    new[..., 1:] = ordered[..., 1:] != ordered[..., :-1]
    distinct = torch.empty_like(perm).scatter_(-1, perm, new.cumsum(-1) - 1)  # (B, P, n S): its distinct cell
    dev = d.device  # the draws too: ``g`` is a generator of this device
    sd = math.sqrt(noise_power / 2)
    noise = torch.randn((replicas, B, P, n * S, 2), generator=g, dtype=torch.float64, device=dev) * sd
    noise = torch.view_as_complex(noise).gather(-1, distinct.expand(replicas, -1, -1, -1))
    phase = torch.rand((replicas, B, P, 1), generator=g, dtype=torch.float64, device=dev) * (2 * math.pi)
    within = cell % (D * U)
    at = response(within // U, within % U, d[:, 0].to(torch.float64)[..., None], u[:, 0].to(torch.float64)[..., None],
                  lobe_cells)  # (B, P, n S)
    z = (amplitude[..., None] * at * torch.polar(torch.ones_like(phase), phase) + noise).abs()  # (R, B, P, n S)
    z = z.view(replicas * B, P, n, S).transpose(1, 2).to(torch.float32)  # (R B, n, P, S)
    a = ml_amplitude(CellValues(z, G.to(torch.float32).repeat(replicas, 1, 1, 1)), noise_power, iterations)
    return a.amax(1).to(torch.float64).view(replicas, B, P)
