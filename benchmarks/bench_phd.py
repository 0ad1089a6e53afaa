"""Benchmark: SMC-PHD run time, six targets over 700 scans, and Stone Soup 1.9.1's SMC-PHD beside it.

Target (the SMC-PHD + GTDA issue): a 700-scan run with six targets, 4,000 particles per target and
10 clutter points per scan at least 50x faster than real time (scans 1 s apart: under 14 s) on the
2-core CPU, particles and runs batched; Stone Soup's ``SMCPHDPredictor`` / ``SMCPHDUpdater`` on
the same detections with the same particle count beside it, seconds per scan and the ratio.

Scene, in the bistatic plane ``[r, rdot]`` (the filter's state), built here: six targets alive for
all scans, ``r_i(t) = 27.5 km + 15 km sin(0.02 t + 2 pi i / 6)`` (ranges 12.5-42.5 km, range-rates
within +-300 m/s, accelerations within 6 m/s^2; evenly spaced phases, so two targets that share a
range are at least 300 m/s apart in range-rate), detected with Pd 0.9, deviations 30 m and
4.5 m/s; Poisson clutter of mean 10 per scan uniform over 6.5-48 km x +-500 m/s; detections
padded to the largest count of the draw (what ``SMCPHD.run`` takes). The filter:
``pmsr_nn.trackers.phd.SMCPHD`` with ``PHDSpec()`` (4,000 particles per target, adaptive births:
800 particles for a scan's births on the detections no target explains, at least 100 per birth;
survival 0.99, birth rate 0.05, sigma 20 m/s^2), clutter intensity 10 / (41,500 m x 1,000 m/s);
``--births every_detection`` times the filter before issue 37 (800 particles on every detection). Timed in this process, the median of ``--repeats`` calls after one
untimed warm-up call:

* ``single``: one run (``B = 1``) of ``--scans`` scans: seconds per run, per scan, real-time factor;
* ``batched``: ``--batch`` runs (independent draws) in one call, divided by the runs (median of
  ``--repeats - 1`` calls after the warm-up, as in ``bench_tbd.py``);
* ``with_gtda``: the single run and GTDA labelling of its estimates (``label_tracks``, default
  ``LabelSpec(method="gtda")``) in one call;
* ``stonesoup``: Stone Soup 1.9.1 (benchmark-only: ``pip install stonesoup==1.9.1``) on scans
  ``--ss-start`` .. ``--ss-start + --ss-scans - 1`` of the single run's detections, started from our
  filter's particles after scan ``--ss-start - 1``; beside it our recursion (the filter's step
  methods predict, update, resample: no estimates, as Stone Soup's classes make none) on the same
  scans from the same particles, both with ``every_detection`` births (Stone Soup's sampler draws a
  fixed count per detection; the adaptive births have no counterpart there). Matched: the motion model exactly (``LinearGaussianTimeInvariantTransitionModel``
  with our ``F`` and ``Q``), ``LinearGaussian`` measurements, Pd, clutter intensity, survival
  (``death_probability = -ln 0.99``), birth rate, the birth particles (a ``ParticleSampler`` drawing
  800 per detection of the previous scan around it and moving them one step, as ours; Stone
  Soup's ``'expansion'`` scheme with ``birth_probability`` set each scan so that it draws exactly
  800 x that count) and the particle count after resampling (``num_samples`` set each scan to
  ours on the same scans), systematic resampling.

Beside every figure, the share of the machine's cores that other jobs used meanwhile
(``others_cpu_share``, from ``/proc/stat``): on this shared 2-core machine one other busy process
slows torch's two threads far more than 2x, so a figure taken beside one is not this code's time:
it is taken again (up to ``--retries`` times; every attempt is recorded).

    python benchmarks/bench_phd.py --json benchmarks/results/bench_phd.json
"""

from __future__ import annotations

import argparse
import math
import os
import time
import statistics
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_info import median_seconds, write_figures  # noqa: E402

from pmsr_nn.errors import ConfigError  # noqa: E402
from pmsr_nn.rng import seeded_generator  # noqa: E402
from pmsr_nn.trackers.labelling import LabelSpec, label_tracks  # noqa: E402
from pmsr_nn.trackers.phd import PHDSpec, PHDState, SMCPHD  # noqa: E402

SD = (30.0, 4.5)  # m, m/s
RANGE_M = (6500.0, 48000.0)
RATE_MPS = (-500.0, 500.0)
DT = 1.0


