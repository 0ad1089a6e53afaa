"""Measured false-alarm rate per cell of the FM front end's OS-CFAR on noise-only maps, and its
calibrated scale factor.

Eq. 2 of the Daniyan seed (Rohling's OS-CFAR) holds for independent, identically distributed
training cells. The chain's maps are independent only for a white reference and no Doppler taper:
an FM reference correlates neighbouring range cells (amplitude correlation 0.89, 0.62, 0.34, 0.15
at 1-4 bins for 25 kHz RMS deviation at 320 kHz) and a Hamming taper neighbouring Doppler rows
(0.63 at one row), which changes the rate. For each case this study makes noise-only maps of the
scenario's size (401 x 52; surveillance channel: white noise; no cancellation) with two
independent seeds: on the first (``--seed + 1``) it measures ``cfar.alpha_factor`` (the empirical
``1 - pfa`` quantile of power over Eq. 2's threshold, :func:`pmsr_nn.frontend.cfar.calibrate_alpha_factor`),
on the second (``--seed``) it counts false alarms with Eq. 2's threshold and with the calibrated
one, each against the binomial 99% interval of the nominal Pfa.

    python evaluate/fm_cfar_false_alarms.py --cpis 100 --json evaluate/results/fm_cfar_false_alarms.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import torch
from scipy.stats import binom

from pmsr_nn.frontend.cfar import calibrate_alpha_factor, os_cfar
from pmsr_nn.frontend.chain import CancellationSpec, FrontEndSpec, range_doppler_map
from pmsr_nn.frontend.fm_signals import simulate_cpi


def noise_maps(spec: FrontEndSpec, reference: str, cpis: int, seed: int) -> torch.Tensor:
    """``(cpis, D, U)`` power maps of white surveillance noise against a white or FM reference."""
    g = torch.Generator().manual_seed(seed)
    sig = dataclasses.replace(spec.signal, dnr_db=-300.0, multipath_delay_samples=(), multipath_cnr_db=())
    N, out = sig.samples, []
    for lo in range(0, cpis, 10):
        rows = min(10, cpis - lo)
        surv = torch.complex(*torch.randn(2, rows, N, generator=g, dtype=torch.float64))
        if reference == "white":
            ref = torch.complex(*torch.randn(2, rows, N, generator=g, dtype=torch.float64))
        else:
            ref = simulate_cpi(sig, torch.zeros(rows, 0), torch.zeros(rows, 0), torch.zeros(rows, 0),
                               torch.zeros(rows, 0, dtype=torch.bool), g).ref
        out.append(range_doppler_map(spec, surv, ref).power)
    return torch.cat(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cpis", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    base = dataclasses.replace(FrontEndSpec(), cancellation=CancellationSpec(method="none"))
    c = base.cfar
    out = {"pfa": c.pfa, "map": list(base.map_shape), "cpis": args.cpis, "calibration_seed": args.seed + 1,
           "test_seed": args.seed, "cases": {}}
    for name, reference, window in (("white reference, no taper", "white", "none"),
                                    ("FM reference, no taper", "fm", "none"),
                                    ("FM reference, Hamming taper (the scenario)", "fm", "hamming")):
        spec = dataclasses.replace(base, window=window)
        cal = calibrate_alpha_factor(noise_maps(spec, reference, args.cpis, args.seed + 1), c.guard, c.train, c.rank, c.pfa)
        maps = noise_maps(spec, reference, args.cpis, args.seed)
        cells = maps.numel()
        lo, hi = binom.interval(0.99, cells, c.pfa)
        case = {"alpha_factor": cal["alpha_factor"], "calibration_cells": cal["cells"],
                "calibration_rate_unscaled": cal["rate_unscaled"], "cells": cells, "nominal_99_interval": [lo, hi]}
        for key, f in (("eq2", 1.0), ("calibrated", cal["alpha_factor"])):
            hits = int(os_cfar(maps, c.guard, c.train, c.rank, c.pfa, full_maps=False, alpha_factor=f).detections.sum())
            case[key] = {"detections": hits, "rate": hits / cells, "rate_over_nominal": hits / cells / c.pfa,
                         "inside_99_interval": bool(lo <= hits <= hi)}
            print(f"{name}, {key} (alpha_factor {f:.4f}): {hits} of {cells:,} cells = {hits / cells:.3g} "
                  f"({hits / cells / c.pfa:.2f}x nominal; 99% interval of the nominal count [{lo:.0f}, {hi:.0f}])", flush=True)
        out["cases"][name] = case
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
