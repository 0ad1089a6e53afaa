"""Detect-then-track on the same maps: threshold each map, then track the detections.

What a user without track-before-detect would do, to show what the seed's filter gains. Each map
is thresholded at a stated per-cell false-alarm probability, by the package's 2-D OS-CFAR
(:func:`~pmsr_nn.frontend.cfar.os_cfar`, ``detector: os_cfar``, the default: the noise power
estimated from training cells around each cell) or with the noise power known (``known_noise``:
for Rayleigh noise ``P(|z|^2 > T) = exp(-T / sigma^2)``, so ``T = sigma^2 ln(1 / Pfa)``, the ideal
a CFAR approaches); every cell above it that is the largest of its neighbourhood (+-1 Doppler row,
the range triangle's half-width) is a detection at that cell.
The tracker is the same SMC multi-Bernoulli filter, births and settings, with the standard
detection likelihood ratio per map instead of the map's (:class:`DetectionLikelihood`):

    ``L(x) = 1 - Pd + Pd sum_j N(z_j; h(x), R) / kappa``

``h(x)`` the state's (Doppler, range) cell, ``R`` diagonal (deviations in cells), ``kappa`` the
false detections' density per cell (``Pfa``: above a high threshold a noise cell is rarely beaten
by a neighbour), ``Pd`` the probability that the target's peak cell crosses the threshold (a
non-central chi-square with 2 degrees of freedom, averaged over the target's uniform sub-cell
offsets, computed from the map model at the true SNR for the known-noise threshold; the OS-CFAR's
loss is not modelled, so its ``Pd`` is slightly optimistic).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
import torch.nn.functional as F
from scipy import stats

from ..config import require
from .maps import triangle


@dataclass(frozen=True)
class DetectSpec:
    """``pfa`` per cell; ``detector``; the OS-CFAR's ``guard`` / ``train`` half-widths (Doppler rows,
    range columns: the guard holds the main lobe, +-1 row and the triangle's +-5 columns) and
    ``rank``; measurement deviations in cells (``sd_doppler_cells``, ``sd_range_cells``: the peak
    cell's quantisation, widened in range where the triangle's flat top lets noise move the peak)."""

    pfa: float = 1e-4
    detector: Literal["os_cfar", "known_noise"] = "os_cfar"
    guard: tuple[int, int] = (1, 5)
    train: tuple[int, int] = (4, 8)
    rank: float = 0.75
    sd_doppler_cells: float = 0.35
    sd_range_cells: float = 1.0

    def __post_init__(self) -> None:
        require(0 < self.pfa < 1, f"detect.pfa must be in (0, 1), got {self.pfa}")
        require(self.detector in ("os_cfar", "known_noise"), f"detect.detector must be os_cfar or known_noise, "
                                                             f"got {self.detector!r}")
        require(self.sd_doppler_cells > 0 and self.sd_range_cells > 0, "detect deviations must be positive")


@dataclass
class Peaks:
    """Detections of ``B`` runs' ``P`` maps, padded to ``J``: fractional cells ``d``, ``u``
    ``(B, P, J)`` and ``valid (B, P, J)``."""

    d: torch.Tensor
    u: torch.Tensor
    valid: torch.Tensor


def detect(maps: torch.Tensor, noise_power: float, pfa: float, lobe_cells: float,
           spec: "DetectSpec | None" = None) -> Peaks:
    """Detections of maps ``(B, P, D, U)`` (complex or magnitude) as module docstring (``spec``:
    the detector; default the known-noise threshold)."""
    power = maps.abs() ** 2
    B, P, D, U = power.shape
    if spec is not None and spec.detector == "os_cfar":
        from ..frontend.cfar import os_cfar

        above = os_cfar(power, tuple(spec.guard), tuple(spec.train), spec.rank, pfa, full_maps=False).detections
    else:
        above = power > noise_power * math.log(1.0 / pfa)
    w = 2 * math.ceil(lobe_cells) + 1
    local = F.max_pool2d(power.reshape(B * P, 1, D, U), (3, w), stride=1, padding=(1, w // 2)).reshape(B, P, D, U)
    hit = above & (power >= local)
    counts = hit.flatten(2).sum(-1)
    J = max(int(counts.max()), 1)
    # the J strongest hits per map (all of them), padded
    score = torch.where(hit, power, torch.full_like(power, -1.0)).flatten(2)
    top, idx = score.topk(J, dim=-1)
    return Peaks((idx // U).to(torch.float32), (idx % U).to(torch.float32), top > 0)


def detection_probability(snr_db: torch.Tensor, pfa: float, lobe_cells: float, points: int = 101) -> torch.Tensor:
    """Per map: probability that the target's peak cell exceeds the threshold, averaged over uniform
    sub-cell offsets in both axes (``|z|^2 / (sigma^2 / 2)`` is non-central chi-square, 2 degrees of
    freedom, non-centrality ``2 SNR G^2``); computed by SciPy on the CPU, given on ``snr_db``'s device."""
    off = (np.arange(points) + 0.5) / points - 0.5
    tri = triangle(torch.from_numpy(off) / lobe_cells).numpy()  # cpu: a NumPy table for SciPy
    G2 = (tri[:, None] * np.sinc(off)[None, :]) ** 2
    snr = 10.0 ** (np.asarray(snr_db.cpu().numpy(), dtype=np.float64) / 10)
    pd = [float(stats.ncx2.sf(2 * math.log(1 / pfa), 2, 2 * s * G2).mean()) for s in snr.ravel()]
    return torch.tensor(pd, dtype=torch.float64, device=snr_db.device).reshape(np.shape(snr))


class DetectionLikelihood:
    """The detection likelihood ratio (module docstring) of states, per map; the SNRs it returns
    (to order the maps) are the true ones, which also set ``Pd``."""

    def __init__(self, spec: DetectSpec, maps, cells, lobe_cells: float, noise_power: float, true_snr_db: torch.Tensor):
        self.spec, self.maps, self.cells, self.lobe_cells, self.noise_power = spec, maps, cells, lobe_cells, noise_power
        self.snr = true_snr_db.to(torch.float64)
        self.pd = detection_probability(self.snr, spec.pfa, lobe_cells)  # (P,)
        self.detections: list[Peaks] = []

    def __call__(self, x: torch.Tensor, valid: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
        s = self.spec
        peaks = detect(self.maps(k), self.noise_power, s.pfa, self.lobe_cells, s)
        self.detections.append(peaks)
        d, u = self.cells(x, k)  # (B, M, P)
        dd = (d[..., None] - peaks.d[:, None]) / s.sd_doppler_cells  # (B, M, P, J)
        du = (u[..., None] - peaks.u[:, None]) / s.sd_range_cells
        dens = torch.exp(-0.5 * (dd * dd + du * du)) / (2 * math.pi * s.sd_doppler_cells * s.sd_range_cells)
        dens = torch.where(peaks.valid[:, None], dens, dens.new_zeros(())).sum(-1).to(torch.float64)
        pd = self.pd.to(torch.float64)
        loglr = torch.log1p(-pd + pd * dens / s.pfa)
        B = x.shape[0]
        return loglr, self.snr.expand(B, -1)