def truths(scans: int, targets: int) -> torch.Tensor:
    """``(K, T, 2)``: the module docstring's six (``targets``) sinusoidal bistatic tracks."""
    t = torch.arange(scans, dtype=torch.float64)[:, None] * DT
    phase = 2 * math.pi * torch.arange(targets, dtype=torch.float64) / targets
    amp, omega = 15000.0, 0.02
    return torch.stack([27500.0 + amp * torch.sin(omega * t + phase), amp * omega * torch.cos(omega * t + phase)], -1)


def draw(truth: torch.Tensor, runs: int, pd: float, clutter: float, seed: int):
    """Detections ``z (B, K, J, 2)`` (NaN where padded) and ``valid (B, K, J)`` of ``runs`` draws."""
    g = seeded_generator(seed, 0)
    K, T, _ = truth.shape
    sd = torch.tensor(SD, dtype=torch.float64)
    seen = torch.rand(runs, K, T, generator=g, dtype=torch.float64) < pd
    zt = truth + torch.randn(runs, K, T, 2, generator=g, dtype=torch.float64) * sd
    count = torch.poisson(torch.full((runs, K), float(clutter), dtype=torch.float64), generator=g).long()
    C = int(count.max())
    u = torch.rand(runs, K, C, 2, generator=g, dtype=torch.float64)
    zc = torch.stack([RANGE_M[0] + (RANGE_M[1] - RANGE_M[0]) * u[..., 0],
                      RATE_MPS[0] + (RATE_MPS[1] - RATE_MPS[0]) * u[..., 1]], -1)
    valid = torch.cat([seen, torch.arange(C) < count[..., None]], 2)
    z = torch.where(valid[..., None], torch.cat([zt, zc], 2), torch.full((), math.nan, dtype=torch.float64))
    return z, valid


def accuracy(est, truth: torch.Tensor) -> dict:
    """Sanity figures of run 0: estimates per scan, and the share of (scan, target) with an
    estimate within 3 deviations on both axes."""
    x, ok = est.x[0], est.exists[0]  # (K, C, 2), (K, C)
    sd = torch.tensor(SD, dtype=torch.float64)
    d = ((torch.nan_to_num(x, nan=1e12)[:, None, :, :] - truth[:, :, None, :]).abs() / sd).amax(-1)  # (K, T, C)
    near = ((d < 3) & ok[:, None, :]).any(-1)
    return {"estimates_per_scan_mean": float(ok.sum(-1).double().mean()),
            "targets_with_estimate_within_3sd": float(near.double().mean()),
            "phd_mass_mean": float(est.expected[0].mean()),
            "particles_after_resampling_mean": float(est.particles[0].double().mean())}


def recursion(phd: SMCPHD, st: PHDState, z: torch.Tensor, valid: torch.Tensor, k0: int, k1: int, g):
    """Our filter's steps without estimates (predict, update, resample; as ``SMCPHD.run``, each scan
    reading only its filled detection columns) over scans ``k0 .. k1 - 1`` of ``z (1, K, J, 2)``
    (NaN-free) from the state after scan ``k0 - 1``; returns the state, the particle counts after
    resampling and the PHD's mass after each update."""
    counts, masses = [], []
    cols = lambda k: valid[0, k].nonzero()[:, 0]
    for k in range(k0, k1):
        prev = (z[:, k - 1, cols(k - 1)], valid[:, k - 1, cols(k - 1)]) if k else (None, None)
        st = phd.predict(st, *prev, g)
        st, _, _ = phd.update(st, z[:, k, cols(k)], valid[:, k, cols(k)])
        masses.append(float(st.w[0].sum()))
        st = phd.resample(st, g)
        counts.append(int((st.w[0] > 0).sum()))
    return st, counts, masses


def others_cpu_seconds() -> float:
    """CPU seconds the whole machine has spent so far (``/proc/stat``: user, nice, system, irq,
    softirq, steal), less this process's own: what other jobs took (NaN off Linux)."""
    try:
        with open("/proc/stat") as f:
            user, nice, system, _idle, _iowait, irq, softirq, steal = (int(v) for v in f.readline().split()[1:9])
    except (OSError, ValueError):
        return math.nan
    t = os.times()
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK") - (t.user + t.system)


