"""The measured values behind the statistical checks of tests/test_tbd.py and tests/test_tbd_snr.py
(same scenes, seeds and particle budgets), printed: the false-alarm rate of the multi-Bernoulli
filter without a target, and the online SNR estimate once the target has been held for a while.

``--estimators``: instead, the seed's scene (5x5, the seed's particle budget) over 32 runs for each
of ``--seeds``, the ICMB with known SNRs beside the modified ICMB with the seed's SNR estimate and
with the bias-corrected one (issue 37): the detected-frame rate over the present frames, the
estimate over frames 11-16 and over the absent frames (about 6 minutes per seed on one core);
then the detected rates' paired differences over every run, with their standard errors.

    python evaluate/tbd_checks.py
    python evaluate/tbd_checks.py --estimators --seeds 7 11
"""

from __future__ import annotations

import argparse
import math

import torch

from pmsr_nn.tbd.maps import MapSpec, Satellite
from pmsr_nn.tbd.multibernoulli import MBSpec
from pmsr_nn.tbd.run import simulate_and_run
from pmsr_nn.tbd.scene import TBDScene

SATS = (Satellite("SVN2", (-17745.0e3, 1835.5e3, 13077.3e3), (2229.2, -519.2, 2058.0)),
        Satellite("SVN10", (10232.9e3, -15519.5e3, 12420.5e3), (190.2, -2114.0, -1798.6)),
        Satellite("SVN18", (6818.7e3, -6090.4e3, 18620.3e3), (1654.7, -2019.3, -926.3)))


def estimators(seeds: list[int], runs: int = 32) -> None:
    scene = TBDScene(SATS, (8.0, 9.0, 10.0), MapSpec(doppler_cell_hz=10.0))
    specs = {"ICMB, known SNRs": MBSpec(), "modified ICMB, seed's max": MBSpec(estimate_snr=True),
             "modified ICMB, bootstrap": MBSpec(estimate_snr=True, snr_estimator="bootstrap")}
    per_run = {name: [] for name in specs}  # each run's detected rate over its present frames
    for seed in seeds:
        for name, spec in specs.items():
            out, truth = simulate_and_run(scene, spec, runs, seed)
            alive = truth.alive[:, 0]
            detected = out.best(0.5)[1].double()  # (runs, frames)
            per_run[name].append(detected[:, alive].mean(1))
            rate, fa = float(detected[:, alive].mean()), float(detected[:, ~alive].mean())
            held = ", ".join(f"{v:.2f}" for v in out.snr_db[:, 10:16].mean((0, 1)).tolist())
            absent = ", ".join(f"{v:.2f}" for v in out.snr_db[:, ~alive].mean((0, 1)).tolist())
            print(f"seed {seed}, {runs} runs, {name}: detected {100 * rate:.1f} % of the present frames, "
                  f"{100 * fa:.2f} % of the absent; SNR used, frames 11-16: {held} dB; absent: {absent} dB")
    rate = {name: torch.cat(v) for name, v in per_run.items()}
    names = list(specs)
    for a, b in ((names[2], names[1]), (names[2], names[0]), (names[1], names[0])):
        d = rate[a] - rate[b]  # paired: the same maps, each filter its own particles
        print(f"{a} - {b}, paired over {len(d)} runs: {100 * float(d.mean()):+.1f} +- "
              f"{100 * float(d.std()) / math.sqrt(len(d)):.1f} points (1 s.e.)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--estimators", action="store_true")
    ap.add_argument("--seeds", type=int, nargs="+", default=[7, 11])
    args = ap.parse_args()
    if args.estimators:
        estimators(args.seeds)
        return
    maps = MapSpec(doppler_cell_hz=10.0)
    # no target before frame 20: 24 runs x 19 absent frames, particle budget 500-2,000 (4,000 births)
    scene = TBDScene(SATS, (8.0, 9.0, 10.0), maps, frames=20, appears_frame=20, disappears_frame=20)
    out, truth = simulate_and_run(scene, MBSpec(estimate_snr=True, particles_min=500, particles_max=2000,
                                                birth_particles=4000), 24, 21)
    _, det, r = out.best(0.5)
    absent = ~truth.alive[:, 0]
    print(f"no target: {int(det[:, absent].sum())} detections in {int(absent.sum()) * 24} frames "
          f"(rate {float(det[:, absent].double().mean()):.4f}), largest existence {float(r[:, absent].max()):.3f}")
    # the seed's scene and particle budget, 8 runs: the estimate over frames 11-16
    scene = TBDScene(SATS, (8.0, 9.0, 10.0), maps)
    out, _ = simulate_and_run(scene, MBSpec(estimate_snr=True), 8, 31)
    est = out.snr_db[:, 10:16].mean((0, 1)).tolist()
    print("online SNR estimate, frames 11-16, for maps of 8, 9, 10 dB: " + ", ".join(f"{v:.2f}" for v in est) + " dB")


if __name__ == "__main__":
    main()
