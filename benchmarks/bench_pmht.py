"""Benchmark: PMHT and 3-D association PMHT run time (issue 15's targets), and Stone Soup's PMHT.

The scenario is evaluate/jeit2021_pmht.yaml: 200 scans, 10 targets, two transmitters on one
frequency, Poisson clutter of mean 79 per scan, detections pooled at the receiver. Timed in one
process, on the same draws:

* ``serial``: one run per call (what the paper's MATLAB Table 3 measures), for 4..8 EM iterations,
  PMHT-3D (pooled lists, illuminator unknown) and PMHT (per-pair lists), beside Table 3;
* ``batched``: a block of runs per call at 6 EM iterations, divided by the runs;
* ``memory``: ``--memory-runs`` runs in one call (chunked by ``chunk_runs``): the peak memory.

Stone Soup 1.9.1's ``PMHTTracker`` with its ``UnscentedKalmanSmoother`` (a benchmark-only
dependency: ``pip install stonesoup==1.9.1``) runs beside ours on a near-clutter-free variant
it can take: one transmitter-receiver pair (its tracker has one measurement model, so the
illuminator is known), the first ``--ss-scans`` scans, Pd 0.8, ``--ss-clutter`` clutter points per
scan, tracks from the same priors (truth + N(0, 50 m / 5 m/s)); the same window (10 scans, 5
shared), 6 EM iterations, fixed priors. Stone Soup has no bistatic measurement model: ours (range
and Doppler of one pair) and our motion model go in through ``pmsr_nn.interop.stonesoup``, which
also converts the detections, priors and tracks. Both trackers' position RMSE and seconds per run
are recorded, and the ratio.

    python benchmarks/bench_pmht.py --json benchmarks/results/bench_pmht.json
    python benchmarks/bench_pmht.py --device cuda --memory-runs 1000 --no-stonesoup   # on a GPU
    OMP_NUM_THREADS=1 python benchmarks/bench_pmht.py --no-stonesoup --cpu-time --e-step point

``--e-step`` overrides the study's E-step (``marginal``) for both trackers; ``--cpu-time`` times
in CPU seconds of the process (``time.process_time``; with one thread, what a loaded shared
machine moves least) instead of wall seconds.
"""

from __future__ import annotations

import argparse
import dataclasses
import resource
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_info import write_figures  # noqa: E402

from pmsr_nn.config import load_yaml  # noqa: E402
from pmsr_nn.errors import ConfigError  # noqa: E402
from pmsr_nn.filters import Gaussian  # noqa: E402
from pmsr_nn.harness.scenario.schema import scenario_from_dict  # noqa: E402
from pmsr_nn.harness.run.blocks import draw_block  # noqa: E402
from pmsr_nn.harness.run.runner import prepare  # noqa: E402
from pmsr_nn.methods.pmht import settings as method_settings  # noqa: E402
from pmsr_nn.methods import MethodCall  # noqa: E402
from pmsr_nn.rng import seeded_generator  # noqa: E402
from pmsr_nn.simulation.detections import simulate_scans  # noqa: E402
from pmsr_nn.trackers.pmht import pmht  # noqa: E402
from pmsr_nn.trackers.pmht_model import AssociationLists  # noqa: E402

SCENARIO = Path(__file__).resolve().parents[1] / "evaluate" / "jeit2021_pmht.yaml"
PAPER_TABLE3 = {"PMHT-3D": {4: 58, 5: 72, 6: 87, 7: 101, 8: 114}, "PMHT": {4: 56, 5: 73, 6: 85, 7: 100, 8: 113}}
"""Table 3 of the paper: seconds for a 200-scan run vs EM iterations (MATLAB)."""


