"""Benchmark: the FM front end on one CPI (issue 18's targets), beside pyapril 1.7.6 on the same signals.

The set-up is evaluate/fm_front_end.yaml's: 320 kHz complex samples, 1 s CPIs (320,000 samples),
52 delay bins (48 km), +-200 Hz Doppler, ECA over 16 delays, batches 2D-CCF (640-sample batches,
Hamming), 2-D OS-CFAR at Pfa 1e-4, centroiding. One CPI of one transmitter-receiver pair with a
direct path (60 dB over noise), four multipath echoes and four target echoes is simulated once,
then timed (median of ``--repeats`` calls, in this process):

* ``ours``: cancellation, 2D-CCF, OS-CFAR and centroids (:func:`pmsr_nn.frontend.chain.process_cpi`),
  one pair per call, and a batch of ``--batch`` pairs per call (divided by the pairs); each stage alone;
* ``pyapril``: its ECA canceller ``clutterCancellation.ECAS`` (one batch, no window extension,
  the same 16 zero-Doppler delays) and its batched cross-ambiguity ``detector.cc_detector_ons``
  (batches of ``r_max`` samples, Doppler zero-padded to 0.5 Hz bins; ``r_max`` must divide the CPI,
  so both sides use 50 delay bins there) on the same samples; pyapril has no OS-CFAR.

"x real time" is the CPI length over the seconds per CPI.

    python benchmarks/bench_front_end.py --json benchmarks/results/bench_front_end.json
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_info import median_seconds, write_figures  # noqa: E402

from pmsr_nn.frontend.cancellation import eca  # noqa: E402
from pmsr_nn.frontend.ccf import ccf_batches  # noqa: E402
from pmsr_nn.frontend.centroid import centroids  # noqa: E402
from pmsr_nn.frontend.cfar import os_cfar  # noqa: E402
from pmsr_nn.frontend.chain import FrontEndSpec, process_cpi  # noqa: E402
from pmsr_nn.frontend.fm_signals import simulate_cpi  # noqa: E402


def signals(spec: FrontEndSpec, rows: int, seed: int = 0):
    """One CPI of ``rows`` pairs, four targets each at 15-40 km and +-150 Hz, -35 dB per sample."""
    g = torch.Generator().manual_seed(seed)
    T = 4
    delay = (15e3 + 25e3 * torch.rand(rows, T, generator=g, dtype=torch.float64)) / 299_792_458.0
    doppler = (torch.rand(rows, T, generator=g, dtype=torch.float64) - 0.5) * 300
    snr = torch.full((rows, T), -35.0, dtype=torch.float64)
    return simulate_cpi(spec.signal, delay, doppler, snr, torch.ones(rows, T, dtype=torch.bool), g)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--batch", type=int, default=6, help="pairs per call in the batched timing")
    ap.add_argument("--no-pyapril", action="store_true")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    spec = FrontEndSpec()
    s = spec.signal
    D, U = spec.map_shape
    cpi = signals(spec, max(args.batch, 1))
    ref1, surv1 = cpi.ref[:1], cpi.surv[:1]
    figures = {"setup": {"sample_rate_hz": s.sample_rate_hz, "cpi_s": s.cpi_s, "samples": s.samples,
                         "map_doppler_x_range": [D, U], "eca_delays": spec.cancellation.range_bins,
                         "batch_len": spec.batch_len, "window": spec.window, "cfar_pfa": spec.cfar.pfa,
                         "threads": torch.get_num_threads()}}

    one = median_seconds(lambda: process_cpi(spec, ref1, surv1), args.repeats)
    many = median_seconds(lambda: process_cpi(spec, cpi.ref, cpi.surv), max(3, args.repeats // 3)) / cpi.ref.shape[0]
    c = spec.cancellation
    clean = eca(surv1, ref1, c.range_bins)[0]
    stage = {"eca": median_seconds(lambda: eca(surv1, ref1, c.range_bins), args.repeats)}
    rd = ccf_batches(clean, ref1, U, spec.batch_len, spec.max_doppler_hz, s.sample_rate_hz, window=spec.window)
    stage["ccf_batches"] = median_seconds(lambda: ccf_batches(clean, ref1, U, spec.batch_len, spec.max_doppler_hz,
                                                              s.sample_rate_hz, window=spec.window), args.repeats)
    power = rd.power
    kw = dict(guard=spec.cfar.guard, train=spec.cfar.train, rank=spec.cfar.rank, pfa=spec.cfar.pfa)
    cf = os_cfar(power, **kw, full_maps=False)
    stage["os_cfar"] = median_seconds(lambda: os_cfar(power, **kw, full_maps=False), args.repeats)
    stage["centroids"] = median_seconds(lambda: centroids(power, cf.detections, cf.noise, threshold=cf.threshold),
                                        args.repeats)
    figures["ours"] = {"seconds_per_cpi_one_pair": one, "x_real_time_one_pair": s.cpi_s / one,
                       f"seconds_per_cpi_batch_of_{cpi.ref.shape[0]}": many, "x_real_time_batched": s.cpi_s / many,
                       "stages_seconds": stage}
    print(f"ours: {one * 1e3:.1f} ms per CPI ({s.cpi_s / one:.1f}x real time); batched {many * 1e3:.1f} ms per pair "
          f"({s.cpi_s / many:.1f}x); stages " + ", ".join(f"{k} {v * 1e3:.1f} ms" for k, v in stage.items()))

    if not args.no_pyapril:
        from pyapril.clutterCancellation import ECAS
        from pyapril.detector import cc_detector_ons

        r = ref1[0].numpy()
        x = surv1[0].numpy()
        K, R = c.range_bins, 50  # cc_detector_ons needs r_max to divide the CPI
        subspace = [[0, k] for k in range(K)]
        t_eca = median_seconds(lambda: ECAS(r, x, subspace, 1, 0), max(3, args.repeats // 5))
        filtered = ECAS(r, x, subspace, 1, 0)
        t_ccf = median_seconds(lambda: cc_detector_ons(r, filtered, s.sample_rate_hz, spec.max_doppler_hz, R),
                               max(3, args.repeats // 5))
        ours_eca_ccf = median_seconds(lambda: ccf_batches(eca(surv1, ref1, K)[0], ref1, R, spec.batch_len,
                                                          spec.max_doppler_hz, s.sample_rate_hz, window=spec.window),
                                      args.repeats)
        ours_clean = eca(surv1, ref1, K)[0][0].numpy()
        agree = float(np.abs(ours_clean - filtered).max() / np.abs(filtered).max())
        figures["pyapril"] = {"version": "1.7.6", "ecas_seconds": t_eca, "cc_detector_ons_seconds": t_ccf,
                              "eca_plus_ccf_seconds": t_eca + t_ccf, "ours_eca_plus_ccf_seconds_50_bins": ours_eca_ccf,
                              "ratio_pyapril_over_ours": (t_eca + t_ccf) / ours_eca_ccf,
                              "eca_output_max_relative_difference": agree}
        print(f"pyapril 1.7.6: ECAS {t_eca * 1e3:.0f} ms + cc_detector_ons {t_ccf * 1e3:.0f} ms; ours (ECA + CCF, 50 "
              f"bins) {ours_eca_ccf * 1e3:.1f} ms: {(t_eca + t_ccf) / ours_eca_ccf:.1f}x faster; ECA outputs agree to "
              f"{agree:.1e} (relative, max)")
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
