"""Inference speed of the set tracker (pmsr_nn/nets/set_tracker.py) on a block of runs.

Draws ``--runs`` scenes of ``--scans`` scans with ``--targets`` targets, Pd 0.7 and 40 clutter
points per pair and scan in the FITEE 2023 geometry (what evaluate/dense_crossing.yaml reads),
then times :func:`~pmsr_nn.nets.set_inference.track_runs` (every window of every run through the
network) on the CPU and, where there is one, on the GPU, after one untimed warm-up each.

    python benchmarks/bench_set_tracker.py --checkpoint models/released/set_tracker_s0.pt --json benchmarks/results/set_tracker.json
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import torch


def main(argv=None) -> int:
    from pmsr_nn.nets.scene_data import SceneConfig, SceneSampler
    from pmsr_nn.nets.set_inference import load_set_checkpoint, track_runs

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--scans", type=int, default=240)
    ap.add_argument("--targets", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--devices", default="cpu,cuda", help="comma-separated: cpu, cuda (cuda only where there is one)")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    ck = load_set_checkpoint(a.checkpoint)
    scenes = SceneConfig(window=a.scans, targets=(a.targets, a.targets), pd=(0.7, 0.7), clutter_per_scan=(40, 40))
    sampler = SceneSampler(str(Path(__file__).resolve().parents[1] / "datasets" / "fitee2023_ca.yaml"), scenes)
    scans, *_ = sampler.draw((0,), a.runs)
    out = {"command": "python benchmarks/bench_set_tracker.py " + " ".join(sys.argv[1:] if argv is None else argv), "date": time.strftime("%Y-%m-%d"),
           "machine": platform.processor() or platform.machine(), "torch": torch.__version__, "threads": torch.get_num_threads(),
           "runs": a.runs, "scans": a.scans, "targets": a.targets, "windows": a.runs * (a.scans - ck.net.cfg.window + 1)}
    asked = a.devices.split(",")
    devices = [d for d in ("cpu", "cuda") if d in asked and (d == "cpu" or torch.cuda.is_available())]
    for dev in devices:
        track_runs(ck.net, scans.z, scans.valid, sampler.model, device=dev)  # warm-up
        times = []
        for _ in range(a.repeats):
            if dev == "cuda":
                torch.cuda.synchronize()
            t0 = time.perf_counter()
            track_runs(ck.net, scans.z, scans.valid, sampler.model, device=dev)
            if dev == "cuda":
                torch.cuda.synchronize()
            times.append(time.perf_counter() - t0)
        out[dev] = {"seconds_per_run": min(times) / a.runs, "all_seconds": times,
                    "name": torch.cuda.get_device_name() if dev == "cuda" else out["machine"]}
        print(f"{dev:5s} {min(times) / a.runs * 1000:.1f} ms per run of {a.scans} scans (best of {a.repeats})")
    if a.json:
        a.json.write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
