"""Range error of the FM front end's detections against their reported deviation, on echoes at
fixed SNRs in noise: the Gaussian lobe fit the chain uses (issue 37) and the power centroid it used
before, beside the delay's Cramer-Rao bound the chain reports.

Every CPI of the scenario's chain (``evaluate/fm_front_end.yaml``'s ``front_end:`` settings: FM
reference at 25 kHz RMS deviation, 320 kHz, 401 x 52 maps, ECA, Hamming taper, OS-CFAR) holds one
echo (no fluctuation, no range law) at a per-sample SNR of the list, its delay uniform either
*inside* the map (8 bins to ``EDGE_BINS`` inside the last) or at its *edge* (``EDGE_BINS`` inside
the last bin to one bin beyond it, where the lobe is cut), its Doppler uniform in +-150 Hz. For
each (SNR, region): the RMS error of both estimates, the RMS reported deviation (the bound), and
the fit's mean of ``(error / reported sd)^2`` with the chi-square 99% interval it lies in when the
reported deviations are right. The seed is independent of the study's.

``--study-runs N`` runs the study's own front end instead (its truth, Swerling 1 echoes, its
SNRs; ``N`` runs with seed ``--study-seed``, independent of the recorded study's) once with the
lobe fit and once with the centroid on the same signals, and gives the range RMSE and the reported
sd by kind of detection (``clear``, ``crowded``, ``edge``: :data:`~pmsr_nn.frontend.chain.DETECTION_KINDS`).

    python evaluate/fm_range_deviation.py --cpis 40 --json evaluate/results/fm_range_deviation.json
    python evaluate/fm_range_deviation.py --cpis 0 --study-runs 1 --json evaluate/results/fm_range_deviation_study.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
from pathlib import Path

import numpy as np
import torch
import yaml
from scipy.stats import chi2

from pmsr_nn.config import from_dict
from pmsr_nn.frontend.centroid import centroids
from pmsr_nn.frontend.cfar import os_cfar
from pmsr_nn.frontend.chain import EDGE_BINS, FrontEndSpec, process_cpi
from pmsr_nn.frontend.fm_signals import simulate_cpi

SNRS_DB = (-42.0, -38.0, -35.0, -30.0, -25.0)


def measure(spec: FrontEndSpec, snr_db: float, lo: float, hi: float, cpis: int, g: torch.Generator) -> dict:
    """Errors (bins) of the fit and the centroid of ``cpis`` echoes with delays uniform in ``[lo, hi]`` bins."""
    sig = dataclasses.replace(spec.signal, fluctuation="none", echo_range_law=False)
    c = spec.cfar
    fit, cen, sd, snr = [], [], [], []
    for start in range(0, cpis, 10):
        rows = min(10, cpis - start)
        d = lo + (hi - lo) * torch.rand(rows, 1, generator=g, dtype=torch.float64)
        fd = -150.0 + 300.0 * torch.rand(rows, 1, generator=g, dtype=torch.float64)
        cpi = simulate_cpi(sig, d / sig.sample_rate_hz, fd, torch.full((rows, 1), snr_db, dtype=torch.float64),
                           torch.ones(rows, 1, dtype=torch.bool), g)
        res = process_cpi(spec, cpi.ref, cpi.surv)
        cf = os_cfar(res.power, c.guard, c.train, c.rank, c.pfa, full_maps=False, alpha_factor=c.alpha_factor)
        plain = centroids(res.power, cf.detections, cf.noise, threshold=cf.threshold)
        k = res.centroids
        dop = res.doppler_hz[0] + k.doppler_bin * (res.doppler_hz[1] - res.doppler_hz[0])
        near = k.valid & ((k.range_bin - d).abs() < 3) & ((dop - fd).abs() < 3)
        first = near & (near.cumsum(1) == 1)  # the echo's detection (the strongest if it split)
        # same detections, so the same blobs in the same slots (ordered by SNR): only the range differs
        fit.append((k.range_bin - d)[first])
        cen.append((plain.range_bin - d)[first])
        sd.append(k.sd_range_bin[first])
        snr.append(k.snr_db[first])
    fit, cen, sd, snr = (torch.cat(x).numpy() for x in (fit, cen, sd, snr))
    if not len(fit):
        return {"echoes": cpis, "detected": 0}
    n = len(fit)
    rms = lambda e: float(np.sqrt(np.mean(np.square(e))))  # noqa: E731
    lo_q, hi_q = chi2.ppf([0.005, 0.995], n) / n
    z2 = float(np.mean((fit / sd) ** 2))
    return {"echoes": cpis, "detected": n, "map_snr_db_mean": float(snr.mean()),
            "reported_sd_bins": rms(sd), "rmse_fit_bins": rms(fit), "rmse_centroid_bins": rms(cen),
            "fit_over_reported": rms(fit) / rms(sd), "centroid_over_reported": rms(cen) / rms(sd),
            "fit_mean_z2": z2, "chi2_99_interval_of_mean_z2": [float(lo_q), float(hi_q)],
            "fit_inside_interval": bool(lo_q <= z2 <= hi_q)}


def study(scenario: Path, runs: int, seed: int) -> dict:
    """Range errors by kind of detection of the scenario's own front end, lobe fit and centroid."""
    from pmsr_nn.frontend import chain
    from pmsr_nn.harness.run.runner import prepare
    from pmsr_nn.harness.scenario.schema import load_scenario

    case = next(c for c in prepare(load_scenario(scenario)).cases if c.sensing.front_end is not None)
    truth = case.truth.draw(runs, torch.Generator().manual_seed(seed))
    out = {}
    for name in ("lobe fit", "centroid"):
        # the same signals (same generator seed) through the chain, its range estimate switched
        chain.centroids = centroids if name == "lobe fit" else (
            lambda *a, lobe_bandwidth=None, **k: centroids(*a, **k))
        try:
            _, rec = chain.front_end_scans(truth.x, truth.alive, case.sensing.detection_model, case.sensing.front_end,
                                           torch.Generator().manual_seed(seed + 1), progress=False)
        finally:
            chain.centroids = centroids
        f = chain.summarise(rec.sums, case.sensing.front_end)
        out[name] = {k: f[k] for k in ("detections_scored", "rmse_range_m", "reported_sd_range_m", "range_by_kind",
                                       "pd_measured", "false_alarms_per_map")}
        kinds = "; ".join(f"{k} {v['detections']}: {v['rmse_range_m']:.0f} / {v['reported_sd_range_m']:.0f} m"
                          for k, v in f["range_by_kind"].items() if v["detections"])
        print(f"study, {name}: {f['detections_scored']} detections, range RMSE {f['rmse_range_m']:.0f} m, reported "
              f"{f['reported_sd_range_m']:.0f} m ({kinds})", flush=True)
    return {"runs": runs, "seed": seed, **out}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cpis", type=int, default=40, help="echoes (one per CPI) per SNR and region")
    ap.add_argument("--seed", type=int, default=37)
    ap.add_argument("--scenario", type=Path, default=Path(__file__).with_name("fm_front_end.yaml"))
    ap.add_argument("--study-runs", type=int, default=0, help="runs of the scenario's own front end (0: none)")
    ap.add_argument("--study-seed", type=int, default=1000)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    spec = from_dict(FrontEndSpec, yaml.safe_load(args.scenario.read_text())["detections"]["front_end"],
                     where="detections.front_end")
    U = spec.range_bins
    g = torch.Generator().manual_seed(args.seed)
    out = {"scenario": os.path.relpath(args.scenario), "seed": args.seed, "map": list(spec.map_shape),
           "range_bin_m": spec.signal.range_bin_m, "edge_bins": EDGE_BINS, "cases": {}}
    if args.study_runs:
        out["study"] = study(args.scenario, args.study_runs, args.study_seed)
    for region, lo, hi in (("inside", 8.0, U - 1 - EDGE_BINS), ("edge", U - 1 - EDGE_BINS, U)):
        if args.cpis <= 0:
            break
        for snr in SNRS_DB:
            r = measure(spec, snr, lo, hi, args.cpis, g)
            out["cases"][f"{region}, {snr:g} dB per sample"] = {"region": region, "delay_bins": [lo, hi],
                                                                 "echo_snr_db": snr, **r}
            if not r["detected"]:
                print(f"{region:6s} {snr:5.0f} dB/sample: none of {r['echoes']} detected", flush=True)
                continue
            print(f"{region:6s} {snr:5.0f} dB/sample: {r['detected']}/{r['echoes']} detected, map SNR "
                  f"{r['map_snr_db_mean']:.1f} dB; reported {r['reported_sd_bins']:.3f} bins; fit "
                  f"{r['rmse_fit_bins']:.3f} ({r['fit_over_reported']:.2f}x, mean z^2 {r['fit_mean_z2']:.2f} in "
                  f"[{r['chi2_99_interval_of_mean_z2'][0]:.2f}, {r['chi2_99_interval_of_mean_z2'][1]:.2f}]); centroid "
                  f"{r['rmse_centroid_bins']:.3f} ({r['centroid_over_reported']:.2f}x)", flush=True)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
