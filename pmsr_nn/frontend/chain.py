"""The FM front end scan by scan: signals -> cancellation -> 2D-CCF -> OS-CFAR -> centroids -> detections.

:func:`front_end_scans` is what the ``detections`` product runs when a scenario asks for
detections from signals (``front_end:`` in a multi-target study): for every scan it simulates one
CPI per run and transmitter-receiver pair (:mod:`.fm_signals`, from the same truth every other
product sees), processes it (:func:`process_cpi`) and keeps only the centroided detections, in
the package's :class:`~pmsr_nn.simulation.detections.Scans` layout (bistatic range in m, Doppler
in Hz, per pair), so S-MSJPDA, PMHT and every other tracker of detections read them unchanged.
Memory: one CPI per row of a chunk of ``chunk_rows`` (run, pair) rows is alive at a time.

A detection's range is the fit of the reference's Gaussian range lobe (of its RMS bandwidth) to
the peak cell and its range neighbours (:func:`~.centroid.centroids` with ``lobe_bandwidth``),
which also places lobes cut by the map's edge; its reported deviation is at least the Cramer-Rao
bound of the delay for the CPI's reference (:func:`delay_crlb_samples`), which the fit's error
follows on echoes in noise within a factor 0.7-1.55 over 11-27 dB map SNR
(``evaluate/fm_range_deviation.py``, ``tests/test_frontend_chain.py``). The
centroid's own model assumes independent cells and falls below the bound where an FM range lobe
spans several cells. Merged echoes of two targets are not modelled: :func:`summarise` gives their
errors apart (``range_by_kind``).

Each detection gets a truth origin for evaluation only: the nearest living target whose true
(range, Doppler) lies within ``gate_cells`` bins of it, one detection per target (the nearest);
any other detection -- noise, a sidelobe, a second peak of a split target -- is clutter. The
statistics of the chain (measured Pd, false alarms, errors of the detections, cancellation depth,
seconds per CPI) are summed per block in :class:`FrontEndRecord` and summarised by
:func:`summarise`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from .. import SPEED_OF_LIGHT
from ..errors import ConfigError
from ..measurements import MeasurementModel
from ..simulation.detections import CLUTTER, PADDING, Scans, check_model_for_detections, shuffled
from .cancellation import cancellation_depth_db, eca, nlms
from .ccf import ccf_batches
from .centroid import centroids
from .cfar import os_cfar
from .fm_signals import FMSignalSpec, echo_snr_db, simulate_cpi
from .settings import CancellationSpec, CfarSpec, FrontEndSpec

__all__ = ["CancellationSpec", "CfarSpec", "FrontEndSpec", "front_end_scans", "process_cpi", "summarise"]


@dataclass
class CpiResult:
    """One CPI of ``B`` rows processed: ``power (B, D, U)`` after cancellation, the CFAR's
    ``detections`` / ``threshold``, the ``centroids`` (see :func:`~.centroid.centroids`),
    ``doppler_hz (D,)`` of the map's rows, ``depth_db (B,)`` cancellation depth."""

    power: torch.Tensor
    detections: torch.Tensor
    threshold: torch.Tensor
    centroids: object
    doppler_hz: torch.Tensor
    depth_db: torch.Tensor


