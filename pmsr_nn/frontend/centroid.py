"""Connected CFAR detections to single measurements: centroid, SNR and a deviation per blob.

A target's main lobe in the range-Doppler map covers a few cells (sinc^2 in Doppler for a
rectangular CPI, about a triangle of +-1 cell in range), and all of them may cross the CFAR
threshold; a tracker wants one measurement per target. The 8-connected components of the
detections of every map are found at once (``scipy.ndimage.label`` on the whole batch with a
structuring element that does not reach across maps) and reduced with ``numpy.bincount``, without a
Python loop over components. Components are not joined across the Doppler edges of the map, even
where the Doppler axis is circular (a peak straddling the edge gives two measurements).

Centroid weights are the power minus the cell's CFAR noise estimate, clipped at 0: the expected
power of a cell is signal + noise, and the noise pedestal, the same in every cell of the blob,
would pull the centroid towards the blob's geometric centre (a detected cell is far above its noise
level, so the clip only matters for noise estimates from elsewhere; a blob whose weights are all 0
falls back to plain power).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from scipy import ndimage
from scipy.integrate import quad

from ..config import require


def _sinc2_pair_bias_rms() -> float:
    """RMS over ``delta ~ U(0, 1/2)`` of the bias ``delta^2 / (delta^2 + (1 - delta)^2) - delta`` of
    the power-weighted centroid of two cells of a sinc^2 peak at ``delta`` bins from the first."""
    def sq(d: float) -> float:
        return (d * d / (d * d + (1 - d) ** 2) - d) ** 2

    return math.sqrt(2.0 * quad(sq, 0.0, 0.5)[0])


SHAPE_BIAS_DOPPLER = _sinc2_pair_bias_rms()
"""RMS shape bias (bins) of the Doppler centroid of a sinc^2 main lobe: about 0.107."""

SHAPE_BIAS_RANGE = 0.0
"""Shape bias (bins) of the range centroid of a power triangle of half-width one cell: none (the
two cells' weights ``1 - e`` and ``e`` put the centroid exactly at the offset ``e``)."""


@dataclass(frozen=True)
class Centroids:
    """Measurements of the connected detections of maps ``(..., D, U)``, padded to ``M`` per map.

    ``doppler_bin``, ``range_bin (..., M)``: power-weighted centroid in fractional bins (Doppler row
    ``0 .. D-1``, range column ``0 .. U-1``; the range is a lobe fit instead where :func:`centroids`
    is given ``lobe_bandwidth``, and may then lie beyond the map's ends). ``peak_power``: largest power of the component (power
    units). ``snr_db``: ``10 log10(peak power / noise estimate at the peak cell)``.
    ``sd_doppler_bin``, ``sd_range_bin``: standard deviation of the centroid's error (bins), see
    :func:`centroids`. ``cells`` int64: the component's number of cells. ``valid`` bool. Valid
    entries come first, strongest (highest ``snr_db``) first; padding is NaN (``cells`` 0).
    """

    doppler_bin: torch.Tensor
    range_bin: torch.Tensor
    peak_power: torch.Tensor
    snr_db: torch.Tensor
    sd_doppler_bin: torch.Tensor
    sd_range_bin: torch.Tensor
    cells: torch.Tensor
    valid: torch.Tensor


def centroids(power: torch.Tensor, detections: torch.Tensor, noise: torch.Tensor,
              max_per_map: int | None = None, threshold: torch.Tensor | None = None,
              lobe_bandwidth: torch.Tensor | None = None) -> Centroids:
    """One measurement per 8-connected component of ``detections (..., D, U)`` (bool) in each map.

    ``power (..., D, U)``: the square-law map; ``noise (..., D, U)``: the mean noise power estimate
    of each cell (:attr:`~pmsr_nn.frontend.cfar.CfarResult.noise`); ``threshold (..., D, U)``
    (optional, :attr:`~pmsr_nn.frontend.cfar.CfarResult.threshold`) sharpens the deviation of blobs
    one bin wide. ``max_per_map``: keep the strongest so many per map and pad to exactly that width
    (default: the largest count of the batch).

    Deviation model, per axis (bins), for main lobes shaped as sinc^2 in Doppler and a power
    triangle of half-width 1 cell in range:

    * a blob two or more bins wide along the axis: ``sd^2 = var_noise + b^2``. ``var_noise =
      sum_i (x_i - c)^2 n_i (n_i + 2 w_i) / W^2`` is the first-order propagation of square-law
      noise (``Var P_i = n_i^2 + 2 n_i s_i`` for signal power ``s_i``, estimated by the weight
      ``w_i``; ``W = sum w_i``) through ``c = sum x_i w_i / W``. ``b`` is the shape bias of the power
      centroid: for sinc^2 the two main cells of a peak at ``delta`` give ``delta^2 / (delta^2 +
      (1 - delta)^2)``, whose error has RMS :data:`SHAPE_BIAS_DOPPLER` = 0.107 over uniform
      ``delta``; for the triangle the two cells give the offset exactly (:data:`SHAPE_BIAS_RANGE` = 0).
    * a blob one bin wide along the axis: the centroid is the bin, and the target lies within
      ``+-a`` of it, uniformly, ``sd^2 = a^2 / 3``, where ``a`` is the offset at which the neighbour
      would have crossed the threshold. With ``S`` the peak's signal-to-noise and ``T`` the threshold
      over noise minus 1 (both from the peak cell), the neighbour/peak ratio ``e/(1-e)`` (triangle)
      or ``(d/(1-d))^2`` (sinc^2) equals ``T/S`` there: ``a = r/(1+r)``, ``r = T/S`` in range and
      ``r = sqrt(T/S)`` in Doppler. Without ``threshold``, ``a = 1/2`` (``sd^2 = 1/12``).

    ``lobe_bandwidth (...)`` (cycles per sample, one per map; :func:`~.chain.rms_bandwidth` of the
    CPI's reference): the range lobe is then taken as that of an FM reference, whose spectrum
    follows the distribution of its instantaneous frequency (Woodward), Gaussian for a Gaussian
    programme: the amplitude autocorrelation is ``exp(-2 pi^2 B^2 x^2)`` (0.89, 0.62, 0.34 at 1-3
    bins for ``B`` = 25 / 320), the log of the power lobe a parabola of known curvature ``kappa = 4
    pi^2 B^2``. The range is then the least-squares fit of that parabola's vertex to the log signal
    powers (power less the noise estimate) of the peak cell and its range neighbours in the peak's
    Doppler row: ``u_p + (ln s_+ - ln s_-) / (4 kappa)`` inside the map, and from the two cells left
    at its last or first range bin ``u_p -+ 1/2 +- (ln s_p - ln s_n) / (2 kappa)`` (``s_n`` the
    neighbour's), which
    extrapolates a lobe cut by the map's edge instead of pulling it inwards as the centroid does.
    ``sd_range_bin`` stays the centroid's model (a floor set by the caller: see
    :func:`~.chain.process_cpi`).
    """
    def describe(x) -> str:
        return f"shape {tuple(x.shape)}" if isinstance(x, torch.Tensor) else type(x).__name__

    require(isinstance(power, torch.Tensor) and power.dim() >= 2,
            f"centroids: power must be a tensor (..., Doppler, range), got {describe(power)}")
    require(lobe_bandwidth is None or (isinstance(lobe_bandwidth, torch.Tensor) and lobe_bandwidth.shape == power.shape[:-2]
                                       and bool(torch.isfinite(lobe_bandwidth).all() and (lobe_bandwidth > 0).all())),
            f"centroids: lobe_bandwidth must be positive and finite, one per map {tuple(power.shape[:-2])}, got "
            f"{describe(lobe_bandwidth)}")
    for name, t in (("detections", detections), ("noise", noise), ("threshold", threshold)):
        if t is not None:
            require(isinstance(t, torch.Tensor) and t.shape == power.shape,
                    f"centroids: {name} must have power's shape {tuple(power.shape)}, got {describe(t)}")
    require(detections.dtype == torch.bool, f"centroids: detections must be bool, got {detections.dtype}")
    require(max_per_map is None or (isinstance(max_per_map, int) and not isinstance(max_per_map, bool) and max_per_map >= 0),
            f"centroids: max_per_map must be a whole number >= 0 or None, got {max_per_map!r}")
    *lead, D, U = power.shape
    B = math.prod(lead)
    P = power.detach().double().cpu().numpy().reshape(-1)
    nz = noise.detach().double().cpu().numpy().reshape(-1)

    structure = np.zeros((3, 3, 3), dtype=bool)
    structure[1] = True  # 8-connected within a map, never across maps
    labels, n = ndimage.label(detections.detach().cpu().numpy().reshape(B, D, U), structure=structure)
    flat = np.flatnonzero(labels)
    lab = labels.reshape(-1)[flat] - 1
    d, u = (flat // U) % D, flat % U
    p, nc = P[flat], nz[flat]
    w = np.clip(p - nc, 0.0, None)
    W = np.bincount(lab, w, n)
    if (W <= 0).any():
        w = np.where((W <= 0)[lab], p, w)
        W = np.bincount(lab, w, n)
    with np.errstate(invalid="ignore", divide="ignore"):
        cd, cu = np.bincount(lab, w * d, n) / W, np.bincount(lab, w * u, n) / W
        spread = nc * (nc + 2.0 * w) / W[lab] ** 2
        var_d = np.bincount(lab, (d - cd[lab]) ** 2 * spread, n)
        var_u = np.bincount(lab, (u - cu[lab]) ** 2 * spread, n)

    count = np.bincount(lab, minlength=n)
    order = np.lexsort((p, lab))  # by component, then power: each component's peak is its last
    start = np.cumsum(count) - count
    peak = order[start + count - 1]
    one_d = np.minimum.reduceat(d[order], start) == np.maximum.reduceat(d[order], start) if n else np.zeros(0, bool)
    one_u = np.minimum.reduceat(u[order], start) == np.maximum.reduceat(u[order], start) if n else np.zeros(0, bool)
    with np.errstate(invalid="ignore", divide="ignore"):
        snr = p[peak] / nc[peak]
        if threshold is None:
            ratio = np.full(n, np.inf)
        else:
            T = threshold.detach().double().cpu().numpy().reshape(-1)[flat][peak]
            ratio = (T / nc[peak] - 1.0) / (snr - 1.0)  # threshold over signal, both above noise
        ratio = np.where(np.isfinite(ratio) & (ratio >= 0), ratio, np.inf)
        a_u = np.minimum(0.5, np.where(np.isinf(ratio), 0.5, ratio / (1.0 + ratio)))
        root = np.sqrt(ratio)
        a_d = np.minimum(0.5, np.where(np.isinf(root), 0.5, root / (1.0 + root)))
    if lobe_bandwidth is not None:
        cu = _gaussian_lobe_range(P, nz, flat[peak], D, U, lobe_bandwidth, B)
    sd_d = np.sqrt(np.where(one_d, a_d ** 2 / 3.0, var_d + SHAPE_BIAS_DOPPLER ** 2))
    sd_u = np.sqrt(np.where(one_u, a_u ** 2 / 3.0, var_u + SHAPE_BIAS_RANGE ** 2))

    # strongest first within each map, then padded to M per map
    comp_map = flat[peak] // (D * U)
    with np.errstate(divide="ignore"):
        snr_db = 10.0 * np.log10(snr)
    rank = np.lexsort((-snr_db, comp_map))
    per_map = np.bincount(comp_map, minlength=B)
    slot = np.empty(n, dtype=np.int64)
    slot[rank] = np.arange(n) - (np.cumsum(per_map) - per_map)[comp_map[rank]]
    M = int(per_map.max(initial=0)) if max_per_map is None else max_per_map
    keep = slot < M
    where = (comp_map[keep], slot[keep])

    def padded(values: np.ndarray, fill, dtype) -> torch.Tensor:
        out = np.full((B, M), fill, dtype=np.asarray(values).dtype if values.size else np.float64)
        out[where] = values[keep]
        return torch.from_numpy(out).to(device=power.device, dtype=dtype).reshape(*lead, M)

    dtype = power.dtype
    return Centroids(doppler_bin=padded(cd, np.nan, dtype), range_bin=padded(cu, np.nan, dtype),
                     peak_power=padded(p[peak], np.nan, dtype), snr_db=padded(snr_db, np.nan, dtype),
                     sd_doppler_bin=padded(sd_d, np.nan, dtype), sd_range_bin=padded(sd_u, np.nan, dtype),
                     cells=padded(count, 0, torch.int64), valid=padded(np.ones(n, dtype=bool), False, torch.bool))


def _gaussian_lobe_range(P: np.ndarray, nz: np.ndarray, peak: np.ndarray, D: int, U: int, bandwidth: torch.Tensor,
                         B: int) -> np.ndarray:
    """Range (fractional bins) of components whose peak cells are ``peak`` (flat indices into
    ``P``, maps ``(B, D, U)`` flattened) from the Gaussian lobe of RMS bandwidth ``bandwidth (B,)``
    (cycles per sample), see :func:`centroids`."""
    kappa = 4.0 * math.pi**2 * bandwidth.detach().double().cpu().numpy().reshape(B)[peak // (D * U)] ** 2
    up = peak % U
    lo, hi = up > 0, up < U - 1
    noise = nz[peak]
    # signal power of a cell: power less the noise estimate, floored where noise swamps it (a
    # neighbour's log is then only a bound, which caps the offset rather than letting it run off)
    def log_signal(i: np.ndarray) -> np.ndarray:
        return np.log(np.maximum(P[i] - noise, 1e-3 * np.maximum(P[peak] - noise, 1e-300)))

    lp = log_signal(peak)
    lm = log_signal(np.where(lo, peak - 1, peak))
    lq = log_signal(np.where(hi, peak + 1, peak))
    with np.errstate(invalid="ignore", divide="ignore"):
        both = up + (lq - lm) / (4.0 * kappa)
        first = up + 0.5 + (lq - lp) / (2.0 * kappa)  # no left neighbour: cells u_p, u_p + 1
        last = up - 0.5 + (lp - lm) / (2.0 * kappa)  # no right neighbour: cells u_p - 1, u_p
    return np.where(lo & hi, both, np.where(hi, first, np.where(lo, last, up.astype(np.float64))))
