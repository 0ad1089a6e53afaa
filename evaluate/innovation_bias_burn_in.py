"""How often the innovation bias test deletes and restarts a track that is right, by burn-in: one
drone seen at every scan by 3 pairs (range, range rate, azimuth; 30 m / 2 m/s / 3 deg), no clutter,
S-MSJPDA starting its own track, 40 runs of 60 scans (the scene of ``tests/test_innovation_bias.py``).
A run counts when it confirms more tracks with the test (window 20 scans, probability 0.999) than
without it. Seconds on one core.

    python evaluate/innovation_bias_burn_in.py [--burn-ins 0,5,10,20] [--json evaluate/results/innovation_bias_burn_in.json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from datetime import date
from pathlib import Path

import torch

RUNS, SCANS, SEED = 40, 60, 5
NOISE = (30.0, 2.0, math.radians(3.0))


def track_counts(bias) -> torch.Tensor:
    """Per run, the tracks S-MSJPDA confirmed for the one drone (``bias``: a BiasTest or None)."""
    from pmsr_nn.geometry import Geometry, Receiver, Transmitter
    from pmsr_nn.measurements import MeasurementModel
    from pmsr_nn.motion import ConstantAcceleration
    from pmsr_nn.rng import seeded_generator
    from pmsr_nn.simulation.detections import ClutterSpec, simulate_scans
    from pmsr_nn.trackers.management import Confirmer, Deleter, FixInitiator, Management
    from pmsr_nn.trackers.msjpda import JPDASettings
    from pmsr_nn.trackers.msjpda_managed import managed_msjpda

    motion = ConstantAcceleration(spatial_dim=2)
    geometry = Geometry.all_pairs([Transmitter((0.0, 0.0), 650e6)],
                                  [Receiver((-7000.0, -3000.0)), Receiver((-8000.0, 500.0)), Receiver((-7500.0, 4000.0))])
    model = MeasurementModel(geometry, ("range", "range_rate", "azimuth"), NOISE, (0, 3), (1, 4), layout="pair")
    x0 = torch.tensor([3000.0, 8.0, 0.0, 6000.0, -5.0, 0.0], dtype=torch.float64)
    F = motion.F(1.0, torch.float64)
    truth = torch.stack([x0 @ torch.linalg.matrix_power(F, k).T for k in range(SCANS)])[None, :, None].expand(RUNS, SCANS, 1, 6)
    scans = simulate_scans(truth, model, 1.0, ClutterSpec(per_scan=0), seeded_generator(SEED))
    prior_sd = torch.tensor([100.0, 5.0, 0.1] * 2, dtype=torch.float64)
    management = Management(FixInitiator(20.0, 2, 0.999), Confirmer(2, 3), Deleter(2), prior_sd, bias=bias)
    report = managed_msjpda(scans, motion, 1.0, 0.01, model, model.R(), JPDASettings(0.99, 1e-9), "sequential", management)
    return report.exists.any(1).sum(-1)


def main(argv=None) -> int:
    from pmsr_nn.trackers.innovation_bias import BiasTest

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--burn-ins", default="0,5,10,20", help="updates left out, comma-separated")
    ap.add_argument("--json", help="write the record here")
    a = ap.parse_args(argv)
    try:
        burn_ins = [int(b) for b in a.burn_ins.split(",")]
        if min(burn_ins) < 0:
            raise ValueError("a burn-in is at least 0")
    except ValueError as exc:
        print(f"error: --burn-ins: {exc}", file=sys.stderr)
        return 2
    start = time.perf_counter()
    plain = track_counts(None)
    restarted = {}
    for b in burn_ins:
        tested = track_counts(BiasTest(window=20.0, probability=0.999, burn_in=b))
        restarted[str(b)] = int((tested > plain).sum())
        print(f"burn-in {b}: the test restarted the track in {restarted[str(b)]} of {RUNS} runs")
    record = {"runs": RUNS, "scans": SCANS, "seed": SEED, "window": 20.0, "probability": 0.999,
              "runs_with_more_tracks_without_the_test": int((plain > 1).sum()), "restarted_runs": restarted,
              "info": {"date": date.today().isoformat(), "seconds": round(time.perf_counter() - start, 1),
                       "command": "python evaluate/innovation_bias_burn_in.py "
                                  + " ".join(argv if argv is not None else sys.argv[1:])}}
    if a.json:
        Path(a.json).write_text(json.dumps(record, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