def _cancel(spec: FrontEndSpec, surv: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
    c = spec.cancellation
    if c.method == "eca":
        clean = eca(surv, ref, c.range_bins, doppler_bins=c.doppler_bins, batches=c.batches)[0]
    elif c.method == "nlms":
        clean = nlms(surv, ref, c.range_bins, c.mu, block=c.block)[0]
    else:
        return surv
    # the first samples hold clutter sent before the CPI, which no delayed copy of this CPI's
    # reference explains: blank them (K - 1 of N samples of signal lost)
    clean = clean.clone()
    clean[..., : c.range_bins - 1] = 0
    return clean


def range_doppler_map(spec: FrontEndSpec, surv: torch.Tensor, ref: torch.Tensor):
    """The 2D-CCF of ``surv`` against ``ref`` ``(B, N)``: the map object of :func:`~.ccf.ccf_batches`."""
    s = spec.signal
    return ccf_batches(surv, ref, spec.range_bins, spec.batch_len, spec.max_doppler_hz, s.sample_rate_hz,
                       window=spec.window)


def process_cpi(spec: FrontEndSpec, ref: torch.Tensor, surv: torch.Tensor, full_maps: bool = False) -> CpiResult:
    """Cancellation, 2D-CCF, OS-CFAR and centroiding of one CPI ``ref, surv (B, N)``;
    ``full_maps``: the CFAR's threshold at every cell (else only at detections, the rest NaN:
    the same detections, several times faster). Non-finite samples are refused (one line) by the
    cancellation and the 2D-CCF, which check their inputs."""
    clean = _cancel(spec, surv, ref)
    depth = cancellation_depth_db(surv, clean)
    rd = range_doppler_map(spec, clean, ref)
    power = rd.power
    c = spec.cfar
    cf = os_cfar(power, guard=c.guard, train=c.train, rank=c.rank, pfa=c.pfa, wrap_doppler=False,
                 full_maps=full_maps, alpha_factor=float(c.alpha_factor))
    # range: the fit of the reference's (Gaussian) lobe, which extrapolates lobes cut by the map's
    # edge. The reported deviation is the delay's Cramer-Rao bound of the waveform's RMS bandwidth
    # (the centroid's own model, for independent cells, falls below it where an FM lobe spans many
    # cells). Measured on echoes in noise (evaluate/fm_range_deviation.py) the fit's RMS error is
    # 0.7-0.85x the bound at 14-27 dB map SNR and 1.5x at 11.5 dB (near the CFAR threshold) inside
    # the map, 1.0-1.55x for lobes cut by its edge: the bound is not an exact model per SNR; over
    # the scenario's mix of SNRs it is within 10 % of the measured RMSE (evaluate/RESULTS.md)
    bandwidth = rms_bandwidth(ref)
    cen = centroids(power, cf.detections, cf.noise, threshold=cf.threshold, lobe_bandwidth=bandwidth)
    floor = delay_crlb_samples(ref, cen.snr_db)
    cen = dataclasses.replace(cen, sd_range_bin=torch.where(cen.valid, torch.maximum(cen.sd_range_bin, floor),
                                                            cen.sd_range_bin))
    return CpiResult(power, cf.detections, cf.threshold, cen, rd.doppler_hz, depth)


def rms_bandwidth(ref: torch.Tensor) -> torch.Tensor:
    """RMS bandwidth of the reference ``ref (B, N)`` in cycles per sample ``(B,)``, from its
    first difference: ``mean |r[n+1] - r[n]|^2 = 4 sin^2(pi f) mean |r|^2`` for a tone of
    ``f`` cycles per sample (for an FM signal: the RMS instantaneous frequency, about its mean)."""
    d = (ref[..., 1:] - ref[..., :-1]).abs().pow(2).mean(-1)
    ratio = (d / ref.abs().pow(2).mean(-1).clamp_min(1e-300)).clamp(0, 4)
    return torch.asin(ratio.sqrt() / 2) / math.pi


def delay_crlb_samples(ref: torch.Tensor, snr_db: torch.Tensor) -> torch.Tensor:
    """Cramer-Rao bound on the delay (samples) of an echo of map SNR ``snr_db (B, M)`` (peak
    power over noise, i.e. E / N0): ``1 / (2 pi B_rms sqrt(2 SNR))``, ``B_rms`` of ``ref (B, N)``
    (:func:`rms_bandwidth`); NaN where ``snr_db`` is."""
    b = rms_bandwidth(ref)[:, None]
    return 1.0 / (2 * math.pi * b * torch.sqrt(2 * 10 ** (snr_db / 10)))


@dataclass
class FrontEndRecord:
    """What the chain measured on one block of runs: ``sums`` name -> float or array, summed over
    runs and scans (:func:`summarise` turns the sums over all blocks into the figures of
    ``results.json``), and ``example``: run 0's maps and detections (numpy)."""

    sums: dict = field(default_factory=dict)
    example: dict = field(default_factory=dict)


def true_cells(model: MeasurementModel, truth: torch.Tensor):
    """True bistatic range (m), Doppler (Hz) and the two leg lengths (m) ``(B, K, N, S)`` of
    targets ``truth (B, K, N, n)`` for every pair of ``model`` (layout ``pair``, range and Doppler)."""
    B, K, N, _ = truth.shape
    S = model.n_pairs
    clean = model.h(truth).reshape(B, K, N, S, 2)
    g = model.geometry
    pos = truth[..., list(model.pos_idx)]
    tx, rx = g.pair_tx_positions(truth.dtype), g.pair_rx_positions(truth.dtype)
    r_tx = torch.linalg.vector_norm(pos[..., None, :] - tx, dim=-1)
    r_rx = torch.linalg.vector_norm(pos[..., None, :] - rx, dim=-1)
    return clean[..., 0], clean[..., 1], r_tx, r_rx


def _label(z: torch.Tensor, valid: torch.Tensor, r_true: torch.Tensor, f_true: torch.Tensor, alive: torch.Tensor,
           cell: tuple[float, float], gate: tuple[float, float]) -> torch.Tensor:
    """Truth origin of detections ``z (R, M, 2)`` given targets' true ``r_true, f_true (R, N)``:
    one detection per target, the nearest within the gate (in bins), else :data:`CLUTTER`."""
    R, M = valid.shape
    N = r_true.shape[1]
    if N == 0 or M == 0:
        return torch.full((R, M), CLUTTER, dtype=torch.int64).masked_fill(~valid, PADDING)
    dr = (z[..., None, 0] - r_true[:, None]) / cell[1]
    df = (z[..., None, 1] - f_true[:, None]) / cell[0]
    inside = (dr.abs() <= gate[1]) & (df.abs() <= gate[0]) & valid[..., None] & alive[:, None]
    dist = torch.where(inside, dr**2 + df**2, math.inf)  # (R, M, N)
    best_det = dist.argmin(1)  # per target: its nearest detection
    has = torch.isfinite(dist.amin(1))
    origin = torch.full((R, M), CLUTTER, dtype=torch.int64)
    rows, targets = torch.nonzero(has, as_tuple=True)
    dets = best_det[rows, targets]
    # a detection nearest to two targets goes to the closer one
    d = dist[rows, dets, targets]
    order = torch.argsort(d, descending=True)  # later writes (closer) win
    origin[rows[order], dets[order]] = targets[order]
    return origin.masked_fill(~valid, PADDING)


DETECTION_KINDS = ("clear", "crowded", "edge")
"""Kinds of labelled detections whose range errors :func:`summarise` gives apart: ``edge``, whose
range lies within :data:`EDGE_BINS` of the map's first or last range bin (a lobe cut by the map);
``crowded``, another living target within (:data:`CROWDED_BINS`) of its target's true cell (lobes
that may merge); ``clear``, the rest."""

EDGE_BINS = 3.0
"""Range bins from the map's ends within which a detection's lobe may be cut: the FM lobe's power
falls to 0.11 at 3 bins (amplitude 0.34 at 25 kHz RMS deviation and 320 kHz)."""

CROWDED_BINS = (3.0, 4.0)
"""(Doppler, range) bins within which two targets' lobes may merge into one blob."""


def _detection_kind(range_m: torch.Tensor, tid: torch.Tensor, r_true: torch.Tensor, f_true: torch.Tensor,
                    alive: torch.Tensor, baseline_m: torch.Tensor, cell: tuple[float, float], U: int) -> torch.Tensor:
    """Index into :data:`DETECTION_KINDS` of detections at ``range_m (R, M)`` labelled with targets
    ``tid (R, M)`` given the targets' true ``r_true, f_true (R, T)``, ``alive (R, T)`` and each
    row's baseline ``(R,)`` (m); ``cell`` (Hz, m)."""
    u = (range_m - baseline_m[:, None]) / cell[1]
    edge = (u < EDGE_BINS) | (u > U - 1 - EDGE_BINS)
    dr = (r_true[:, :, None] - r_true[:, None, :]).abs() / cell[1]
    df = (f_true[:, :, None] - f_true[:, None, :]).abs() / cell[0]
    T = r_true.shape[1]
    near = (dr <= CROWDED_BINS[1]) & (df <= CROWDED_BINS[0]) & alive[:, :, None] & alive[:, None, :] \
        & ~torch.eye(T, dtype=torch.bool)
    crowded = near.any(-1).gather(1, tid) if T else torch.zeros_like(tid, dtype=torch.bool)
    return torch.where(edge, 2, torch.where(crowded, 1, 0))


def front_end_scans(truth: torch.Tensor, alive: torch.Tensor, model: MeasurementModel, spec: FrontEndSpec,
                    generator: torch.Generator | None = None, progress: bool | None = None) -> tuple[Scans, FrontEndRecord]:
    """Detections of targets ``truth (B, K, T, n)`` (SI, NaN where not alive; ``alive (K, T)``)
    through the signal chain, per pair of ``model`` (layout ``pair``, components ``range``,
    ``doppler``): ``Scans`` with ``z (B, K, S, M, 2)`` in m and Hz, and the chain's record.
    ``progress``: a bar over the scans (``None``: only on a terminal)."""
    from tqdm.auto import tqdm

    check_model_for_detections(model)
    if tuple(model.components) != ("range", "doppler"):
        raise ConfigError(f"detections from signals are (range, doppler) per pair; the model has {model.components}")
    B, K, T, _ = truth.shape
    S = model.n_pairs
    sig = spec.signal
    fs, c = sig.sample_rate_hz, SPEED_OF_LIGHT
    baseline = torch.tensor(model.geometry.baselines_m(), dtype=torch.float64)  # (S,)
    r_true, f_true, r_tx, r_rx = true_cells(model, truth.to(torch.float64))
    live = alive.to(torch.bool).expand(B, K, T)
    delay = (r_true - baseline) / c  # (B, K, T, S)
    snr = echo_snr_db(sig, r_tx, r_rx)
    D, U = spec.map_shape
    cell = (spec.doppler_bin_hz, sig.range_bin_m)
    in_map = live[..., None] & (delay >= 0) & (delay * fs <= U - 1) & (f_true.abs() <= spec.max_doppler_hz)

    rows = B * S
    lists_z, lists_ok, lists_org = [], [], []
    sums = {"detected": np.zeros((T, S)), "in_map": np.zeros((T, S)), "false_alarms": np.zeros(S), "maps": 0.0,
            "err_range_sq": 0.0, "err_doppler_sq": 0.0, "sd_range_sq": 0.0, "sd_doppler_sq": 0.0, "errors": 0.0,
            "by_kind_err_range_sq": np.zeros(len(DETECTION_KINDS)), "by_kind_sd_range_sq": np.zeros(len(DETECTION_KINDS)),
            "by_kind_errors": np.zeros(len(DETECTION_KINDS)),
            "depth_db": 0.0, "cpis": 0.0, "sim_seconds": 0.0, "proc_seconds": 0.0}
    record = FrontEndRecord(sums)
    example = {}
    order_b = torch.arange(rows) // S  # row -> run
    order_s = torch.arange(rows) % S  # row -> pair
    for k in tqdm(range(K), desc=f"front end, {rows} CPIs per scan", unit="scan", leave=False,
                  disable=None if progress is None else not progress):
        parts_z = []
        for lo in range(0, rows, spec.chunk_rows):
            idx = torch.arange(lo, min(rows, lo + spec.chunk_rows))
            b, s = order_b[idx], order_s[idx]
            t0 = time.perf_counter()
            cpi = simulate_cpi(sig, delay[b, k, :, s], f_true[b, k, :, s], snr[b, k, :, s], live[b, k] & (delay[b, k, :, s] >= 0),
                               generator)
            t1 = time.perf_counter()
            keep = k in spec.example_scans and lo == 0
            res = process_cpi(spec, cpi.ref, cpi.surv, full_maps=keep)
            t2 = time.perf_counter()
            sums["proc_seconds"] += t2 - t1
            sums["sim_seconds"] += t1 - t0
            sums["depth_db"] += float(res.depth_db.sum())
            sums["cpis"] += len(idx)
            cen = res.centroids
            f0, df = float(res.doppler_hz[0]), float(res.doppler_hz[1] - res.doppler_hz[0])
            rng = cen.range_bin * sig.range_bin_m + baseline[s, None]
            dop = f0 + cen.doppler_bin * df
            parts_z.append((torch.stack([rng, dop], -1), cen.valid,
                            torch.stack([cen.sd_range_bin * sig.range_bin_m, cen.sd_doppler_bin * df], -1)))
            if keep:
                before = range_doppler_map(spec, cpi.surv[:S], cpi.ref[:S]).values.abs() ** 2
                example[k] = (before, res.power[:S], res.threshold[:S], res.detections[:S], res.doppler_hz)
        M = max(p[1].shape[1] for p in parts_z)
        z_k = torch.cat([torch.cat([p[0], p[0].new_full((p[0].shape[0], M - p[0].shape[1], 2), math.nan)], 1)
                         for p in parts_z])
        ok_k = torch.cat([torch.cat([p[1], p[1].new_zeros((p[1].shape[0], M - p[1].shape[1]))], 1) for p in parts_z])
        sd_k = torch.cat([torch.cat([p[2], p[2].new_full((p[2].shape[0], M - p[2].shape[1], 2), math.nan)], 1)
                          for p in parts_z])
        r_k = r_true[order_b, k, :, order_s]  # (rows, T)
        f_k = f_true[order_b, k, :, order_s]
        org = _label(z_k, ok_k, r_k, f_k, live[order_b, k], cell, spec.gate_cells)
        # statistics of this scan
        hit = org >= 0
        det_t = torch.zeros(rows, T)
        if T and M:
            det_t.scatter_add_(1, org.clamp_min(0), hit.to(det_t.dtype))
        inm = in_map[order_b, k, :, order_s]  # (rows, T)
        sums["detected"] += (det_t * inm).reshape(B, S, T).sum(0).T.numpy()
        sums["in_map"] += inm.to(torch.float64).reshape(B, S, T).sum(0).T.numpy()
        sums["false_alarms"] += (org == CLUTTER).sum(1).reshape(B, S).sum(0).to(torch.float64).numpy()
        sums["maps"] += B  # maps per pair
        if bool(hit.any()):
            tid = org.clamp_min(0)
            er = z_k[..., 0] - r_k.gather(1, tid)
            ef = z_k[..., 1] - f_k.gather(1, tid)
            sums["err_range_sq"] += float((er[hit] ** 2).sum())
            sums["err_doppler_sq"] += float((ef[hit] ** 2).sum())
            sums["sd_range_sq"] += float((sd_k[..., 0][hit] ** 2).sum())
            sums["sd_doppler_sq"] += float((sd_k[..., 1][hit] ** 2).sum())
            sums["errors"] += float(hit.sum())
            kind = _detection_kind(z_k[..., 0], tid, r_k, f_k, live[order_b, k], baseline[order_s], cell, U)
            for i in range(len(DETECTION_KINDS)):
                sel = hit & (kind == i)
                sums["by_kind_err_range_sq"][i] += float((er[sel] ** 2).sum())
                sums["by_kind_sd_range_sq"][i] += float((sd_k[..., 0][sel] ** 2).sum())
                sums["by_kind_errors"][i] += float(sel.sum())
        lists_z.append(z_k.reshape(B, S, M, 2))
        lists_ok.append(ok_k.reshape(B, S, M))
        lists_org.append(org.reshape(B, S, M))
    M = max([z.shape[2] for z in lists_z] + [0])

    def pad(t: torch.Tensor, fill) -> torch.Tensor:
        shape = list(t.shape)
        shape[2] = M - t.shape[2]
        return torch.cat([t, t.new_full(shape, fill)], 2)

    z = torch.stack([pad(t, math.nan) for t in lists_z], 1)
    ok = torch.stack([pad(t, False) for t in lists_ok], 1)
    origin = torch.stack([pad(t, PADDING) for t in lists_org], 1)
    z, ok, (origin,) = shuffled(z, ok, (origin,), generator)
    scans = Scans(z, ok, origin.masked_fill(~ok, PADDING))
    record.example = _example(example, scans, r_true, f_true, live, sig, spec)
    return scans, record


def _example(maps: dict, scans: Scans, r_true, f_true, live, sig: FMSignalSpec, spec: FrontEndSpec) -> dict:
    """Run 0's maps at the example scans and its detections and truth over all scans (numpy)."""
    out = {}
    if maps:
        ks = sorted(maps)
        out["@maps"] = np.stack([np.stack([m.numpy() for m in maps[k][:4]], 1) for k in ks]).astype(np.float32)
        out["@map_scans"] = np.asarray(ks, dtype=np.int64)
        out["@map_doppler_hz"] = maps[ks[0]][4].numpy()
    z0 = scans.z[0].numpy()  # (K, S, M, 2)
    out["@detections"] = np.concatenate([z0, scans.origin[0].numpy()[..., None].astype(np.float64)], -1)
    truth_rd = torch.stack([r_true[0], f_true[0]], -1)  # (K, T, S, 2)
    out["@truth_rd"] = torch.where(live[0][..., None, None], truth_rd, math.nan).numpy()
    return out


def summarise(sums: dict, spec: FrontEndSpec) -> dict:
    """The chain's figures for ``results.json`` from its sums over all blocks (each entry the
    total of :attr:`FrontEndRecord.sums`)."""
    in_map, detected = np.asarray(sums["in_map"]), np.asarray(sums["detected"])
    maps = float(sums["maps"])
    S = in_map.shape[-1]
    D, U = spec.map_shape
    cpis = max(float(sums["cpis"]), 1.0)
    proc = float(sums["proc_seconds"]) / cpis
    err = float(sums["errors"])
    per_target = np.where(in_map.sum(-1) > 0, detected.sum(-1) / np.maximum(in_map.sum(-1), 1), np.nan)
    return {
        "pd_measured": float(detected.sum() / max(in_map.sum(), 1)),
        "pd_measured_per_target": [None if np.isnan(v) else float(v) for v in per_target],
        "false_alarms_per_map": float(sums["false_alarms"].sum() / max(maps * S, 1)),
        "false_alarms_per_map_per_pair": (sums["false_alarms"] / max(maps, 1)).tolist(),
        "nominal_false_alarms_per_map": spec.cfar.pfa * D * U,
        "map_cells": D * U,
        "rmse_range_m": math.sqrt(sums["err_range_sq"] / err) if err else None,
        "rmse_doppler_hz": math.sqrt(sums["err_doppler_sq"] / err) if err else None,
        "reported_sd_range_m": math.sqrt(sums["sd_range_sq"] / err) if err else None,
        "reported_sd_doppler_hz": math.sqrt(sums["sd_doppler_sq"] / err) if err else None,
        "detections_scored": int(err),
        "range_by_kind": {name: {"detections": int(n), "rmse_range_m": math.sqrt(e / n) if n else None,
                                 "reported_sd_range_m": math.sqrt(v / n) if n else None}
                          for name, e, v, n in zip(DETECTION_KINDS, np.asarray(sums.get("by_kind_err_range_sq", [0] * 3)),
                                                   np.asarray(sums.get("by_kind_sd_range_sq", [0] * 3)),
                                                   np.asarray(sums.get("by_kind_errors", [0] * 3)))},
        "cancellation_depth_db": float(sums["depth_db"]) / cpis,
        "cpis": int(sums["cpis"]),
        "pairs": int(S),
        "processing_seconds_per_cpi": proc,
        "faster_than_real_time": spec.signal.cpi_s / proc if proc > 0 else None,
        "simulation_seconds_per_cpi": float(sums["sim_seconds"]) / cpis,
    }