def _to(device, lists: AssociationLists, prior: Gaussian, runs: slice):
    l = lists.take(runs)
    return (AssociationLists(l.z.to(device), l.valid.to(device), l.candidates.to(device)),
            Gaussian(prior.x[runs].to(device), prior.P[runs].to(device)))


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def ours(args) -> tuple[dict, object]:
    data = load_yaml(SCENARIO)
    data.update(mc_runs=args.runs, block_runs=args.runs)
    sc = scenario_from_dict(data, SCENARIO.parent)
    setup = prepare(sc)
    case = setup.cases[0]
    det = draw_block(setup, 0, 0)[1]["detections"]
    m, sensing = setup.models, case.sensing
    model, R = sensing.detection_model, sensing.detection_model.R().to(args.device)
    out = {"device": args.device, "runs": args.runs, "methods": {}, "e_step": args.e_step or "the study's",
           "clock": "process_time" if args.cpu_time else "perf_counter"}
    clock = time.process_time if args.cpu_time else time.perf_counter
    for spec in setup.methods:
        if spec.kind not in ("pmht", "pmht_3d") or "no annealing" in spec.name:
            continue
        call = MethodCall(spec, det, case.alive, m, sensing)
        lists = AssociationLists.pooled(det.pooled) if spec.kind == "pmht_3d" else AssociationLists.per_pair(det.scans)
        base = dataclasses.replace(method_settings(call), chunk_runs=args.chunk_runs)
        if args.e_step:
            base = dataclasses.replace(base, e_step=args.e_step)
        run = lambda s, runs: pmht(*_to(args.device, lists, det.prior, runs), m.motion, m.dt, m.q, model, R, s)
        run(base, slice(0, 1))  # warm-up
        serial = {}
        for it in range(4, 9):
            s = dataclasses.replace(base, em_iterations=it)
            times = []
            for r in range(args.serial_runs):
                _sync(args.device)
                t0 = clock()
                run(s, slice(r, r + 1))
                _sync(args.device)
                times.append(clock() - t0)
            serial[it] = statistics.median(times)
        _sync(args.device)
        t0 = clock()
        res = run(base, slice(0, args.runs))
        _sync(args.device)
        batched = (clock() - t0) / args.runs
        err = (res.x.cpu() - case.truth.x)[..., list(m.motion.pos_idx)].norm(dim=-1)
        rmse = float(err[:, sc.warmup_steps:].pow(2).mean((0, 2)).sqrt().mean())
        out["methods"][spec.name] = {"serial_s_per_run_vs_em": serial, "paper_s_per_run_vs_em": PAPER_TABLE3[spec.name],
                                     "batched_s_per_run_6em": batched, "rmse_pos_m": rmse}
        print(f"{spec.name:8s} serial s/run vs EM 4..8: " + ", ".join(f"{serial[i]:.2f}" for i in range(4, 9))
              + f"  (paper {', '.join(str(v) for v in PAPER_TABLE3[spec.name].values())})  batched "
              f"{batched:.3f} s/run  pos RMSE {rmse:.0f} m over {args.runs} runs")
    if args.memory_runs:
        spec = next(s for s in setup.methods if s.kind == "pmht_3d")
        data.update(mc_runs=args.memory_runs, block_runs=args.memory_runs)
        big = prepare(scenario_from_dict(data, SCENARIO.parent))
        det = draw_block(big, 0, 0)[1]["detections"]
        base = dataclasses.replace(method_settings(MethodCall(spec, det, case.alive, m, sensing)),
                                   chunk_runs=args.chunk_runs)
        lists = AssociationLists.pooled(det.pooled)
        if args.device.startswith("cuda"):
            torch.cuda.reset_peak_memory_stats()
        rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        _sync(args.device)
        t0 = time.perf_counter()
        pmht(*_to(args.device, lists, det.prior, slice(None)), m.motion, m.dt, m.q, model, R, base)
        _sync(args.device)
        seconds = time.perf_counter() - t0
        mem = {"runs": args.memory_runs, "chunk_runs": base.chunk_runs, "seconds": seconds,
               "s_per_run": seconds / args.memory_runs,
               "detections_mib": (det.pooled.scans.z.numel() * 8 + det.scans.z.numel() * 8) / 2**20,
               "peak_rss_growth_mib": (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0) / 1024}
        if args.device.startswith("cuda"):
            mem["peak_gpu_mib"] = torch.cuda.max_memory_allocated() / 2**20
        out["memory"] = mem
        print(f"{args.memory_runs} runs of PMHT-3D in one call (chunks of {base.chunk_runs}): {seconds:.1f} s "
              f"({seconds / args.memory_runs:.3f} s/run), " + ", ".join(f"{k} {v:.0f}" for k, v in mem.items()
                                                                       if k.endswith("mib")))
    return out, (setup, case)


# ---------------------------------------------------------------------------------- Stone Soup


