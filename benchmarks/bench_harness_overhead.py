"""Benchmark: what the one runner costs on top of calling the trackers directly (issue 14).

For each scenario the same blocks run two ways, alternately, ``--repeats`` times:

* ``harness``: :func:`pmsr_nn.harness.run.blocks.run_blocks` (draw truth and products, call every
  method through its registered kind, score: point sums, set metrics, loss rule);
* ``direct``: the products drawn beforehand (not timed), then the tracker functions called as a
  user would (``ekf`` / ``ukf`` on the target streams, those living equally long stacked as runs,
  ``Tracker.track``, ``msjpda``), nothing scored.

The figure is the ratio of the medians, harness / direct (1.05 = 5 % overhead). Scenarios:
evaluate/fitee2023_three_trajectories.yaml (first case; EKF, UKF, SI+KF, two released networks)
and evaluate/shared_drones.yaml (three drones, S-MSJPDA on detections, set metrics).

    python benchmarks/bench_harness_overhead.py --json benchmarks/results/bench_harness_overhead.json
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_info import write_figures  # noqa: E402

from pmsr_nn.filters import Gaussian, ekf, si_kf, ukf  # noqa: E402
from pmsr_nn.harness.scenario.loading import load_any  # noqa: E402
from pmsr_nn.harness.run.blocks import draw_block, run_blocks  # noqa: E402
from pmsr_nn.harness.run.runner import prepare  # noqa: E402
from pmsr_nn.methods.msjpda import settings  # noqa: E402
from pmsr_nn.methods import MethodCall  # noqa: E402
from pmsr_nn.trackers.msjpda import msjpda  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
KEEP = {"EKF", "UKF", "SI+KF", "MDFNN local [seed 0]", "KalmanNet [seed 0]", "S-MSJPDA"}


def _equal_lives(alive: torch.Tensor):
    """``[(targets, first scans, length)]``: targets grouped by how many scans they live."""
    groups: dict[int, list[tuple[int, int]]] = {}
    for t in range(alive.shape[1]):
        on = torch.nonzero(alive[:, t]).flatten()
        groups.setdefault(int(on[-1]) + 1 - int(on[0]), []).append((t, int(on[0])))
    return [([t for t, _ in g], [k for _, k in g], L) for L, g in groups.items()]


def direct(setup, products_per_block: list[dict]) -> None:
    """Every method of ``setup`` on pre-drawn products, by direct calls of the tracker functions."""
    m = setup.models
    case = setup.cases[0]
    alive = case.alive
    for products in products_per_block:
        for spec in setup.methods:
            if spec.kind == "s_msjpda":
                det = products["detections"]
                call = MethodCall(spec, det, alive, m, case.sensing)
                msjpda(det.scans, det.prior, m.motion, m.dt, m.q, case.sensing.detection_model,
                       case.sensing.detection_model.R(), settings(call), "sequential",
                       active=None if bool(alive.all()) else alive)
                continue
            s = products["measurements"]
            for targets, k0s, L in _equal_lives(alive):  # targets living equally long: their runs stacked
                z = torch.cat([s.z[:, t, k0:k0 + L] for t, k0 in zip(targets, k0s)])
                prior = Gaussian(torch.cat([s.prior.x[:, t] for t in targets]), torch.cat([s.prior.P[:, t] for t in targets]))
                if spec.kind == "ekf":
                    ekf(prior, z, m.motion, m.dt, m.q, m.model, m.R)
                elif spec.kind == "ukf":
                    ukf(prior, z, m.motion, m.dt, m.q, m.model, m.R)
                elif spec.kind == "si_kf":
                    si_kf(z, m.model, m.motion, m.dt, m.q, noise_std=m.noise_std.expand(z.shape[0], -1), prior=prior)
                elif spec.kind == "learned":
                    setup.resources[spec.name].track(z)
                else:
                    raise SystemExit(f"no direct call for kind {spec.kind}")


def measure(path: Path, runs: int, repeats: int) -> dict:
    sc = load_any(path, mc_runs=runs)
    sc = sc.replace(cases=sc.cases[:1], methods=tuple(x for x in sc.methods if x.name in KEEP))
    setup = prepare(sc)
    blocks = range(sc.n_blocks)
    drawn = [draw_block(setup, 0, b)[1] for b in blocks]
    harness, plain = [], []
    with torch.no_grad():
        direct(setup, drawn[:1])  # untimed warm-up of both paths
        run_blocks(setup, range(1), progress=False)
        for _ in range(repeats):
            t0 = time.perf_counter()
            run_blocks(setup, blocks, progress=False)
            harness.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            direct(setup, drawn)
            plain.append(time.perf_counter() - t0)
    h, d = statistics.median(harness), statistics.median(plain)
    print(f"{path.name}: harness {h:.2f} s, direct calls {d:.2f} s, ratio {h / d:.3f} "
          f"({runs} runs, {len(setup.methods)} methods, median of {repeats})")
    return {"scenario": path.name, "case": sc.cases[0].name, "runs": runs, "block_runs": sc.block_runs,
            "methods": [x.name for x in setup.methods], "harness_s": harness, "direct_s": plain,
            "ratio_of_medians": h / d}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=20, help="Monte Carlo runs per scenario (default 20)")
    ap.add_argument("--repeats", type=int, default=3, help="alternating repeats, median taken (default 3)")
    ap.add_argument("--json", type=Path, help="write the figures here")
    args = ap.parse_args()
    figures = {"threads": torch.get_num_threads(), "scenarios": [
        measure(ROOT / "evaluate" / name, args.runs, args.repeats)
        for name in ("fitee2023_three_trajectories.yaml", "shared_drones.yaml")]}
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