def measured(fn, repeats: int, retries: int) -> tuple[float, dict]:
    """:func:`median_seconds` of ``fn``, and the share of the machine's cores other jobs used meanwhile
    (this machine is shared: a figure taken beside another job is not this code's time). A figure
    taken while others used more than 5% is taken again, up to ``retries`` more times; every
    attempt is kept (``attempts``: seconds, share), the figure is the last attempt's."""
    attempts = []
    for _ in range(retries + 1):
        before, t0 = others_cpu_seconds(), time.perf_counter()
        s = median_seconds(fn, repeats)
        wall = time.perf_counter() - t0
        share = max(0.0, (others_cpu_seconds() - before) / (wall * (os.cpu_count() or 1)))  # ticks: 10 ms
        attempts.append([s, share])
        if not share > 0.05:
            break
        print(f"  ({s:.2f} s taken while other jobs used {100 * share:.0f}% of the cores: taken again)")
    return s, {"wall_s": wall, "others_cpu_share": share, "attempts": attempts}


def busy(load: dict) -> str:
    return f" [other jobs: {100 * load['others_cpu_share']:.0f}% of the cores]"


# ---------------------------------------------------------------------------------- Stone Soup


def stone_soup(args, phd: SMCPHD, z: torch.Tensor, valid: torch.Tensor, kappa: float) -> dict:
    try:
        import stonesoup
        from pmsr_nn.interop import stonesoup as ss
        from stonesoup.models.measurement.linear import LinearGaussian
        from stonesoup.models.transition.linear import LinearGaussianTimeInvariantTransitionModel
        from stonesoup.predictor.particle import SMCPHDPredictor
        from stonesoup.resampler.particle import SystematicResampler
        from stonesoup.sampler.particle import ParticleSampler
        from stonesoup.types.array import StateVectors
        from stonesoup.types.detection import MissedDetection
        from stonesoup.types.hypothesis import SingleHypothesis
        from stonesoup.types.multihypothesis import MultipleHypothesis
        from stonesoup.types.state import ParticleState
        from stonesoup.updater.particle import SMCPHDUpdater
    except (ImportError, ConfigError):  # ConfigError: pmsr_nn.interop.stonesoup without Stone Soup
        print("Stone Soup not installed (pip install stonesoup==1.9.1): its comparison is skipped")
        return {"skipped": "stonesoup not installed"}
    # Stone Soup's births are a fixed count per detection: compare with ours on every detection
    phd = SMCPHD(replace(phd.spec, adaptive_birth=False), phd.sd, phd.pd, kappa, DT)
    spec = phd.spec
    k0, n = args.ss_start, args.ss_scans
    k1 = k0 + n
    assert 1 <= k0 and k1 <= z.shape[1], "--ss-start / --ss-scans outside the run"
    z = torch.nan_to_num(z)
    # our particles after scan k0 - 1, then our recursion over the window (timed; its counts set Stone Soup's)
    start, _, _ = recursion(phd, phd.empty(1), z, valid, 0, k0, seeded_generator(args.seed, 3))
    _, counts, ours_masses = recursion(phd, start, z, valid, k0, k1, seeded_generator(args.seed, 4))
    ours_s, ours_load = measured(lambda: recursion(phd, start, z, valid, k0, k1, seeded_generator(args.seed, 4)),
                                 args.repeats, args.retries)

    F, Q, R = phd.F.numpy(), phd.Q.numpy(), np.diag(np.array(SD) ** 2)
    G, sd = phd.G.numpy(), np.array(SD)
    transition = LinearGaussianTimeInvariantTransitionModel(transition_matrix=F, covariance_matrix=Q)
    measurement = LinearGaussian(ndim_state=2, mapping=(0, 1), noise_covar=R)
    when = ss.scan_times(z.shape[1], DT)
    dets = [lists[0] for lists in ss.scan_detections(z[0][:, None], valid[0][:, None], [measurement], DT)]
    rng = np.random.default_rng(args.seed)

    def births(num_samples: int, seeds: np.ndarray) -> np.ndarray:
        """``(2, num_samples)``: ``num_samples / J`` particles around each of ``seeds (J, 2)``, moved one
        step (as ours)."""
        x = seeds[np.arange(num_samples) % len(seeds)] + rng.standard_normal((num_samples, 2)) * sd
        return (x @ F.T + rng.standard_normal((num_samples, 1)) * G).T

    sampler = ParticleSampler(distribution_func=births, params={"seeds": np.zeros((1, 2))}, ndim_state=2)
    predictor = SMCPHDPredictor(transition_model=transition, death_probability=-math.log(spec.survival),
                                birth_probability=0.5, birth_rate=spec.birth_rate, birth_sampler=sampler)
    updater = SMCPHDUpdater(measurement_model=measurement, prob_detect=phd.pd, clutter_intensity=kappa,
                            resampler=SystematicResampler(), num_samples=counts[0])
    keep = start.w[0] > 0
    prior0 = ParticleState(StateVectors(start.x[0][keep].numpy().T.copy()),
                           log_weight=start.w[0][keep].log().numpy().copy(), timestamp=when[k0 - 1])
    masses, births_drawn = [], []

    def ss_window():
        np.random.seed(args.seed)  # SystematicResampler draws from NumPy's global generator
        prior = prior0
        masses.clear(), births_drawn.clear()
        for i, k in enumerate(range(k0, k1)):
            seeds = np.array([d.state_vector.ravel() for d in dets[k - 1]], dtype=float).reshape(-1, 2)
            if len(seeds) == 0:
                raise RuntimeError(f"scan {k - 1} has no detection: Stone Soup's expansion scheme would draw "
                                   "no births (ours adds none either); pick another --ss-start")
            predictor.birth_probability = spec.particles_per_birth * len(seeds) / len(prior)
            sampler.params = {"seeds": seeds}
            prediction = predictor.predict(prior, timestamp=when[k], random_state=rng)
            births_drawn.append(len(prediction) - len(prior))
            hyps = MultipleHypothesis([SingleHypothesis(prediction, MissedDetection(timestamp=when[k]))]
                                      + [SingleHypothesis(prediction, d) for d in dets[k]])
            updater.num_samples = counts[i]
            prior = updater.update(hyps)
            masses.append(float(np.exp(np.logaddexp.reduce(prior.log_weight))))

    ss_s, ss_load = measured(ss_window, args.ss_repeats, args.retries)
    expected_births = [spec.particles_per_birth * int(valid[0, k - 1].sum()) for k in range(k0, k1)]
    out = {"version": stonesoup.__version__, "scans": [k0, k1 - 1], "repeats": args.ss_repeats,
           "stonesoup_s_per_scan": ss_s / n, "ours_recursion_s_per_scan": ours_s / n,
           "ratio_recursion": ss_s / ours_s,
           "particles_after_resampling_mean": statistics.fmean(counts),
           "births_per_scan_mean": statistics.fmean(births_drawn),
           "births_match_ours": births_drawn == expected_births,
           "stonesoup_phd_mass_mean": statistics.fmean(masses), "ours_phd_mass_mean": statistics.fmean(ours_masses),
           "others_cpu_share": {"stonesoup": ss_load["others_cpu_share"], "ours": ours_load["others_cpu_share"]}}
    print(f"Stone Soup {stonesoup.__version__} SMC-PHD, scans {k0}-{k1 - 1}: {ss_s / n * 1e3:.1f} ms per scan "
          f"({out['particles_after_resampling_mean']:.0f} particles after resampling, "
          f"{out['births_per_scan_mean']:.0f} births per scan, PHD mass {out['stonesoup_phd_mass_mean']:.2f}); "
          f"ours, the same recursion from the same particles: {ours_s / n * 1e3:.1f} ms per scan "
          f"(PHD mass {out['ours_phd_mass_mean']:.2f}) "
          f"({out['ratio_recursion']:.0f}x) [other jobs: {100 * ss_load['others_cpu_share']:.0f}% of the cores during "
          f"Stone Soup's, {100 * ours_load['others_cpu_share']:.0f}% during ours]")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scans", type=int, default=700)
    ap.add_argument("--targets", type=int, default=6)
    ap.add_argument("--pd", type=float, default=0.9)
    ap.add_argument("--clutter", type=float, default=10.0, help="mean clutter points per scan")
    ap.add_argument("--births", choices=("adaptive", "every_detection"), default="adaptive",
                    help="the filter's births (PHDSpec.adaptive_birth; every_detection: before issue 37)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--batch", type=int, default=5, help="runs per call of the batched timing")
    ap.add_argument("--seed", type=int, default=2016)
    ap.add_argument("--ss-start", type=int, default=100, help="first scan of the Stone Soup comparison")
    ap.add_argument("--ss-scans", type=int, default=50, help="scans of the Stone Soup comparison")
    ap.add_argument("--ss-repeats", type=int, default=1, help="timed passes of the Stone Soup window")
    ap.add_argument("--retries", type=int, default=2,
                    help="times a figure taken while other jobs used over 5%% of the cores is taken again")
    ap.add_argument("--no-stonesoup", action="store_true")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()

    spec = PHDSpec(adaptive_birth=args.births == "adaptive")
    kappa = args.clutter / ((RANGE_M[1] - RANGE_M[0]) * (RATE_MPS[1] - RATE_MPS[0]))
    phd = SMCPHD(spec, torch.tensor(SD, dtype=torch.float64), args.pd, kappa, DT)
    truth = truths(args.scans, args.targets)
    z1, v1 = draw(truth, 1, args.pd, args.clutter, args.seed)
    zB, vB = draw(truth, args.batch, args.pd, args.clutter, args.seed + 1)
    K, real_time = args.scans, args.scans * DT
    figures = {"threads": torch.get_num_threads(), "scans": K, "targets": args.targets, "pd": args.pd,
               "clutter_per_scan": args.clutter, "clutter_intensity": kappa, "repeats": args.repeats,
               "spec": {k: getattr(spec, k) for k in spec.__dataclass_fields__},
               "detections_per_scan_mean": float(v1.sum(-1).double().mean()),
               "detection_columns_padded": int(v1.shape[-1]), "target_seconds_per_run": real_time / 50}
    print(f"{args.targets} targets, {K} scans, Pd {args.pd}, {args.clutter:g} clutter per scan: "
          f"{figures['detections_per_scan_mean']:.1f} detections per scan, padded to {v1.shape[-1]}; "
          f"{torch.get_num_threads()} threads")

    est = phd.run(z1, v1, seeded_generator(args.seed, 1))
    figures["accuracy"] = accuracy(est, truth)
    a = figures["accuracy"]
    print(f"run 0: {a['estimates_per_scan_mean']:.2f} estimates per scan, "
          f"{100 * a['targets_with_estimate_within_3sd']:.1f}% of targets x scans with an estimate within 3 sd, "
          f"PHD mass {a['phd_mass_mean']:.2f}, {a['particles_after_resampling_mean']:.0f} particles after resampling")

    s, load = measured(lambda: phd.run(z1, v1, seeded_generator(args.seed, 1)), args.repeats, args.retries)
    figures["single"] = {"seconds_per_run": s, "seconds_per_scan": s / K, "real_time_factor": real_time / s,
                         "target_met": s < real_time / 50, **load}
    print(f"ours, one run per call: {s:.2f} s per {K}-scan run, {s / K * 1e3:.1f} ms per scan, "
          f"{real_time / s:.1f}x real time (target: 50x, under {real_time / 50:.0f} s){busy(load)}")

    s, load = measured(lambda: phd.run(zB, vB, seeded_generator(args.seed, 2)), max(1, args.repeats - 1),
                       args.retries)
    s /= args.batch
    load["attempts"] = [[a / args.batch, share] for a, share in load["attempts"]]  # seconds per run
    figures["batched"] = {"runs_per_call": args.batch, "seconds_per_run": s, "seconds_per_scan": s / K,
                          "real_time_factor": real_time / s, "target_met": s < real_time / 50, **load}
    print(f"ours, {args.batch} runs per call: {s:.2f} s per run, {real_time / s:.1f}x real time{busy(load)}")

    label_spec = LabelSpec(method="gtda")

    def with_gtda():
        e = phd.run(z1, v1, seeded_generator(args.seed, 1))
        return label_tracks(e.x, e.P, e.exists, phd.F, phd.Q, label_spec, seeded_generator(args.seed, 5))

    s, load = measured(with_gtda, args.repeats, args.retries)
    labels = int(label_tracks(est.x, est.P, est.exists, phd.F, phd.Q, label_spec,
                              seeded_generator(args.seed, 5)).extras["labels"][0])
    figures["with_gtda"] = {"seconds_per_run": s, "seconds_per_scan": s / K, "real_time_factor": real_time / s,
                            "labelling_seconds": s - figures["single"]["seconds_per_run"], "labels_started": labels,
                            "target_met": s < real_time / 50, **load}
    print(f"ours + GTDA labelling, one run per call: {s:.2f} s per run ({real_time / s:.1f}x real time; "
          f"{labels} labels started){busy(load)}")

    if not args.no_stonesoup:
        ss = stone_soup(args, phd, z1, v1, kappa)
        if "skipped" not in ss:
            ss["ratio"] = ss["stonesoup_s_per_scan"] / figures["single"]["seconds_per_scan"]
            print(f"Stone Soup s per scan / ours (the {K}-scan run, estimates included) s per scan: "
                  f"{ss['ratio']:.0f}x")
        figures["stonesoup"] = ss
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