def stone_soup(args, setup, case) -> dict:
    try:
        from pmsr_nn.interop import stonesoup as ss
        from stonesoup.predictor.kalman import UnscentedKalmanPredictor
        from stonesoup.smoother.kalman import UnscentedKalmanSmoother
        from stonesoup.tracker.pmht import PMHTTracker
        from stonesoup.updater.kalman import UnscentedKalmanUpdater
    except ConfigError:  # pmsr_nn.interop.stonesoup without Stone Soup
        print("Stone Soup not installed (pip install stonesoup==1.9.1): its comparison is skipped")
        return {"skipped": "stonesoup not installed"}

    K, m = args.ss_scans, setup.models
    sub = case.sensing.detection_model.for_pairs([0])  # one pair: Stone Soup's tracker has one model
    truth = case.truth.x[None, :K].expand(args.ss_runs, K, *case.truth.x.shape[1:]).contiguous()
    box = dataclasses.replace(case.sensing.clutter, per_scan=float(args.ss_clutter))
    g = seeded_generator(setup.scenario.seed, 15, 0)
    scans = simulate_scans(truth, sub, case.sensing.pd, box, g)
    sd = torch.tensor([50.0, 5.0] * 3, dtype=torch.float64)
    B, _, T, n = truth.shape
    prior = Gaussian(truth[:, 0] + torch.randn(B, T, n, generator=g, dtype=torch.float64) * sd,
                     torch.diag(sd**2).expand(B, T, n, n).clone())
    ref = MethodCall(next(s for s in setup.methods if s.kind == "pmht"), None, case.alive, m, case.sensing)
    s = dataclasses.replace(method_settings(ref), clutter_rate=(max(float(args.ss_clutter), 0.1),), overlap=5,
                            anneal=1.0, volume=box.volume_of(sub.components))
    lists = AssociationLists.per_pair(scans)
    pmht(lists.take(slice(0, 1)), Gaussian(prior.x[:1], prior.P[:1]), m.motion, m.dt, m.q, sub, sub.R(), s)  # warm-up
    t0 = time.perf_counter()  # one run per call, as Stone Soup runs
    x_ours = torch.cat([pmht(lists.take(slice(r, r + 1)), Gaussian(prior.x[r:r + 1], prior.P[r:r + 1]), m.motion, m.dt,
                             m.q, sub, sub.R(), s).x for r in range(B)])
    ours_s = (time.perf_counter() - t0) / B

    ss_model = ss.measurement_model(sub, n)  # our range-Doppler model of the pair
    cv = ss.transition_model(m.motion, m.q)  # ours; equals Stone Soup's ConstantVelocity per axis
    lo, span = box.box(sub.components)
    meas_range = np.array([[lo[i], lo[i] + span[i]] for i in range(2)])
    times = ss.scan_times(K, m.dt)
    ss_seconds, estimates = [], []
    for r in range(B):
        detector = ss.detector_feed(ss.scan_detections(scans.z[r], scans.valid[r], [ss_model], m.dt), m.dt)
        priors = [ss.gaussian_state(prior.x[r, t], prior.P[r, t], times[0]) for t in range(T)]
        tracker = PMHTTracker(detector=detector, predictor=UnscentedKalmanPredictor(cv),
                              updater=UnscentedKalmanUpdater(measurement_model=ss_model),
                              smoother=UnscentedKalmanSmoother(transition_model=cv), meas_range=meas_range,
                              clutter_rate=s.clutter_rate[0], batch_len=s.window, overlap_len=s.overlap,
                              update_log_pi=False, detection_probability=s.pd, init_priors=priors,
                              max_num_iterations=s.em_iterations)
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            for _ in tracker:
                pass
        ss_seconds.append(time.perf_counter() - t0)
        # each prior's track, the prior itself left out
        estimates.append([next(tr for tr in tracker.tracks if tr[0] is p).states[1:] for p in priors])
    x_ss = ss.tracks_to_estimates(estimates, K, m.dt, n).x.numpy()
    pos = list(m.motion.pos_idx)

    def rmse(x) -> float:
        e = (torch.as_tensor(x) - truth)[..., pos].norm(dim=-1)  # (B, K, T)
        return float(e[:, 10:].pow(2).nanmean((0, 2)).sqrt().nanmean())

    out = {"scans": K, "runs": B, "clutter_per_scan": args.ss_clutter, "pairs": 1, "targets": T,
           "ours_s_per_run": ours_s, "stonesoup_s_per_run": statistics.fmean(ss_seconds),
           "ours_rmse_pos_m": rmse(x_ours), "stonesoup_rmse_pos_m": rmse(x_ss),
           "stonesoup_scans_estimated": int(np.isfinite(x_ss[0, :, 0, 0]).sum())}
    out["speed_ratio"] = out["stonesoup_s_per_run"] / ours_s
    print(f"Stone Soup 1.9.1 PMHT vs ours, {T} targets, {K} scans, one pair, {args.ss_clutter} clutter/scan: "
          f"{out['stonesoup_s_per_run']:.2f} vs {ours_s:.3f} s/run ({out['speed_ratio']:.0f}x), pos RMSE "
          f"{out['stonesoup_rmse_pos_m']:.0f} vs {out['ours_rmse_pos_m']:.0f} m "
          f"(Stone Soup estimated {out['stonesoup_scans_estimated']} of {K} scans)")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=10, help="runs of the batched call (default 10)")
    ap.add_argument("--serial-runs", type=int, default=3, help="single-run calls timed per EM count (median)")
    ap.add_argument("--memory-runs", type=int, default=0, help="also run this many runs in one call (chunked)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--chunk-runs", type=int, default=64, help="runs per pass inside one call (bounds memory)")
    ap.add_argument("--ss-runs", type=int, default=2, help="runs of the Stone Soup comparison")
    ap.add_argument("--ss-scans", type=int, default=50, help="scans of the Stone Soup comparison")
    ap.add_argument("--ss-clutter", type=int, default=1, help="clutter per scan in the Stone Soup comparison")
    ap.add_argument("--no-stonesoup", action="store_true")
    ap.add_argument("--e-step", choices=("point", "marginal"), help="E-step of both trackers (default: the study's)")
    ap.add_argument("--cpu-time", action="store_true",
                    help="time serial and batched calls in CPU seconds of this process (time.process_time) instead "
                         "of wall time: on a machine shared with other jobs it moves less")
    ap.add_argument("--json", type=Path, help="write the figures here")
    args = ap.parse_args()
    figures, (setup, case) = ours(args)
    if not args.no_stonesoup:
        figures["stonesoup"] = stone_soup(args, setup, case)
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
